"""The Angle-I2P outlier-rejection network (paper section 3.3), sized for a CPU core.

Inputs (built in Rust by `angle-i2p export` / the node, never inside the graph):
  features     [N, 24]    eq. (9)
  local_index  [V, K]     each local node's K nearest correspondences (int64)
  local_theta  [V, K, K]  angle consistency θ inside each node's group (eq. 7)
  global_index [M]        the M keypoint correspondences (int64)
  global_theta [M, M]     θ among the keypoints
  cross_theta  [N, M]     θ between every correspondence and every keypoint
  matcher_score [N]       the matcher's own confidence (only a model built with
                          `use_matcher_score`; an input beyond eq. 9), or instead
  matcher_rank [N]        its within-frame ranks in [0, 1] (`matcher_input="matcher_rank"`:
                          blind to the matcher's scale; the runtime feeds what the model names)
Output: score [N], the inlier probability.

Each block: self-attention inside every local group, self-attention among the keypoints,
then cross-attention from every correspondence to the keypoints; all attention logits are
multiplied by θ before the softmax (eq. 10-11). GraphSCNet's layout (ops, layers, model kept
apart), written here from the paper.
"""
import math

import torch
from torch import nn

INPUT_NAMES = ["features", "local_index", "local_theta", "global_index", "global_theta", "cross_theta"]


class ThetaAttention(nn.Module):
    """Single-head attention whose logits are multiplied by a consistency matrix θ."""

    def __init__(self, d: int):
        super().__init__()
        self.q = nn.Linear(d, d)
        self.k = nn.Linear(d, d)
        self.v = nn.Linear(d, d)
        self.out = nn.Linear(d, d)
        self.norm = nn.LayerNorm(d)
        self.ffn = nn.Sequential(nn.Linear(d, 2 * d), nn.ReLU(), nn.Linear(2 * d, d))
        self.norm2 = nn.LayerNorm(d)
        self.scale = 1.0 / math.sqrt(d)

    def forward(self, query, key, theta):
        # query [..., A, d], key [..., B, d], theta [..., A, B]
        logits = theta * (self.q(query) @ self.k(key).transpose(-1, -2)) * self.scale
        x = self.norm(query + self.out(torch.softmax(logits, dim=-1) @ self.v(key)))
        return self.norm2(x + self.ffn(x))


class Block(nn.Module):
    def __init__(self, d: int, use_global: bool = True):
        super().__init__()
        self.local = ThetaAttention(d)
        self.use_global = use_global
        if use_global:
            self.keypoints = ThetaAttention(d)
            self.cross = ThetaAttention(d)

    def forward(self, f, local_index, local_theta, global_index, global_theta, cross_theta):
        n, d = f.shape
        groups = f[local_index]  # [V, K, d]
        groups = self.local(groups, groups, local_theta)
        # Each correspondence: mean over the groups it belongs to (itself where in none).
        flat_index = local_index.reshape(-1)
        summed = torch.zeros_like(f).index_add(0, flat_index, groups.reshape(-1, d))
        count = torch.zeros(n, 1, dtype=f.dtype).index_add(0, flat_index, torch.ones(flat_index.shape[0], 1))
        f = torch.where(count > 0, summed / count.clamp(min=1.0), f)
        if self.use_global:
            keys = f[global_index]
            keys = self.keypoints(keys, keys, global_theta)
            f = self.cross(f, keys, cross_theta)
        return f


class AngleI2PNet(nn.Module):
    def __init__(self, d: int = 32, blocks: int = 2, use_global: bool = True, use_matcher_score: bool = False,
                 matcher_input: str = "matcher_score"):
        super().__init__()
        assert matcher_input in ("matcher_score", "matcher_rank"), matcher_input
        self.use_matcher_score = use_matcher_score
        self.matcher_input = matcher_input
        self.config = {"d": d, "blocks": blocks, "use_global": use_global, "use_matcher_score": use_matcher_score}
        if use_matcher_score and matcher_input != "matcher_score":
            self.config["matcher_input"] = matcher_input
        self.input_names = INPUT_NAMES + ([matcher_input] if use_matcher_score else [])
        self.embed = nn.Sequential(nn.Linear(24 + int(use_matcher_score), d), nn.ReLU(), nn.Linear(d, d))
        self.blocks = nn.ModuleList(Block(d, use_global) for _ in range(blocks))
        self.head = nn.Sequential(nn.Linear(d, d), nn.ReLU(), nn.Linear(d, 1))

    def embed_correspondences(self, features, local_index, local_theta, global_index, global_theta, cross_theta,
                              matcher_score=None):
        """The per-correspondence features [N, d] after the attention blocks (what the head scores)."""
        if self.use_matcher_score:
            features = torch.cat([features, matcher_score.unsqueeze(-1)], dim=-1)
        f = self.embed(features)
        for block in self.blocks:
            f = block(f, local_index, local_theta, global_index, global_theta, cross_theta)
        return f

    def score(self, f):
        return torch.sigmoid(self.head(f)).squeeze(-1)

    def forward(self, features, local_index, local_theta, global_index, global_theta, cross_theta, matcher_score=None):
        f = self.embed_correspondences(features, local_index, local_theta, global_index, global_theta, cross_theta,
                                       matcher_score)
        return self.score(f)
