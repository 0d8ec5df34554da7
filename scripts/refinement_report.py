"""Writes results/refinement.md from the runs of scripts/benchmark_refinement.sh.

usage: refinement_report.py OUT PHOTOS [EUROC_MAV0]
  PHOTOS: the photograph scenes replayed as bags, comma separated (each with its `rotavg images` run,
  OUT/<scene>_offline.txt). EUROC_MAV0: the EuRoC excerpt's mav0 folder (its calibration), for the stereo rows.
"""
import os
import re
import sys

import numpy as np

from camera_models_report import body_from_camera, stereo_errors
from report_common import reproduce_line, value, view_errors

MEDIAN = r"^median error: ([\d.]+) deg"
NEES = r"^posterior covariances against the ground truth: NEES median ([\d.]+) \(2.37 if honest\), "
WITHIN = r"^posterior covariances against the ground truth: .*, ([\d.]+)% within"
REFINEMENT = r"^refinement \(bundle adjustment of the newest keyframes\): "
HELD = r"^refinement, latest: bundle adjustment: \d+ views \((\d+) held\)"
LABELS = {
    "castle-P19": "castle-P19 (19 photographs)",
    "entry-P10": "entry-P10 (10 photographs)",
    "fountain-P11": "fountain-P11 (11 photographs)",
    "lund_door": "lund_door (12 photographs; COLMAP's model as ground truth)",
    "demo": "demo bag (two cameras, rig, one capture a second)",
    "stream": "20 Hz two-camera stream, one loop in 30 s",
    "one_camera": "20 Hz stream, forward camera alone",
    "euroc": "EuRoC stereo, raw (cam0 -> cam1 error)",
}


def read(out, name):
    path = os.path.join(out, name + ".txt")
    return open(path).read() if os.path.exists(path) else ""


def refinements(text):
    runs = value(text, REFINEMENT + r"(\d+) runs", "")
    if not runs:
        return "-", "-"
    applied = value(text, REFINEMENT + r"\d+ runs, (\d+) applied", "-")
    times = value(text, REFINEMENT + r".*time per refinement: median ([\d.]+) ms, p95 ([\d.]+) ms", "-")
    p95 = value(text, REFINEMENT + r".*time per refinement: median [\d.]+ ms, p95 ([\d.]+) ms", "-")
    return "%s / %s" % (applied, runs), "%s / %s" % (times, p95)


def row(out, name, refinement, offline=None, error=None):
    """One table row of a replay; `error`: a median error of its own (EuRoC's stereo), else the summary's."""
    text = read(out, "%s_%s" % (name, refinement))
    if not text:
        return None
    median = error if error is not None else value(text, MEDIAN, "-")
    applied, times = refinements(text)
    cells = [LABELS.get(name, name), "on" if refinement == "true" else "off",
             value(text, r"^keyframes: (\d+) ", "-"), median, value(text, r"^AUC@2: ([\d.]+) %", "-"),
             value(text, NEES, "-"), value(text, WITHIN, "-"), applied, times,
             value(text, r"\(([\d.]+)x real time\)", "-") + "x", value(text, r"CPU time: ([\d.]+) s", "-")]
    if offline is not None:
        offline_median = value(offline, MEDIAN, "")
        ratio = "%.2f" % (float(median) / float(offline_median)) if offline_median and median != "-" else "-"
        cells += [offline_median or "-", ratio]
    else:
        cells += ["-", "-"]
    return "| " + " | ".join(cells) + " |"


def refined_focal(text):
    """(camera, scale, deviation) as printed, of the refinement's latest focal estimates in a replay's summary."""
    return re.findall(r"^focal length by the refinement, (\S+): x([\d.]+) \+- ([\d.]+)", text, re.M)


def focal_estimates(text):
    """The refinement's latest focal estimates of a replay's summary, one per camera."""
    return ", ".join("%s x%s +- %s" % f for f in refined_focal(text)) or "-"


