"""Writes results/tracks.md from the runs of scripts/benchmark_tracks.sh.

usage: tracks_report.py OUT EUROC_MAV0 SEEDS
  SEEDS: the noise seeds of the two-camera stream, comma separated (the first is the stream of the camera rows).
"""
import os
import statistics
import sys

import numpy as np

from budget_report import budget
from camera_models_report import body_from_camera, stereo_errors
from report_common import reproduce_line, value


def read(out, name):
    path = os.path.join(out, name + ".txt")
    return open(path).read() if os.path.exists(path) else ""


def track_pairs(text):
    return value(text, r"^tracks: (\d+) pairs estimated from shared KLT tracks", "0")


def stream_row(cameras, tracks, text):
    i, k, p = budget(text)
    cells = [
        str(cameras), "`%s`" % tracks,
        value(text, r"^keyframes: (\d+) ", "-"),
        value(text, r"\(([\d.]+)x real time\)", "-") + "x",
        "%s / %s" % (i[0], i[1]),
        "%s / %s" % (k[0], k[1]),
        "%s / %s" % (p[0], p[1]),
        track_pairs(text),
        value(text, r"^median error: ([\d.]+) deg", "-"),
        value(text, r"^posterior covariances against the ground truth: NEES median ([\d.]+)", "-"),
    ]
    return "| " + " | ".join(cells) + " |"


def median_of(text):
    found = value(text, r"^median error: ([\d.]+) deg", "")
    return float(found) if found else None


