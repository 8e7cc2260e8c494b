#!/usr/bin/env bash
# Builds the training and validation samples of models/angle_i2p.onnx: synthetic bags
# (`angle-i2p synth`, hard and extreme tiers, seeds 11–30) plus the shared real *-train bags,
# validated on the shared *-val bags; every frame exported with `angle-i2p export`.
#   training/make_dataset.sh [OUT_DIR]   (default: training/data)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-training/data}
shared=${ANGLE_I2P_DATA:-../shared/data}
bin=./target/release/angle-i2p
[ -x "$bin" ] || cargo build --release
rm -rf "$out"
for seed in $(seq 11 30); do
  for tier in hard extreme; do
    "$bin" synth --preset "$tier" --seed "$seed" --frames 20 --out "$out/bags/synth-$tier-$seed" > /dev/null
    "$bin" export "$out/bags/synth-$tier-$seed" --out "$out/train/synth-$tier-$seed"
  done
done
for tier in hard extreme sift; do
  "$bin" export "$shared/redkitchen-$tier-train" --out "$out/train/$tier-train"
  "$bin" export "$shared/redkitchen-$tier-val" --out "$out/val/$tier-val"
done
