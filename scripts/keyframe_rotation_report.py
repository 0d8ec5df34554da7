"""Writes results/keyframe_rotation.md from the runs of scripts/benchmark_keyframe_rotation.sh.

usage: keyframe_rotation_report.py OUT PHOTOS STREAMS ROTATIONS [EUROC_MAV0 [SEEDS]]
  PHOTOS: the photograph scenes, STREAMS: the 20 Hz streams' capture counts, ROTATIONS: the thresholds
  (keyframe_min_rotation_deg) of each row; all comma separated. The default's rows are marked. EUROC_MAV0: the
  EuRoC excerpt's mav0 folder (its calibration), for the stereo rows. SEEDS: the noise seeds of the one-camera
  rows, comma separated.
"""
import os
import sys

import numpy as np

from camera_models_report import body_from_camera, stereo_errors
from report_common import reproduce_line, value

DEFAULT_ROTATION = "6"


def read(out, name):
    path = os.path.join(out, name + ".txt")
    return open(path).read() if os.path.exists(path) else ""


def label(rotation):
    if rotation == "0":
        return "0 (motion and tracking alone)"
    return rotation + (" (default)" if rotation == DEFAULT_ROTATION else "")


def made(text, reason):
    return value(text, r"^  keyframes made: .*?(\d+) " + reason + r"[,;]", "0")


def cells(text):
    return [
        value(text, r"^keyframes: (\d+) ", "-"),
        made(text, "by motion"), made(text, "by rotation"), made(text, "by tracks lost"),
        value(text, r"\(([\d.]+)x real time\)", "-") + "x",
        value(text, r"^time per image \(decoding, checks, keyframe selection\): median ([\d.]+ ms)", "-"),
        value(text, r"^  rotation checks \(keyframe_min_rotation_deg\): (\d+), ", "0"),
        value(text, r"^  rotation checks \(keyframe_min_rotation_deg\): \d+, ([\d.]+) ms each", "-"),
        value(text, r"^median error: ([\d.]+) deg", "-"),
        value(text, r"^AUC@2: ([\d.]+) %", "-"),
    ]


