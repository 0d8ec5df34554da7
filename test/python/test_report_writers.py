"""Tests of the results writers (scripts/*_report.py) on replay summaries written as
rotation_averaging_replay prints them: each row holds the summary's figures, and a figure
the summary lacks shows as such rather than as another's."""
import os
import subprocess
import sys

import pytest

SCRIPTS = os.path.join(os.path.dirname(__file__), "..", "..", "scripts")
sys.path.insert(0, SCRIPTS)
import report_common  # noqa: E402


def summary(keyframes, median, images=None, wall=20.0, loops=150, selection="all", extra=()):
    """The lines of a replay summary the writers read."""
    images = keyframes if images is None else images
    lines = [
        "messages: 180 of 180",
        "bag time: 59.00 s; wall time: %.2f s (%.2fx real time); CPU time: 34.50 s; peak memory: 188.90 MiB"
        % (wall, 59.0 / wall),
        "keyframes: %d (%d images through the front end, 0 rejected); relative-pose messages rejected: 0"
        % (keyframes, images),
        "keyframe selection (%s): %d images, %d keyframes, %d not keyframes; 2.50 ms per image"
        % (selection, images, keyframes, images - keyframes),
        "loop closures: %d edges from 200 verified candidates; retrieval: vocabulary of 4096 words" % loops,
        "solved variables: %d (keyframes, or rig captures); edges: 295 (loop_closure 179, sequential 116)"
        % (keyframes // 2),
        "components: 1; outlier edges: 43; solves: 90; final cost: 997.665937",
        "median error: %.4f deg" % median,
        "mean error: %.4f deg" % (median * 1.1),
        "AUC@2: 99.18 %",
    ]
    lines += list(extra)
    lines += ["outputs:", "  orientations.csv"]
    return "\n".join(lines) + "\n"


def run(script, *args):
    result = subprocess.run([sys.executable, os.path.join(SCRIPTS, script)] + [str(a) for a in args],
                            capture_output=True, text=True, check=True)
    return result.stdout


def table_row(text, first_cell):
    rows = [line for line in text.splitlines() if line.startswith("| %s |" % first_cell)]
    assert len(rows) == 1, (first_cell, text)
    return [cell.strip() for cell in rows[0].strip("|").split("|")]


def test_value_joins_every_match_and_falls_back_to_the_default():
    text = "median error: 0.0137 deg\nother: 1\nmedian error: 0.0200 deg\n"
    assert report_common.value(text, r"^median error: ([0-9.]*) deg") == "0.0137\n0.0200"
    assert report_common.value(text, r"^mean error: ([0-9.]*) deg", "-") == "-"
    assert report_common.reproduce_line("bash x.sh").startswith("Reproduce with: `bash x.sh`. Generated ")


def test_restart_rows_hold_each_cut_against_the_uninterrupted_run(tmp_path):
    (tmp_path / "full.txt").write_text(summary(120, 0.0137))
    os.makedirs(tmp_path / "map_30")
    (tmp_path / "map_30" / "graph.txt.keyframes").write_bytes(b"x" * (60 * 1024 * 100))  # 100 KB per keyframe
    (tmp_path / "before_30.txt").write_text(summary(60, 0.0150, extra=[
        "map saved in 22.5 ms (the graph held 0.0 ms, the front end 14.0 ms): view graph saved to g"]))
    (tmp_path / "after_30.txt").write_text(summary(120, 0.0175, images=60, extra=[
        "map loaded in 9.1 ms: view graph of 30 views loaded from g",
        "loaded keyframes at the first solve: moved at most 0.0000 deg from where the map had them",
        "loaded keyframes when new keyframes joined them (solve 1): moved at most 0.0008 deg, "
        "0.071 posterior standard deviations; their frame as a whole rotated by 0.0001 deg"]))
    text = run("restart_report.py", tmp_path, 30)
    assert table_row(text, "none (uninterrupted)")[1:6] == ["-", "120", "1", "150", "0.0137"]
    row = table_row(text, "30")
    assert row[1] == "60 / 60"
    assert row[5:7] == ["0.0175", "1.28"]  # 0.0175 / 0.0137
    assert row[7:10] == ["0.0000", "0.0008 / 0.071", "0.0001"]
    assert row[10:] == ["100.0", "22.5", "9.1"]


def test_keyframe_selection_compares_the_stream_with_the_keyframe_bag_over_seeds(tmp_path):
    (tmp_path / "demo_1hz.txt").write_text(summary(120, 0.0137))
    (tmp_path / "stream_8_0.4.txt").write_text(summary(134, 0.0154, images=2400, selection="motion"))
    (tmp_path / "demo_1hz_chain.txt").write_text(summary(120, 0.0071))
    (tmp_path / "stream_chain.txt").write_text(summary(134, 0.0066, images=2400, selection="motion"))
    runs = {"1": (0.0137, 0.0154, 0.0071, 0.0066), "2": (0.0181, 0.0157, 0.0083, 0.0070)}
    for seed, (one_hz, stream, one_hz_chain, stream_chain) in runs.items():
        (tmp_path / ("seed%s_1hz.txt" % seed)).write_text(summary(120, one_hz))
        (tmp_path / ("seed%s_stream.txt" % seed)).write_text(summary(134, stream, images=2400, selection="motion"))
        (tmp_path / ("seed%s_1hz_chain.txt" % seed)).write_text(summary(120, one_hz_chain))
        (tmp_path / ("seed%s_stream_chain.txt" % seed)).write_text(
            summary(134, stream_chain, images=2400, selection="motion"))
    text = run("keyframe_selection_report.py", tmp_path, "8/0.4", "1,2")
    row = table_row(text, "20 Hz stream, 8 deg / 0.4 (defaults)")
    assert row[1:4] == ["2400", "134", "67"]
    assert row[4] == "2.50" and row[7] == "0.0154"
    assert table_row(text, "20 Hz stream, defaults but `window_pairs: false`")[7] == "0.0066"
    assert table_row(text, "2") == ["2", "0.0181", "134", "0.0157", "0.0083", "0.0070"]
    mean = table_row(text, "mean (min - max)")
    assert mean[1] == "0.0159 (0.0137 - 0.0181)" and mean[3] == "0.0155 (0.0154 - 0.0157)"
    assert mean[4] == "0.0077 (0.0071 - 0.0083)" and mean[5] == "0.0068 (0.0066 - 0.0070)"


def budget_lines(image, keyframe, pair, keyframes, pairs):
    """The summary's time-budget lines: (median, p95) in ms of each."""
    return ["time per image (decoding, checks, keyframe selection): median %.2f ms, p95 %.2f ms (of 1200)" % image,
            "time per keyframe (front end): median %.2f ms, p95 %.2f ms (of %d); per two-view pair: median %.2f ms, "
            "p95 %.2f ms (of %d)" % (keyframe + (keyframes,) + pair + (pairs,))]


def test_budget_rows_hold_each_runs_times_and_the_keyframe_bins(tmp_path):
    focal = "time per camera_info check estimate (one camera's pairs; the node runs it beside the front end): " \
            "median 420.00 ms, p95 610.00 ms (of 8)"
    refined = "refinement (bundle adjustment of the newest keyframes): 2 runs, 2 applied, 0 changed nothing; " \
              "time per refinement: median 4524.54 ms, p95 4669.08 ms (of 2); correspondences held: 512 edges"
    for cameras, keyframes in (("1", 40), ("2", 66)):
        extra = budget_lines((2.1, 3.4), (180.0, 260.0), (31.5, 70.2), keyframes, 3 * keyframes)
        (tmp_path / ("stream_%scam.txt" % cameras)).write_text(
            summary(keyframes, 0.0054, images=600 * int(cameras), selection="motion",
                    extra=extra + ([focal, refined] if cameras == "2" else [])))
        # The same bag with `refinement: false`: its speed-up and median in columns of their own.
        (tmp_path / ("stream_%scam_unrefined.txt" % cameras)).write_text(
            summary(keyframes, 0.0060, images=600 * int(cameras), wall=10.0, selection="motion", extra=extra))
    (tmp_path / "every_image_300.txt").write_text(
        summary(600, 0.0050, extra=budget_lines((0.1, 0.2), (200.0, 300.0), (30.0, 60.0), 600, 2400)))
    (tmp_path / "every_image_300_unrefined.txt").write_text(summary(600, 0.0052, wall=10.0))
    os.makedirs(tmp_path / "every_image_300")
    with open(tmp_path / "every_image_300" / "frontend_cost.csv", "w") as f:
        f.write("keyframe,features_ms,retrieval_ms,pairs_ms,total_ms\n")
        for k in range(150):
            f.write("%d,80,5,100,%d\n" % (k + 1, 100 + k))  # 100..249 ms
    text = run("budget_report.py", tmp_path, "1,2")
    row = table_row(text, "2")
    assert row[1:5] == ["1200", "66", "2.95x", "5.90x"]
    assert row[5:8] == ["2.10 / 3.40", "180.00 / 260.00", "31.50 / 70.20"]
    assert row[8:13] == ["3.0", "8, 420.00 / 610.00", "2, 4524.54 / 4669.08", "0.0054", "0.0060"]
    # A run without the check's estimates or a refinement says so rather than showing another's.
    assert table_row(text, "1")[2] == "40" and table_row(text, "1")[9:11] == ["-", "-"]
    # Bins of 100 keyframes by nearest rank: 1-100 hold 100..199 ms, 101-150 hold 200..249 ms.
    assert table_row(text, "1-100") == ["1-100", "149.0", "194.0"]
    assert table_row(text, "101-150") == ["101-150", "224.0", "247.0"]
    assert "600 keyframes; 2.95x real time, 5.90x with `refinement: false`; per keyframe median 200.00 ms" in text


def test_posterior_rows_hold_each_inputs_nees(tmp_path):
    def line(median, within):
        return (f"posterior covariances against the ground truth: NEES median {median} (2.37 if honest), "
                f"mean 6.29, {within}% within chi-square's 95% bound, 118 keyframes")
    variants = {"default": ("1.62", "98.3"), "grid0": ("2.17", "98.3"), "grid2": ("0.89", "98.3"),
                "grid4": ("1.99", "98.3"), "cells_alone": ("6.31", "80.2"), "averaging": ("1.07", "98.3"),
                "no_refinement": ("2.91", "100.0"),
                "no_refinement_no_floor": ("6.98", "62.7")}
    for variant, (median, within) in variants.items():
        (tmp_path / ("demo_%s.txt" % variant)).write_text(summary(120, 0.0048, extra=[line(median, within)]))
        (tmp_path / ("castle-P19_full_resolution_%s.txt" % variant)).write_text(summary(19, 0.05))
    (tmp_path / "castle-P19_full_resolution.txt").write_text("median error: 0.0309 deg\n")
    (tmp_path / "demo_rig_joint.txt").write_text(summary(120, 0.0048, extra=[line("7.46", "50.8")]))
    text = run("posterior_report.py", tmp_path, "demo,castle-P19_full_resolution")
    # The rig's section: a row for each rig input with both runs, each camera's own covariance first.
    assert table_row(text, "the demo bag (two cameras, 1 Hz)")[1:] == ["0.0048", "1.62 / 98.3 (meets)", "7.46 / 50.8"]
    assert "the rig at 20 Hz (two cameras)" not in text
    demo = table_row(text, "the demo bag: rendered two-camera rig, 1 Hz, every image a keyframe")
    assert demo[1:] == ["120", "0.0048", "1.62", "6.29", "98.3", "118", "yes"]
    assert table_row(text, "demo")[1:] == ["2.17 / 98.3 (meets)", "0.89 / 98.3", "1.62 / 98.3 (meets)",
                                           "1.99 / 98.3 (meets)", "6.31 / 80.2", "1.07 / 98.3",
                                           "2.91 / 100.0 (meets)", "6.98 / 62.7"]
    # A summary without the line shows its NEES as missing, not another run's; the reference's own error.
    castle = table_row(text, "castle-P19 as a bag, against `rotavg images` at full resolution (its own median "
                             "error against the LIDAR-registered cameras: 0.0309 deg)")
    assert castle[3:] == ["-"] * 4 + ["no"]
    assert table_row(text, "inputs meeting the target")[1:] == ["1", "0", "1", "1", "0", "0", "1", "0"]


def test_a_missing_run_stops_the_writer_with_its_name(tmp_path):
    (tmp_path / "full.txt").write_text(summary(120, 0.0137))
    with pytest.raises(subprocess.CalledProcessError) as failure:
        run("restart_report.py", tmp_path, 15)
    assert "before_15.txt" in failure.value.stderr


def test_tracks_rows_hold_each_runs_figures_and_the_seeds_mean(tmp_path):
    (tmp_path / "precision.md").write_text("| image | images apart |\n|---|---|\n| room | 1 (0.8 deg) |\n")
    track_line = "tracks: 223 pairs estimated from shared KLT tracks, 0 matched by descriptors when their tracks did not verify"
    for tracks, keyframes, median, wall in (("true", 94, 0.0080, 14.0), ("false", 128, 0.0066, 20.0)):
        extra = budget_lines((2.5, 4.9), (90.0, 150.0), (8.8, 25.9), keyframes, 4 * keyframes)
        if tracks == "true":
            extra.append(track_line)
        (tmp_path / ("stream_2cam_tracks_%s.txt" % tracks)).write_text(
            summary(keyframes, median, images=1200, wall=wall, selection="motion", extra=extra))
    for seed, medians in (("2", (0.0060, 0.0066)),):
        for tracks, median in zip(("true", "false"), medians):
            (tmp_path / ("seed%s_tracks_%s.txt" % (seed, tracks))).write_text(summary(94, median, selection="motion"))
    text = run("tracks_report.py", tmp_path, tmp_path / "no_euroc", "1,2,3")
    row = table_row(text, "2 | `true`")
    assert row[2:4] == ["94", "4.21x"]
    assert row[4:8] == ["2.50 / 4.90", "90.00 / 150.00", "8.80 / 25.90", "223"]
    assert row[8] == "0.0080"
    without = table_row(text, "2 | `false`")
    assert without[2] == "128" and without[7:9] == ["0", "0.0066"]
    # Seed 1 is the stream of the camera rows, seed 2 its own runs, seed 3 has none.
    assert table_row(text, "1")[1:] == ["0.0080", "4.21x", "0.0066", "2.95x"]
    assert table_row(text, "2 | 0.0060")[1:] == ["0.0060", "2.95x", "0.0066", "2.95x"]
    assert table_row(text, "3")[1:] == ["-", "-x", "-", "-x"]
    assert table_row(text, "mean (min - max)")[1] == "0.0070 (0.0060 - 0.0080)"
    assert "EuRoC" not in text
    assert "| room | 1 (0.8 deg) |" in text


def test_keyframe_rotation_rows_hold_each_runs_keyframes_by_reason(tmp_path):
    made = "  keyframes made: 1 first of their camera, %d by motion, %d by rotation, %d by tracks lost, 0 by interval, " \
           "0 with the rig's other cameras"
    (tmp_path / "door_all.txt").write_text(summary(12, 0.0214))
    (tmp_path / "door_rot0.txt").write_text(summary(2, 0.0380, images=12, selection="motion",
                                                   extra=[made % (0, 0, 1)]))
    (tmp_path / "door_rot6.txt").write_text(summary(6, 0.0226, images=12, selection="motion",
                                                   extra=[made % (0, 5, 0)]))
    (tmp_path / "stream600_rot6.txt").write_text(summary(132, 0.0054, images=1200, selection="motion",
                                                        extra=[made % (2, 26, 39),
                                                               "  rotation checks (keyframe_min_rotation_deg): 238, "
                                                               "2.01 ms each"]))
    text = run("keyframe_rotation_report.py", tmp_path, "door", "600", "0,6", tmp_path / "no_euroc")
    every = table_row(text, "door | every image (`keyframe_selection: all`)")
    assert every[2] == "12" and every[10] == "0.0214"
    alone = table_row(text, "door | 0 (motion and tracking alone)")
    assert alone[2:6] == ["2", "0", "0", "1"] and alone[8:11] == ["0", "-", "0.0380"]
    by_rotation = table_row(text, "door | 6 (default)")
    assert by_rotation[2:6] == ["6", "0", "5", "0"] and by_rotation[10] == "0.0226"
    stream = table_row(text, "600 captures (30 s) | 6 (default)")
    assert stream[2:6] == ["132", "2", "26", "39"] and stream[8:11] == ["238", "2.01", "0.0054"]
    # A run the benchmark did not make has no row; no EuRoC folder, no EuRoC section.
    assert "600 captures (30 s) | 0 (motion" not in text
    assert "EuRoC" not in text
    assert "One camera" not in text
    # The one-camera seeds: each seed's runs without and with the rotation, and their means.
    for seed, medians in (("1", (0.0164, 0.0250)), ("2", (0.0341, 0.0149))):
        for rotation, median in zip(("0", "6"), medians):
            (tmp_path / ("one_camera_seed%s_rot%s.txt" % (seed, rotation))).write_text(
                summary(48 if rotation == "0" else 51, median, images=600, selection="motion",
                        extra=[made % (0, 30 if rotation == "6" else 0, 37)]))
    text = run("keyframe_rotation_report.py", tmp_path, "door", "600", "0,6", tmp_path / "no_euroc", "1,2,3")
    assert table_row(text, "1")[1:] == ["48", "0.0164", "51", "30", "0.0250"]
    assert table_row(text, "mean")[2] == "0.0253" and table_row(text, "mean")[5] == "0.0200"


def test_refinement_rows_hold_each_runs_figures_and_the_ratio_to_offline(tmp_path):
    refined = ("refinement (bundle adjustment of the newest keyframes): 3 runs, 2 applied, 1 changed nothing; "
               "19 keyframes corrected, the latest by median 0.21 deg, at most 0.59 deg (0 held back); time per "
               "refinement: median 241.00 ms, p95 300.50 ms (of 3); correspondences held: 46 edges, 0.26 MiB")
    nees = ("posterior covariances against the ground truth: NEES median 0.83 (2.37 if honest), mean 1.10, "
            "100.0% within chi-square's 95% bound, 19 keyframes")
    (tmp_path / "door_false.txt").write_text(summary(12, 0.0214))
    (tmp_path / "door_true.txt").write_text(summary(12, 0.0048, extra=[refined, nees]))
    (tmp_path / "door_offline.txt").write_text("median error: 0.0053 deg\n")
    (tmp_path / "stream_true.txt").write_text(summary(128, 0.0065, extra=[refined]))
    text = run("refinement_report.py", tmp_path, "door", tmp_path / "no_euroc")
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in text.splitlines()
            if line.startswith("| door |")]
    assert [r[1] for r in rows] == ["off", "on"]
    off, on = rows
    assert off[2:5] == ["12", "0.0214", "99.18"] and off[5:9] == ["-", "-", "-", "-"]
    assert off[11:] == ["0.0053", "4.04"]
    assert on[3] == "0.0048" and on[5:9] == ["0.83", "100.0", "2 / 3", "241.00 / 300.50"]
    assert on[11:] == ["0.0053", "0.91"]
    # A run the benchmark did not make has no row; no offline run, no ratio.
    assert "| 20 Hz two-camera stream, one loop in 30 s | off |" not in text
    stream = table_row(text, "20 Hz two-camera stream, one loop in 30 s")
    assert stream[1] == "on" and stream[11:] == ["-", "-"]
    assert "EuRoC" not in text
    assert "## A focal length that agrees" not in text  # none of its runs
    # The focal length held once it agrees against free in every refinement.
    focal = ("focal length by the refinement, cam_front: x1.0004 +- 0.0055 (matches 0.0055, principal point "
             "0.0001), 100 keyframes of the one in use")
    (tmp_path / "long_false.txt").write_text(summary(600, 0.0055))
    (tmp_path / "long_true.txt").write_text(summary(600, 0.0085, extra=[refined, nees]))
    (tmp_path / "long_free_focal.txt").write_text(summary(600, 0.0124, extra=[refined, nees, focal]))
    text = run("refinement_report.py", tmp_path, "door", tmp_path / "no_euroc")
    assert "## A focal length that agrees" in text
    long = table_row(text, "600 keyframes (two cameras, 300 captures, every image a keyframe)")
    assert long[1:] == ["600", "0.0055", "0.0085", "0.0124", "0.83 / 0.83", "cam_front x1.0004 +- 0.0055"]
    assert "x1), every one within two of its deviations." in text
    # An estimate beyond two of its deviations is named, with how far.
    far = focal.replace("x1.0004 +- 0.0055", "x1.0004 +- 0.0001")
    (tmp_path / "long_free_focal.txt").write_text(summary(600, 0.0124, extra=[refined, nees, far]))
    text = run("refinement_report.py", tmp_path, "door", tmp_path / "no_euroc")
    assert ("within two of their deviations but for the 600 keyframes (two cameras, 300 captures, every image a "
            "keyframe)'s cam_front, 4.0 deviations off.") in text


