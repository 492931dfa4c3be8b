#!/usr/bin/env bash
# svbrdf capture on every real photo in ../shared/data/real (one output folder per source folder) and the DNG.
# Usage: export/studies/real_photos.sh [SHARED_DATA [OUT [capture options...]]]   (svbrdf on PATH)
set -u
SHARED=${1:-../shared/data}; OUT=${2:-/tmp/real_out}; shift $(( $# < 2 ? $# : 2 ))
rm -rf "$OUT"; mkdir -p "$OUT"
fails=0; n=0
while IFS= read -r dir; do
  mapfile -t files < <(find "$dir" -maxdepth 1 -type f \( -iname '*.jpg' -o -iname '*.jpeg' -o -iname '*.png' \) ! -name 'paper_*' | sort)
  [ ${#files[@]} -eq 0 ] && continue
  n=$((n + ${#files[@]}))
  rel=${dir#"$SHARED"/real}; rel=${rel#/}
  svbrdf capture "${files[@]}" -o "$OUT/real/${rel:-root}" -q "$@" || fails=$((fails + 1))
done < <(find "$SHARED/real" -type d ! -name reference_maps | sort)
svbrdf capture "$SHARED/raw/imageio_test_images/Blackmagic_PocketCinema4K_12bit.dng" -o "$OUT/raw" -q "$@" || fails=$((fails + 1))
sets=$(find "$OUT" -name material.json | wc -l)
echo "photos: $n + 1 DNG; complete sets: $sets; failed capture commands: $fails"
