"""Writes results/map.md from the runs of scripts/benchmark_map.sh.

usage: map_report.py OUT
  OUT: the benchmark's folder (replay.txt: the demo's replay that saved the map; table.md: rotavg_map_benchmark's
  table).
"""
import os
import sys

from report_common import reproduce_line, value


def main():
    out = sys.argv[1]
    keyframes = value(open(os.path.join(out, "replay.txt")).read(), r"^keyframes: ([0-9]*) ").split("\n")[0]
    print("# The saved map at the size of a robot's")
    print()
    print(reproduce_line("bash scripts/benchmark_map.sh"))
    print("""The keyframes of the demo's saved map (%s
keyframes: 640×480 images, SIFT, config/demo.yaml) repeated under new stamps to each size, with a view graph
that chains them (`rotavg_map_benchmark`). Through the node's pipeline: the keyframe database on disk;
loading the database alone (read, checksum, every keyframe checked, inverted index built) and the whole map
(`load_graph`: graph, first solve, database), first as a node starting up loads it, then again (median of 2
more loads: the process's memory is mapped by then, which is what the first load spends beyond them);
saving the map as autosave does (median of 5), and how long the save held the graph (a solve waits that
long) and the front end (a new keyframe waits that long); the files are written after those copies, outside
both. Files are read from the page cache (just written): a cold start reads them from the disk first. Peak
memory is the process's, cumulative over the rows.""" % keyframes)
    print()
    print(open(os.path.join(out, "table.md")).read().rstrip("\n"))


if __name__ == "__main__":
    main()