def test_the_window_section_holds_each_runs_figures_and_its_errors_along_the_bag(tmp_path):
    nees = ("posterior covariances against the ground truth: NEES median %s (2.37 if honest), mean 4.00, "
            "%s%% within chi-square's 95%% bound, 600 keyframes")
    latest = ("refinement, latest: bundle adjustment: %s views%s, 764 edges (1 of the rotation-only model, 0 unusable), "
              "12473 tracks")
    (tmp_path / "long_false.txt").write_text(summary(600, 0.0055, extra=[nees % ("5.43", "72.2")]))
    (tmp_path / "long_window_alone.txt").write_text(
        summary(600, 0.0085, extra=[nees % ("3.94", "60.0"), latest % (200, "")]))
    (tmp_path / "long_no_sweep.txt").write_text(
        summary(600, 0.0052, extra=[nees % ("3.71", "86.6"), latest % (215, " (15 held)")]))
    (tmp_path / "long_true.txt").write_text(
        summary(600, 0.0036, extra=[nees % ("1.28", "97.5"), latest % (226, " (26 held)")]))
    # Per-view errors of the held run only, out of stamp order: twelve keyframes, two per sixth.
    os.makedirs(tmp_path / "long_true")
    views = ["view cam@%d %.4f" % (stamp, error) for stamp, error in
             [(12, 0.0060), (1, 0.0010), (2, 0.0012), (3, 0.0020), (4, 0.0022), (5, 0.0030), (6, 0.0032),
              (7, 0.0040), (8, 0.0042), (9, 0.0050), (10, 0.0052), (11, 0.0058)]]
    (tmp_path / "long_true" / "per_view.txt").write_text("median error: 0.0035 deg\n" + "\n".join(views) + "\n")
    text = run("refinement_report.py", tmp_path, "door", tmp_path / "no_euroc")
    assert "## The keyframes before the window" in text
    label = "| 600 keyframes (two cameras, 300 captures, every image a keyframe) |"
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in text.splitlines()
            if line.startswith(label)]
    table = [r for r in rows if len(r) == 9]
    assert [r[1:7] for r in table] == [["refinement off", "600", "0.0055", "5.43", "72.2", "-"],
                                       ["window alone, swept back", "600", "0.0085", "3.94", "60.0", "0"],
                                       ["older keyframes held, no sweep back", "600", "0.0052", "3.71", "86.6", "15"],
                                       ["older keyframes held, swept back (the defaults)", "600", "0.0036", "1.28",
                                        "97.5", "26"]]
    # Along the bag: only the run with its per-view errors, each sixth's median in stamp order.
    along = [r for r in rows if len(r) == 8]
    assert along == [["600 keyframes (two cameras, 300 captures, every image a keyframe)",
                      "older keyframes held, swept back (the defaults)",
                      "0.0011", "0.0021", "0.0031", "0.0041", "0.0051", "0.0059"]]
    # Without the window-alone run, no section.
    os.remove(tmp_path / "long_window_alone.txt")
    assert "## The keyframes before the window" not in run("refinement_report.py", tmp_path, "door",
                                                           tmp_path / "no_euroc")


