#!/usr/bin/env bash
# Leave-one-family-out: how the rejector carries to a family of scenes it never saw (#34).
#   training/transfer.sh [FAMILY ...]     (default: office building close; ~8 min of training each)
#   WITH=WEIGHTS.pt compares with another model than the shipped one (trained with every family).
# Needs `make training-env`, a release build, and training/make_dataset.sh's samples under
# training/data/angle. For each family F:
#   * held-out bags of F (seeds 201–202, never in any training set) are generated and exported
#     under training/data/heldout/F;
#   * stage 2 of the shipped model is trained again from rooms_only on the whole mix *but F*
#     (the same recipe: 6 epochs, lr 3e-4, α 0.9, the real frames ×4) into
#     training/data/models/without_F.onnx;
#   * that model and the shipped one (trained with F) are scored on F's held-out samples
#     (training/evaluate.py: precision and recall of score ≥ τ, precision of the 40 best, frames
#     whose kept set holds ≥ 6 true matches) into training/data/transfer/F.json.
# The end-to-end figures (RR, false poses with each model) come from `angle-i2p replay` + `eval`
# on the same held-out bags; models/MODEL_CARD.md, *Leave one family out*, has both.
set -euo pipefail
cd "$(dirname "$0")"
py=.venv/bin/python
source ./stage2.sh
bin=${ANGLE_I2P_BIN:-../target/release/angle-i2p}
data=data
families=("$@")
[ ${#families[@]} -gt 0 ] || families=(office building close)

# The held-out bags of a family: presets × seeds 201–202 (buildings: one seed, their maps are large).
heldout_presets() {
  case $1 in
    office) echo hard+office extreme+office extreme+office+harsh ;;
    building) echo building extreme+building extreme+building+harsh ;;
    close) echo hard+close extreme+close extreme+close+harsh ;;
    *) echo "unknown family $1 (office, building, close)" >&2; exit 2 ;;
  esac
}
heldout_seeds() { if [ "$1" = building ]; then echo 201; else echo 201 202; fi; }

# The training directories of the whole mix but one family (its samples' names hold its word).
mix_without() {
  local family=$1 d
  for d in "$data"/angle/train/*; do
    case $(basename "$d") in *"$family"*) ;; *) echo "$d" ;; esac
  done
}

mkdir -p "$data/models" "$data/transfer" "$data/heldout-bags"
real="$data/angle/train/hard-train $data/angle/train/extreme-train $data/angle/train/sift-train"
for family in "${families[@]}"; do
  for preset in $(heldout_presets "$family"); do
    for seed in $(heldout_seeds "$family"); do
      name="${preset//+/_}-$seed"
      bag="$data/heldout-bags/$name"
      [ -d "$bag" ] || "$bin" synth --preset "$preset" --seed "$seed" --frames 20 --out "$bag" > /dev/null
      [ -d "$data/heldout/$family/$name" ] || "$bin" export "$bag" --out "$data/heldout/$family/$name"
    done
  done
  model="$data/models/without_$family.onnx"
  if [ ! -f "$model" ]; then
    # shellcheck disable=SC2046,SC2086
    $py train.py --train $(mix_without "$family") $real $real $real --val "$data/heldout/$family" \
      --out "$model" "${STAGE2_ARGS[@]}" > "${model%.onnx}.log" 2>&1
  fi
  for weights in "${WITH:-../models/angle_i2p.pt}" "${model%.onnx}.pt"; do
    echo "== $family, $(basename "$weights" .pt)"
    $py evaluate.py --weights "$weights" --json "$data/transfer/${family}_$(basename "$weights" .pt).json" \
      "$data"/heldout/"$family"/*
  done
done
