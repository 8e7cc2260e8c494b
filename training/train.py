"""Trains the Angle-I2P rejector on exported samples and writes an ONNX model.

    python train.py --train DIR [DIR ...] --val DIR [DIR ...] --out ../models/angle_i2p.onnx

The model carries the `network.*` values its training inputs were built with (its metadata
`angle_i2p.*`, read and enforced at load): `angle-i2p export` writes them beside the samples
(`model_constants.json`), and every training directory must agree.
"""
import argparse
import glob
import json
import os
import random
import time

import numpy as np
import torch

from dataset import load_dir
from model import AngleI2PNet
from stamp_metadata import EXPORT_FILE, load_constants, stamp_file


def focal_loss(score, label, gamma=2.0, alpha=0.75):
    valid = label >= 0
    p, y = score[valid].clamp(1e-6, 1 - 1e-6), label[valid]
    pt = torch.where(y > 0.5, p, 1 - p)
    w = torch.where(y > 0.5, torch.full_like(p, alpha), torch.full_like(p, 1 - alpha))
    return (-w * (1 - pt) ** gamma * pt.log()).mean()


def feature_consistency_loss(f, label, pairs=256):
    """GraphSCNet's second term: the cosine similarity of two correspondences' features, mapped
    to [0, 1], should be 1 exactly when both are inliers. Class-balanced BCE over the pairs of up
    to `pairs` random labelled correspondences."""
    valid = torch.nonzero(label >= 0).squeeze(-1)
    if valid.numel() > pairs:
        valid = valid[torch.randperm(valid.numel())[:pairs]]
    y = (label[valid] > 0.5).float()
    g = torch.nn.functional.normalize(f[valid], dim=-1)
    sim = ((g @ g.T + 1) / 2).clamp(1e-6, 1 - 1e-6)
    target = y[:, None] * y[None, :]
    pos, neg = target > 0.5, target < 0.5
    loss = -(1 - sim[neg]).log().mean()
    if pos.any():
        loss = loss - sim[pos].log().mean()
    return loss


def augment_confidence(score, rng, missing=0.25):
    """One frame's matcher confidence as another matcher might have published it. Users' matchers
    are calibrated differently (a ratio test, 2D3D-MATR's softmax, none at all), and a network
    that learned one calibration misreads the others (models/MODEL_CARD.md, *The confidence-rank
    model*: on raw scores this costs ~3.5 points of extreme-tier RR on the published ones; with
    --confidence-rank only the constant and the shuffle change the input). Per frame, one of:
      kept as is (half the frames);
      a random monotone remap a * s^g (g in [1/3, 3], a in [0.3, 1]): same order, other scale;
      `missing` for every match (what the runtime feeds for a matcher without confidence:
      `network.missing_confidence`, a model constant: the export's value);
      shuffled among the frame's matches: the same distribution, no information."""
    u = rng.random()
    if u < 0.5:
        return score
    if u < 0.75:
        gamma = float(np.exp(rng.uniform(-np.log(3.0), np.log(3.0))))
        return rng.uniform(0.3, 1.0) * score.clamp(min=0.0) ** gamma
    if u < 0.875:
        return torch.full_like(score, missing)
    return score[torch.from_numpy(rng.permutation(score.shape[0]))]


def confidence_rank(score):
    """A frame's matcher confidence as within-frame ranks in [0, 1] (ties: their mean rank; one
    score for every match: 0.5): blind to the matcher's scale, only its order counts."""
    n = score.shape[0]
    if n < 2:
        return torch.full_like(score, 0.5)
    values = score.numpy().astype(np.float64)
    values = np.where(np.isfinite(values), values, -np.inf)  # no confidence: the least
    order = np.argsort(values, kind="stable")
    ranks = np.empty(n)
    sorted_values = values[order]
    start = 0
    while start < n:
        end = start
        while end + 1 < n and sorted_values[end + 1] == sorted_values[start]:
            end += 1
        ranks[order[start:end + 1]] = 0.5 * (start + end)
        start = end + 1
    return torch.from_numpy((ranks / (n - 1)).astype(np.float32))


def scores_of(model, samples):
    """The model's scores of every sample (no gradient)."""
    with torch.no_grad():
        return [model(*[s[k] for k in model.input_names]) for s in samples]


def metrics_of(scores, samples, tau):
    """Precision/recall of score ≥ τ, and precision of the top-40 scores, over labelled points."""
    tp = fp = fn = 0
    top = []
    for score, s in zip(scores, samples):
        y = s["labels"]
        valid = y >= 0
        keep = (score >= tau) & valid
        tp += int(((y == 1) & keep).sum()); fp += int(((y == 0) & keep).sum()); fn += int(((y == 1) & ~keep & valid).sum())
        order = torch.argsort(-score)[:40]
        top.append(float((y[order] == 1).float().mean()))
    return {"precision": tp / max(1, tp + fp), "recall": tp / max(1, tp + fn), "top40_precision": float(np.mean(top))}


def metrics(model, samples, tau):
    """[`metrics_of`] the model's scores of `samples`."""
    return metrics_of(scores_of(model, samples), samples, tau)


