#!/usr/bin/env bash
# Builds the training and validation samples of the models in models/: synthetic bags
# (`angle-i2p synth`: hard tier seeds 11–30, extreme tier seeds 11–50 in the default room, and a
# mix of other sensors, scenes, maps and priors — close-range RGB-D, wide and HD cameras, sparse
# maps, harsh metric-like priors and affine-invariant disparity, seeds 101–106 each; building-scale
# scenes of each tier and prior, seeds 101–104; offices of identical cubicles seen by an Xtion-like
# camera over maps fused from drifted keyframes, seeds 101–106) plus the
# shared real *-train bags, validated on the shared *-val bags; every frame exported with
# `angle-i2p export` (disparity priors read as such).
#   training/make_dataset.sh [OUT_DIR] [PARAMS_FILE]   (default: training/data, built-in params)
# PARAMS_FILE selects the input variant (e.g. `network.theta: distance` for that ablation);
# the synthetic bags are generated once under OUT_DIR/../bags and reused by every variant.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-training/data}
params=()
[ -n "${2:-}" ] && params=(--params-file "$2")
shared=${ANGLE_I2P_DATA:-../shared/data}
bin=${ANGLE_I2P_BIN:-./target/release/angle-i2p}
bags="$(dirname "$out")/bags"
[ -x "$bin" ] || cargo build --release
rm -rf "$out"
synth() { # preset seed [export args]
  local preset=$1 seed=$2; shift 2
  local name="synth-${preset//+/_}-$seed"
  [ -d "$bags/$name" ] || "$bin" synth --preset "$preset" --seed "$seed" --frames 20 --out "$bags/$name" > /dev/null
  "$bin" export "$bags/$name" --out "$out/train/$name" "$@" "${params[@]}"
}
for seed in $(seq 11 30); do synth hard "$seed"; done
for seed in $(seq 11 50); do synth extreme "$seed"; done
for seed in $(seq 101 106); do
  for preset in hard+close extreme+close hard+close+small-map extreme+close+harsh hard+wide extreme+wide+harsh \
    hard+small-map extreme+harsh hard+harsh; do
    synth "$preset" "$seed"
  done
  for preset in hard+disparity extreme+disparity extreme+close+disparity; do
    synth "$preset" "$seed" -p depth_kind:=disparity
  done
done
for seed in 101 102; do synth hard+hd "$seed"; synth extreme+hd+harsh "$seed"; done
# Building-scale scenes (rows of furnished rooms along a route, maps of ~2 M points).
for seed in 101 102 103 104; do
  for preset in building building+harsh extreme+building extreme+building+harsh; do synth "$preset" "$seed"; done
  for preset in building+disparity extreme+building+disparity; do synth "$preset" "$seed" -p depth_kind:=disparity; done
done
# Offices: rows of identical cubicles, a 640×480 camera, maps fused from keyframes with SfM-like errors.
for seed in $(seq 101 106); do
  for preset in hard+office extreme+office extreme+office+harsh; do synth "$preset" "$seed"; done
  synth hard+office+disparity "$seed" -p depth_kind:=disparity
done
for tier in hard extreme sift; do
  "$bin" export "$shared/redkitchen-$tier-train" --out "$out/train/$tier-train" "${params[@]}"
  "$bin" export "$shared/redkitchen-$tier-val" --out "$out/val/$tier-val" "${params[@]}"
done
