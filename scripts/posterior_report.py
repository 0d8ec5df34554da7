"""Writes results/posterior.md from the runs of scripts/benchmark_posterior.sh.

usage: posterior_report.py OUT INPUTS
  INPUTS: the names of the inputs, comma separated; each has one replay summary per variant,
  OUT/<name>_<variant>.txt (variants: default, grid0, grid2, grid4, averaging, no_refinement,
  no_refinement_no_floor). An input <scene>_full_resolution is the scene's bag scored against
  `rotavg images` on the full-resolution photographs (its summary: OUT/<scene>_full_resolution.txt).
"""
import os
import sys

from report_common import first, reproduce_line, value

LABELS = {
    "demo": "the demo bag: rendered two-camera rig, 1 Hz, every image a keyframe",
    "stream": "the rendered rig at 20 Hz (600 captures), keyframe_selection: motion",
    "one_camera": "its forward camera alone at 20 Hz, keyframe_selection: motion",
    "castle-P19": "castle-P19 as a bag, against the LIDAR-registered cameras",
    "entry-P10": "entry-P10 as a bag, against the LIDAR-registered cameras",
    "fountain-P11": "fountain-P11 as a bag, against the LIDAR-registered cameras",
    "castle-P19_full_resolution": "castle-P19 as a bag, against `rotavg images` at full resolution",
    "entry-P10_full_resolution": "entry-P10 as a bag, against `rotavg images` at full resolution",
    "fountain-P11_full_resolution": "fountain-P11 as a bag, against `rotavg images` at full resolution",
    "lund_door": "lund_door as a bag, against COLMAP's model",
}
AFTER_MEDIAN = r"^posterior covariances against the ground truth: NEES median [\d.]+ \(2.37 if honest\), "


def nees(text):
    """NEES median, mean, % within the bound and keyframes scored of one replay's summary."""
    return [
        value(text, r"^posterior covariances against the ground truth: NEES median ([\d.]+) ", "-"),
        value(text, AFTER_MEDIAN + r"mean ([\d.]+),", "-"),
        value(text, AFTER_MEDIAN + r"mean [\d.]+, ([\d.]+)% within", "-"),
        value(text, AFTER_MEDIAN + r".*, (\d+) keyframes$", "-"),
    ]


def meets(cells):
    """Whether a NEES median and share within the bound meet the target (median 1.5-6, >= 85%)."""
    try:
        return 1.5 <= float(cells[0]) <= 6.0 and float(cells[2]) >= 85.0
    except ValueError:
        return False


def read(out, name, variant):
    """One variant's replay summary (a missing one stops the writer with its name)."""
    return open(os.path.join(out, "%s_%s.txt" % (name, variant))).read()


