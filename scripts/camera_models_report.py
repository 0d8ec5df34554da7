"""Writes results/camera_models.md from the runs of scripts/benchmark_camera_models.sh.

usage: camera_models_report.py OUT EUROC_MAV0 PLUMB_BOB FISHEYE SCENE...
"""
import os
import re
import sys

import numpy as np

from report_common import first, reproduce_line, view_errors


def quaternion_matrix(w, x, y, z):
    q = np.array([w, x, y, z]) / np.linalg.norm([w, x, y, z])
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def angle_deg(r):
    return np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1)))


# The demo's inputs replayed without the rig: (run name, label).
DEMO_PAIR_INPUTS = (("none_model", "original images"), ("plumb_bob_model", "plumb_bob, with the model"),
                    ("plumb_bob_rectified", "plumb_bob, warped, then rectified"))


def demo_pair_runs(out):
    """(run name, label, its `rotavg eval --graph` output) of each demo input that ran."""
    for input, label in DEMO_PAIR_INPUTS:
        scored = os.path.join(out, "demo_%s_pairs_eval.txt" % input)
        if os.path.exists(scored):
            yield input, label, scored


def edge_sources(graph_txt):
    """{pair of keyframe names: edge source} of a graph file's edges; a
    sequential edge between keyframes of one camera that are not next to each
    other in its sequence (a window pair, or a failed pair bridged) is
    "window pair"."""
    names, sources = {}, {}
    for line in open(graph_txt):
        f = line.split()
        if f and f[0] == "VIEW":
            names[f[1]] = f[2]
        elif f and f[0] == "EDGE":
            sources[frozenset((f[1], f[2]))] = f[3]
    order = {}  # keyframe name (camera@stamp) -> its place in its camera's sequence
    for camera in {n.split("@")[0] for n in names.values()}:
        own = sorted((n for n in names.values() if n.split("@")[0] == camera), key=lambda n: int(n.split("@")[1]))
        order.update({n: i for i, n in enumerate(own)})
    out = {}
    for ids, source in sources.items():
        pair = frozenset(names[i] for i in ids)
        a, b = sorted(pair)
        if source == "sequential" and a.split("@")[0] == b.split("@")[0] and abs(order[a] - order[b]) > 1:
            source = "window pair"
        out[pair] = source
    return out


def pair_kinds(graph_txt, per_edge_txt):
    """{kind: [(error_deg, nees)]} of a graph's scored pairs: sequential,
    loop closures within a camera, loop closures between cameras (a keyframe
    name is camera@stamp)."""
    source_by_names = edge_sources(graph_txt)
    kinds = {}
    for line in open(per_edge_txt):
        f = line.split()
        if not f or f[0] != "edge":
            continue
        source = source_by_names[frozenset((f[1], f[2]))]
        if source not in ("sequential", "window pair"):
            source = "loop closure, " + ("one camera" if f[1].split("@")[0] == f[2].split("@")[0] else
                                         "two cameras")
        kinds.setdefault(source, []).append((float(f[3]), float(f[4])))
    return kinds


def sequential_pairs(out, scene, run):
    """{pair of keyframe names: (error_deg, nees)} of a Strecha run's
    sequential pairs, or None if the run was not scored."""
    scored = os.path.join(out, "%s_%s_eval.txt" % (scene, run))
    if not os.path.exists(scored):
        return None
    sources = edge_sources(os.path.join(out, "%s_%s" % (scene, run), "graph.txt"))
    sequential = {names for names, source in sources.items() if source == "sequential"}
    pairs = {}
    for line in open(scored):
        f = line.split()
        if f and f[0] == "edge" and frozenset((f[1], f[2])) in sequential:
            pairs[frozenset((f[1], f[2]))] = (float(f[3]), float(f[4]))
    return pairs


def strecha_pair_table(out, scenes):
    """The Strecha scenes' sequential pairs common to the original input,
    each lens with its model and the same lens warped, then rectified."""
    print("| scene | lens | pairs | original: median pair error (deg) | with the model | warped, then rectified "
          "| ratio, model to rectified | pairs where the model is closer | NEES median: original / model / rectified |")
    print("|---|---|---|---|---|---|---|---|---|")
    for scene in scenes:
        original = sequential_pairs(out, scene, "none_model")
        for lens in ("plumb_bob", "equidistant"):
            model = sequential_pairs(out, scene, lens + "_model")
            rectified = sequential_pairs(out, scene, lens + "_rectified")
            if original is None or model is None or rectified is None:
                continue
            common = sorted(set(original) & set(model) & set(rectified), key=sorted)
            if not common:
                continue
            runs = (original, model, rectified)
            err = [np.array([r[p][0] for p in common]) for r in runs]
            nees = [np.median([r[p][1] for p in common]) for r in runs]
            print("| %s | %s | %d | %.4f | %.4f | %.4f | %.2f | %d of %d | %.1f / %.1f / %.1f |" % (
                scene, lens, len(common), np.median(err[0]), np.median(err[1]), np.median(err[2]),
                np.median(err[1]) / np.median(err[2]), int(np.sum(err[1] < err[2])), len(common), *nees))


