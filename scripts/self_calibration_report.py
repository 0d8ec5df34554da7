"""Writes results/self_calibration.md from the runs of scripts/benchmark_self_calibration.sh.

usage: self_calibration_report.py OUT INPUT...   (INPUT: name_scale, scale being camera_info's focal length of the
true one; each with the runs INPUT_fixed, INPUT_warn and INPUT_apply)
"""
import math
import os
import re
import sys

from report_common import reproduce_line

ESTIMATE = re.compile(r"^focal length by the refinement, (\S+): x([\d.]+) \+- ([\d.]+) \(matches ([\d.]+), "
                      r"principal point ([\d.]+)\), (\d+) keyframes", re.M)
CORRECTED = re.compile(r"^focal length corrected \(focal_calibration: apply\): (\S+): camera_info's focal length "
                       r"x([\d.]+)", re.M)
FIRST_DISAGREEMENT = re.compile(r"camera_info check: (\S+): the refinement puts the focal length at x[\d.]+ \+- [\d.]+ "
                                r"\(matches [\d.]+, principal point [\d.]+\), (\d+) keyframes, of the one in use: it "
                                r"disagrees")
MEDIAN = re.compile(r"^median error: ([\d.]+) deg", re.M)
NEES = re.compile(r"NEES median ([\d.]+) .*?, ([\d.]+)% within", re.M)

NAMES = {
    "demo": "demo rig", "one": "one camera", "plumb_bob": "rig, plumb_bob lens with its model",
    "fountain-P11": "fountain-P11", "entry-P10": "entry-P10", "castle-P19": "castle-P19",
    "lund_door": "lund_door", "euroc": "EuRoC V1_01 stereo",
}


def read(out, name):
    path = os.path.join(out, name + ".txt")
    return open(path).read() if os.path.exists(path) else ""


def median(text):
    m = MEDIAN.search(text)
    return m.group(1) if m else "no ground truth"


def nees(text):
    m = NEES.search(text)
    return "%s / %s%%" % (m.group(1), m.group(2)) if m else ""


def decimals(*deviations):
    """Decimals enough for two significant digits of the smallest positive deviation (4 to 8), as the node
    prints them."""
    positive = [d for d in deviations if d > 0]
    return min(max(1 - math.floor(math.log10(min(positive))), 4), 8) if positive else 4


def described(e, with_parts):
    n = decimals(e["sd"], e["matches"], e["pp"]) if with_parts else decimals(e["sd"])
    text = "x%.*f +- %.*f" % (n, e["scale"], n, e["sd"])
    if with_parts:
        text += " (%.*f, %.*f), %d keyframes" % (n, e["matches"], n, e["pp"], e["views"])
    return text


def estimates(text):
    return {m.group(1): {"scale": float(m.group(2)), "sd": float(m.group(3)), "matches": float(m.group(4)),
                         "pp": float(m.group(5)), "views": int(m.group(6))} for m in ESTIMATE.finditer(text)}