def main():
    out, mav0, seeds = sys.argv[1], sys.argv[2], [s for s in sys.argv[3].split(",") if s]
    print("# KLT tracks against descriptor matching")
    print()
    print(reproduce_line("bash scripts/benchmark_tracks.sh"))
    print("With `tracks: true` keyframe selection tracks every image of each camera by KLT at full")
    print("resolution (forward-backward checked, replenished at a minimum spacing), and a keyframe's pairs with the")
    print("earlier keyframes of its camera's window come from the tracks they share, re-tracked between the two")
    print("images, by the same estimation with covariance and the same checks as matched SIFT features; loop")
    print("closures, rig pairs and pairs whose tracks do not verify are matched by descriptors. `tracks: false` (the")
    print("default): selection by a KLT on images reduced to 320 px, and every pair matched by descriptors.")
    print()
    print("## How precisely a point is placed")
    print()
    print("`rotavg_track_precision`: a 640x480 view (f = 420 px) of a real photograph, or of the renderer's room,")
    print("turning on the spot by 0.8 deg per image about two axes; image t is image 0 moved by the homography")
    print("K R_t K^-1 (exact for a turning camera), with fresh grey-level noise (sigma 2). For each number of images")
    print("between the pair: the tracks that lasted (*tracked*: followed from image to image), the same points")
    print("re-tracked between the two images through the homography the tracks fit (*re-tracked*, as the front end")
    print("does), and SIFT matched between the two (1500 features, ratio test and mutual check; matches more than 3 px")
    print("off are wrong ones and not counted); each with its count and the median distance from the truth.")
    print()
    print(open(os.path.join(out, "precision.md")).read().rstrip())
    print()
    print("A track's point drifts as it is followed (each step's error adds up, and KLT's window does not deform")
    print("with the view): over a keyframe's 8 deg it is no more precise than a SIFT keypoint. Re-tracked between the")
    print("two images it is several times more precise, on the photographs as on the renderer; SIFT matches two to")
    print("three times as many points.")
    print()
    print("## The node on a 20 Hz stream")
    print()
    print("The demo renderer's rig as a 20 Hz driver publishes it (`rotation_averaging_make_demo_bag --captures 600")
    print("--period 0.05 --cameras N`: 30 s, one loop of the room), `keyframe_selection: motion`, config/demo.yaml")
    print("otherwise. Times in ms, median / 95th percentile (as results/budget.md); *track pairs*: pairs estimated from")
    print("shared tracks; NEES: the published posterior covariances against the truth (2.37 if honest).")
    print()
    print("| cameras | tracks | keyframes | speed-up | per image | per keyframe | per pair | track pairs | median (deg) | NEES median |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for cameras in (1, 2, 4):
        for tracks in ("true", "false"):
            text = read(out, "stream_%dcam_tracks_%s" % (cameras, tracks))
            if text:
                print(stream_row(cameras, tracks, text))
    print()
    print("## Over noise realisations")
    print()
    print("One bag's median is one draw of the renderer's pixel noise: the two-camera stream rendered with other")
    print("noise (`--noise-seed`; seed %s is the stream above)." % seeds[0])
    print()
    print("| noise seed | `tracks: true`: median (deg) | speed-up | `tracks: false`: median (deg) | speed-up |")
    print("|---|---|---|---|---|")
    medians = {"true": [], "false": []}
    for seed in seeds:
        texts = {t: read(out, ("stream_2cam_tracks_%s" % t) if seed == seeds[0] else ("seed%s_tracks_%s" % (seed, t)))
                 for t in ("true", "false")}
        cells = [seed]
        for t in ("true", "false"):
            m = median_of(texts[t])
            if m is not None:
                medians[t].append(m)
            cells += [value(texts[t], r"^median error: ([\d.]+) deg", "-"),
                      value(texts[t], r"\(([\d.]+)x real time\)", "-") + "x"]
        print("| " + " | ".join(cells) + " |")
    if medians["true"] and medians["false"]:
        print("| mean (min - max) | %.4f (%.4f - %.4f) | | %.4f (%.4f - %.4f) | |" % (
            statistics.mean(medians["true"]), min(medians["true"]), max(medians["true"]),
            statistics.mean(medians["false"]), min(medians["false"]), max(medians["false"])))
    slow = [(label, read(out, name)) for label, name in (
        ("`true`", "slow_tracks_true"), ("`false`", "slow_tracks_false"),
        ("`true`, pairs matched by descriptors (`min_track_matches: 1000000`)", "slow_tracks_selection"))]
    if any(text for _, text in slow):
        print()
        print("## At half the turn rate")
        print()
        print("The two-camera rig over one loop of the room in 60 s (`--captures 1200 --period 0.05`, the stream of")
        print("results/keyframe_selection.md), otherwise as above; the last row decides keyframes on the tracks and")
        print("matches every pair by descriptors.")
        print()
        print("| tracks | keyframes | speed-up | per pair | track pairs | median (deg) |")
        print("|---|---|---|---|---|---|")
        for label, text in slow:
            if not text:
                continue
            _, _, p = budget(text)
            print("| %s | %s | %s | %s / %s | %s | %s |" % (
                label, value(text, r"^keyframes: (\d+) ", "-"), value(text, r"\(([\d.]+)x real time\)", "-") + "x",
                p[0], p[1], track_pairs(text), value(text, r"^median error: ([\d.]+) deg", "-")))
    euroc = {t: os.path.join(out, "euroc_tracks_%s" % t, "orientations.csv") for t in ("true", "false")}
    if os.path.isdir(mav0) and all(os.path.exists(p) for p in euroc.values()):
        r10 = body_from_camera(os.path.join(mav0, "cam1/sensor.yaml")).T @ body_from_camera(
            os.path.join(mav0, "cam0/sensor.yaml"))
        print()
        print("## EuRoC V1_01: a real raw stereo stream")
        print()
        print("`rotation_averaging_images_to_bag --euroc` on `euroc_v1_01_micro/mav0` (95 captures of cam0 and cam1 at")
        print("20 Hz, raw, radial-tangential lens), `keyframe_selection: motion` with `keyframe_max_interval_s: 0.5`")
        print("(the vehicle stands still), `use_rig_extrinsics: false`: each capture's cam0 -> cam1 rotation is solved,")
        print("and compared with the calibration's (0.818 deg); the captures are joined by the cameras' sequential pairs.")
        print()
        print("| tracks | keyframes | track pairs | sequential edges | cam0 -> cam1: median error (deg) | max (deg) |")
        print("|---|---|---|---|---|---|")
        for t in ("true", "false"):
            text = read(out, "euroc_tracks_%s" % t)
            errors = stereo_errors(euroc[t], r10)
            print("| `%s` | %s | %s | %s | %.4f | %.4f |" % (
                t, value(text, r"^keyframes: (\d+) ", "-"), track_pairs(text),
                value(text, r"sequential (\d+)\)", "-"), float(np.median(errors)), float(errors.max())))


if __name__ == "__main__":
    main()
