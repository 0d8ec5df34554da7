"""Writes results/replay.md from the runs of scripts/benchmark_replay.sh.

usage: replay_report.py OUT DATA SCENES OFFLINE
  OUT: the benchmark's folder; DATA: ../shared/data; SCENES: the Strecha scenes replayed, comma separated
  (may be empty); OFFLINE: the scenes compared with `rotavg images`, comma separated.
"""
import os
import re
import sys

from report_common import reproduce_line, value

MEDIAN = r"^median error: ([0-9.]*) deg"
MEAN = r"^mean error: ([0-9.]*) deg"
RECALL = r"^recall of the correct verifiable loop pairs: (.*)$"
FOUND = r"^found by retrieval: (.*)$"


class Runs:
    def __init__(self, out):
        self.out = out

    def path(self, name):
        return os.path.join(self.out, name)

    def text(self, name):
        return open(self.path(name)).read()


def table_head(p, header):
    """A table's header line and the line under it."""
    p(header)
    p("|" + "---|" * header.count(" | ") + "---|")


def auc(text, threshold):
    return value(text, r"^AUC@%d: ([0-9.]*) %%" % threshold)


def bag_row(label, text):
    cells = [label, value(text, r"^keyframes: ([0-9]*) "), value(text, r"^bag time: ([0-9.]*) s"),
             value(text, r"wall time: ([0-9.]*) s"), value(text, r"\(([0-9.]*)x real time\)") + "x",
             value(text, r"CPU time: ([0-9.]*) s"), value(text, r"peak memory: ([0-9.]*) MiB"),
             value(text, MEDIAN), auc(text, 2), auc(text, 5), auc(text, 10)]
    return "| " + " | ".join(cells) + " |"


def cost(text):
    return "%.2f" % float(text) if text else "-"


def offline_row(label, node, afresh, offline):
    """The node's summary against the offline run's; `afresh`: the node's graph solved again, or None."""
    node_median, offline_median = value(node, MEDIAN), value(offline, MEDIAN)
    cells = [label, value(node, r"^keyframes: ([0-9]*) "), value(node, r"^solved variables: .*; edges: ([0-9]*) "),
             node_median, value(node, MEAN), cost(value(node, r"; final cost: ([0-9.]*)$"))]
    if afresh is not None:
        cells += [value(afresh, MEDIAN), value(afresh, MEAN), cost(value(afresh, r"^final cost: ([0-9.]*)$"))]
    else:
        cells += ["-", "-", "-"]
    cells += [value(offline, r"^averaging: components solved: .*, ([0-9]*) edges\)$"), offline_median,
             "%.2f" % (float(node_median) / float(offline_median))]
    return "| " + " | ".join(cells) + " |"


def recall_row(scene, runs, data):
    vocabulary, voting = runs.text(scene + "_vocabulary_recall.txt"), runs.text(scene + "_voting_recall.txt")
    images = [f for f in os.listdir(os.path.join(data, "strecha", scene, "images"))
              if f.lower().endswith((".jpg", ".png"))]
    pairs = "\n".join("%s (%s correct)" % m.groups() for m in
                      re.finditer(r"^loop pairs .*: ([0-9]*), of them correct \(< 2 deg\): ([0-9]*)$", vocabulary,
                                  re.M))
    cells = [scene, str(len(images)), pairs, value(vocabulary, FOUND), value(vocabulary, RECALL),
             value(vocabulary, r"median fraction ([0-9.]*)", "-"), value(voting, FOUND), value(voting, RECALL)]
    return "| " + " | ".join(cells) + " |"


def compact_row(scene, mode, label, runs):
    summary, recall = runs.text("%s_%s.txt" % (scene, mode)), runs.text("%s_%s_recall.txt" % (scene, mode))
    cells = [scene, label, value(summary, r"compact, ([0-9.]*) KB each", "-"), value(recall, RECALL),
             value(summary, MEDIAN), value(summary, MEAN), auc(summary, 2)]
    return "| " + " | ".join(cells) + " |"


def loop_row(scene, mode, label, runs):
    summary, recall = runs.text("%s_%s.txt" % (scene, mode)), runs.text("%s_%s_recall.txt" % (scene, mode))
    cells = [scene, label, value(recall, FOUND), value(recall, RECALL),
             value(recall, r"^whitened squared errors.*; median ([0-9.]*)$", "-"),
             value(summary, MEDIAN), value(summary, MEAN), auc(summary, 2)]
    return "| " + " | ".join(cells) + " |"


def place_row(label, option, summary, recall):
    """A replay with or without one_loop_per_place; `recall`: its loop recall's output, or None."""
    cells = [label, option, value(summary, r"^loop closures: ([0-9]*) edges"),
             value(summary, r"^  and ([0-9]*) dropped for a loop with more inliers", "0"),
             value(recall, RECALL) if recall is not None else "-",
             value(summary, MEDIAN), value(summary, MEAN), auc(summary, 2)]
    return "| " + " | ".join(cells) + " |"


