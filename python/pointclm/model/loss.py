"""The paper's contrastive loss (eq. 3): pull inliers of one instance together, push each
inlier's hardest negative (closest correspondence outside its instance) beyond a margin."""

from __future__ import annotations

import torch

__all__ = ["IGNORE", "contrastive_loss", "negative_distances"]

#: Label of a correspondence the loss leaves out: neither an anchor, a positive nor a negative.
IGNORE = -2


def negative_distances(
    dist: torch.Tensor,
    labels: torch.Tensor,
    mode: str = "hardest",
    generator: torch.Generator | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per anchor: the distance to its chosen negative, and whether the anchor counts.

    dist: (B, N, N) feature distances; labels: (B, N), -1 outlier, k instance k, `IGNORE`
    left out. Anchors are inliers that have at least one negative. `mode` "hardest" takes the
    closest negative, "random" a uniformly drawn one (the paper's ablation).
    """
    anchor = labels >= 0
    neg = (labels[:, :, None] != labels[:, None, :]) & (labels[:, None, :] != IGNORE)
    valid = anchor & neg.any(dim=-1)
    if mode == "hardest":
        chosen = dist.masked_fill(~neg, float("inf")).amin(dim=-1)
    elif mode == "random":
        noise = torch.rand(dist.shape, generator=generator, device=dist.device, dtype=dist.dtype)
        pick = noise.masked_fill(~neg, -1.0).argmax(dim=-1, keepdim=True)
        chosen = dist.gather(-1, pick).squeeze(-1)
    else:
        raise ValueError(f"negatives must be 'hardest' or 'random', got {mode!r}")
    return torch.where(valid, chosen, torch.zeros_like(chosen)), valid


def contrastive_loss(
    features: torch.Tensor,
    labels: torch.Tensor,
    *,
    margin_pos: float = 0.1,
    margin_neg: float = 1.4,
    negatives: str = "hardest",
    generator: torch.Generator | None = None,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """``mean_P [D - m_p]_+^2 + mean_N [m_n - D]_+^2`` over a batch.

    features: (B, N, C) unit vectors; labels: (B, N). Positives are ordered pairs (i != j) of
    inliers of the same instance. Returns the loss and detached statistics (mean distance and
    cosine similarity of positives and of the chosen negatives).
    """
    dist = torch.cdist(features, features)
    same = (labels[:, :, None] == labels[:, None, :]) & (labels[:, :, None] >= 0)
    eye = torch.eye(labels.shape[1], dtype=torch.bool, device=labels.device)
    pos = same & ~eye
    zero = features.new_zeros(())
    n_pos = pos.sum()
    pos_term = (torch.relu(dist - margin_pos) ** 2)[pos].sum() / n_pos if n_pos > 0 else zero
    neg_dist, valid = negative_distances(dist, labels, negatives, generator)
    n_neg = valid.sum()
    neg_term = (torch.relu(margin_neg - neg_dist) ** 2)[valid].sum() / n_neg if n_neg > 0 else zero
    with torch.no_grad():
        stats = {
            "pos_dist": dist[pos].mean() if n_pos > 0 else zero,
            "neg_dist": neg_dist[valid].mean() if n_neg > 0 else zero,
            # unit vectors: cos = 1 - d^2 / 2
            "pos_cos": (1 - dist[pos] ** 2 / 2).mean() if n_pos > 0 else zero,
            "neg_cos": (1 - neg_dist[valid] ** 2 / 2).mean() if n_neg > 0 else zero,
        }
    return pos_term + neg_term, stats
