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

VERSION=$(colmap -h 2>&1 | sed -n 's/^COLMAP \([0-9.]*\).*/COLMAP \1/p' | head -1)
python3 scripts/colmap_report.py "$OUT" "$DATA" "$VERSION" "${SCENES[@]}" > results/colmap.md
cat results/colmap.md
