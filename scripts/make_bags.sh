#!/usr/bin/env bash
# Regenerates the synthetic bags shipped in bags/ (deterministic: fixed presets and seeds).
set -euo pipefail
cd "$(dirname "$0")/.."
bin=./target/release/angle-i2p
[ -x "$bin" ] || cargo build --release
for tier in sift hard extreme; do
  "$bin" synth --preset "$tier" --seed 1 --frames 20 --out "bags/synth-$tier"
done