def test_self_calibration_rows_print_each_estimate_to_two_significant_digits_of_its_deviation(tmp_path):
    def estimate(scale, sd, matches, pp):
        return ("focal length by the refinement, cam_front: x%s +- %s (matches %s, principal point %s), "
                "60 keyframes of the one in use" % (scale, sd, matches, pp))
    nees = ("posterior covariances against the ground truth: NEES median 2.79 (2.37 if honest), mean 3.00, "
            "98.3% within chi-square's 95% bound, 118 keyframes")
    (tmp_path / "demo_0.97_fixed.txt").write_text(summary(120, 0.3058, extra=[nees]))
    (tmp_path / "demo_0.97_warn.txt").write_text(
        summary(120, 0.0034, extra=[nees, estimate("1.0309832", "0.0000500", "0.0000495", "0.0000074")]))
    (tmp_path / "demo_0.97_apply.txt").write_text(summary(120, 0.0043, extra=[
        nees, estimate("0.999700", "0.000052", "0.000051", "0.000008"),
        "focal length corrected (focal_calibration: apply): cam_front: camera_info's focal length x1.0312"]))
    text = run("self_calibration_report.py", tmp_path, "demo_0.97")
    row = table_row(text, "demo rig")
    assert row[1:3] == ["x0.97", "cam_front"]
    # The warn run's estimate with its parts; how far from the true 1 / 0.97 in its deviations.
    assert row[4] == "x1.0309832 +- 0.0000500 (0.0000495, 0.0000074), 60 keyframes"
    assert row[5] == "+1.1"
    # With apply: ended at 0.97 x 1.0312; the last estimate against the truth in the focal length in use.
    assert row[7] == "x1.00026 (+0.03%)"
    assert row[8] == "x0.999700 +- 0.000052: -0.7"
