#!/usr/bin/env bash
# Stamps the model constants (ONNX metadata `angle_i2p.*`, training/stamp_metadata.py) into the
# models in models/ that were trained before train.py stamped them, with the values each one's
# training inputs were built with: the `network.*` defaults of the commit that trained it
# (git log models/…) plus its variant in training/variants/ (train_models.sh says which).
# Idempotent; changes no weight, so every model scores bit for bit as before. `make stamp-models`.
#   missing_confidence: stamped where the model was calibrated (angle_i2p: measured on it when the
#   key came in) or trained with it (confidence_rank: --augment-confidence's constant); the other
#   ablations predate the key and were never measured with one, so they leave it to the params.
set -euo pipefail
cd "$(dirname "$0")/.."
stamp() { python3 training/stamp_metadata.py "$@"; }
# The defaults every model was trained with (aad95f4 … 0faaf0f: K 32, M 100, angle θ, σ_d 0.2,
# prior aligned, 4 keypoint iterations, keypoints by spectral × matcher confidence).
defaults=(--set neighbours=32 --set keypoints=100 --set theta=angle --set sigma_d=0.2 --set align_prior=true
  --set keypoint_iterations=4 --set keypoint_ranking=spectral_matcher)
stamp models/angle_i2p.onnx "${defaults[@]}" --set missing_confidence=0.25
# training/variants/confidence_rank.yaml
stamp models/ablations/confidence_rank.onnx "${defaults[@]}" --set keypoint_ranking=spectral_matcher_rank \
  --set missing_confidence=0.25
for m in rooms_only no_global no_matcher_score d64_blocks3; do
  stamp "models/ablations/$m.onnx" "${defaults[@]}"
done
# training/variants/distance.yaml, training/variants/no_scale_alignment.yaml
stamp models/ablations/distance_theta.onnx "${defaults[@]}" --set theta=distance
stamp models/ablations/no_scale_alignment.onnx "${defaults[@]}" --set align_prior=false
