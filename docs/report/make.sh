#!/usr/bin/env bash
# Regenerates the report pictures docs/eval.md shows: bags/synth-extreme replayed with each method,
# then `eval --report`; a few of the report's PNGs are copied here (through pngquant, when it is
# installed, to keep the repository small: `apt-get install pngquant`).
set -euo pipefail
cd "$(dirname "$0")/../.."
make build ort
bin="${CARGO_TARGET_DIR:-target}/release/angle-i2p"
out=out/report-docs
rm -rf "$out"
mkdir -p "$out"
for m in angle-i2p consistency ransac; do
    "$bin" replay bags/synth-extreme --out "$out/$m" --method "$m"
done
"$bin" eval bags/synth-extreme --est "$out/angle-i2p" --est "$out/consistency" --est "$out/ransac" --report "$out/report"
for f in trajectory.png cumulative.png frames-angle-i2p.png frames-consistency.png frames-consistency-sheet.png; do
    if command -v pngquant >/dev/null; then
        pngquant --quality 60-90 --speed 1 --force --output "docs/report/$f" "$out/report/$f"
    else
        cp "$out/report/$f" "docs/report/$f"
    fi
done
echo "report: $out/report/index.html; pictures: docs/report/"
