"""Writes PyTorch's scores for an exported sample, the reference the Rust parity test compares
ONNX Runtime's scores with (≤ 1e-4).

    python parity.py --weights ../models/angle_i2p.pt --sample ../models/parity/sample
"""
import argparse
import json
import os

import numpy as np
import torch

from dataset import load_sample
from model import INPUT_NAMES, AngleI2PNet


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--weights", required=True)
    ap.add_argument("--sample", required=True)
    ap.add_argument("--config", default=None, help="JSON with the model's d and blocks (default: model card's)")
    a = ap.parse_args()
    cfg = json.load(open(a.config)) if a.config else {"d": 32, "blocks": 2}
    model = AngleI2PNet(d=cfg["d"], blocks=cfg["blocks"])
    model.load_state_dict(torch.load(a.weights))
    model.eval()
    s = load_sample(a.sample)
    with torch.no_grad():
        score = model(*[s[k] for k in INPUT_NAMES]).numpy().astype(np.float32)
    np.save(os.path.join(a.sample, "scores_torch.npy"), score)
    print(f"{len(score)} scores, mean {score.mean():.4f}")


if __name__ == "__main__":
    main()
