#!/usr/bin/env bash
# Trains the committed model and the paper's ablations from scratch on CPU (~90 min on 2 cores):
#   models/ablations/rooms_only.onnx            the method on rooms only (the default room and
#                                               redkitchen): stage 1 of the shipped model
#   models/angle_i2p.onnx                       the shipped model: rooms_only fine-tuned on the whole
#                                               mix (other sensors, scenes, buildings, priors), the
#                                               real frames weighted ×4
#   models/ablations/confidence_rank.onnx       the shipped model's training with the matcher's
#                                               confidence as within-frame ranks (input
#                                               matcher_rank), rewritten in training as other
#                                               matchers publish it: blind to its calibration
#   models/ablations/no_global.onnx             local attention only (same inputs)
#   models/ablations/distance_theta.onnx        graphs' θ from length consistency
#   models/ablations/no_scale_alignment.onnx    raw prior cloud, no scale alignment
#   models/ablations/no_matcher_score.onnx      eq. (9) features only, no matcher confidence
#   models/ablations/d64_blocks3.onnx           a wider, deeper network (size/latency trade-off)
# The ablations are trained on rooms only, like rooms_only, which they are compared with.
# Every model carries the network.* values its dataset was exported with (K, M, θ, …) in its ONNX
# metadata: `angle-i2p export` writes them beside the samples and train.py stamps them.
# Needs `make training-env` and a release build (`make build`). EPOCHS overrides stage 1's epochs.
set -euo pipefail
cd "$(dirname "$0")"
epochs=${EPOCHS:-30}
py=.venv/bin/python
source ./stage2.sh
mkdir -p ../models/ablations
./make_dataset.sh training/data/angle
./make_dataset.sh training/data/distance training/variants/distance.yaml
./make_dataset.sh training/data/no-scale-alignment training/variants/no_scale_alignment.yaml
./make_dataset.sh training/data/rank training/variants/confidence_rank.yaml
rooms() { # data: the default room's synthetic bags and the real redkitchen frames
  echo data/"$1"/train/synth-hard-* data/"$1"/train/synth-extreme-* data/"$1"/train/*-train
}
train() { # data out [flags]: on rooms only
  local data=$1 out=$2; shift 2
  # shellcheck disable=SC2046
  $py train.py --train $(rooms "$data") --val "data/$data/val/hard-val" "data/$data/val/extreme-val" \
    --out "$out" --epochs "$epochs" --alpha 0.9 --threads 1 "$@" > "${out%.onnx}.log" 2>&1
}
train angle ../models/ablations/rooms_only.onnx --matcher-score
# Stage 2: every scene, sensor and prior of the dataset, the real frames three more times.
real="data/angle/train/hard-train data/angle/train/extreme-train data/angle/train/sift-train"
# shellcheck disable=SC2086
$py train.py --train data/angle/train $real $real $real --val data/angle/val/hard-val data/angle/val/extreme-val \
  --out ../models/angle_i2p.onnx "${STAGE2_ARGS[@]}" > ../models/angle_i2p.log 2>&1
$py parity.py --weights ../models/angle_i2p.pt --sample ../models/parity/sample
# The confidence-rank model: its own dataset (keypoints ranked by the confidence's rank).
ranked="data/rank/train/hard-train data/rank/train/extreme-train data/rank/train/sift-train"
# shellcheck disable=SC2086
$py train.py --train data/rank/train $ranked $ranked $ranked --val data/rank/val/hard-val data/rank/val/extreme-val \
  --out ../models/ablations/confidence_rank.onnx "${STAGE2_ARGS[@]}" --confidence-rank --augment-confidence \
  > ../models/ablations/confidence_rank.log 2>&1
train angle ../models/ablations/no_global.onnx --matcher-score --no-global
train distance ../models/ablations/distance_theta.onnx --matcher-score
train no-scale-alignment ../models/ablations/no_scale_alignment.onnx --matcher-score
train angle ../models/ablations/no_matcher_score.onnx
train angle ../models/ablations/d64_blocks3.onnx --matcher-score --d 64 --blocks 3 --lr 3e-4
