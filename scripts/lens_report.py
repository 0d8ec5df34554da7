"""Writes results/lens.md from the runs of scripts/benchmark_lens.sh.

usage: lens_report.py OUT EUROC_MAV0 INPUT...   (each INPUT with the runs INPUT_lens, INPUT_warn and INPUT_apply;
demo_rectified_apply on its own)
"""
import os
import re
import sys

import numpy as np

from camera_models_report import body_from_camera, stereo_errors
from report_common import reproduce_line

MEDIAN = re.compile(r"^median error: ([\d.]+) deg", re.M)
AUC2 = re.compile(r"^AUC@2: ([\d.]+) %", re.M)
NEES = re.compile(r"NEES median ([\d.]+) .*?, ([\d.]+)% within", re.M)
GIVEN = re.compile(r"^lens given where camera_info describes none \(focal_calibration: apply\): (\S+): division "
                   r"model (-?[\d.]+) \+- ([\d.]+), ([\d.]+) px at the corners", re.M)
SEEN = re.compile(r"^camera_info check, last estimate: (\S+): .*?radial distortion seen \(division model\) "
                  r"(-?[\d.]+) \+- ([\d.]+), ([\d.]+) px at the corners", re.M)
CHECK = re.compile(r"^camera_info check, last estimate: (\S+): focal length x([\d.]+) \+- ([\d.]+) .*?: (agrees|"
                   r"disagrees|cannot tell)", re.M)
CORRECTED = re.compile(r"^focal length corrected \(focal_calibration: apply\): (\S+): camera_info's focal length "
                       r"x([\d.]+)", re.M)
WARNED = re.compile(r"camera_info check: (\S+): .*?the images are distorted but camera_info has no distortion model")
CPU = re.compile(r"CPU time: ([\d.]+) s")

NAMES = {
    "demo_-0.1": "rendered rig, barrel lens k1 -0.1", "demo_-0.05": "rendered rig, barrel lens k1 -0.05",
    "demo_0.05": "rendered rig, pincushion lens k1 +0.05", "fountain-P11": "fountain-P11 through k1 -0.1",
    "entry-P10": "entry-P10 through k1 -0.1", "euroc": "EuRoC V1_01 stereo, raw (its own lens)",
}


def read(out, name):
    path = os.path.join(out, name + ".txt")
    return open(path).read() if os.path.exists(path) else ""


def error(out, name, r10):
    """Median error (deg) against the ground truth, or of cam0 -> cam1 against the calibration (EuRoC)."""
    text = read(out, name)
    m = MEDIAN.search(text)
    if m:
        return "%.4f" % float(m.group(1))
    csv = os.path.join(out, name, "orientations.csv")
    if r10 is not None and os.path.exists(csv):
        e = stereo_errors(csv, r10)
        return "%.4f (cam0 -> cam1)" % float(np.median(e)) if len(e) else "-"
    return "-"


def first(pattern, text, fmt):
    m = pattern.search(text)
    return fmt(m) if m else "-"


def lenses(text):
    given = {m.group(1): "%s +- %s (%s px)" % (m.group(2), m.group(3), m.group(4)) for m in GIVEN.finditer(text)}
    return "; ".join("%s %s" % (c, given[c]) for c in sorted(given)) if given else "none"


def checks(text):
    rows = ["%s x%s +- %s %s" % (m.group(1), m.group(2), m.group(3), m.group(4)) for m in CHECK.finditer(text)]
    corrected = ["%s corrected x%s" % (m.group(1), m.group(2)) for m in CORRECTED.finditer(text)]
    return "; ".join(sorted(rows) + corrected) if rows or corrected else "-"


def main():
    out, mav0, inputs = sys.argv[1], sys.argv[2], sys.argv[3:]
    r10 = None
    if os.path.exists(os.path.join(mav0, "cam1/sensor.yaml")):
        r10 = body_from_camera(os.path.join(mav0, "cam1/sensor.yaml")).T @ body_from_camera(
            os.path.join(mav0, "cam0/sensor.yaml"))
    print("# A lens camera_info does not describe\n")
    print(reproduce_line("bash scripts/benchmark_lens.sh") + " "
          "Every run is `rotation_averaging_replay` (the node's pipeline) on raw images through a lens. *lens*: "
          "camera_info carries the lens (the reference); *warn* and *apply*: camera_info has no distortion model "
          "(`focal_calibration: warn`, and `apply`, the default). The camera_info check measures the distortion "
          "of a camera without a model as a one-parameter division model (docs/node.md, \"The camera_info "
          "check\"); with `apply`, once two of its estimates in a row see the same lens, the camera's keypoints "
          "are undistorted by it (a plumb_bob lens fitted to the division model out to the image's corner) and "
          "its pairs estimated again. The rendered rig is the README's demo (two cameras, 60 captures, 640x480, "
          "f = 420 px); the Strecha scenes are real photographs at a quarter of full width warped through the "
          "lens; EuRoC's pair is raw, its lens k1 -0.28, k2 0.07 (its error: the median over captures of the "
          "solved cam0 -> cam1 rotation against the calibration's). Errors in degrees.\n")
    print("| input | error: lens in camera_info | error: warn | error: apply | AUC@2 (%): lens / warn / apply "
          "| lens given (apply): division model, corner shift | the check's last focal estimate (apply) "
          "| NEES (apply) | CPU (s): lens / apply |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in inputs:
        runs = {k: read(out, "%s_%s" % (name, k)) for k in ("lens", "warn", "apply")}
        auc = " / ".join(first(AUC2, runs[k], lambda m: m.group(1)) for k in ("lens", "warn", "apply"))
        cpu = " / ".join(first(CPU, runs[k], lambda m: m.group(1)) for k in ("lens", "apply"))
        print("| %s | %s | %s | %s | %s | %s | %s | %s | %s |" % (
            NAMES.get(name, name), error(out, name + "_lens", r10), error(out, name + "_warn", r10),
            error(out, name + "_apply", r10), auc, lenses(runs["apply"]), checks(runs["apply"]),
            first(NEES, runs["apply"], lambda m: "%s / %s%%" % (m.group(1), m.group(2))), cpu))
    rectified = read(out, "demo_rectified_apply")
    print()
    print("The rig's images through k1 -0.1 and rectified again (image_proc's image_rect), camera_info without "
          "a lens, `apply`: lens given: %s; median error %s deg; the check's last estimates: %s." % (
              lenses(rectified), error(out, "demo_rectified_apply", None),
              "; ".join("%s %s +- %s (%s px)" % (m.group(1), m.group(2), m.group(3), m.group(4))
                        for m in SEEN.finditer(rectified)) or "no distortion estimated"))
    print()
    warned = sorted({m.group(1) for name in inputs for m in WARNED.finditer(read(out, name + "_warn"))})
    print("With `warn`, the check warned of the lens on: %s." % (", ".join(warned) if warned else "no camera"))
    print()
    print("The replays' summaries are in %s/*.txt." % out)


if __name__ == "__main__":
    main()
