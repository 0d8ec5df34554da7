"""Writes results/sessions.md from the runs of scripts/benchmark_sessions.sh.

usage: sessions_report.py OUT
  OUT: the benchmark's folder (a.txt, b.txt, b_alone.txt, added.txt, one.txt, map/).
"""
import os
import sys

from report_common import cores, reproduce_line, value


def row(label, text):
    cells = [label, value(text, r"^keyframes: ([0-9]*) "), value(text, r"^components: ([0-9]*);"),
             value(text, r"^loop closures: ([0-9]*) edges"), value(text, r"^median error: ([0-9.]*) deg"),
             value(text, r"^AUC@2: ([0-9.]*) %"), value(text, r"^bag time: .*wall time: ([0-9.]*) s")]
    return "| " + " | ".join(cells) + " |"


def main():
    out = sys.argv[1]
    read = lambda name: open(os.path.join(out, name)).read()  # noqa: E731
    a, b, b_alone, added, one = (read(n + ".txt") for n in ("a", "b", "b_alone", "added", "one"))
    merged = value(b, r"^median error: ([0-9.]*) deg")
    one_median = value(one, r"^median error: ([0-9.]*) deg")
    kf_a = value(a, r"^keyframes: ([0-9]*) ")
    database = os.path.getsize(os.path.join(out, "map", "graph.txt.keyframes"))
    joined = r"^loaded keyframes when new keyframes joined them \(solve [0-9]*\): (.*)$"
    print("# Two sessions merged into one map")
    print()
    print(reproduce_line("bash scripts/benchmark_sessions.sh"))
    print("""The rendered room and two-camera rig of the demo (config/demo.yaml; 640×480, keyframes as the bags hold
them, one capture per second). Session A: 400 captures, two laps. Session B, the same room another day:
400 captures, two laps, starting a quarter of the loop further on, under other lighting (gain 0.8, 40%
brighter on one side of the room than on the other) and other image noise, replayed with `load_graph` on
the map A saved, and scored over both sessions' keyframes. The reference is one run of 800 captures, four
laps, at the same spacing.""")
    print()
    print("| run | keyframes | components | loop closures | median (deg) | AUC@2 (%) | wall (s) |")
    print("|---|---|---|---|---|---|---|")
    print(row("session A", a))
    print(row("session B, from A's map (A and B scored together)", b))
    print(row("session B alone", b_alone))
    print(row("A's map and B's alone added to it, then 4 captures (A and B scored together)", added))
    print(row("one run of 800 captures", one))
    print()
    print("Merged against one run: median %s° against %s° (%.2f×)." %
          (merged, one_median, float(merged) / float(one_median)))
    print("A's saved map: %.1f KB of keyframe database per keyframe;" % (database / 1024 / float(kf_a)))
    print("%s." % value(b, r"^(map loaded in .* ms):"))
    print("When B's keyframes first joined A's, A's keyframes %s." % value(b, joined))
    print()
    print("B's map alone added to A's (`add_maps`): %s" %
          value(added, r"^ *of them between added maps and the map held: (.*)$"))
    print("loop closures between the two maps, found as it was added (each of B's keyframes retrieved and verified")
    print("against A's, on %d threads). At the first solve, A's keyframes %s;" % (cores(), value(added, joined)))
    print("B's map, saved in a frame a quarter turn from A's, was placed in A's frame.")


if __name__ == "__main__":
    main()
