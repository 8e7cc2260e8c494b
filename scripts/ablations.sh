#!/usr/bin/env bash
# The paper's ablations (section 4.4) on the shared validation bags, each replayed and scored by
# `angle-i2p eval`: the method; the model trained on rooms only and the ablation models trained
# like it (no global attention, distance θ, no scale alignment, no matcher score); the shipped
# model's training with the matcher's confidence as within-frame ranks; keypoints by
# spectral score only; τ ∈ {0.1, 0.2, 0.4, 0.5}; the PnP without the prior check, with plain
# inlier counting and without verification against the dense prior (`verify`); the
# training-free rejectors (distance and angle spectral consistency; also with ≥ 1500 PnP
# iterations, which spends about the network's time per frame) and plain LO-RANSAC.
#   scripts/ablations.sh [BAG ...]   (default: ../shared/data/redkitchen-{extreme,hard}-val)
# Needs `make build ort`. Output bags go to out/ablations/<bag>/<row>.
set -euo pipefail
cd "$(dirname "$0")/.."
bin=./target/release/angle-i2p
data=${ANGLE_I2P_DATA:-../shared/data}
bags=("$@")
[ ${#bags[@]} -gt 0 ] || bags=("$data/redkitchen-extreme-val" "$data/redkitchen-hard-val")
# Keypoints by spectral score only, with the shipped network: the ranking is a model constant (the
# model refuses params that contradict it), so this row runs a copy whose metadata says `spectral`.
spectral_only=out/ablations/keypoints_spectral_only.onnx
mkdir -p out/ablations
python3 training/stamp_metadata.py models/angle_i2p.onnx --out "$spectral_only" --set keypoint_ranking=spectral > /dev/null
rows=(
  "angle-i2p|--method angle-i2p"
  "rooms-only-model|--method angle-i2p --params-file params/ablations/rooms_only.yaml"
  "no-global-attention|--method angle-i2p --params-file params/ablations/no_global.yaml"
  "distance-theta|--method angle-i2p --params-file params/ablations/distance_theta.yaml"
  "no-scale-alignment|--method angle-i2p --params-file params/ablations/no_scale_alignment.yaml"
  "no-matcher-score|--method angle-i2p --params-file params/ablations/no_matcher_score.yaml"
  "confidence-rank-model|--method angle-i2p --params-file params/ablations/confidence_rank.yaml"
  "keypoints-spectral-only|--method angle-i2p -p network.model_path:=$spectral_only"
  "tau-0.1|--method angle-i2p -p network.tau:=0.1"
  "tau-0.4|--method angle-i2p -p network.tau:=0.4"
  "tau-0.5|--method angle-i2p -p network.tau:=0.5"
  "consistency-distance|--method consistency"
  "consistency-angle|--method consistency -p spectral.metric:=angle"
  "consistency-distance-equal-time|--method consistency -p pnp.min_iterations:=1500"
  "consistency-angle-equal-time|--method consistency -p spectral.metric:=angle -p pnp.min_iterations:=1500"
  "ransac|--method ransac"
  "ransac-no-verification|--method ransac -p verify.enabled:=false"
  "ransac-count-scoring|--method ransac -p pnp.coverage_cell_px:=0"
  "angle-i2p-no-prior-check|--method angle-i2p -p pnp.prior_tolerance:=0"
  "angle-i2p-count-scoring|--method angle-i2p -p pnp.coverage_cell_px:=0"
  "angle-i2p-no-verification|--method angle-i2p -p verify.enabled:=false"
  "consistency-distance-no-verification|--method consistency -p verify.enabled:=false"
)
for bag in "${bags[@]}"; do
  name=$(basename "$bag")
  dir=out/ablations/$name
  rm -rf "$dir" && mkdir -p "$dir"
  est=()
  for row in "${rows[@]}"; do
    label=${row%%|*}
    # shellcheck disable=SC2086 # the row's arguments are split on purpose
    "$bin" replay "$bag" --out "$dir/$label" ${row#*|} > /dev/null
    est+=(--est "$dir/$label")
  done
  echo "## $name"
  "$bin" eval "$bag" "${est[@]}"
done