def focal_section(out):
    """The focal length held once it agrees against free in every refinement."""
    inputs = [("demo", "demo bag (two cameras, 120 keyframes)"), ("stream", "20 Hz two-camera stream"),
              ("four_cameras", "20 Hz four-camera stream"),
              ("long", "600 keyframes (two cameras, 300 captures, every image a keyframe)")]
    rows = []
    far = []  # (input, camera, deviations off the truth, x1) of the free estimates beyond two deviations
    for name, label in inputs:  # each with the defaults, the refinement off, the focal length free
        t_on, t_off, t_free = (read(out, name + suffix) for suffix in ("_true", "_false", "_free_focal"))
        if not (t_on and t_off and t_free):
            continue
        for camera, scale, sigma in refined_focal(t_free):
            off = abs(float(scale) - 1.0) / float(sigma) if float(sigma) > 0.0 else float("inf")
            if off > 2.0:
                far.append((label, camera, off))
        rows.append("| %s | %s | %s | %s | %s | %s / %s | %s |" % (
            label, value(t_on, r"^keyframes: (\d+) ", "-"), value(t_off, MEDIAN, "-"), value(t_on, MEDIAN, "-"),
            value(t_free, MEDIAN, "-"), value(t_on, NEES, "-"), value(t_free, NEES, "-"), focal_estimates(t_free)))
    if not rows:
        return
    print("""
## A focal length that agrees

The averaging's pairs are estimated with the focal length in use. With `refinement_focal: true` every
refinement also estimates each camera's, and one whose estimate differs from the one in use by a little (within
its deviation) turns its orientations against the averaging's by that error times the angle its window turns
through. With `refinement_hold_agreed_focal: true` (the default) a camera whose focal length a refinement finds
agreeing with the one in use (within the larger of 0.5% and 3 deviations, known to 0.5%: the focal check's verdict)
keeps the one in use in the later refinements, until camera_info is corrected. The rendered rig, whose
camera_info is exact: the final solution's median error (deg) with the refinement off, on (the default), and on
with `refinement_hold_agreed_focal: false`; NEES median of the published covariances on / free; and the latest
focal estimates of the free runs (each camera's last refinement that estimated it). The four-camera stream (316
keyframes) and the 600-keyframe bag have more keyframes than the refinement's window (200).
""")
    print("| input | keyframes | refinement off | on | on, focal length free in every refinement "
          "| NEES median: on / free | focal estimates, free |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(r)
    beyond = ("every one within two of its deviations" if not far else
              "within two of their deviations but for " +
              ", ".join("the %s's %s, %.1f deviations off" % (label, camera, off) for label, camera, off in far))
    print("""
The free runs' estimates are within a few hundredths of a percent of the truth (camera_info's focal length is
exact here, x1), %s. Each refinement's window turns through a large angle (120 deg of the 600-keyframe bag's
loop), and its orientations turn against the averaging's by the focal length's error times that angle: compare
the on and free columns of the two bags whose keyframes outnumber the window.""" % beyond)


def along_the_bag(out, run, parts=6):
    """Median error (deg) of a run's keyframes in `parts` equal parts of the bag, in stamp order (rotavg eval
    --per-view of its final solution, OUT/<run>/per_view.txt); none if missing."""
    errors = view_errors(os.path.join(out, run, "per_view.txt"))
    if not errors:
        return []
    errors.sort(key=lambda e: (int(e[0].split("@")[1]), e[0]))
    chunks = np.array_split(np.array(errors, dtype=object), parts)
    return ["%.4f" % np.median([float(e) for _, e in chunk]) for chunk in chunks]


def window_section(out):
    """The window adjusted alone, with the older keyframes its edges reach held, and swept back at the end."""
    inputs = [("four_cameras", "20 Hz four-camera stream"),
              ("long", "600 keyframes (two cameras, 300 captures, every image a keyframe)")]
    runs = [("_false", "refinement off"), ("_window_alone", "window alone, swept back"),
            ("_no_sweep", "older keyframes held, no sweep back"), ("_true", "older keyframes held, swept back (the defaults)")]
    rows, bins = [], []
    for name, label in inputs:
        texts = [read(out, name + suffix) for suffix, _ in runs]
        if not all(texts):
            continue
        for (suffix, what), text in zip(runs, texts):
            held = value(text, HELD, "-" if suffix == "_false" else "0")
            applied, _ = refinements(text)
            rows.append("| %s | %s | %s | %s | %s | %s | %s | %s | %sx |" % (
                label, what, value(text, r"^keyframes: (\d+) ", "-"), value(text, MEDIAN, "-"), value(text, NEES, "-"),
                value(text, WITHIN, "-"), held, applied, value(text, r"\(([\d.]+)x real time\)", "-")))
            sixths = along_the_bag(out, name + suffix)
            if sixths:
                bins.append("| %s | %s | %s |" % (label, what, " | ".join(sixths)))
    if not rows:
        return
    print("""
## The keyframes before the window, and the sweep back

A refinement adjusts the newest `refinement_max_keyframes` (200) keyframes. On a run longer than that, the window
is an open arc: adjusted alone it bends along its length, its loop closures to the places seen before it lie
outside it, and the rotation fitted to turn it to the averaging's frame (one per camera, or per rig) carries the
averaging's drift of that day into its corrections. With `refinement_hold_outside: true` (the default) the older
keyframes the window's edges reach (the pairs of its first keyframes, its loop closures) join the adjustment with
their orientations held as the averaging has them, and hold the window's frame in their place. Either way a
keyframe that leaves the window keeps a correction fitted against the averaging of its day, before the loops that
close later, and the averaging's move since is added to it. With `refinement_sweep_back: true` (the default), a
refinement of a solution already refined (the node's input gone quiet, the end of the bag) sweeps back over the
keyframes the windows had no room for, newest first, a window at a time, the keyframes already adjusted in that
solution held as published. The two bags of the rendered rig whose keyframes outnumber the window: median error
(deg) of the final solution; NEES median and share within chi-square's 95% bound of the published covariances;
the keyframes held in the last refinement; refinements applied / run; the replay's speed-up.
""")
    print("| input | run | keyframes | median | NEES median | within bound (%) | keyframes held, last refinement "
          "| refinements | speed-up |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(r)
    if bins:
        print("""
Along the bag: the median error (deg) of each sixth of the keyframes in stamp order (`rotavg eval --per-view` of
the final solution, the same alignment to the truth as above).
""")
        print("| input | run | 1st | 2nd | 3rd | 4th | 5th | 6th |")
        print("|---|---|---|---|---|---|---|---|")
        for b in bins:
            print(b)
    print("""
Without the sweep back, the four-camera stream's first third keeps the corrections of the first of its two
refinements, whose window held few older keyframes, and is its least accurate part, behind the refinement off.
Swept back, that third is as accurate as the rest, and the 600-keyframe bag's middle (its third and fourth
sixths, whose last windows ended long before the loop closed) is more than twice as accurate as without the
sweep; the newest sixth, which the final window adjusts either way, gains less. The sweep costs the replay time
at the end of the bag: one refinement more on the four-camera stream, two on the 600-keyframe bag (the node
sweeps only once its input is quiet). On the four-camera stream the swept keyframes' covariances are wider than
their errors (the NEES median of the table above): each is relative to the keyframe the averaging holds best
inside its window, plus that keyframe's covariance in the averaging, where the adjustment holds the window on the
keyframes at both its ends (docs/decisions.md, "A rig capture's covariance", with what was tried).""")


def main():
    out, photos = sys.argv[1], [p for p in sys.argv[2].split(",") if p]
    mav0 = sys.argv[3] if len(sys.argv) > 3 else ""
    print("# Background refinement in the node\n")
    print(reproduce_line("bash scripts/benchmark_refinement.sh"))
    print("""
The node bundle adjusts its newest keyframes (`refinement_max_keyframes`) on their pairs' inliers in the
background (`refinement: true`, docs/node.md "Background refinement"): the adjustment `rotavg images` runs after
the averaging, started from the node's averaged orientations. Each keyframe keeps the correction it found, in its
camera's frame, and every later solution is published with it; the cameras of a rig capture share one correction.
Here each bag is replayed with the refinement off and on (the defaults otherwise); the replay starts a refinement
every `refinement_period_s` of bag time on a thread of its own while the bag goes on, takes what it found when the
next is due, and refines the final solution once more in its own thread (then, on a bag whose keyframes
outnumber the window, sweeps back over the rest: "The keyframes before the window, and the sweep back" below), so the refinements' time is in the
wall and CPU time. Errors of the final solution against the ground truth, in degrees; NEES: the
published posterior covariances (with the refinement on, the refined keyframes' from the bundle adjustment:
results/posterior.md) against the errors of the published orientations, with the share of keyframes within
chi-square's 95% bound; refinements: applied / run; time per refinement: median / p95
(ms). `rotavg images`: the same images, every pair tried, with focal self-calibration and the bundle adjustment
(`--downsample 0.25 --pairs exhaustive`); ratio: the node's median over it (the target is 1.5 or less).
""")
    print("| input | refinement | keyframes | median | AUC@2 (%) | NEES median | within bound (%) | refinements "
          "| time per refinement (ms) | speed-up | CPU (s) | rotavg images: median | ratio |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for s in photos:
        offline = read(out, s + "_offline")
        for r in ("false", "true"):
            line = row(out, s, r, offline)
            if line:
                print(line)
    for name in ("demo", "stream", "one_camera"):
        for r in ("false", "true"):
            line = row(out, name, r)
            if line:
                print(line)
    if mav0 and os.path.isdir(mav0):
        r10 = body_from_camera(os.path.join(mav0, "cam1/sensor.yaml")).T @ body_from_camera(
            os.path.join(mav0, "cam0/sensor.yaml"))
        for r in ("false", "true"):
            orientations = os.path.join(out, "euroc_" + r, "orientations.csv")
            if os.path.exists(orientations):
                errors = stereo_errors(orientations, r10)
                line = row(out, "euroc", r, error="%.4f" % float(np.median(errors)))
                if line:
                    print(line)
    focal_section(out)
    window_section(out)
    pairs = []
    for k in (1, 2):
        pool, held = read(out, "openblas_pool_%d" % k), read(out, "openblas_held_%d" % k)
        if pool and held:
            pairs.append((k, pool, held))
    if pairs:
        print("""
## OpenBLAS

Debian's BLAS is OpenBLAS's pthread build: it splits each call over a pool of worker threads, one per core,
and a waiting worker spins on sched_yield for a while before it sleeps. The bundle adjustment's sparse Schur
solves (CHOLMOD's supernodes) call it every iteration, and a profile of this replay with the pool (`perf record
-F 200 -g` of `rotation_averaging_replay --bag build/demo/demo_60.bag` with config/demo.yaml and `num_threads: 1`,
then `perf report --sort pid,sym`) showed a worker spinning on sched_yield for 15% of the process's samples. The package holds OpenBLAS to one thread (`util/blas_threads.h`; a thread
count the user sets is left alone). The demo bag with the refinement on and the front end on one thread, so
that the second core is the pool's: OpenBLAS's pool (`OPENBLAS_NUM_THREADS=2`) against held to one thread,
alternated twice in this run (this machine is shared: compare within a pair):
""")
        print("| pair | CPU (s), pool | CPU (s), held | CPU saved | wall (s), pool | wall (s), held |")
        print("|---|---|---|---|---|---|")
        for k, pool, held in pairs:
            cpu_pool = float(value(pool, r"CPU time: ([\d.]+) s", "nan"))
            cpu_held = float(value(held, r"CPU time: ([\d.]+) s", "nan"))
            print("| %d | %.1f | %.1f | %.0f%% | %s | %s |" % (
                k, cpu_pool, cpu_held, 100.0 * (cpu_pool - cpu_held) / cpu_pool,
                value(pool, r"wall time: ([\d.]+) s", "-"), value(held, r"wall time: ([\d.]+) s", "-")))
        same = all(open(os.path.join(out, "openblas_held_%d" % k, "orientations.csv")).read() ==
                   open(os.path.join(out, "openblas_pool_%d" % k, "orientations.csv")).read() for k, _, _ in pairs)
        print("\nThe orientations of the two are %s." % ("the same, bit for bit" if same else
                                                          "different in their last bits: a product split over "
                                                          "two threads sums in another order"))
    print("""
The replays' summaries (`refinement, latest:` gives the last adjustment's report) are in
build/benchmark_refinement/*.txt.""")


if __name__ == "__main__":
    main()
