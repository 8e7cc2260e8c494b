# shellcheck shell=bash
# Stage 2's recipe: rooms_only fine-tuned on a mix (6 epochs, lr 3e-4, focal α 0.9, 2 threads, the
# matcher's confidence as an input). Sourced, from training/, by train_models.sh (the shipped model
# and the confidence-rank one) and transfer.sh (the leave-one-family-out models), so that every
# model compared was trained alike.
# shellcheck disable=SC2034
STAGE2_ARGS=(--epochs 6 --lr 3e-4 --alpha 0.9 --threads 2 --matcher-score --init ../models/ablations/rooms_only.pt)