STRECHA_RUNS = (("original", "none_model"), ("plumb_bob, with the model", "plumb_bob_model"),
                ("plumb_bob, warped, then rectified", "plumb_bob_rectified"),
                ("equidistant, with the model", "equidistant_model"),
                ("equidistant, warped, then rectified", "equidistant_rectified"))


def strecha_view_tables(out, scenes):
    median = r"^median error: ([0-9.]+) deg"
    for scene in scenes:
        # Each view's error (deg), in name order.
        rows = [(label, [float(e) for _, e in sorted(view_errors(os.path.join(out, "%s_%s_views.txt" % (scene, run))))])
                for label, run in STRECHA_RUNS]
        n = max(len(e) for _, e in rows)
        print("%s, each view's error (deg), views in name order:" % scene)
        print()
        print("| input | " + " | ".join(str(k) for k in range(n)) + " |")
        print("|---|" + "---|" * n)
        for label, errors in rows:
            print("| %s | " % label + " | ".join("%.2f" % e for e in errors) + " |")
        print()
    print("The plumb_bob inputs with loop closures admitted at fewer and at more inliers (`min_loop_inliers`,")
    print("default 40): median error (deg).")
    print()
    print("| scene | input | 36 | 40 (default) | 44 |")
    print("|---|---|---|---|---|")
    for scene in scenes:
        for label, run in STRECHA_RUNS[:3]:
            cells = [summary_value(os.path.join(out, "%s_%s_loops36.txt" % (scene, run)), median),
                     summary_value(os.path.join(out, "%s_%s.txt" % (scene, run)), median),
                     summary_value(os.path.join(out, "%s_%s_loops44.txt" % (scene, run)), median)]
            print("| %s | %s | %s |" % (scene, label, " | ".join(cells)))


def body_from_camera(sensor_yaml):
    """T_BS's rotation (camera-to-body) from a EuRoC sensor.yaml."""
    text = open(sensor_yaml).read()
    block = re.search(r"T_BS:.*?data:\s*\[(.*?)\]", text, re.S).group(1)
    t = np.array([float(v) for v in block.replace("\n", " ").split(",")]).reshape(4, 4)
    return t[:3, :3]


def stereo_errors(orientations_csv, r10):
    """Per capture: angle between the solved cam0 -> cam1 rotation and r10."""
    world_to_camera = {}
    for line in open(orientations_csv).read().splitlines()[1:]:
        name, *q = line.split(",")
        camera, stamp = name.split("@")
        world_to_camera[(camera, stamp)] = quaternion_matrix(*map(float, q))
    errors = []
    for (camera, stamp), r0 in world_to_camera.items():
        r1 = world_to_camera.get(("cam1", stamp)) if camera == "cam0" else None
        if r1 is not None:
            errors.append(angle_deg(r1 @ r0.T @ r10.T))  # x_cam1 = R1 R0^T x_cam0
    return np.array(errors)


def summary_value(path, pattern):
    return first(open(path).read(), pattern, "-")


# The demo read out of a larger sensor (benchmark_camera_models.sh, readout):
# (run name, sensor, readout, lens, camera_info's principal point).
READOUTS = (
    ("none_model", "640x480", "whole", "none", "right"),
    ("readout_binned", "1280x960", "binned 2 x 2", "none", "right"),
    ("readout_binned_offset", "1280x960", "binned 2 x 2", "none", "0.5 px off (image_geometry's binning)"),
    ("readout_roi", "800x600", "640x480 region at (80, 60)", "none", "right"),
    ("plumb_bob_model", "640x480", "whole", "plumb_bob", "right"),
    ("readout_binned_plumb_bob", "1280x960", "binned 2 x 2", "plumb_bob", "right"),
    ("readout_binned_plumb_bob_offset", "1280x960", "binned 2 x 2", "plumb_bob",
     "0.5 px off (image_geometry's binning)"),
    ("readout_roi_plumb_bob", "800x600", "640x480 region at (80, 60)", "plumb_bob", "right"),
)