def main():
    out, inputs = sys.argv[1], sys.argv[2].split(",")
    print("# Posterior covariances against ground truth\n")
    print(reproduce_line("bash scripts/benchmark_posterior.sh"))
    print("""The node publishes a posterior covariance with each keyframe's orientation on `~orientations` (a left
perturbation of the world-to-camera rotation, relative to its component's gauge keyframe). Each replay here
scores its last solution's covariances against a reference: the keyframe's error relative to the gauge,
d = Log(R_k R_g^T R_g,ref R_k,ref^T), whitened by its covariance, NEES = d^T C^-1 d
(`EvaluatePosteriorCovariances`; the gauge and the other cameras of its rig capture are held, not scored;
every replay writes each keyframe's error, standard deviation and NEES to `posterior.csv` in its output
directory). Honest covariances give chi-square with 3 degrees of freedom: median 2.37, mean 3, 95% of keyframes within
7.81. The target is a NEES median within 1.5-6 and at least 85% within the bound on every input. The
EuRoC excerpt in ../shared/data has no ground truth and is not scored.

With the defaults the refinement (`refinement: true`) publishes its keyframes with the bundle adjustment's
covariances (`refinement_covariances: true`, docs/node.md "Background refinement"): the pixel model over the
adjustment's normal equations, scaled by its variance factor, at least in every direction the delete-one-cell
jackknife's over a 3 x 3 grid of each keyframe's observations (`refinement_jackknife_grid`) and the jackknife's
over clusters of whole tracks, those that start in one of those cells (`refinement_jackknife_tracks`: errors a
feature carries along its track), both jackknives' moves scaled to the robust loss' expected Hessian (sum w /
sum w^2 of Cauchy's weights, docs/decisions.md), relative to the keyframe the averaging holds best, plus that
keyframe's own covariance in the averaging.""")
    print("""
## The defaults

A reference's own error is in every NEES against it. The Strecha scenes' LIDAR-registered cameras are
0.02-0.05 deg from the truth per view (results/README.md, "Against which reference?"), as far as the node at a
quarter of the resolution is from them; so each scene is also scored against `rotavg images` on the
full-resolution photographs (every pair, focal self-calibration, bundle adjustment: sixteen times the pixels
of the bag's images), whose own median error against the LIDAR-registered cameras is given in the row. It
shares the images, K and the method with the node, so an error they share cannot show against it.
""")
    print("| input | keyframes | median error (deg) | NEES median | NEES mean | within chi-square's 95% bound (%) "
          "| keyframes scored | meets the target |")
    print("|---|---|---|---|---|---|---|---|")
    for name in inputs:
        text = read(out, name, "default")
        label = LABELS.get(name, name)
        if name.endswith("_full_resolution"):
            summary = open(os.path.join(out, name + ".txt")).read()
            own = first(summary, r"^median error: ([\d.]+) deg", "-")
            label += " (its own median error against the LIDAR-registered cameras: %s deg)" % own
        cells = nees(text)
        print("| " + " | ".join([label, value(text, r"^keyframes: (\d+) ", "-"),
                                 value(text, r"^median error: ([\d.]+) deg", "-")] + cells +
                                ["yes" if meets(cells) else "no"]) + " |")
    print("""
## The jackknife's grid, and the averaging's covariances

NEES median / % within the bound of the same replays with the adjustment's covariances as the pixel model alone
(`refinement_jackknife_grid: 0`), with the jackknives over 2 x 2, 3 x 3 (the default) and 4 x 4 cells (the cells' and
the track clusters'), with the cells' alone over 3 x 3 (`refinement_jackknife_tracks: false`); with the
averaging's covariances for the refined orientations (`refinement_covariances: false`); and without the refinement
(`refinement: false`: the averaging's orientations and covariances), with the covariance floor of its residuals
(`posterior_covariance_floor: true`, the default) and without it. The orientations are the same in every column
but the last two.
""")
    columns = [("grid0", "pixel model alone"), ("grid2", "2 x 2"), ("default", "3 x 3 (default)"),
               ("grid4", "4 x 4"), ("cells_alone", "3 x 3, the cells' alone"),
               ("averaging", "the averaging's, refined orientations"),
               ("no_refinement", "no refinement, with the floor"),
               ("no_refinement_no_floor", "no refinement, without the floor")]
    print("| input | " + " | ".join(label for _, label in columns) + " |")
    print("|---|" + "---|" * len(columns))
    totals = {variant: 0 for variant, _ in columns}
    for name in inputs:
        row = [name.replace("_full_resolution", ", against full resolution")]
        for variant, _ in columns:
            cells = nees(read(out, name, variant))
            totals[variant] += meets(cells)
            row.append("%s / %s%s" % (cells[0], cells[2], " (meets)" if meets(cells) else ""))
        print("| " + " | ".join(row) + " |")
    print("| inputs meeting the target | " + " | ".join(str(totals[v]) for v, _ in columns) + " |")
    rigs = [(name, label) for name, label in [("demo", "the demo bag (two cameras, 1 Hz)"),
                                              ("stream", "the rig at 20 Hz (two cameras)"),
                                              ("four_cameras", "the rig's four cameras at 20 Hz")]
            if os.path.exists(os.path.join(out, name + "_rig_joint.txt"))]
    if rigs:
        print("""
## A rig's covariances

With the rig's extrinsics known, the refinement turns each capture's cameras together, every camera's tracks
holding the capture. The refined keyframes' covariances by default come from each camera's own tracks at that
solution, relative to its own camera's view of the reference capture, a capture's cameras getting that of the
camera its tracks hold best (`refinement_rig_joint_covariance: false`); here also those of the joint problem the
rig makes (`true`). The four-camera rig: the demo renderer's rig as a 20 Hz driver
publishes it (`--captures 600 --period 0.05 --cameras 4`), `keyframe_selection: motion`. NEES median / % within
the bound; the orientations are the same in both columns.
""")
        print("| input | median error (deg) | each camera's own (default) | the rig's joint problem |")
        print("|---|---|---|---|")
        for name, label in rigs:
            own = read(out, name, "default")
            joint = read(out, name, "rig_joint")
            row = [label, value(own, r"^median error: ([\d.]+) deg", "-")]
            for text in (own, joint):
                cells = nees(text)
                row.append("%s / %s%s" % (cells[0], cells[2], " (meets)" if meets(cells) else ""))
            print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
