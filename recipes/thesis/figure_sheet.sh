#!/bin/sh
# The thesis's figures as one sheet, from the frames `kmpipe run recipes/thesis/recipe.toml -o OUT` rendered:
# a row per figure (5.5 with subsurface scattering, 5.58 without, 5.59 (c)-(f) looks), a column per panel.
#   sh recipes/thesis/figure_sheet.sh OUT SHEET.png        (run from the repository root)
set -eu
out=${1:?"usage: figure_sheet.sh OUT_DIR SHEET.png"}
sheet=${2:?"usage: figure_sheet.sh OUT_DIR SHEET.png"}
kmpipe=${KMPIPE:-.venv/bin/kmpipe}
f="$out/frames"
"$kmpipe" sheet -o "$sheet" --columns 4 \
  --header "Thesis figures 5.5, 5.58, 5.59 with the bundled samples · D65 · column labels: top rows | bottom row" \
  --column-labels "bare skin | (c) F1 B1 L1,F1 3 um | (d) F2 B1 L1,F1 15 um | (e) F2 B1 L2,F1 30 um | (f) F1 L2" \
  --row-labels "5.5 with SSS,5.58 without SSS,5.59 looks" \
  "$f/5-5-skin/frame_000.exr" "$f/5-5-f1-thin/frame_000.exr" "$f/5-5-f1-medium/frame_000.exr" \
  "$f/5-5-f1-thick/frame_000.exr" \
  "$f/5-58-skin/frame_000.exr" "$f/5-58-f1-thin/frame_000.exr" "$f/5-58-f1-medium/frame_000.exr" \
  "$f/5-58-f1-thick/frame_000.exr" \
  "$f/5-59-look-c/frame_000.exr" "$f/5-59-look-d/frame_000.exr" "$f/5-59-look-e/frame_000.exr" \
  "$f/5-59-look-f/frame_000.exr"
