"""Writes results/posterior.md from the runs of scripts/benchmark_posterior.sh.

usage: posterior_report.py OUT INPUTS
  INPUTS: the names of the runs (OUT/<name>.txt, replay summaries with the defaults, and
  OUT/<name>_no_floor.txt, with posterior_covariance_floor: false), comma separated.
"""
import os
import sys

from report_common import reproduce_line, value

LABELS = {
    "demo": "the demo bag: rendered two-camera rig, 1 Hz, every image a keyframe",
    "stream": "the rendered rig at 20 Hz (600 captures), keyframe_selection: motion",
    "castle-P19": "castle-P19 as a bag (quarter resolution)",
    "entry-P10": "entry-P10 as a bag (quarter resolution)",
    "fountain-P11": "fountain-P11 as a bag (quarter resolution)",
    "lund_door": "lund_door as a bag (quarter resolution; COLMAP's model as ground truth)",
}
POSTERIOR = r"^posterior covariances against the ground truth: NEES median ([\d.]+) \(2.37 if honest\), "
AFTER_MEDIAN = r"^posterior covariances against the ground truth: NEES median [\d.]+ \(2.37 if honest\), "


def nees(text):
    """NEES median, mean, % within the bound and keyframes scored of one replay's summary."""
    return [
        value(text, POSTERIOR, "-"),
        value(text, AFTER_MEDIAN + r"mean ([\d.]+),", "-"),
        value(text, AFTER_MEDIAN + r"mean [\d.]+, ([\d.]+)% within", "-"),
        value(text, AFTER_MEDIAN + r".*, (\d+) keyframes$", "-"),
    ]


def row(name, text, no_floor):
    cells = [LABELS.get(name, name), value(text, r"^keyframes: (\d+) ", "-"),
             value(text, r"^median error: ([\d.]+) deg", "-")]
    cells += nees(text)
    cells += [nees(no_floor)[0], nees(no_floor)[2]]
    return "| " + " | ".join(cells) + " |"


def main():
    out, inputs = sys.argv[1], sys.argv[2].split(",")
    print("# Posterior covariances against ground truth\n")
    print(reproduce_line("bash scripts/benchmark_posterior.sh"))
    print("""The node publishes a posterior covariance with each keyframe's orientation on `~orientations` (a left
perturbation of the world-to-camera rotation, relative to its component's gauge keyframe). Each replay here
scores its last solution's covariances against the ground truth: the keyframe's error relative to the gauge,
d = Log(R_k R_g^T R_g,true R_k,true^T), whitened by its covariance, NEES = d^T C^-1 d
(`EvaluatePosteriorCovariances`; the gauge and the other cameras of its rig capture are held, not scored).
Honest covariances give chi-square with 3 degrees of freedom: median 2.37, mean 3, 95% of keyframes within
7.81. The target is a NEES median within 1.5-6 and at least 85% within the bound on every input. The
EuRoC excerpt in ../shared/data has no ground truth and is not scored.

The defaults compute the posterior from edges widened by the covariance floor their residuals show,
C + s^2 I (`posterior_covariance_floor: true`, `ComputeViewCovariances`); the last two columns are the same
replay with `posterior_covariance_floor: false`, where the residual variance factor alone scales the
posterior (the solution is the same). A floor the residuals cannot see, an error all of a view's pairs
share (results/README.md, "The view term"), is left in neither.

| input | keyframes | median error (deg) | NEES median | NEES mean | within chi-square's 95% bound (%) | keyframes scored | NEES median without the floor | within the bound without the floor (%) |
|---|---|---|---|---|---|---|---|---|""")
    for name in inputs:
        text = open(os.path.join(out, name + ".txt")).read()
        print(row(name, text, open(os.path.join(out, name + "_no_floor.txt")).read()))


if __name__ == "__main__":
    main()