def main():
    out, inputs = sys.argv[1], sys.argv[2:]
    print("# Focal self-calibration in the refinement: camera_info's focal length right and 3% off\n")
    print(reproduce_line("bash scripts/benchmark_self_calibration.sh") + " "
          "Every run is `rotation_averaging_replay` (the node's pipeline) on a bag whose camera_info carries the "
          "true focal length times *camera_info* (the images are the same). Three configurations: *fixed* "
          "(`refinement_focal: false`, `focal_calibration: warn`: the focal length is camera_info's throughout), "
          "*warn* (`refinement_focal: true`, `focal_calibration: warn`: the background refinement estimates each "
          "camera's focal length with everything else and warns when it disagrees) and *apply* (`refinement_focal: "
          "true`, `focal_calibration: apply`, the defaults: the camera's focal length is corrected by that estimate, "
          "or by the focal check's, and its pairs estimated again).\n")
    print("*estimate*: the last refinement's, of the focal length in use, with its standard deviation (matches, "
          "principal point); *in deviations*: how far it is from the true ratio. *first warning*: the keyframes of "
          "the refinement that first said it disagrees (warn). *ended at*: the focal length in use at the end with "
          "`apply`, of the true one. The rig's two cameras are estimated apart (one focal length each). *not estimated*: "
          "a camera whose lens keeps its keypoints from scaling with the focal length (`FocalScalingError` above "
          "5%: the plumb_bob rig's and EuRoC's) has it held in the refinement; its focal check estimates it.\n")
    print("| input | camera_info | camera | median error, deg: fixed / warn / apply | estimate (warn) | in deviations "
          "| first warning | ended at (apply) | last estimate with apply, in deviations | NEES median / within "
          "(fixed, warn, apply) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for name in inputs:
        base, scale = name.rsplit("_", 1)
        scale = float(scale)
        fixed, warn, apply = (read(out, name + "_" + c) for c in ("fixed", "warn", "apply"))
        warn_estimates, apply_estimates = estimates(warn), estimates(apply)
        corrected = {m.group(1): float(m.group(2)) for m in CORRECTED.finditer(apply)}
        first = {}
        for m in FIRST_DISAGREEMENT.finditer(warn):
            first.setdefault(m.group(1), int(m.group(2)))
        truth_known = base != "euroc"
        cameras = sorted(set(warn_estimates) | set(corrected) | set(re.findall(
            r"^camera_info check, last estimate: (\S+):", fixed, re.M)))
        for camera in cameras or ["(none)"]:
            e = warn_estimates.get(camera)
            row = [NAMES.get(base, base), "x%g" % scale, camera,
                   " / ".join(median(t) for t in (fixed, warn, apply))]
            if e:
                row.append(described(e, True))
                row.append("%+.1f" % ((e["scale"] - 1.0 / scale) / e["sd"]) if truth_known and e["sd"] > 0 else "")
            else:
                row += ["not estimated", ""]
            row.append("at %d keyframes" % first[camera] if camera in first else "none")
            correction = corrected.get(camera, 1.0)
            ended = scale * correction
            if truth_known:
                row.append("x%.5f (%+.2f%%)%s" % (ended, 100 * (ended - 1.0),
                                                 "" if camera in corrected else ", not corrected"))
            else:
                row.append("x%.5f of camera_info's%s" % (correction, "" if camera in corrected else " (not corrected)"))
            a = apply_estimates.get(camera)
            if a and truth_known and a["sd"] > 0:
                row.append("%s: %+.1f" % (described(a, False), (a["scale"] - 1.0 / ended) / a["sd"]))
            elif a:
                row.append(described(a, False))
            else:
                row.append("")
            row.append("; ".join(nees(t) for t in (fixed, warn, apply)) if truth_known else "")
            print("| " + " | ".join(row) + " |")
    print()
    print("## What it costs\n")
    print("The same runs with camera_info right: CPU time and peak memory of the whole replay (the replays of "
          "*fixed* and *warn* ran two at a time, *apply* alone).\n")
    print("| input | CPU time, s: fixed / warn / apply | peak memory, MiB: fixed / warn / apply |")
    print("| --- | --- | --- |")
    for name in inputs:
        base, scale = name.rsplit("_", 1)
        if float(scale) != 1.0:
            continue
        texts = [read(out, name + "_" + c) for c in ("fixed", "warn", "apply")]
        cpu = [re.search(r"CPU time: ([\d.]+) s", t) for t in texts]
        memory = [re.search(r"peak memory: ([\d.]+) MiB", t) for t in texts]
        print("| %s | %s | %s |" % (NAMES.get(base, base), " / ".join(m.group(1) if m else "" for m in cpu),
                                    " / ".join(m.group(1) if m else "" for m in memory)))
    print()
    print("The two-view focal check (results/focal_check.md) runs beside this in every configuration; with `apply`, "
          "its corrections are made too where it disagrees first. The replay, whose input ends, applies a "
          "correction the final refinement calls for as the next keyframe would, then solves and refines again "
          "(twice at most); the node applies it as soon as the refinement lands.")


if __name__ == "__main__":
    main()
