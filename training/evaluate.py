"""The rejector's quality on exported samples, per folder: precision and recall of score ≥ τ,
precision of the 40 best scores, and the share of frames whose kept set holds at least 6 true
matches (fewer and PnP on the kept set cannot find the pose; the geometry-only search must).

    python evaluate.py --weights ../models/angle_i2p.pt DIR [DIR ...] [--json OUT]
(the model's shape is read from the .json beside the weights, written by train.py)
"""
import argparse
import json

import torch

from dataset import load_dir
from model import AngleI2PNet
from train import metrics_of, scores_of

ENOUGH_TRUE_KEPT = 6


def frames_with_enough_kept(scores, samples, tau):
    """Share of frames whose scores ≥ τ keep at least ENOUGH_TRUE_KEPT labelled inliers."""
    enough = sum(int(((score >= tau) & (s["labels"] == 1)).sum()) >= ENOUGH_TRUE_KEPT for score, s in zip(scores, samples))
    return enough / max(1, len(samples))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--weights", required=True)
    ap.add_argument("--tau", type=float, default=0.2)
    ap.add_argument("--json", help="also write the report here")
    ap.add_argument("dirs", nargs="+")
    a = ap.parse_args()
    torch.set_num_threads(2)
    with open(a.weights.replace(".pt", ".json")) as f:
        model = AngleI2PNet(**json.load(f))
    model.load_state_dict(torch.load(a.weights))
    model.eval()
    report = {}
    for d in a.dirs:
        samples = load_dir(d)
        scores = scores_of(model, samples)
        row = metrics_of(scores, samples, a.tau)
        row["frames_enough_kept"] = frames_with_enough_kept(scores, samples, a.tau)
        row["frames"] = len(samples)
        report[d.rstrip("/").split("/")[-1]] = row
        print(f"{d}: " + json.dumps({k: round(v, 3) for k, v in row.items()}), flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(report, f, indent=1)


if __name__ == "__main__":
    main()
