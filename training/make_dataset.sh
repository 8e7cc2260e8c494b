#!/usr/bin/env bash
# Builds the training and validation samples of the models in models/: synthetic bags
# (`angle-i2p synth`: hard tier seeds 11–30, extreme tier seeds 11–50) plus the shared real
# *-train bags, validated on the shared *-val bags; every frame exported with `angle-i2p export`.
#   training/make_dataset.sh [OUT_DIR] [PARAMS_FILE]   (default: training/data, built-in params)
# PARAMS_FILE selects the input variant (e.g. `network.theta: distance` for that ablation);
# the synthetic bags are generated once under OUT_DIR/../bags and reused by every variant.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-training/data}
params=()
[ -n "${2:-}" ] && params=(--params-file "$2")
shared=${ANGLE_I2P_DATA:-../shared/data}
bin=./target/release/angle-i2p
bags="$(dirname "$out")/bags"
[ -x "$bin" ] || cargo build --release
rm -rf "$out"
synth() { # tier seed
  [ -d "$bags/synth-$1-$2" ] || "$bin" synth --preset "$1" --seed "$2" --frames 20 --out "$bags/synth-$1-$2" > /dev/null
  "$bin" export "$bags/synth-$1-$2" --out "$out/train/synth-$1-$2" "${params[@]}"
}
for seed in $(seq 11 30); do synth hard "$seed"; done
for seed in $(seq 11 50); do synth extreme "$seed"; done
for tier in hard extreme sift; do
  "$bin" export "$shared/redkitchen-$tier-train" --out "$out/train/$tier-train" "${params[@]}"
  "$bin" export "$shared/redkitchen-$tier-val" --out "$out/val/$tier-val" "${params[@]}"
done