def window_row(label, option, summary, offline):
    """A bag with or without window_pairs: its window edges, speed and errors, and the ratio to the offline run."""
    median = value(summary, MEDIAN)
    found = re.search(r"^window pairs: ([0-9]*) edges .*, ([0-9]*) verified but off", summary, re.M)
    cells = [label, option, found.group(1) if found else "0", found.group(2) if found else "0",
             value(summary, r"pair verification ([0-9.]*) ms"), value(summary, r"\(([0-9.]*)x real time\)") + "x",
             median, value(summary, MEAN), auc(summary, 2),
             "%.2f" % (float(median) / float(value(offline, MEDIAN)))]
    return "| " + " | ".join(cells) + " |"


def main():
    out, data = sys.argv[1], sys.argv[2]
    scenes = [s for s in sys.argv[3].split(",") if s]
    offline = [s for s in sys.argv[4].split(",") if s]
    runs = Runs(out)
    castle = os.path.exists(runs.path("castle-P19_vocabulary.txt"))
    p = print
    p("# Bag replay")
    p()
    p(reproduce_line("bash scripts/benchmark_replay.sh"))
    p("""Each bag goes through `rotation_averaging_replay` (the node's pipeline: SIFT front end with
loop-closure retrieval, MAGSAC + covariance averaging re-solved every second of bag time). Speed-up =
bag duration / wall time; both bags hold one capture per second.""")
    p()
    table_head(p, "| bag | keyframes | bag time (s) | wall (s) | speed-up | CPU (s) | peak MiB | median (deg) | AUC@2 | AUC@5 "
      "| AUC@10 |")
    p(bag_row("demo: rendered 2-camera rig, 640x480, 60 captures (config/demo.yaml)", runs.text("demo.txt")))
    if castle:
        p(bag_row("castle-P19 at 768x512 (one camera, 19 images)", runs.text("castle-P19_vocabulary.txt")))
    p()
    p("## Demo bag")
    p()
    p("```")
    p(runs.text("demo.txt").rstrip("\n"))
    p("```")
    if castle:
        p()
        p("## castle-P19")
        p()
        p("Made with `rotation_averaging_images_to_bag --images castle-P19/images --intrinsics "
          "castle-P19/images/K.txt --gt castle-P19 --downsample 0.25`.")
        p()
        p("```")
        p(runs.text("castle-P19_vocabulary.txt").rstrip("\n"))
        p("```")
    if not scenes:
        p()
        p("The Strecha scenes were skipped: %s/strecha is absent." % data)
        return
    p()
    p("## The node against `rotavg images` on the same images")
    p()
    p("""The Strecha bags above, and lund_door (12 photographs, COLMAP's model as ground truth) made the same
way, replayed with the defaults, against `rotavg images --pairs exhaustive
--downsample 0.25 --no-bundle-adjustment` on the same images (every pair tried, the averaging
alone). "afresh": the node's final graph solved by `rotavg solve` from its spanning tree, as the
offline solve starts (the replay's solves start from the solution before, and from the spanning
tree alone when new keyframes came, keeping the lower cost), scored against the replay's
`ground_truth.csv`. The demo: its 120 images at full size (`rotation_averaging_make_demo_bag
--images-dir`) against its bag replayed with config/demo.yaml, whose rig's extrinsics the node
uses and the offline run cannot (each image is a view of its own there; no afresh solve: the
node's graph is of rig captures). Median and mean errors in degrees; cost: the final cost of the
averaging's objective (the same for both solves of one graph: where the node's is lower, its graph
prefers the node's solution to the one from the spanning tree); ratio: the node's median over the
offline one.""")
    p()
    table_head(p, "| scene | keyframes | node: edges | node: median | node: mean | node: cost "
      "| afresh: median | afresh: mean | afresh: cost | offline: edges | offline: median | ratio |")
    for s in offline:
        p(offline_row(s, runs.text(s + "_vocabulary.txt"), runs.text(s + "_afresh.txt"),
                      runs.text(s + "_exhaustive.txt")))
    p(offline_row("demo (two cameras, rig)", runs.text("demo.txt"), None, runs.text("demo_exhaustive.txt")))
    p()
    p("## Loop-closure recall on the Strecha scenes played as sequences")
    p()
    p("""Each scene's images in order as a bag, as castle-P19 above; each path returns towards its start.
Against an exhaustive two-view search of the same images (`rotavg images --pairs exhaustive
--downsample 0.25`, then `rotavg_loop_recall`): the loop pairs (more than 5 images apart) the search
verifies with >= 60 inliers, of them those within 2 deg of ground truth, and how many of them the
front end found, with the vocabulary (defaults: compact keyframes of 1000 features) and with voting
over every keyframe's full features (`vocabulary: none`: no memory bound, cost growing with the
map). "inliers kept": median over the loops found of their inliers against the exhaustive search's
for the same pair (a compact keyframe keeps part of its correspondences).""")
    p()
    table_head(p, "| scene | images | loop pairs verifiable | vocabulary: found | vocabulary: recall | inliers kept "
      "| voting: found | voting: recall |")
    for s in scenes:
        p(recall_row(s, runs, data))
    p()
    p("### Loop closures and their covariances")
    p()
    p("""A loop-closure pair is a wide-baseline pair: groups of its matches share their error (repeated
structure matched to its neighbour), which the pixel model counts as independent. The node gives
loop closures the cell jackknife's covariance (`loop_jackknife_grid: 4`, the default)
and accepts them from `min_loop_inliers` (default 40) inliers. The same bags with the pixel model
for loop closures (`loop_jackknife_grid: 0`), and with it at `min_loop_inliers: 60`.
"loop NEES": median whitened squared error of the loop closures found against ground truth (3 when
their covariances are calibrated); errors of the replay's final solution.""")
    p()
    table_head(p, "| scene | loop closures | found | loop recall | loop NEES | median (deg) | mean (deg) | AUC@2 (%) |")
    for s in scenes:
        p(loop_row(s, "vocabulary", "defaults: jackknife, >= 40 inliers", runs))
        p(loop_row(s, "pixel", "pixel model, >= 40 inliers", runs))
        p(loop_row(s, "pixel60", "pixel model, >= 60 inliers", runs))
    p()
    p("### One loop closure per place")
    p()
    p("""The loop closures of one keyframe to neighbouring old keyframes (one after the other on one
camera's chain) see one place through near-duplicate images, so wrong matches on its repeated
structure recur in all of them. With `one_loop_per_place: true` (the default) a loop is dropped when
one with more inliers reaches the keyframe next to its old end; `false` keeps every loop. "dropped":
loops so dropped. Errors against ground truth of the replay's final solution.""")
    p()
    table_head(p, "| bag | one_loop_per_place | loop closures | dropped | loop recall | median (deg) | mean (deg) "
      "| AUC@2 (%) |")
    for s in offline:
        for mode, option in (("vocabulary", "true (default)"), ("all", "false")):
            recall = runs.path("%s_%s_recall.txt" % (s, mode))
            p(place_row(s, option, runs.text("%s_%s.txt" % (s, mode)),
                        open(recall).read() if os.path.exists(recall) else None))
    p(place_row("demo (config/demo.yaml)", "true (default)", runs.text("demo.txt"), None))
    p(place_row("demo (config/demo.yaml)", "false", runs.text("demo_all.txt"), None))
    p()
    p("### Window pairs")
    p()
    p("""A keyframe is related to the previous keyframe of its camera (and, when that pair fails, to the
newest of its `covisibility_window` that verifies). With `window_pairs: true` (the default) it is
also related to the older keyframes of the window (two and three before it), each pair kept when it
agrees with the rotation the chain through the previous keyframe predicts (within three standard
deviations of both), with the cell jackknife's covariance as loop closures have; `false` keeps the
chain alone. "window edges": pairs so kept; "off the chain": verified but dropped. "pairs, ms": pair
verification per keyframe (two more pairs each with window pairs); speed-up against real time.
Errors against ground truth of the replay's final solution; ratio: the median over `rotavg images`'
in the table above.""")
    p()
    table_head(p, "| bag | window_pairs | window edges | off the chain | pairs, ms | speed-up | median (deg) "
      "| mean (deg) | AUC@2 (%) | ratio to rotavg images |")
    for s in offline:
        exhaustive = runs.text(s + "_exhaustive.txt")
        p(window_row(s, "true (default)", runs.text(s + "_vocabulary.txt"), exhaustive))
        p(window_row(s, "false", runs.text(s + "_chain.txt"), exhaustive))
    p(window_row("demo (config/demo.yaml)", "true (default)", runs.text("demo.txt"), runs.text("demo_exhaustive.txt")))
    p(window_row("demo (config/demo.yaml)", "false", runs.text("demo_chain.txt"), runs.text("demo_exhaustive.txt")))
    p()
    p("### Twice the features per compact keyframe")
    p()
    p("""The same bags with `compact_features: 2000` (twice the default; packed descriptors keep them
under 200 KB): more loop closures are found, but those loop pairs err several times the standard
deviations their covariances give, even with the jackknife (errors and NEES in the lists below),
and the averaging is less accurate with them. Errors against ground truth of the replay's final
solution.""")
    p()
    table_head(p, "| scene | compact features | KB per compact keyframe | loop recall | median (deg) | mean (deg) | AUC@2 (%) |")
    for s in scenes:
        p(compact_row(s, "vocabulary", "1000 (default)", runs))
        p(compact_row(s, "compact2000", "2000", runs))
    for s in scenes:
        p()
        p("### %s" % s)
        p()
        p("```")
        for label, mode in (("vocabulary:", "vocabulary"), ("voting:", "voting"),
                            ("vocabulary, compact_features 2000:", "compact2000"),
                            ("vocabulary, loop closures with the pixel model (loop_jackknife_grid 0):", "pixel"),
                            ("the same at min_loop_inliers 60:", "pixel60"),
                            ("vocabulary, every loop kept (one_loop_per_place false):", "all"),
                            ("vocabulary, the chain alone (window_pairs false):", "chain")):
            p(label)
            p(runs.text("%s_%s_recall.txt" % (s, mode)).rstrip("\n"))
        p("```")


if __name__ == "__main__":
    main()
