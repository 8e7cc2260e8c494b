#!/usr/bin/env bash
# Trains the committed model and the paper's ablations from scratch on CPU (~60 min on 2 cores):
#   models/angle_i2p.onnx                       the method
#   models/ablations/no_global.onnx             local attention only (same inputs)
#   models/ablations/distance_theta.onnx        graphs' θ from length consistency
#   models/ablations/no_scale_alignment.onnx    raw prior cloud, no scale alignment
#   models/ablations/no_matcher_score.onnx      eq. (9) features only, no matcher confidence
#   models/ablations/d64_blocks3.onnx           a wider, deeper network (size/latency trade-off)
# Needs `make training-env` and a release build (`make build`). EPOCHS overrides the epochs.
set -euo pipefail
cd "$(dirname "$0")"
epochs=${EPOCHS:-30}
py=.venv/bin/python
mkdir -p ../models/ablations
./make_dataset.sh training/data/angle
./make_dataset.sh training/data/distance training/variants/distance.yaml
./make_dataset.sh training/data/no-scale-alignment training/variants/no_scale_alignment.yaml
train() { # data out [flags]
  local data=$1 out=$2; shift 2
  $py train.py --train "data/$data/train" --val "data/$data/val/hard-val" "data/$data/val/extreme-val" \
    --out "$out" --epochs "$epochs" --alpha 0.9 --threads 1 "$@" > "${out%.onnx}.log" 2>&1
}
train angle ../models/angle_i2p.onnx --matcher-score
train angle ../models/ablations/no_global.onnx --matcher-score --no-global
train distance ../models/ablations/distance_theta.onnx --matcher-score
train no-scale-alignment ../models/ablations/no_scale_alignment.onnx --matcher-score
train angle ../models/ablations/no_matcher_score.onnx
train angle ../models/ablations/d64_blocks3.onnx --matcher-score --d 64 --blocks 3 --lr 3e-4
