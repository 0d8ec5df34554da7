#!/usr/bin/env bash
# Regenerates results/colmap.md: COLMAP's incremental SfM with bundle
# adjustment (Debian's colmap package, on the CPU) against `rotavg images`
# with its defaults (averaging, then bundle adjustment) and with the averaging
# alone, on the Strecha scenes at full resolution, all scored by
# the same evaluator (`rotavg eval`: one robustly fitted alignment rotation,
# then per-view angular errors). COLMAP gets what rotavg gets: the images and
# the given intrinsics (one PINHOLE camera), with its defaults otherwise (it
# refines the focal length in its bundle adjustment).
# lund_door is left out: its reference poses are a COLMAP reconstruction.
# It also scores rotavg's pairs (their covariances) against the reference,
# COLMAP's model and our bundle adjustment on COLMAP's features, and estimates
# each estimate's own error from their differences (three-cornered hat).
#   bash scripts/benchmark_colmap.sh      (about 20 minutes on 2 cores)
#   bash scripts/benchmark_colmap.sh --rotavg-only   (rotavg again, COLMAP's last runs kept)
#   bash scripts/benchmark_colmap.sh --report-only   (results/colmap.md from the last runs)
source "$(dirname "$0")/common.sh"
MODE=${1:-}
bash scripts/setup.sh > /dev/null
if ! command -v colmap > /dev/null; then
  DEBIAN_FRONTEND=noninteractive apt-get install -y colmap > /dev/null
fi
export QT_QPA_PLATFORM=offscreen  # colmap's command line needs no display
OUT=build/benchmark_colmap
mkdir -p "$OUT"

