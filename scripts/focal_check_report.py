"""Writes results/focal_check.md from the runs of scripts/benchmark_focal_check.sh.

usage: focal_check_report.py OUT SCENE...
"""
import os
import re
import sys

from report_common import reproduce_line

CHECK = re.compile(r"(\S+): focal length x([\d.]+) \+- ([\d.]+) \(matches ([\d.]+), principal point ([\d.]+)\) "
                   r"of the given ([\d.]+) px \((\d+) of (\d+) verified pairs\): (\w+)")
UNDETERMINED = re.compile(r"(\S+): focal length not determined yet \((\d+) verified pairs")


def read(out, name):
    return open(os.path.join(out, name + ".txt")).read()


def value(text, pattern):
    m = re.search(pattern, text)
    return float(m.group(1)) if m else float("nan")


def checks(text, prefix):
    """Per camera, the check lines after `prefix` (in order)."""
    found = {}
    for line in text.splitlines():
        if not line.startswith(prefix):
            continue
        rest = line[len(prefix):]
        m = CHECK.search(rest)
        if m:
            found.setdefault(m.group(1), []).append({
                "scale": float(m.group(2)), "sd": float(m.group(3)), "matches": float(m.group(4)),
                "pp": float(m.group(5)), "given": float(m.group(6)), "used": int(m.group(7)),
                "seen": int(m.group(8)), "verdict": m.group(9)})
            continue
        m = UNDETERMINED.search(rest)
        if m:
            found.setdefault(m.group(1), []).append({"seen": int(m.group(2)), "verdict": "undetermined"})
    return found


DISTORTION = re.compile(r"(\S+): .*radial distortion seen \(division model\) ([-\d.]+) \+- ([\d.]+), ([\d.]+) px at the "
                        r"corners(?: \(the pairs' cost ([-\d.]+) \+- ([\d.]+) below the focal length's alone\))?: (.*)$")


def distortion(text, prefix):
    """Per camera, the last radial-distortion check after `prefix`."""
    found = {}
    for line in text.splitlines():
        if line.startswith(prefix):
            m = DISTORTION.search(line[len(prefix):])
            if m:
                verdict = m.group(7)
                verdict = ("unmodelled: warned" if "no distortion model" in verdict else
                           "explained as well by the focal length alone" if "focal length's scale alone"
                           in verdict else "none beyond the noise")
                if m.group(5):
                    verdict = "cost %s ± %s below the focal length alone's; %s" % (m.group(5), m.group(6), verdict)
                found[m.group(1)] = (float(m.group(2)), float(m.group(3)), float(m.group(4)), verdict)
    return found


def first_warning(warned, camera):
    """The estimate of `camera` that first disagreed, as a table cell."""
    first = [w for w in warned.get(camera, []) if w["verdict"] == "disagrees"]
    return "at %d pairs: x%.4f ± %.4f" % (first[0]["seen"], first[0]["scale"], first[0]["sd"]) if first else "none"


def cell(c, truth=None):
    if c["verdict"] == "undetermined":
        return "not determined (%d pairs)" % c["seen"], "", ""
    text = "x%.4f ± %.4f (matches %.4f, principal point %.4f), %d of %d pairs" % (
        c["scale"], c["sd"], c["matches"], c["pp"], c["used"], c["seen"])
    off = "" if truth is None else "%+.2f%%" % (100 * (c["scale"] / truth - 1))
    sigmas = "" if truth is None or c["sd"] <= 0 else "%+.1f" % ((c["scale"] - truth) / c["sd"])
    return text, off, sigmas


