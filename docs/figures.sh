#!/usr/bin/env bash
# Regenerates the figures of the documentation (docs/figures/*.png) from built-in shapes:
#   bash docs/figures.sh        (uses .venv/bin/selfsupport; about a minute)
# Every figure is drawn by `selfsupport render` (or written by the command it illustrates) from a
# network that the same commands as in the guide produce.
set -euo pipefail
cd "$(dirname "$0")/.."
BIN="${BIN:-.venv/bin}"
OUT=docs/figures
WORK="$(mktemp -d)"
trap 'rm -rf "$WORK"' EXIT
ss() { "$BIN/selfsupport" "$@"; }
DPI=80

ss solve shape:pillar_vault:676 --out "$WORK/pv.json" --quiet >/dev/null 2>&1
for what in network deviation airy reciprocal directions history; do
    ss render "$WORK/pv.json" --what "$what" --dpi "$DPI" --out "$OUT/pillar-vault-$what.png" >/dev/null
done
ss solve shape:dome:300 --out "$WORK/dome.json" --quiet >/dev/null 2>&1
ss pq "$WORK/dome.json" --out "$WORK/dome-pq.json" >/dev/null 2>&1
ss render "$WORK/dome-pq.json" --dpi "$DPI" --out "$OUT/dome-pq.png" >/dev/null
ss koebe --example enneper --alpha 1 --out "$WORK/enneper.json" >/dev/null
ss render "$WORK/enneper.json" --dpi "$DPI" --out "$OUT/enneper-alpha1.png" >/dev/null
ss construct --disk 8 --out "$WORK/construct.json" >/dev/null
ss render "$WORK/construct.json" --dpi "$DPI" --out "$OUT/construct-disk.png" >/dev/null
ss destroy shape:dome:300 --thickness 0.3 --remove 0 --out "$WORK/destroy" >/dev/null 2>&1
cp "$WORK/destroy/stages.png" "$OUT/destroy-dome-stages.png"
ss stability shape:dome:300 --thickness 0.3 --load-at 0 --loads 0,5000 --out "$WORK/stability" >/dev/null 2>&1
ss render "$WORK/stability/load-5000kg.json" --what deviation --thickness 0.3 --dpi "$DPI" \
    --out "$OUT/stability-dome-5000kg.png" >/dev/null
printf '[start]\nscene = "shape:pillar_vault:300"\n\n[[edit]]\nop = "pillar"\nselect = { nearest = [0.5, 0.5], relative = true }\nhole = true\n' \
    > "$WORK/pillar.toml"
ss edit "$WORK/pillar.toml" --out "$WORK/edit" >/dev/null 2>&1
ss render "$WORK/edit/stage-01.json" --dpi "$DPI" --out "$OUT/edit-pillar.png" >/dev/null
echo "figures -> $OUT"
