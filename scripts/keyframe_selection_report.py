"""Writes results/keyframe_selection.md from the runs of scripts/benchmark_keyframe_selection.sh.

usage: keyframe_selection_report.py OUT SETTINGS SEEDS
  SETTINGS: "motion/tracked" thresholds of the stream rows, comma separated (e.g. "3/0.6,8/0.4");
  the row of the defaults is marked. SEEDS: the noise seeds of the realisation rows, comma separated.
"""
import os
import statistics
import sys

from report_common import reproduce_line, value

DEFAULT_SETTING = "8/0.4"


def row(label, text):
    images = value(text, r"^keyframe selection \([a-z]+\): (\d+) images")
    if not images:
        images = value(text, r"^keyframes: .* \((\d+) images through", "-")
    cells = [
        label, images,
        value(text, r"^keyframes: (\d+) ", "-"),
        value(text, r"^solved variables: (\d+) ", "-"),
        value(text, r" not keyframes; ([\d.]+) ms per image$", "-"),
        value(text, r"wall time: ([\d.]+) s", "-"),
        value(text, r"\(([\d.]+)x real time\)", "-") + "x",
        value(text, r"^median error: ([\d.]+) deg", "-"),
        value(text, r"^AUC@2: ([\d.]+) %", "-"),
    ]
    return "| " + " | ".join(cells) + " |"


def read(out, name):
    return open(os.path.join(out, name + ".txt")).read()


def median_of(text):
    return float(value(text, r"^median error: ([\d.]+) deg", "nan"))


def main():
    out, settings, seeds = sys.argv[1], sys.argv[2].split(","), sys.argv[3].split(",")
    print("# Keyframe selection on a raw stream")
    print()
    print(reproduce_line("bash scripts/benchmark_keyframe_selection.sh"))
    print("The demo renderer's rig (two cameras 90 deg apart, 640x480, one loop of the room in 60 s) as a")
    print("camera driver publishes it, 20 captures per second (`rotation_averaging_make_demo_bag --captures 1200")
    print("--period 0.05`), replayed with `keyframe_selection: motion` at the thresholds of each row")
    print("(`keyframe_min_motion_deg` / `keyframe_min_tracked_fraction`; config/demo.yaml otherwise); the first")
    print("row is the 1 Hz demo bag, whose every image is a keyframe (`keyframe_selection: all`). Accuracy over")
    print("the keyframes (the ground truth of images that were not keyframes is not scored); speed-up = bag")
    print("duration / wall time of the replay, which runs the node's pipeline as fast as the CPU allows.")
    print()
    print("| input | images | keyframes | rig captures solved | selection ms per image | wall (s) | speed-up "
          "| median (deg) | AUC@2 |")
    print("|---|---|---|---|---|---|---|---|---|")
    print(row("1 Hz demo bag, every image a keyframe", read(out, "demo_1hz")))
    for setting in settings:
        motion, tracked = setting.split("/")
        label = "20 Hz stream, %s deg / %s" % (motion, tracked)
        if setting == DEFAULT_SETTING:
            label += " (defaults)"
        print(row(label, read(out, "stream_%s_%s" % (motion, tracked))))
    print(row("1 Hz demo bag, `window_pairs: false`", read(out, "demo_1hz_chain")))
    print(row("20 Hz stream, defaults but `window_pairs: false`", read(out, "stream_chain")))
    print()
    print("`window_pairs: true` (the default) relates each keyframe also to the older keyframes of its window "
          "(results/replay.md, \"Window pairs\"): two more pairs per keyframe; the last two rows relate it to the "
          "previous one alone.")
    print()
    print("## Over noise realisations")
    print()
    print("One bag's median is one draw of the renderer's pixel noise. The same scenes rendered again with")
    print("other noise (`--noise-seed`; seed 1 is the bags above), the 20 Hz stream replayed with the default")
    print("thresholds: the spread between seeds is the scale on which the two inputs can be compared.")
    print()
    print("| noise seed | 1 Hz demo: median (deg) | 20 Hz stream: keyframes | 20 Hz stream: median (deg) "
          "| 1 Hz demo, `window_pairs: false` | 20 Hz stream, `window_pairs: false` |")
    print("|---|---|---|---|---|---|")
    columns = ([], [], [], [])
    for seed in seeds:
        runs = [read(out, "seed%s_%s" % (seed, name)) for name in ("1hz", "stream", "1hz_chain", "stream_chain")]
        for column, text in zip(columns, runs):
            column.append(median_of(text))
        print("| %s | %s | %s | %s | %s | %s |" % (
            seed, value(runs[0], r"^median error: ([\d.]+) deg", "-"), value(runs[1], r"^keyframes: (\d+) ", "-"),
            value(runs[1], r"^median error: ([\d.]+) deg", "-"), value(runs[2], r"^median error: ([\d.]+) deg", "-"),
            value(runs[3], r"^median error: ([\d.]+) deg", "-")))
    spread = ["%.4f (%.4f - %.4f)" % (statistics.mean(c), min(c), max(c)) for c in columns]
    print("| mean (min - max) | %s | | %s | %s | %s |" % tuple(spread))
    print()
    print("## The 20 Hz stream with the defaults")
    print()
    print("```")
    motion, tracked = DEFAULT_SETTING.split("/")
    print(read(out, "stream_%s_%s" % (motion, tracked)).rstrip())
    print("```")


if __name__ == "__main__":
    main()