def table(out, rows):
    lines = ["| input | keyframe_min_rotation_deg | keyframes | by motion | by rotation | by tracks lost | speed-up "
             "| per image (median) | rotation checks | ms per check | median (deg) | AUC@2 |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, what, setting in rows:
        text = read(out, name)
        if text:
            lines.append("| " + " | ".join([what, setting] + cells(text)) + " |")
    return "\n".join(lines)


def euroc_rows(out, rotations, mav0):
    """The EuRoC rows: each capture's solved cam0 -> cam1 rotation against the calibration's."""
    r10 = body_from_camera(os.path.join(mav0, "cam1/sensor.yaml")).T @ body_from_camera(
        os.path.join(mav0, "cam0/sensor.yaml"))
    lines = ["| keyframe_min_rotation_deg | keyframes | by rotation | cam0 -> cam1: median error (deg) | max (deg) |",
             "|---|---|---|---|---|"]
    for r in rotations:
        text = read(out, "euroc_rot" + r)
        orientations = os.path.join(out, "euroc_rot" + r, "orientations.csv")
        if not text or not os.path.exists(orientations):
            continue
        errors = stereo_errors(orientations, r10)
        lines.append("| %s | %s | %s | %.4f | %.4f |" % (label(r), value(text, r"^keyframes: (\d+) ", "-"),
                                                      made(text, "by rotation"), float(np.median(errors)),
                                                      float(errors.max())))
    return lines


def one_camera_rows(out, seeds):
    """Keyframes and median per seed without the rotation (0) and with the default, and their means."""
    runs = [(s, read(out, "one_camera_seed%s_rot0" % s), read(out, "one_camera_seed%s_rot%s" % (s, DEFAULT_ROTATION)))
            for s in seeds]
    runs = [r for r in runs if r[1] and r[2]]
    if not runs:
        return []
    lines = ["| noise seed | keyframes, 0 | median (deg), 0 | keyframes, %s (default) | by rotation | median (deg), %s |"
             % (DEFAULT_ROTATION, DEFAULT_ROTATION), "|---|---|---|---|---|---|"]
    medians = ([], [])
    for seed, without, with_rotation in runs:
        cells = [seed]
        for i, text in enumerate((without, with_rotation)):
            cells.append(value(text, r"^keyframes: (\d+) ", "-"))
            if i == 1:
                cells.append(made(text, "by rotation"))
            median = value(text, r"^median error: ([\d.]+) deg", "-")
            cells.append(median)
            if median != "-":
                medians[i].append(float(median))
        lines.append("| " + " | ".join(cells) + " |")
    if all(medians):
        lines.append("| mean | | %.4f | | | %.4f |" % (sum(medians[0]) / len(medians[0]),
                                                      sum(medians[1]) / len(medians[1])))
    return lines


def main():
    out, photos, streams, rotations = sys.argv[1], sys.argv[2].split(","), sys.argv[3].split(","), \
        sys.argv[4].split(",")
    photos = [p for p in photos if p]
    print("# Keyframes by the camera's rotation")
    print()
    print(reproduce_line("bash scripts/benchmark_keyframe_rotation.sh"))
    print("With `keyframe_selection: motion` a frame becomes a keyframe when the corners tracked from its camera's")
    print("last keyframe moved by a median of `keyframe_min_motion_deg` (8), when fewer than")
    print("`keyframe_min_tracked_fraction` (0.4) of them are still tracked, and, with `keyframe_min_rotation_deg`,")
    print("when the rotation the same corners show (essential matrix, or the rotation-only model where it explains")
    print("them; the corners placed again at full resolution) reaches it, checked at most every 0.2 s of a camera's")
    print("stamps. Accuracy over the keyframes (the ground truth of images that were not keyframes is not")
    print("scored); speed-up = bag duration / wall time of the replay, which runs the node's pipeline as fast as the")
    print("CPU allows.")
    print()
    if photos:
        print("## Photographs as a camera stream")
        print()
        print("Each scene's images in order, one a second, at a quarter of full width (`rotation_averaging_images_to_bag")
        print("--downsample 0.25`), one camera; `all`: every image a keyframe. The camera circles the facade or the door")
        print("it looks at: it turns between photographs while the corners on what it looks at move less.")
        print()
        rows = []
        for p in photos:
            rows.append((p + "_all", p, "every image (`keyframe_selection: all`)"))
            rows += [(p + "_rot" + r, p, label(r)) for r in rotations]
        print(table(out, rows))
        print()
    print("## The renderer's rig as a 20 Hz stream")
    print()
    print("The demo renderer's two-camera rig as a 20 Hz driver publishes it (`rotation_averaging_make_demo_bag")
    print("--captures N --period 0.05`: one loop of the room in N / 20 s), config/demo.yaml with")
    print("`keyframe_selection: motion`.")
    print()
    rows = []
    for s in streams:
        rows += [("stream%s_rot%s" % (s, r), "%s captures (%d s)" % (s, int(s) // 20), label(r)) for r in rotations]
    print(table(out, rows))
    print()
    seeds = [s for s in (sys.argv[6] if len(sys.argv) > 6 else "").split(",") if s]
    one_camera = one_camera_rows(out, seeds)
    if one_camera:
        print("## One camera, three noise seeds")
        print()
        print("The rig's forward camera alone over one loop in 30 s (`--cameras 1 --noise-seed N`), as above. One")
        print("camera's median moves by a factor of two between noise seeds: compare the means.")
        print()
        print("\n".join(one_camera))
        print()
    mav0 = sys.argv[5] if len(sys.argv) > 5 else ""
    euroc = euroc_rows(out, rotations, mav0) if os.path.isdir(mav0) else []
    if len(euroc) > 2:
        print("## EuRoC V1_01: a real raw stereo stream")
        print()
        print("`rotation_averaging_images_to_bag --euroc` on `euroc_v1_01_micro/mav0` (95 captures of cam0 and cam1 at")
        print("20 Hz, the vehicle standing still), `keyframe_max_interval_s: 0.5`, `use_rig_extrinsics: false`: no")
        print("rotation to make keyframes by.")
        print()
        print("\n".join(euroc))


if __name__ == "__main__":
    main()