def readout_table(out, median):
    """The demo read out of a larger sensor binned or by a region of interest."""
    runs = [r for r in READOUTS if os.path.exists(os.path.join(out, "demo_%s.txt" % r[0]))]
    if not runs:
        return
    print()
    print("## A sensor read out binned or by a region of interest")
    print()
    print("A driver that bins its sensor's pixels or reads out a region of it keeps camera_info's K, width and")
    print("height those of the full sensor and says how it read it out in `binning_x`, `binning_y` and `roi`")
    print("(REP 104). The demo (two cameras, 60 captures, `config/demo.yaml`) rendered on a larger sensor with the")
    print("same field of view and read out as such a driver does (`rotation_averaging_make_demo_bag --binning 2`:")
    print("each image pixel the mean of a 2 x 2 block; `--roi`: a region of the sensor), against the demo rendered")
    print("at 640x480 directly. A binned pixel lies at the centre of its block, half a sensor pixel from where")
    print("image_geometry's binning formula puts it: the rows with camera_info's principal point that far off")
    print("(`--info-principal-offset 0.5,0.5`) are what that formula would give.")
    print()
    print("| sensor | readout | image | lens | camera_info's principal point | keyframes | median (deg) |")
    print("|---|---|---|---|---|---|---|")
    for name, sensor, readout, lens, principal in runs:
        summary = os.path.join(out, "demo_%s.txt" % name)
        keyframes = summary_value(summary, r"^keyframes: (\d+)")
        print("| %s | %s | 640x480 | %s | %s | %s | %s |" % (sensor, readout, lens, principal, keyframes,
                                                            summary_value(summary, median)))



