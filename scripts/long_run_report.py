"""Writes results/long_run.md from the runs of scripts/benchmark_long_run.sh.

usage: long_run_report.py OUT
  OUT: the benchmark's folder (long.txt, laps.txt, demo.txt, demo_voting.txt, mid.txt, long_pixel60.txt,
  mid_pixel60.txt, long_all_loops.txt, mid_all_loops.txt and laps/graph.txt).
"""
import os
import re
import sys

from report_common import first, reproduce_line

RUNS = ("long", "laps", "demo", "demo_voting", "mid", "long_pixel60", "mid_pixel60", "long_all_loops", "mid_all_loops")
LAP_CAPTURES, FIRST_STAMP_S, LAPS = 60, 1000, 3  # the three-lap bag: 60 captures per lap, stamps from 1000 s


def row(label, text):
    cells = [label, first(text, r"^keyframes: ([0-9]*) "), first(text, r"\(([0-9.]*)x real time\)") + "x",
             first(text, r"retrieval ([0-9.]*) ms"), first(text, r"pair verification ([0-9.]*) ms"),
             first(text, r"peak memory: ([0-9.]*) MiB"), first(text, r"compact, ([0-9.]*) KB each"),
             first(text, r"^loop closures: ([0-9]*) edges"), first(text, r"^median error: ([0-9.]*) deg$"),
             first(text, r"^AUC@2: ([0-9.]*) %$")]
    return "| " + " | ".join(cells) + " |"


def lap_rows(graph):
    """Loop closures by the lap of their newer keyframe, and how many reach an earlier lap."""
    lap, count, across = {}, [0] * LAPS, [0] * LAPS
    for line in open(graph).read().splitlines():
        parts = line.split()
        if len(parts) >= 3 and parts[0] == "VIEW":
            stamp_s = int(parts[2].split("@")[1]) / 1e9
            lap[parts[1]] = int((stamp_s - FIRST_STAMP_S) / LAP_CAPTURES)
        elif len(parts) >= 4 and parts[0] == "EDGE" and parts[3] == "loop_closure":
            a, b = lap[parts[1]], lap[parts[2]]
            newer, older = max(a, b), min(a, b)
            if 0 <= newer < LAPS:
                count[newer] += 1
                across[newer] += older < newer
    return ["| %d | %d | %d |" % (l + 1, count[l], across[l]) for l in range(LAPS)]


def main():
    out = sys.argv[1]
    text = {name: open(os.path.join(out, name + ".txt")).read() for name in RUNS}
    print("# Long image runs")
    print()
    print(reproduce_line("bash scripts/benchmark_long_run.sh"))
    print("""Each bag goes through `rotation_averaging_replay` with `config/demo.yaml` (the node's pipeline and
defaults: SIFT, 1500 features, retrieval with the default vocabulary, two loop candidates per keyframe,
MAGSAC + covariance averaging re-solved every second of bag time). Bags hold one capture of two cameras
per second; speed = bag time / wall time. Retrieval and pair verification are wall time per keyframe.""")
    print()
    print("| run | keyframes | speed | retrieval (ms) | pair verification (ms) | peak memory (MiB) | compact keyframe "
          "(KB) | loop closures | median error (deg) | AUC@2 (%) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, label in (("long", "400 captures, one lap"), ("laps", "180 captures, three laps"),
                        ("demo", "60 captures (the demo)"),
                        ("demo_voting", "60 captures, voting over every keyframe (`vocabulary: none`)"),
                        ("mid", "200 captures, one lap"),
                        ("long_pixel60", "400 captures, loop closures with the pixel model at 60 inliers"),
                        ("mid_pixel60", "200 captures, the same"),
                        ("long_all_loops", "400 captures, every loop kept (`one_loop_per_place: false`)"),
                        ("mid_all_loops", "200 captures, the same")):
        print(row(label, text[name]))
    print()
    print("""The pixel-model rows: loop closures on the pixel model's covariance (`loop_jackknife_grid: 0`)
at `min_loop_inliers: 60`, against the defaults (the cell jackknife's covariance at 40; results/README.md,
"Loop closures and their covariances"). The last two rows: every loop closure kept, against the default of
one per place (docs/decisions.md, "One loop closure per place").""")
    print()
    print("## Cost per keyframe against the keyframe count (400 captures)")
    print()
    print("""Front-end wall time of each keyframe, means of 20 (`frontend_cost.csv` of the replay has every
keyframe): ![front-end cost](plots/long_run_frontend_cost.png)""")
    print()
    print("```")
    cost = re.compile(r"^(front-end cost per keyframe|front end per keyframe|front-end memory|loop closures|"
                      r"two-view pairs)")
    for line in text["long"].splitlines():
        if cost.match(line):
            print(line)
    print("```")
    print()
    print("## Loop closures on every lap (three laps)")
    print()
    print("Loop-closure edges by the lap of their newer keyframe, and of them those to a keyframe of an earlier lap:")
    print()
    print("| lap | loop closures | to an earlier lap |")
    print("|---|---|---|")
    for line in lap_rows(os.path.join(out, "laps", "graph.txt")):
        print(line)
    print()
    print("## Summaries")
    for name in RUNS:
        print()
        print("### %s" % name)
        print()
        print("```")
        lines = text[name].splitlines()
        if "outputs:" in lines:
            lines = lines[:lines.index("outputs:")]
        print("\n".join(lines))
        print("```")


if __name__ == "__main__":
    main()
