"""Writes results/colmap.md from the runs of scripts/benchmark_colmap.sh.

usage: colmap_report.py OUT DATA COLMAP_VERSION SCENE...
  OUT: the benchmark's folder (one subfolder per scene); DATA: ../shared/data;
  COLMAP_VERSION: e.g. "COLMAP 3.8", or "" when unknown.
"""
import math
import os
import re
import sys

from report_common import reproduce_line, view_errors

ESTIMATES = ("edges_vs_reference", "edges_vs_colmap", "edges_vs_colmap_matches")


def fields(path, label):
    """Every value after `label: ` in the file (the run of [0-9.a-z] that follows), in order."""
    pattern = re.compile(r"^%s: ([0-9.a-z]*)" % re.escape(label))
    values = []
    for line in open(path).read().splitlines():
        match = pattern.match(line)
        if match:
            values.append(match.group(1))
    return values


def field(path, label):
    return "\n".join(fields(path, label))


def floored(path, label):
    """eval --graph prints the covariances as given, with the floor, then with the floor and the view term."""
    values = fields(path, label)
    return values[1] if len(values) > 1 else ""


def viewed(path, label):
    values = fields(path, label)
    return values[2] if len(values) > 2 else ""


def view_error(path, name):
    """The view's error to 4 decimals, or - if it has none."""
    for view, error in view_errors(path):
        if view == name and re.fullmatch(r"[0-9.e+-]*", error):
            return "%.4f" % float(error)
    return "-"


def whole_seconds(path):
    return "%.0f" % float(open(path).read())


def hat(ab, ac, bc):
    """The three-cornered hat: a's own error from the differences of three independent estimates."""
    ab, ac, bc = float(ab), float(ac), float(bc)
    v = (ab * ab + ac * ac - bc * bc) / 2
    return "~0" if v <= 0 else "%.4f" % math.sqrt(v)


def scored_rows(out, scenes, leading, per_estimate, missing):
    """A row per scene whose pairs were scored: the scene, `leading(reference file)`, then per reference
    estimate `per_estimate(its file)`, or `missing` where there is none."""
    for s in scenes:
        w = os.path.join(out, s)
        reference = os.path.join(w, "edges_vs_reference.txt")
        if not os.path.exists(reference):
            continue
        cells = [s] + leading(reference)
        for name in ESTIMATES:
            path = os.path.join(w, name + ".txt")
            cells += per_estimate(path) if os.path.exists(path) else missing
        yield "| " + " | ".join(cells) + " |"


def given_k(data, scene):
    values = open(os.path.join(data, "strecha", scene, "images", "K.txt")).read().split()
    return values[0], values[4]