def main():
    out, mav0, plumb_bob, fisheye, scenes = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4], sys.argv[5:]
    r10 = body_from_camera(os.path.join(mav0, "cam1/sensor.yaml")).T @ body_from_camera(
        os.path.join(mav0, "cam0/sensor.yaml"))
    print("# Camera models: raw, distorted images")
    print()
    print(reproduce_line("bash scripts/benchmark_camera_models.sh"))
    print("Every run is `rotation_averaging_replay` (the node's pipeline) on a bag whose `camera_info` carries")
    print("the lens's model, as a camera driver's `image_raw` does. *with the model*: `image_type: auto` (the")
    print("default: keypoints undistorted by camera_info's K, distortion_model and D); *model ignored*: the same")
    print("bag with `image_type: rectified` (camera_info's P, no undistortion), which is what the node did with")
    print("every image before it read D; *rectified input*: the images themselves undistorted.")
    print()
    print("## EuRoC V1_01: a real stereo camera at 20 Hz")
    print()
    print("`rotation_averaging_images_to_bag --euroc` on `euroc_v1_01_micro/mav0`: 95 captures of cam0 and")
    print("cam1 (752x480, radial-tangential, k1 = -0.28), their `camera_info` from `sensor.yaml`. The replay")
    print("does not use the rig's extrinsics (`use_rig_extrinsics: false`), so each capture's two keyframes")
    print("are solved on their own; the table compares their solved relative rotation with the calibration's")
    print("(cam0 -> cam1 from the two T_BS: %.3f deg)." % angle_deg(r10))
    print()
    print("| input | captures | median error (deg) | 90th percentile (deg) | max (deg) | wall (s) |")
    print("|---|---|---|---|---|---|")
    for name, label in (("euroc_model", "image_raw, with the model"),
                        ("euroc_ignored", "image_raw, model ignored"),
                        ("euroc_rectified", "rectified images (`--rectify`)")):
        e = stereo_errors(os.path.join(out, name, "orientations.csv"), r10)
        wall = summary_value(os.path.join(out, name + ".txt"), r"wall time: ([0-9.]+) s")
        print("| %s | %d | %.3f | %.3f | %.3f | %s |" % (label, len(e), np.median(e), np.percentile(e, 90), e.max(),
                                                        wall))
    print()
    print("## Known distortion on real and rendered images")
    print()
    print("Strecha scenes (one camera, images at a quarter of full width, in name order as a sequence) and the")
    print("demo renderer (two cameras, 60 captures, `config/demo.yaml`), written through a lens with")
    print("`--distortion`: plumb_bob `%s` and equidistant (fisheye) `%s`, the scene's K kept. The" %
          (plumb_bob.split(":", 1)[1], fisheye.split(":", 1)[1]))
    print("corners of the Strecha scenes' plumb_bob images see rays outside the original image and are black;")
    print("the demo renders the wider field the lens sees (no black pixel). Median error of")
    print("the keyframes' orientations against ground truth (one robustly fitted rotation). *warped, then")
    print("rectified*: the lens's images undistorted again (`--distortion ... --rectify`), the same content")
    print("through the same two resamplings, without a model to apply (image_proc's `image_rect` of the raw")
    print("stream). The two ratios: the median with the model over the original input's, and over the warped,")
    print("then rectified images'.")
    print()
    print("| scene | lens | original input: median (deg) | with the model: median (deg) | ratio to original | model ignored: median (deg) | warped, then rectified: median (deg) | ratio to rectified |")
    print("|---|---|---|---|---|---|---|---|")
    median = r"^median error: ([0-9.]+) deg"
    for scene in list(scenes) + ["demo"]:
        base = summary_value(os.path.join(out, scene + "_none_model.txt"), median)
        for lens in ("plumb_bob", "equidistant"):
            model_file = os.path.join(out, "%s_%s_model.txt" % (scene, lens))
            if not os.path.exists(model_file):
                continue
            with_model = summary_value(model_file, median)
            ignored = summary_value(os.path.join(out, "%s_%s_ignored.txt" % (scene, lens)), median)
            rectified_file = os.path.join(out, "%s_%s_rectified.txt" % (scene, lens))
            rectified = summary_value(rectified_file, median) if os.path.exists(rectified_file) else "-"
            ratio = "%.2f" % (float(with_model) / float(base)) if "-" not in (base, with_model) else "-"
            to_rectified = ("%.2f" % (float(with_model) / float(rectified))
                            if "-" not in (rectified, with_model) else "-")
            print("| %s | %s | %s | %s | %s | %s | %s | %s |" %
                  (scene, lens, base, with_model, ratio, ignored, rectified, to_rectified))
    print()
    print("The Strecha scenes' sequential pairs (each image and the next), the same image pairs in every")
    print("input, scored one by one against ground truth with their covariances (`rotavg eval --graph`), over")
    print("the pairs that verified in all three inputs. A scene of 11 or 19 views is a chain of these pairs, so")
    print("its median error above is decided by its few worst; the pairs' own errors compare the inputs")
    print("pair for pair.")
    print()
    strecha_pair_table(out, scenes)
    print()
    print("Where along the sequence the inputs differ, and whether the medians are the inputs' own: each")
    print("view's error, and the medians again with the loop closures that only just pass or fail the")
    print("inlier bar included or left out. castle-P19 is a courtyard of repeated windows whose pairs match")
    print("windows to their neighbours (results/README.md, \"How accurate is it from images?\"); the views")
    print("along them are off in every input, and how far their error spreads to the rest of the sequence")
    print("differs from input to input, while the pairs themselves compare as in the table above.")
    print()
    strecha_view_tables(out, scenes)
    print()
    print("The demo's pairs on their own: the same bags replayed without the rig's extrinsics")
    print("(`use_rig_extrinsics: false`: each keyframe a view of its own), each pair of the final graph scored")
    print("against ground truth with its covariance (`rotavg eval --graph`): NEES = the pair's error whitened by")
    print("its covariance, squared (median 2.37 when the covariances are right); after per-view offsets: with the")
    print("one rotation per view removed that best explains its pairs' errors, an error all of a view's pairs share.")
    print()
    print("| demo input | median (deg) | pairs | median pair error (deg) | NEES median | NEES median after per-view offsets |")
    print("|---|---|---|---|---|---|")
    for input, label, scored in demo_pair_runs(out):
        summary = os.path.join(out, "demo_%s_pairs.txt" % input)
        print("| %s | %s | %s | %s | %s | %s |" % (label, summary_value(summary, median),
                                                  summary_value(scored, r"^edges scored: (\d+)"),
                                                  summary_value(scored, r"^median edge error: ([0-9.]+) deg"),
                                                  summary_value(scored, r"^NEES median: ([0-9.]+)"),
                                                  summary_value(scored, r"^NEES median after per-view offsets: ([0-9.]+)")))
    print()
    print("The same pairs by kind: sequential (a camera's keyframe and its previous one), window pairs (the")
    print("older keyframes of its window, `window_pairs`), loop closures between two keyframes of one camera,")
    print("and between keyframes of the two cameras.")
    print()
    print("| demo input | kind | pairs | median pair error (deg) | NEES median |")
    print("|---|---|---|---|---|")
    for input, label, scored in demo_pair_runs(out):
        kinds = pair_kinds(os.path.join(out, "demo_%s_pairs" % input, "graph.txt"), scored)
        for kind in ("sequential", "window pair", "loop closure, one camera", "loop closure, two cameras"):
            pairs = np.array(kinds.get(kind, [])).reshape(-1, 2)
            if len(pairs) == 0:
                continue
            print("| %s | %s | %d | %.4f | %.1f |" % (label, kind, len(pairs), np.median(pairs[:, 0]),
                                                     np.median(pairs[:, 1])))
    readout_table(out, median)
    print()
    print("## The replay's summary of the EuRoC run with the model")
    print()
    print("```")
    print(open(os.path.join(out, "euroc_model.txt")).read().rstrip())
    print("```")


if __name__ == "__main__":
    main()
