"""Training samples written by `angle-i2p export BAG --out DIR` (one folder of .npy per frame)."""
import glob
import os

import numpy as np
import torch

from model import INPUT_NAMES


def load_sample(folder):
    """The network inputs, `matcher_score` (column 5 of correspondences.npy), and
    `labels`/`spectral` when the folder has them."""
    names = INPUT_NAMES + [n for n in ("labels", "spectral") if os.path.exists(os.path.join(folder, n + ".npy"))]
    sample = {n: torch.from_numpy(np.load(os.path.join(folder, n + ".npy"))) for n in names}
    corr = np.load(os.path.join(folder, "correspondences.npy"))
    sample["matcher_score"] = torch.from_numpy(np.ascontiguousarray(corr[:, 5], dtype=np.float32))
    return sample


def load_dir(root):
    """Every sample below `root` (any depth)."""
    return [load_sample(os.path.dirname(p)) for p in sorted(glob.glob(os.path.join(root, "**", "labels.npy"), recursive=True))]