def main():
    out, data, version, scenes = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4:]
    p = print
    p("# Rotation averaging from images against COLMAP's bundle adjustment")
    p()
    p(reproduce_line("bash scripts/benchmark_colmap.sh", ", %s from Debian" % version))
    p()
    p("""Both methods get the images at full resolution and the given intrinsics. COLMAP:
`feature_extractor` (one PINHOLE camera with the given K, CPU SIFT), `exhaustive_matcher`,
`mapper` (incremental SfM with bundle adjustment; by default it refines the focal length), every
other setting its default. rotavg: `rotavg images` with its defaults (rotation averaging, then
bundle adjustment from the averaged orientations), and with `--no-bundle-adjustment` (the averaging
alone). "On COLMAP's matches": the same back end (the package's two-view estimation, averaging
and bundle adjustment, defaults) on COLMAP's own SIFT features and verified matches from the
database above (`examples/python/colmap_database.py`; seconds exclude COLMAP's extraction and
matching), so that only the back ends differ. All are scored by `rotavg eval` against the
LIDAR-registered cameras: one robustly fitted rotation aligns the estimate, then the angle of every
view's error. Times are wall time of the whole run on this machine.""")
    p()
    p("| scene | views | COLMAP: registered | median (deg) | mean (deg) | AUC@2 (%) | seconds | rotavg: median (deg) "
      "| mean (deg) | AUC@2 (%) | seconds | averaging alone: median (deg) | mean (deg) | on COLMAP's matches: pairs "
      "| median (deg) | mean (deg) | seconds |")
    p("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for s in scenes:
        w = os.path.join(out, s)
        f = lambda name: os.path.join(w, name)  # noqa: E731
        pairs = re.search(r"^relative poses: (\d+ of \d+)", open(f("colmap_matches.log")).read(), re.M)
        ours = " | ".join([
            field(f("rotavg_scores.txt"), "median error"), field(f("rotavg_scores.txt"), "mean error"),
            field(f("rotavg_scores.txt"), "AUC@2"), whole_seconds(f("rotavg_seconds.txt")),
            field(f("averaging_scores.txt"), "median error"), field(f("averaging_scores.txt"), "mean error"),
            pairs.group(1) if pairs else "",
            field(f("colmap_matches_scores.txt"), "median error"), field(f("colmap_matches_scores.txt"), "mean error"),
            whole_seconds(f("colmap_matches_seconds.txt"))])
        views = field(f("rotavg_scores.txt"), "views in ground truth")
        if os.path.exists(f("colmap_failed.txt")):
            p("| %s | %s | mapper did not finish | - | - | - | > %s | %s |" %
              (s, views, whole_seconds(f("colmap_seconds.txt")), ours))
        else:
            colmap = f("colmap_scores.txt")
            p("| %s | %s | %s | %s | %s | %s | %s | %s |" %
              (s, views, field(colmap, "views common"), field(colmap, "median error"), field(colmap, "mean error"),
               field(colmap, "AUC@2"), whole_seconds(f("colmap_seconds.txt")), ours))
    p()
    p("COLMAP's camera after its bundle adjustment (cameras.txt: fx, fy, cx, cy) against the given K:")
    p()
    p("| scene | given fx, fy | COLMAP fx, fy |")
    p("|---|---|---|")
    for s in scenes:
        cameras = os.path.join(out, s, "cameras.txt")
        if not os.path.exists(cameras):
            continue
        fx, fy = given_k(data, s)
        first = [line for line in open(cameras).read().splitlines() if not line.startswith("#")][0].split()
        p("| %s | %s, %s | %.1f, %.1f |" % (s, fx, fy, float(first[4]), float(first[5])))
    p()
    p("## Which reference can check the two-view covariances?")
    p()
    p("""The pairs' covariances (with the floor `rotavg images` adds) are too confident against the
LIDAR-registered cameras (frontend.md, "Calibration"). A pair's error against a reference is its
own plus the reference's: the reference has to be more accurate than the pairs claim to be.
Three estimates of the orientations that share only the images and the given K are rotavg
(our features, matching and back end), COLMAP (its own SIFT, matching and bundle adjustment, which
also refines the focal length) and the reference. Their median view errors against one another
(`rotavg eval`) give, if their errors are independent and isotropic (so that the squared
medians add), each one's own median error: the three-cornered hat,
e_a = sqrt((d_ab^2 + d_ac^2 - d_bc^2) / 2). What rotavg and COLMAP share (the images and the given
K) is counted as the reference's error.""")
    p()
    p("| scene | rotavg - reference | COLMAP - reference | rotavg - COLMAP | rotavg's own | COLMAP's own "
      "| the reference's own | averaging alone - reference | averaging alone - COLMAP |")
    p("|---|---|---|---|---|---|---|---|---|")
    for s in scenes:
        w = os.path.join(out, s)
        if not os.path.exists(os.path.join(w, "rotavg_vs_colmap.txt")):
            continue
        ar = field(os.path.join(w, "rotavg_scores.txt"), "median error")
        cr = field(os.path.join(w, "colmap_scores.txt"), "median error")
        ac = field(os.path.join(w, "rotavg_vs_colmap.txt"), "median error")
        p("| %s | %s | %s | %s | %s | %s | %s | %s | %s |" %
          (s, ar, cr, ac, hat(ar, ac, cr), hat(cr, ac, ar), hat(ar, cr, ac),
           field(os.path.join(w, "averaging_scores.txt"), "median error"),
           field(os.path.join(w, "averaging_vs_colmap.txt"), "median error")))
    p()
    p(""""~0": below what the differences resolve. The last two columns score the averaging alone
(without the bundle adjustment) against the reference and against COLMAP's model, an estimate
independent of ours.""")
    p()
    p("""The pairs of rotavg's averaging (`rotavg eval --graph graph.txt --gt ...`) against three
references: NEES = eta^T (C + s^2 I)^-1 eta with the floor s of `rotavg images` (calibrated:
median 2.37, 95% of pairs below 7.81). "Our bundle adjustment on COLMAP's matches" is the column
"on COLMAP's matches" above: other features than the pairs', the same back end and K.""")
    p()
    p("| scene | pairs | floor (deg) | against the reference: median pair error (deg) | NEES median | within 95% "
      "| against COLMAP's model: median error | NEES median | within 95% | against our bundle adjustment on "
      "COLMAP's matches: median error | NEES median | within 95% |")
    p("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for row in scored_rows(out, scenes,
                           lambda r: [floored(r, "edges scored"), floored(r, "covariance floor")],
                           lambda e: [floored(e, "median edge error"), floored(e, "NEES median"),
                                      floored(e, "NEES within the 95% quantile") + " %"],
                           ["-", "-", "-"]):
        p(row)
    p()
    p("""The same errors split into views and pairs: the per-view offsets that best explain every pair's
error against a reference (one rotation per view, fitted on the pairs' whitened errors with the
floor; in effect the averaging of the pairs about that reference), and the pairs' NEES after them.
What a view's offset holds, all of its pairs share: the reference's own error for that view, or
one that every pair of that image inherits. The pairs' consistency with each other, and the floor
estimated from it, cannot see it, and no covariance of a single pair can express it. What remains
after the offsets is the same against any reference (the fit takes 3 (views - 1) of the
3 x pairs values, about a fifth here, so calibrated pairs would give a median a little below 2.37).""")
    p()
    p("| scene | NEES median after the per-view offsets | median pair error after them (deg) | median per-view "
      "offset (deg): against the reference | against COLMAP's model | against our bundle adjustment on COLMAP's "
      "matches |")
    p("|---|---|---|---|---|---|")
    for row in scored_rows(out, scenes,
                           lambda r: [floored(r, "NEES median after per-view offsets"),
                                      floored(r, "median edge error after per-view offsets")],
                           lambda e: [floored(e, "median per-view offset")], ["-"]):
        p(row)
    p()
    p("""The bundle adjustment `rotavg images` runs can see that shared error: it ties each view's points
and centre to the other views', where each pair's summary has a translation and depths of its
own. The view term v is the standard deviation per axis of the views' offsets against it
(robustly: median |d|^2 over the views = 2.366 v^2 for an isotropic Gaussian), as `rotavg images`
prints it; added to both views of each pair, a pair's covariance is C + (s^2 + 2 v^2) I
(`rotavg eval --graph graph.txt --gt ... --view-term-from rotavg.csv`). It uses no reference.""")
    p()
    p("| scene | view term v (deg per axis) | NEES median with the floor and the view term: against the reference "
      "| within 95% | against COLMAP's model | within 95% | against our bundle adjustment on COLMAP's matches "
      "| within 95% |")
    p("|---|---|---|---|---|---|---|---|")
    view_term = r"^covariances with the floor and the view term \(([0-9.]*) deg"
    for row in scored_rows(out, scenes, lambda r: ["\n".join(re.findall(view_term, open(r).read(), re.M))],
                           lambda e: [viewed(e, "NEES median"), viewed(e, "NEES within the 95% quantile") + " %"],
                           ["-", "-"]):
        p(row)
    p()
    p("Per view (deg), COLMAP / rotavg / the averaging alone / rotavg on COLMAP's matches:")
    for s in scenes:
        w = os.path.join(out, s)
        p()
        p("**%s**" % s)
        p()
        p("| view | COLMAP | rotavg | averaging alone | on COLMAP's matches |")
        p("|---|---|---|---|---|")
        for name, error in view_errors(os.path.join(w, "rotavg_scores.txt")):
            p("| %s | %s | %.4f | %s | %s |" %
              (name, view_error(os.path.join(w, "colmap_scores.txt"), name), float(error),
               view_error(os.path.join(w, "averaging_scores.txt"), name),
               view_error(os.path.join(w, "colmap_matches_scores.txt"), name)))


if __name__ == "__main__":
    main()