def main():
    out, scenes = sys.argv[1], sys.argv[2:]
    print("# Focal-length check: camera_info against the images\n")
    print(reproduce_line("bash scripts/benchmark_focal_check.sh"))
    print("Every run is `rotation_averaging_replay` (the node's pipeline) with `focal_calibration: warn`, the "
          "default: each camera's focal length is estimated from its own verified essential-matrix pairs "
          "(at 20, 40, 80, ... pairs, from at most 60 of them with 200 matches each) and a camera_info whose "
          "focal length is further from the estimate than 0.5% and 3 standard deviations is a warning. "
          "*scale* is estimated / given focal length; *off truth* how far it is from the true ratio, also in "
          "its standard deviations.\n")

    print("## The demo renderer with camera_info's focal length off\n")
    print("`rotation_averaging_make_demo_bag --info-focal-scale S` (two cameras, 60 captures 1 s apart, "
          "`config/demo.yaml`): the images are rendered with the true K, camera_info carries its focal lengths "
          "times S. The true scale is 1/S. *first warning*: the estimate that first disagreed.\n")
    print("| camera_info | camera | last estimate | off truth | in deviations | verdict | first warning | "
          "lens distortion seen (the lens is ideal) | median error, deg |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    timing = []
    for s in ["0.97", "1", "1.03"]:
        text = read(out, "demo_%s_warn" % s)
        truth = 1.0 / float(s)
        last = checks(text, "camera_info check, last estimate: ")
        warned = checks(text, "warning: camera_info check: ")
        lens = distortion(text, "camera_info check, last estimate: ")
        median = value(text, r"median error: ([\d.]+) deg")
        for camera in sorted(last):
            c = last[camera][-1]
            text_cell, off, sigmas = cell(c, truth)
            first_cell = first_warning(warned, camera)
            seen = lens.get(camera)
            lens_cell = "%.3f ± %.3f, %.1f px: %s" % seen if seen else "not determined"
            print("| x%s | %s | %s | %s | %s | %s | %s | %s | %.4f |" % (
                s, camera, text_cell, off, sigmas, c["verdict"], first_cell, lens_cell, median))
        off_text = read(out, "demo_%s_off" % s)
        timing.append((s, value(text, r"wall time: ([\d.]+) s"), value(off_text, r"wall time: ([\d.]+) s"),
                       value(text, r"CPU time: ([\d.]+) s"), value(off_text, r"CPU time: ([\d.]+) s"),
                       value(off_text, r"median error: ([\d.]+) deg")))
    print("\nThe averaging's error is that of the focal length given: with `warn` the check reports, it does not correct "
          "(a 3% error costs the demo's orientations over 20 times their error with the right focal length). "
          "The distortion check runs at the focal length camera_info gives: where that is wrong, the pairs are "
          "bent, and a radial distortion takes up part of it (*lens distortion seen*). So it is compared, on the "
          "same pairs, with the estimated focal length and no distortion, and flagged only when it lowers the "
          "pairs' cost by more than 3 standard deviations of that advantage.\n")

    print("## focal_calibration: apply on the demo rig\n")
    print("The same bags with `focal_calibration: apply`. The rig's cameras share one orientation per capture "
          "(extrinsics on /tf_static), and its forward camera cannot be checked, so the sideways camera is not "
          "corrected alone; nor while its images look distorted (the table above). The replay's notices say "
          "so, once for each reason.\n")
    print("| camera_info | corrections applied | median error, deg (warn) | median error, deg (apply) |")
    print("| --- | --- | --- | --- |")
    for s in ["0.97", "1", "1.03"]:
        text = read(out, "demo_%s_apply" % s)
        applied = re.findall(r"focal length corrected \(focal_calibration: apply\): (.*)", text)
        rig = len(re.findall(r"focal length not corrected: the other cameras of its rig", text))
        lens = len(re.findall(r"focal length not corrected: its images are distorted", text))
        reasons = ["%d for the rig" % rig] if rig else []
        reasons += ["%d as its images look distorted" % lens] if lens else []
        cell_text = "; ".join(applied) if applied else (
            "none (held back: %s)" % ", ".join(reasons) if reasons else "none")
        print("| x%s | %s | %.4f | %.4f |" % (s, cell_text, value(read(out, "demo_%s_warn" % s), r"median error: ([\d.]+) deg"),
                                          value(text, r"median error: ([\d.]+) deg")))
    print()
    print("## What the check costs\n")
    print("The replay waits for each estimate before it goes on, so that its output is the same on every run; "
          "the node runs them on a thread of their own beside its front end. Same bag, `focal_calibration: "
          "warn` against `off`, in the same run of this script.\n")
    print("| camera_info | wall time, warn / off (s) | CPU time, warn / off (s) | median error with off, deg |")
    print("| --- | --- | --- | --- |")
    for s, wall_warn, wall_off, cpu_warn, cpu_off, median_off in timing:
        print("| x%s | %.1f / %.1f | %.1f / %.1f | %.4f |" % (s, wall_warn, wall_off, cpu_warn, cpu_off, median_off))

    print("\n## A lens that camera_info does not describe\n")
    print("A camera_info without a distortion model (no `distortion_model`, or D all zero) also has its pairs "
          "checked for a radial distortion: the division-model coefficient lambda (x / (1 + lambda |x|^2) in "
          "normalised coordinates, about a plumb_bob k1) that fits them best, flagged when it moves a corner "
          "keypoint by more than 2 px and is 3 standard deviations from 0. *read without the model*: "
          "`image_type: rectified` on the raw images, as a driver whose camera_info lacks D gives them.\n")
    print("| input | camera | lambda | at the corners | verdict | median error, deg |")
    print("| --- | --- | --- | --- | --- | --- |")
    rows = [("demo, ideal lens (camera_info right)", "demo_1_warn"),
            ("demo through plumb_bob k1 = -0.28, read without the model", "demo_plumb_bob_ignored")]
    if os.path.exists(os.path.join(out, "euroc_ignored.txt")):
        rows.append(("EuRoC V1_01 stereo (k1 = -0.28), read without the model", "euroc_ignored"))
    for label, name in rows:
        text = read(out, name)
        found = distortion(text, "camera_info check, last estimate: ")
        median = value(text, r"median error: ([\d.]+) deg")
        median_cell = "%.4f" % median if median == median else "no ground truth"
        if not found:
            seen = checks(text, "camera_info check, last estimate: ")
            why = "no estimate (fewer than 20 verified essential-matrix pairs of one camera)" if not seen else \
                "not determined"
            print("| %s | | %s | | | %s |" % (label, why, median_cell))
        for camera in sorted(found):
            lam, sd, corner, verdict = found[camera]
            print("| %s | %s | %.3f ± %.3f | %.1f px | %s | %s |" % (label, camera, lam, sd, corner, verdict,
                                                                   median_cell))
    with_model = value(read(out, "demo_plumb_bob_model"), r"median error: ([\d.]+) deg")
    print("\nThe same plumb_bob demo with its model in camera_info: median %.4f deg (the distortion check does "
          "not run: camera_info describes the lens)." % with_model)

    print("\n## A raw camera with its model, camera_info's focal length off\n")
    print("The plumb_bob demo with its model in camera_info (`--distortion`), and with camera_info's focal "
          "lengths also 3% short (`--info-focal-scale 0.97`): keypoints undistorted with the wrong K land near "
          "where the right K would put them, with a radial error. The check undistorts them again for every "
          "focal length it tries. The true scale is 1/S.\n")
    print("| camera_info | camera | last estimate | off truth | in deviations | verdict | first warning | "
          "median error, deg (warn) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for s, name in (("1", "demo_plumb_bob_model"), ("0.97", "demo_plumb_bob_0.97_warn")):
        text = read(out, name)
        last = checks(text, "camera_info check, last estimate: ")
        warned = checks(text, "warning: camera_info check: ")
        median = value(text, r"median error: ([\d.]+) deg")
        for camera in sorted(last):
            c = last[camera][-1]
            text_cell, off, sigmas = cell(c, 1.0 / float(s))
            first_cell = first_warning(warned, camera)
            print("| x%s | %s | %s | %s | %s | %s | %s | %.4f |" % (s, camera, text_cell, off, sigmas, c["verdict"],
                                                                   first_cell, median))
    median_of = lambda name: value(read(out, name), r"median error: ([\d.]+) deg")
    cpu_of = lambda name: value(read(out, name), r"CPU time: ([\d.]+) s")

    def per_camera(name, cameras, pattern, cell, missing):
        # One entry per camera from the (camera, number) pairs `pattern` finds in a replay's summary.
        found = dict(re.findall(pattern, read(out, name)))
        return ", ".join("%s %s" % (c, cell(float(found[c])) if c in found else missing) for c in cameras)

    def ended_at(name, cameras):
        # camera_info's focal length times the corrections, of the true one (camera_info is 0.97 of it).
        return per_camera(name, cameras, r"focal length corrected \(focal_calibration: apply\): (\S+): camera_info's "
                          r"focal length x([\d.]+)", lambda v: "x%.5f" % (0.97 * v), "not corrected")

    def loops_deviation(name, cameras):
        # The loops' last estimate's standard deviation, of the focal length in use.
        return per_camera(name, cameras, r"focal length by the loops, last estimate: (\S+): the loops put its focal "
                          r"length at x[\d.]+ \+- ([\d.]+)", lambda v: "±%.4f%%" % (100.0 * v), "none")

    print("\nWith `focal_calibration: apply` on the x0.97 bags: the check's estimate alone "
          "(`focal_loop_refinement: false`), and refined by the loops of the averaging as loop closures arrive "
          "(the default; docs/node.md). *ended at*: the focal lengths used at the end, of the true ones. "
          "*one camera*: `make_demo_bag --cameras 1`, the rig's forward camera alone.\n")
    print("| input | camera_info right | x0.97, warn | x0.97, apply, the check alone | x0.97, apply | "
          "apply / right | ended at (check alone) | ended at (apply) | the loops' last deviation (apply) | "
          "CPU time, apply / check alone (s) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for label, prefix, cameras in (("demo rig", "demo_plumb_bob", ("cam_front", "cam_left")),
                                   ("one camera", "demo1_plumb_bob", ("cam_front",))):
        right = median_of(prefix + "_model")
        apply = median_of(prefix + "_0.97_apply")
        print("| %s | %.4f | %.4f | %.4f | %.4f | %.2fx | %s | %s | %s | %.1f / %.1f |" %
              (label, right, median_of(prefix + "_0.97_warn"), median_of(prefix + "_0.97_check_only"), apply,
               apply / right, ended_at(prefix + "_0.97_check_only", cameras), ended_at(prefix + "_0.97_apply", cameras),
               loops_deviation(prefix + "_0.97_apply", cameras), cpu_of(prefix + "_0.97_apply"),
               cpu_of(prefix + "_0.97_check_only")))
    scales = open(os.path.join(out, "demo_plumb_bob_corrected.scales")).read().split()[0].split(",")
    scale1 = open(os.path.join(out, "demo1_plumb_bob_corrected.scales")).read().split()[0]
    print("\nHow the error depends on the focal length: the same lens and model with camera_info's focal lengths "
          "a little off from the first image, `focal_calibration: off`. *where `apply` ended*: each camera given "
          "the focal length that `apply` ended at above.\n")
    print("| input | camera_info's focal lengths, of the true ones | median error, deg |")
    print("| --- | --- | --- |")
    print("| demo rig | x1 (right) | %.4f |" % median_of("demo_plumb_bob_model"))
    for s in ("0.9998", "0.9987"):
        print("| demo rig | x%s, both cameras | %.4f |" % (s, median_of("demo_plumb_bob_%s_off" % s)))
    print("| demo rig | x%s (cam_front), x%s (cam_left): where `apply` ended | %.4f |" %
          (scales[0], scales[1], median_of("demo_plumb_bob_corrected_off")))
    print("| one camera | x1 (right) | %.4f |" % median_of("demo1_plumb_bob_model"))
    for s in ("0.99998", "0.9999"):
        print("| one camera | x%s | %.4f |" % (s, median_of("demo1_plumb_bob_%s_off" % s)))
    print("| one camera | x%s: where `apply` ended | %.4f |" % (scale1, median_of("demo1_plumb_bob_corrected_off")))
    print("\nThe demo's loop turns through 360 degrees, so a focal length off by a few hundredths of a percent "
          "bends it by more than its error with the right K, and two rig cameras off by different amounts "
          "disagree as well. The check's standard deviations (above) are tenths of a percent, and its estimates "
          "a few hundredths off: the check alone is bounded by them. A loop measured with the wrong focal length "
          "does not close, and once the loops close they know the focal length several times more precisely "
          "than the check (the node logs each of their estimates with its deviation, docs/node.md; the replay's "
          "summary gives the last one).")
    given1, applied1 = median_of("demo1_plumb_bob_corrected_off"), median_of("demo1_plumb_bob_0.97_apply")
    print("\nOne camera alone is bent the most by a focal length off, since no second camera's pairs relate its "
          "captures: there a few thousandths of a percent count, which is about its loops' own deviation on 60 "
          "captures (the apply table). The focal length `apply` ended at, given from the first image, gives "
          "%.4f deg against the %.4f deg of `apply` itself: %s." %
          (given1, applied1, "what is left is the estimate's deviation, not the pairs measured before the correction"
           if given1 >= 0.9 * applied1 else "the pairs measured before the correction cost the rest"))
    print("\n## Strecha scenes: exact intrinsics\n")
    print("`rotation_averaging_images_to_bag --downsample 0.25` with the scene's K, `keyframe_selection: all`, "
          "`max_features: 4000`: the photographs as one camera's keyframes. Their K is exact, so the check "
          "must agree (the true scale is 1). 8 to 19 photographs give a camera fewer than the 20 verified pairs "
          "a first estimate needs; `rotavg images`, which pairs every two of them, estimates it on these scenes "
          "in results/frontend.md (\"Focal self-calibration\").\n")
    print("| scene | last estimate | off truth | in deviations | verdict |")
    print("| --- | --- | --- | --- | --- |")
    for scene in scenes:
        last = checks(read(out, scene), "camera_info check, last estimate: ")
        if not last:
            print("| %s | no estimate (fewer than 20 verified pairs) | | | |" % scene)
        for camera in sorted(last):
            c = last[camera][-1]
            text_cell, off, sigmas = cell(c, 1.0)
            print("| %s | %s | %s | %s | %s |" % (scene, text_cell, off, sigmas, c["verdict"]))


if __name__ == "__main__":
    main()
