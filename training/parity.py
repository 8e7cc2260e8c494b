"""Writes PyTorch's scores for an exported sample, the reference the Rust parity test compares
ONNX Runtime's scores with (≤ 1e-4).

    python parity.py --weights ../models/angle_i2p.pt --sample ../models/parity/sample
(the model's shape is read from the .json beside the weights, written by train.py)
"""
import argparse
import json
import os

import numpy as np
import torch

from dataset import load_sample
from model import AngleI2PNet


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--weights", required=True)
    ap.add_argument("--sample", required=True)
    a = ap.parse_args()
    with open(a.weights.replace(".pt", ".json")) as f:
        model = AngleI2PNet(**json.load(f))
    model.load_state_dict(torch.load(a.weights))
    model.eval()
    s = load_sample(a.sample)
    with torch.no_grad():
        score = model(*[s[k] for k in model.input_names]).numpy().astype(np.float32)
    np.save(os.path.join(a.sample, "scores_torch.npy"), score)
    print(f"{len(score)} scores, mean {score.mean():.4f}")


if __name__ == "__main__":
    main()