seconds() { date +%s.%N; }
# The 3x3 K of a scene, row by row, into the array k. Some K.txt files end
# their lines with CR LF: a CR left in would be read as an entry and shift
# every later one (COLMAP would get fy = 0).
read_k() {
  read -r -a k < <(tr -s ' \t\r\n' ' ' < "$DATA/strecha/$1/images/K.txt"; echo)
  if [ ${#k[@]} -ne 9 ] || ! awk -v fx="${k[0]}" -v fy="${k[4]}" 'BEGIN { exit !(fx > 0 && fy > 0) }'; then
    echo "$DATA/strecha/$1/images/K.txt: expected a 3x3 K with positive focal lengths, read: ${k[*]}" >&2
    exit 1
  fi
}

SCENES=()
for s in fountain-P11 entry-P10 castle-P19; do
  [ -d "$DATA/strecha/$s" ] && SCENES+=("$s")
done
if [ ${#SCENES[@]} -eq 0 ]; then
  echo "no Strecha scenes under $DATA/strecha: nothing to compare" >&2
  exit 1
fi

for s in "${SCENES[@]}"; do
  [ "$MODE" = "--report-only" ] && break
  C="$DATA/strecha/$s"
  W="$OUT/$s"
  mkdir -p "$W"
  if [ "$MODE" != "--rotavg-only" ]; then
    rm -rf "$W"
    mkdir -p "$W/sparse"
    read_k "$s"
    fx=${k[0]} cx=${k[2]} fy=${k[4]} cy=${k[5]}
    start=$(seconds)
    colmap feature_extractor --database_path "$W/database.db" --image_path "$C/images" \
      --ImageReader.camera_model PINHOLE --ImageReader.single_camera 1 \
      --ImageReader.camera_params "$fx,$fy,$cx,$cy" --SiftExtraction.use_gpu 0 > "$W/colmap.log" 2>&1
    colmap exhaustive_matcher --database_path "$W/database.db" --SiftMatching.use_gpu 0 >> "$W/colmap.log" 2>&1
    # Bounded, so that a mapper that does not converge (COLMAP 3.8 spins in
    # the essential-matrix RANSAC of its initial pair when given a camera
    # that is not one, e.g. fy = 0) is reported as not finished rather than
    # holding up the benchmark.
    if timeout "${COLMAP_MAPPER_TIMEOUT:-420}" colmap mapper --database_path "$W/database.db" --image_path "$C/images" \
      --output_path "$W/sparse" >> "$W/colmap.log" 2>&1 && [ -d "$W/sparse/0" ]; then
      # The largest model is 0.
      colmap model_converter --input_path "$W/sparse/0" --output_path "$W" --output_type TXT >> "$W/colmap.log" 2>&1
      "$BIN/rotavg" eval --estimate "$W/images.txt" --estimate-format colmap --gt "$C" --per-view > "$W/colmap_scores.txt"
    else
      echo "mapper did not finish" > "$W/colmap_failed.txt"
    fi
    echo "$(seconds) - $start" | bc > "$W/colmap_seconds.txt"
  fi

  start=$(seconds)
  "$BIN/rotavg" images --images "$C/images" --intrinsics "$C/images/K.txt" --output "$W/rotavg.csv" > "$W/rotavg.log"
  echo "$(seconds) - $start" | bc > "$W/rotavg_seconds.txt"
  "$BIN/rotavg" eval --estimate "$W/rotavg.csv" --gt "$C" --per-view > "$W/rotavg_scores.txt"
  "$BIN/rotavg" images --images "$C/images" --intrinsics "$C/images/K.txt" --no-bundle-adjustment \
    --output "$W/averaging.csv" --graph-out "$W/graph.txt" > "$W/averaging.log"
  "$BIN/rotavg" eval --estimate "$W/averaging.csv" --gt "$C" --per-view > "$W/averaging_scores.txt"
  # The back end alone: the package's two-view estimation, averaging and
  # bundle adjustment on COLMAP's own features and verified matches
  # (examples/python/colmap_database.py), so that the features and matching
  # are the same as COLMAP's.
  start=$(seconds)
  $DEVEL/env.sh python3 examples/python/colmap_database.py "$W/database.db" \
    --output "$W/colmap_matches.csv" > "$W/colmap_matches.log"
  echo "$(seconds) - $start" | bc > "$W/colmap_matches_seconds.txt"
  "$BIN/rotavg" eval --estimate "$W/colmap_matches.csv" --gt "$C" --per-view > "$W/colmap_matches_scores.txt"
done

# Which reference can check the pairs' covariances (also with --report-only,
# from the last runs): rotavg's pairs (the averaging's graph) scored against
# the LIDAR-registered cameras, COLMAP's model and our bundle adjustment on
# COLMAP's features; rotavg and the averaging alone against COLMAP's model,
# for the three-cornered hat of the report.
for s in "${SCENES[@]}"; do
  W="$OUT/$s"
  rm -f "$W"/edges_vs_*.txt "$W/rotavg_vs_colmap.txt" "$W/averaging_vs_colmap.txt"
  [ -f "$W/graph.txt" ] || continue
  VIEWS=(--view-term-from "$W/rotavg.csv")
  "$BIN/rotavg" eval --graph "$W/graph.txt" --gt "$DATA/strecha/$s" "${VIEWS[@]}" > "$W/edges_vs_reference.txt"
  "$BIN/rotavg" eval --graph "$W/graph.txt" --gt "$W/colmap_matches.csv" "${VIEWS[@]}" > "$W/edges_vs_colmap_matches.txt"
  if [ ! -f "$W/colmap_failed.txt" ]; then
    "$BIN/rotavg" eval --graph "$W/graph.txt" --gt "$W/images.txt" "${VIEWS[@]}" > "$W/edges_vs_colmap.txt"
    "$BIN/rotavg" eval --estimate "$W/rotavg.csv" --gt "$W/images.txt" > "$W/rotavg_vs_colmap.txt"
    "$BIN/rotavg" eval --estimate "$W/averaging.csv" --gt "$W/images.txt" > "$W/averaging_vs_colmap.txt"
  fi
done

field() {  # file, label
  sed -n "s/^$2: \([0-9.a-z]*\).*/\1/p" "$1"
}
view_error() {  # scores file, view name: the view's error to 4 decimals, or - if it has none
  local e
  e=$(sed -n "s/^view $2 \([0-9.e+-]*\)$/\1/p" "$1" 2>/dev/null || true)
  if [ -n "$e" ]; then printf '%.4f' "$e"; else echo -; fi
}
whole_seconds() { printf '%.0f' "$(cat "$1")"; }
# An edge calibration file's figure after its label: eval --graph prints the
# covariances as given, with the floor (floored), then with the floor and the
# view term (viewed).
floored() { field "$1" "$2" | sed -n 2p; }
viewed() { field "$1" "$2" | sed -n 3p; }
# The three-cornered hat: from the differences d_ab, d_ac, d_bc of three
# independent estimates, a's own error sqrt((d_ab^2 + d_ac^2 - d_bc^2) / 2);
# below what the differences resolve ("~0") when that is negative.
hat() {
  awk -v ab="$1" -v ac="$2" -v bc="$3" 'BEGIN { v = (ab * ab + ac * ac - bc * bc) / 2;
    if (v <= 0) print "~0"; else printf "%.4f", sqrt(v) }'
}

{
  echo "# Rotation averaging from images against COLMAP's bundle adjustment"
  echo
  echo "Reproduce with: \`bash scripts/benchmark_colmap.sh\`. Generated $(date -u '+%Y-%m-%d %H:%M') UTC on a $(nproc)-core machine, $(colmap -h 2>&1 | sed -n 's/^COLMAP \([0-9.]*\).*/COLMAP \1/p' | head -1) from Debian."
  echo
  echo "Both methods get the images at full resolution and the given intrinsics. COLMAP:"
  echo "\`feature_extractor\` (one PINHOLE camera with the given K, CPU SIFT), \`exhaustive_matcher\`,"
  echo "\`mapper\` (incremental SfM with bundle adjustment; by default it refines the focal length), every"
  echo "other setting its default. rotavg: \`rotavg images\` with its defaults (rotation averaging, then"
  echo "bundle adjustment from the averaged orientations), and with \`--no-bundle-adjustment\` (the averaging"
  echo "alone). \"On COLMAP's matches\": the same back end (the package's two-view estimation, averaging"
  echo "and bundle adjustment, defaults) on COLMAP's own SIFT features and verified matches from the"
  echo "database above (\`examples/python/colmap_database.py\`; seconds exclude COLMAP's extraction and"
  echo "matching), so that only the back ends differ. All are scored by \`rotavg eval\` against the"
  echo "LIDAR-registered cameras: one robustly fitted rotation aligns the estimate, then the angle of every"
  echo "view's error. Times are wall time of the whole run on this machine."
  echo
  echo "| scene | views | COLMAP: registered | median (deg) | mean (deg) | AUC@2 (%) | seconds | rotavg: median (deg) | mean (deg) | AUC@2 (%) | seconds | averaging alone: median (deg) | mean (deg) | on COLMAP's matches: pairs | median (deg) | mean (deg) | seconds |"
  echo "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
  for s in "${SCENES[@]}"; do
    W="$OUT/$s"
    views=$(field "$W/rotavg_scores.txt" "views in ground truth")
    ours="$(field "$W/rotavg_scores.txt" "median error") | $(field "$W/rotavg_scores.txt" "mean error") | $(field "$W/rotavg_scores.txt" "AUC@2") | $(whole_seconds "$W/rotavg_seconds.txt") | $(field "$W/averaging_scores.txt" "median error") | $(field "$W/averaging_scores.txt" "mean error")"
    ours+=" | $(sed -n 's/^relative poses: \([0-9]* of [0-9]*\).*/\1/p' "$W/colmap_matches.log") | $(field "$W/colmap_matches_scores.txt" "median error") | $(field "$W/colmap_matches_scores.txt" "mean error") | $(whole_seconds "$W/colmap_matches_seconds.txt")"
    if [ -f "$W/colmap_failed.txt" ]; then
      echo "| $s | $views | mapper did not finish | - | - | - | > $(whole_seconds "$W/colmap_seconds.txt") | $ours |"
    else
      echo "| $s | $views | $(field "$W/colmap_scores.txt" "views common") | $(field "$W/colmap_scores.txt" "median error") | $(field "$W/colmap_scores.txt" "mean error") | $(field "$W/colmap_scores.txt" "AUC@2") | $(whole_seconds "$W/colmap_seconds.txt") | $ours |"
    fi
  done
  echo
  echo "COLMAP's camera after its bundle adjustment (cameras.txt: fx, fy, cx, cy) against the given K:"
  echo
  echo "| scene | given fx, fy | COLMAP fx, fy |"
  echo "|---|---|---|"
  for s in "${SCENES[@]}"; do
    [ -f "$OUT/$s/cameras.txt" ] || continue
    read_k "$s"
    fx=${k[0]} fy=${k[4]}
    refined=$(grep -v '^#' "$OUT/$s/cameras.txt" | head -1 | awk '{printf "%.1f, %.1f", $5, $6}')
    echo "| $s | $fx, $fy | $refined |"
  done
  echo
  echo "## Which reference can check the two-view covariances?"
  echo
  echo "The pairs' covariances (with the floor \`rotavg images\` adds) are too confident against the"
  echo "LIDAR-registered cameras (frontend.md, \"Calibration\"). A pair's error against a reference is its"
  echo "own plus the reference's: the reference has to be more accurate than the pairs claim to be."
  echo "Three estimates of the orientations that share only the images and the given K are rotavg"
  echo "(our features, matching and back end), COLMAP (its own SIFT, matching and bundle adjustment, which"
  echo "also refines the focal length) and the reference. Their median view errors against one another"
  echo "(\`rotavg eval\`) give, if their errors are independent and isotropic (so that the squared"
  echo "medians add), each one's own median error: the three-cornered hat,"
  echo "e_a = sqrt((d_ab^2 + d_ac^2 - d_bc^2) / 2). What rotavg and COLMAP share (the images and the given"
  echo "K) is counted as the reference's error."
  echo
  echo "| scene | rotavg - reference | COLMAP - reference | rotavg - COLMAP | rotavg's own | COLMAP's own | the reference's own | averaging alone - reference | averaging alone - COLMAP |"
  echo "|---|---|---|---|---|---|---|---|---|"
  for s in "${SCENES[@]}"; do
    W="$OUT/$s"
    [ -f "$W/rotavg_vs_colmap.txt" ] || continue
    ar=$(field "$W/rotavg_scores.txt" "median error")
    cr=$(field "$W/colmap_scores.txt" "median error")
    ac=$(field "$W/rotavg_vs_colmap.txt" "median error")
    echo "| $s | $ar | $cr | $ac | $(hat "$ar" "$ac" "$cr") | $(hat "$cr" "$ac" "$ar") | $(hat "$ar" "$cr" "$ac") | $(field "$W/averaging_scores.txt" "median error") | $(field "$W/averaging_vs_colmap.txt" "median error") |"
  done
  echo
  echo "\"~0\": below what the differences resolve. The last two columns score the averaging alone"
  echo "(without the bundle adjustment) against the reference and against COLMAP's model, an estimate"
  echo "independent of ours."
  echo
  echo "The pairs of rotavg's averaging (\`rotavg eval --graph graph.txt --gt ...\`) against three"
  echo "references: NEES = eta^T (C + s^2 I)^-1 eta with the floor s of \`rotavg images\` (calibrated:"
  echo "median 2.37, 95% of pairs below 7.81). \"Our bundle adjustment on COLMAP's matches\" is the column"
  echo "\"on COLMAP's matches\" above: other features than the pairs', the same back end and K."
  echo
  echo "| scene | pairs | floor (deg) | against the reference: median pair error (deg) | NEES median | within 95% | against COLMAP's model: median error | NEES median | within 95% | against our bundle adjustment on COLMAP's matches: median error | NEES median | within 95% |"
  echo "|---|---|---|---|---|---|---|---|---|---|---|---|"
  for s in "${SCENES[@]}"; do
    W="$OUT/$s"
    [ -f "$W/edges_vs_reference.txt" ] || continue
    row="| $s | $(floored "$W/edges_vs_reference.txt" "edges scored") | $(floored "$W/edges_vs_reference.txt" "covariance floor")"
    for f in edges_vs_reference edges_vs_colmap edges_vs_colmap_matches; do
      if [ -f "$W/$f.txt" ]; then
        row+=" | $(floored "$W/$f.txt" "median edge error") | $(floored "$W/$f.txt" "NEES median") | $(floored "$W/$f.txt" "NEES within the 95% quantile") %"
      else
        row+=" | - | - | -"
      fi
    done
    echo "$row |"
  done
  echo
  echo "The same errors split into views and pairs: the per-view offsets that best explain every pair's"
  echo "error against a reference (one rotation per view, fitted on the pairs' whitened errors with the"
  echo "floor; in effect the averaging of the pairs about that reference), and the pairs' NEES after them."
  echo "What a view's offset holds, all of its pairs share: the reference's own error for that view, or"
  echo "one that every pair of that image inherits. The pairs' consistency with each other, and the floor"
  echo "estimated from it, cannot see it, and no covariance of a single pair can express it. What remains"
  echo "after the offsets is the same against any reference (the fit takes 3 (views - 1) of the"
  echo "3 x pairs values, about a fifth here, so calibrated pairs would give a median a little below 2.37)."
  echo
  echo "| scene | NEES median after the per-view offsets | median pair error after them (deg) | median per-view offset (deg): against the reference | against COLMAP's model | against our bundle adjustment on COLMAP's matches |"
  echo "|---|---|---|---|---|---|"
  for s in "${SCENES[@]}"; do
    W="$OUT/$s"
    [ -f "$W/edges_vs_reference.txt" ] || continue
    row="| $s | $(floored "$W/edges_vs_reference.txt" "NEES median after per-view offsets") | $(floored "$W/edges_vs_reference.txt" "median edge error after per-view offsets")"
    for f in edges_vs_reference edges_vs_colmap edges_vs_colmap_matches; do
      if [ -f "$W/$f.txt" ]; then row+=" | $(floored "$W/$f.txt" "median per-view offset")"; else row+=" | -"; fi
    done
    echo "$row |"
  done
  echo
  echo "The bundle adjustment \`rotavg images\` runs can see that shared error: it ties each view's points"
  echo "and centre to the other views', where each pair's summary has a translation and depths of its"
  echo "own. The view term v is the standard deviation per axis of the views' offsets against it"
  echo "(robustly: median |d|^2 over the views = 2.366 v^2 for an isotropic Gaussian), as \`rotavg images\`"
  echo "prints it; added to both views of each pair, a pair's covariance is C + (s^2 + 2 v^2) I"
  echo "(\`rotavg eval --graph graph.txt --gt ... --view-term-from rotavg.csv\`). It uses no reference."
  echo
  echo "| scene | view term v (deg per axis) | NEES median with the floor and the view term: against the reference | within 95% | against COLMAP's model | within 95% | against our bundle adjustment on COLMAP's matches | within 95% |"
  echo "|---|---|---|---|---|---|---|---|"
  for s in "${SCENES[@]}"; do
    W="$OUT/$s"
    [ -f "$W/edges_vs_reference.txt" ] || continue
    v=$(sed -n 's/^covariances with the floor and the view term (\([0-9.]*\) deg.*/\1/p' "$W/edges_vs_reference.txt")
    row="| $s | $v"
    for f in edges_vs_reference edges_vs_colmap edges_vs_colmap_matches; do
      if [ -f "$W/$f.txt" ]; then
        row+=" | $(viewed "$W/$f.txt" "NEES median") | $(viewed "$W/$f.txt" "NEES within the 95% quantile") %"
      else
        row+=" | - | -"
      fi
    done
    echo "$row |"
  done
  echo
  echo "Per view (deg), COLMAP / rotavg / the averaging alone / rotavg on COLMAP's matches:"
  for s in "${SCENES[@]}"; do
    W="$OUT/$s"
    echo
    echo "**$s**"
    echo
    echo "| view | COLMAP | rotavg | averaging alone | on COLMAP's matches |"
    echo "|---|---|---|---|---|"
    while read -r _ name error; do
      printf '| %s | %s | %.4f | %s | %s |\n' "$name" "$(view_error "$W/colmap_scores.txt" "$name")" "$error" \
        "$(view_error "$W/averaging_scores.txt" "$name")" "$(view_error "$W/colmap_matches_scores.txt" "$name")"
    done < <(grep '^view ' "$W/rotavg_scores.txt")
  done
} > results/colmap.md
cat results/colmap.md
