"""Writes results/restart.md from the runs of scripts/benchmark_restart.sh.

usage: restart_report.py OUT CUT...
  OUT: the benchmark's folder (full.txt, before_N.txt, after_N.txt, map_N/); CUT: the captures after which
  the node was restarted.
"""
import os
import sys

from report_common import cores, reproduce_line, value


def main():
    out, cuts = sys.argv[1], sys.argv[2:]
    read = lambda name: open(os.path.join(out, name)).read()  # noqa: E731
    full = read("full.txt")
    full_median = value(full, r"^median error: ([0-9.]*) deg")
    print("# Restarts: the map saved and loaded")
    print()
    print(reproduce_line("bash scripts/benchmark_restart.sh"))
    print("""The demo bag (60 captures of the rendered two-camera rig, once round the room; config/demo.yaml) cut
after the capture of each row: the part before it replayed with `save_on_shutdown` (the map: graph,
`.rig`, `.keyframes`), the part after it with `load_graph` on that map, as a node killed there and
restarted would (`rotation_averaging_replay` runs the node's pipeline; docs/node.md, "The map across
restarts and sessions"). Components, keyframes and accuracy are those of the second replay, over every
keyframe of both parts; the uninterrupted replay of the whole bag is the reference. "Moved at load": the
largest angle between a saved keyframe's orientation in the map file and at the first solve after loading
(the frames published before the restart). "Moved at the merge": the largest move of a saved keyframe
from there to the first solve that joined a new keyframe to them, in degrees and in that keyframe's
posterior standard deviation along the move (relative to the gauge keyframe, which the solve holds where
it was published), and the rotation of their frame as a whole (the one rotation that best maps them from
before to after: a new gauge would turn it by degrees).""")
    print()
    print("| restart after capture | keyframes before / after the restart | keyframes in the final map | components "
          "| loop closures after the restart | median (deg) | median / uninterrupted | moved at load (deg) "
          "| moved at the merge (deg / std) | frame rotated at the merge (deg) | database per keyframe (KB) "
          "| save (ms) | load (ms) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    print("| none (uninterrupted) | - | %s | %s | %s | %s | 1.00 | - | - | - | - | - | - |" %
          (value(full, r"^keyframes: ([0-9]*) "), value(full, r"^components: ([0-9]*);"),
           value(full, r"^loop closures: ([0-9]*) edges"), full_median))
    for n in cuts:
        before, after = read("before_%s.txt" % n), read("after_%s.txt" % n)
        kf_before = value(before, r"^keyframes: ([0-9]*) ")
        median = value(after, r"^median error: ([0-9.]*) deg")
        db_bytes = os.path.getsize(os.path.join(out, "map_%s" % n, "graph.txt.keyframes"))
        cells = [
            n,
            "%s / %s" % (kf_before, value(after, r"^keyframes: .* \(([0-9]*) images through")),
            value(after, r"^keyframes: ([0-9]*) "),
            value(after, r"^components: ([0-9]*);"),
            value(after, r"^loop closures: ([0-9]*) edges"),
            median,
            "%.2f" % (float(median) / float(full_median)),
            value(after, r"^loaded keyframes at the first solve: moved at most ([0-9.]*) deg"),
            "%s / %s" % (value(after, r"^loaded keyframes when .*moved at most ([0-9.]*) deg, "),
                         value(after, r"^loaded keyframes when .* deg, ([0-9.]*) posterior")),
            value(after, r"^loaded keyframes when .*rotated by ([0-9.]*) deg$"),
            "%.1f" % (db_bytes / 1024 / float(kf_before)),
            value(before, r"^map saved in ([0-9.]*) ms"),
            value(after, r"^map loaded in ([0-9.]*) ms"),
        ]
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
