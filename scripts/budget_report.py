"""Writes results/budget.md from the runs of scripts/benchmark_budget.sh.

usage: budget_report.py OUT CAMERAS
  CAMERAS: the camera counts of the 20 Hz stream rows, comma separated.
"""
import csv
import math
import os
import re
import sys

from report_common import reproduce_line, value

TIME = r"median ([\d.]+) ms, p95 ([\d.]+) ms \(of (\d+)\)"


def budget(text):
    """(median, p95, count) per image, per keyframe and per pair, as strings, from a replay summary."""
    missing = ("-",) * 3
    image = re.search(r"^time per image \(decoding, checks, keyframe selection\): " + TIME, text, re.M)
    keyframe = re.search(r"^time per keyframe \(front end\): " + TIME, text, re.M)
    pair = re.search(r"^time per keyframe .*; per two-view pair: " + TIME, text, re.M)
    return tuple(m.groups() if m else missing for m in (image, keyframe, pair))


def counted_times(text, pattern):
    """"count, median / p95 ms" of the times after `pattern` in a replay summary; "-" without them."""
    m = re.search(pattern + TIME, text, re.M)
    return "%s, %s / %s" % (m.group(3), m.group(1), m.group(2)) if m else "-"


def focal_check(text):
    """The camera_info check's estimates: counted_times."""
    return counted_times(text, r"^time per camera_info check estimate .*?: ")


def refinements(text):
    """The background refinement's runs (bundle adjustments): counted_times."""
    return counted_times(text, r"^refinement \(bundle adjustment .*?time per refinement: ")


def quantile(sorted_values, q):
    """Nearest rank, as TimeDistribution::Quantile."""
    if not sorted_values:
        return float("nan")
    rank = math.ceil(q * len(sorted_values))
    return sorted_values[max(rank, 1) - 1]


def stream_row(cameras, text, unrefined):
    i, k, p = budget(text)
    keyframes = int(value(text, r"^keyframes: (\d+) ", "0"))
    pairs = int(p[2]) if p[2] != "-" else 0
    cells = [
        str(cameras),
        value(text, r"^keyframe selection \([a-z]+\): (\d+) images", "-"),
        str(keyframes),
        value(text, r"\(([\d.]+)x real time\)", "-") + "x",
        value(unrefined, r"\(([\d.]+)x real time\)", "-") + "x",
        "%s / %s" % (i[0], i[1]),
        "%s / %s" % (k[0], k[1]),
        "%s / %s" % (p[0], p[1]),
        "%.1f" % (pairs / keyframes) if keyframes else "-",
        focal_check(text),
        refinements(text),
        value(text, r"^median error: ([\d.]+) deg", "-"),
        value(unrefined, r"^median error: ([\d.]+) deg", "-"),
    ]
    return "| " + " | ".join(cells) + " |"


def keyframe_bins(path, width):
    """Per-keyframe front-end time (total_ms of frontend_cost.csv) in bins of `width` keyframes: rows."""
    with open(path) as f:
        totals = [float(r["total_ms"]) for r in csv.DictReader(f)]
    rows = []
    for start in range(0, len(totals), width):
        part = sorted(totals[start:start + width])
        rows.append("| %d-%d | %.1f | %.1f |" % (start + 1, start + len(part), quantile(part, 0.5), quantile(part, 0.95)))
    return rows


def main():
    out, cameras = sys.argv[1], sys.argv[2].split(",")
    print("# The time budget: per image, per keyframe, per pair\n")
    print(reproduce_line("bash scripts/benchmark_budget.sh"))
    print("""Where the node's time goes, as the replay's summary and the node's diagnostics report it: per valid
image, its decoding, checks and keyframe selection (what its callback costs); per keyframe, the front end
(`ProcessKeyframe`: features, retrieval, the two-view pairs, the edges), wall time; per two-view pair, its
matching and estimation on the thread that ran it. Medians and 95th percentiles in ms (nearest rank).
The replay runs the node's pipeline as fast as the CPU allows: speed-up = bag duration / wall time. With
the defaults the background refinement (`refinement: true`) bundle adjusts the newest keyframes on a
thread of its own, by bag time, the replay taking each refinement when the next is due and refining its
final solution once more (and, where the keyframes outnumber the window, sweeping back over the rest:
`refinement_sweep_back`, which the node does once its input is quiet): its time is in the speed-up, and each
bag is also replayed with `refinement: false` (the front end and the averaging alone). The per-image, per-keyframe and per-pair times are those of
the run with the defaults.

## Against the camera count

The demo renderer's rig as a 20 Hz driver publishes it (`rotation_averaging_make_demo_bag --captures 600
--period 0.05 --cameras N`: 30 s, one loop of the room), `keyframe_selection: motion` (config/demo.yaml
otherwise). A keyframe's pairs: its previous keyframe and the window (`window_pairs`), loop candidates, and
the cameras of its capture whose extrinsics are not known. The camera_info check (`focal_calibration:
apply`, the default) estimates each camera's focal length on a thread of its own at 20, 40, 80, ... of its
pairs; the replay waits for each estimate (the node runs it beside its front end). A refinement's time is
that of one run of it on its own thread: the bundle adjustment of its window, its covariance included.

| cameras | images | keyframes | speed-up | speed-up, `refinement: false` | per image (ms): median / p95 | per keyframe (ms): median / p95 | per pair (ms): median / p95 | pairs per keyframe | camera_info check: estimates, ms median / p95 | refinement: runs, ms median / p95 | median error (deg) | median error, `refinement: false` (deg) |
|---|---|---|---|---|---|---|---|---|---|---|---|---|""")
    for n in cameras:
        text = open(os.path.join(out, "stream_%scam.txt" % n)).read()
        unrefined = open(os.path.join(out, "stream_%scam_unrefined.txt" % n)).read()
        print(stream_row(n, text, unrefined))
    long_text = open(os.path.join(out, "every_image_300.txt")).read()
    long_unrefined = open(os.path.join(out, "every_image_300_unrefined.txt")).read()
    i, k, p = budget(long_text)
    print("""
## Against the keyframe count

A 1 Hz two-camera bag whose every image is a keyframe (`--captures 300 --cameras 2`, config/demo.yaml:
600 keyframes; %s real time, %s with `refinement: false`; per keyframe median %s ms, p95 %s ms; per pair
median %s ms, p95 %s ms over %s pairs; refinements, runs and ms median / p95: %s). The front end's time per keyframe in bins of 100 keyframes in arrival
order (the replay's frontend_cost.csv): whether it grows with the map, where retrieval and the loop
candidates it verifies could make it grow.

| keyframes | median (ms) | p95 (ms) |
|---|---|---|""" % (value(long_text, r"\(([\d.]+x) real time\)", "-"),
                  value(long_unrefined, r"\(([\d.]+x) real time\)", "-"), k[0], k[1], p[0], p[1], p[2],
                  refinements(long_text)))
    for r in keyframe_bins(os.path.join(out, "every_image_300", "frontend_cost.csv"), 100):
        print(r)


if __name__ == "__main__":
    main()