def training_constants(dirs):
    """The model constants the samples under `dirs` were exported with (`model_constants.json`,
    written by `angle-i2p export`): one set for all of them, since one model can carry one."""
    found = {}
    for d in dirs:
        for path in sorted(glob.glob(os.path.join(d, "**", EXPORT_FILE), recursive=True)):
            found[path] = load_constants(path)
    if not found:
        raise SystemExit(f"no {EXPORT_FILE} under {' '.join(dirs)}: export the samples again with a current "
                         "`angle-i2p export` (it writes the network.* values the inputs were built with)")
    first_path, first = next(iter(found.items()))
    for path, constants in found.items():
        if constants != first:
            diff = sorted(k for k in set(first) | set(constants) if first.get(k) != constants.get(k))
            raise SystemExit(f"{path} and {first_path} were exported with other network.* values ({', '.join(diff)}): "
                             "one model is trained on inputs of one kind")
    return first


def export(model, sample, path, constants):
    """One ONNX file (no external data), dynamic N, V, K, M; opset 18; the model constants in its
    metadata (stamp_metadata.py)."""
    torch.save(model.state_dict(), path.replace(".onnx", ".pt"))
    with open(path.replace(".onnx", ".json"), "w") as f:
        json.dump(model.config, f)
    args = tuple(confidence_rank(sample["matcher_score"]) if k == "matcher_rank" else sample[k] for k in model.input_names)
    n, v, k, m = torch.export.Dim("n"), torch.export.Dim("v"), torch.export.Dim("k"), torch.export.Dim("m")
    dims = {"features": {0: n}, "local_index": {0: v, 1: k}, "local_theta": {0: v, 1: k, 2: k},
            "global_index": {0: m}, "global_theta": {0: m, 1: m}, "cross_theta": {0: n, 1: m}}
    if model.use_matcher_score:
        dims["matcher_score"] = {0: n}
    torch.onnx.export(model, args, path, input_names=model.input_names, output_names=["score"], dynamic_shapes=dims,
                      opset_version=18, external_data=False)
    stamp_file(path, constants)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--train", nargs="+", required=True)
    ap.add_argument("--val", nargs="+", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--epochs", type=int, default=20)
    ap.add_argument("--d", type=int, default=32)
    ap.add_argument("--blocks", type=int, default=2)
    ap.add_argument("--no-global", action="store_true", help="ablation: local attention only")
    ap.add_argument("--matcher-score", action="store_true", help="also feed the matcher's confidence")
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--init", help="weights (.pt) to start from instead of a random initialisation")
    ap.add_argument("--tau", type=float, default=0.2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--alpha", type=float, default=0.75, help="focal loss weight of the inlier class")
    ap.add_argument("--augment-confidence", action="store_true",
                    help="rewrite half the frames' matcher confidence as other matchers publish it")
    ap.add_argument("--confidence-rank", action="store_true",
                    help="feed the matcher's confidence as within-frame ranks, input `matcher_rank` (after any "
                         "augmentation): a model blind to the matcher's scale")
    ap.add_argument("--consistency-weight", type=float, default=0.0,
                    help="weight of the feature-consistency loss (GraphSCNet), 0: focal loss only")
    a = ap.parse_args()
    torch.manual_seed(a.seed); random.seed(a.seed)
    rng = np.random.default_rng(a.seed)
    torch.set_num_threads(a.threads)
    constants = training_constants(a.train)
    missing = float(constants["missing_confidence"])
    train = [s for d in a.train for s in load_dir(d)]
    val = {d: load_dir(d) for d in a.val}
    if a.confidence_rank:
        for v in val.values():
            for s in v:
                s["matcher_rank"] = confidence_rank(s["matcher_score"])
    print(f"{len(train)} training samples; val: " + ", ".join(f"{d}: {len(v)}" for d, v in val.items()), flush=True)
    model = AngleI2PNet(d=a.d, blocks=a.blocks, use_global=not a.no_global, use_matcher_score=a.matcher_score,
                        matcher_input="matcher_rank" if a.confidence_rank else "matcher_score")
    if a.init:
        # Fine-tuning: start from trained weights of the same shape (e.g. on a wider data mix).
        model.load_state_dict(torch.load(a.init))
    opt = torch.optim.AdamW(model.parameters(), lr=a.lr, weight_decay=1e-6)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, a.epochs * len(train))
    for epoch in range(a.epochs):
        random.shuffle(train)
        t0, total = time.time(), 0.0
        model.train()
        for s in train:
            inputs = dict(s)
            if a.augment_confidence and model.use_matcher_score:
                inputs["matcher_score"] = augment_confidence(s["matcher_score"], rng, missing)
            if a.confidence_rank and model.use_matcher_score:
                inputs["matcher_rank"] = confidence_rank(inputs["matcher_score"])
            f = model.embed_correspondences(*[inputs[k] for k in model.input_names])
            loss = focal_loss(model.score(f), s["labels"], alpha=a.alpha)
            if a.consistency_weight > 0:
                loss = loss + a.consistency_weight * feature_consistency_loss(f, s["labels"])
            opt.zero_grad(); loss.backward(); opt.step(); sched.step()
            total += loss.item()
        model.eval()
        report = {d.rstrip("/").split("/")[-1]: metrics(model, v, a.tau) for d, v in val.items()}
        print(f"epoch {epoch}: loss {total / len(train):.4f} ({time.time() - t0:.0f}s) " + json.dumps(report), flush=True)
        export(model, train[0], a.out, constants)  # every epoch: a usable model at any time
        print("wrote", a.out, flush=True)


if __name__ == "__main__":
    main()
