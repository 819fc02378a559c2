"""SCNonlocal (from PointDSC), the correspondence embedding network of PointCLM.

Input: the 6-vector of each correspondence minus the scene mean. A 1x1 convolution lifts it to
`width` channels, then `depth` blocks of [1x1 conv + BatchNorm + ReLU, then a non-local block
whose attention logits `q_i . k_j / sqrt(width)` are scaled by the spatial consistency
`beta_ij`]. The output is L2-normalised per correspondence (no projection head). With the
defaults (12 blocks, 128 channels) it has 1,048,448 parameters, as the paper's.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

__all__ = ["EmbeddingConfig", "SCNonlocal", "spatial_consistency"]


@dataclass(frozen=True)
class EmbeddingConfig:
    """Architecture of the network and the beta it attends with."""

    depth: int = 12
    width: int = 128
    sigma_d: float = 0.05

    def __post_init__(self) -> None:
        if self.depth < 1 or self.width < 4 or self.width % 2:
            raise ValueError(f"need depth >= 1 and an even width >= 4, got {self}")
        if not self.sigma_d > 0:
            raise ValueError(f"sigma_d must be > 0, got {self.sigma_d}")

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


def spatial_consistency(corr: torch.Tensor, sigma_d: float) -> torch.Tensor:
    """``beta_ij = [1 - d_ij^2 / sigma_d^2]_+`` for (B, N, 6) correspondences -> (B, N, N).

    The same formula as the Rust core (`pointclm.staged.spatial_consistency`); a test checks
    they agree.
    """
    src, dst = corr[..., :3], corr[..., 3:]
    exact = "donot_use_mm_for_euclid_dist"  # matmul-based cdist loses ~1e-11
    d = torch.cdist(src, src, compute_mode=exact) - torch.cdist(dst, dst, compute_mode=exact)
    return torch.clamp(1.0 - d * d / (sigma_d * sigma_d), min=0.0)


class NonLocalBlock(nn.Module):
    def __init__(self, width: int) -> None:
        super().__init__()
        half = width // 2
        self.q = nn.Conv1d(width, width, 1)
        self.k = nn.Conv1d(width, width, 1)
        self.v = nn.Conv1d(width, width, 1)
        self.message = nn.Sequential(
            nn.Conv1d(width, half, 1),
            nn.BatchNorm1d(half),
            nn.ReLU(inplace=True),
            nn.Conv1d(half, half, 1),
            nn.BatchNorm1d(half),
            nn.ReLU(inplace=True),
            nn.Conv1d(half, width, 1),
        )
        self.scale = width**-0.5

    def forward(self, feat: torch.Tensor, beta: torch.Tensor) -> torch.Tensor:
        q, k, v = self.q(feat), self.k(feat), self.v(feat)  # (B, C, N)
        logits = torch.einsum("bci,bcj->bij", q, k) * self.scale
        weight = torch.softmax(beta * logits, dim=-1)
        message = torch.einsum("bij,bcj->bci", weight, v)
        return feat + self.message(message)


class SCNonlocal(nn.Module):
    """Correspondences (B, N, 6) -> unit-norm embeddings (B, N, width)."""

    def __init__(self, config: EmbeddingConfig | None = None) -> None:
        super().__init__()
        self.config = config or EmbeddingConfig()
        w = self.config.width
        self.lift = nn.Conv1d(6, w, 1)
        self.pointcn = nn.ModuleList(
            nn.Sequential(nn.Conv1d(w, w, 1), nn.BatchNorm1d(w), nn.ReLU(inplace=True))
            for _ in range(self.config.depth)
        )
        self.nonlocal_blocks = nn.ModuleList(NonLocalBlock(w) for _ in range(self.config.depth))

    def forward(self, corr: torch.Tensor, beta: torch.Tensor | None = None) -> torch.Tensor:
        if beta is None:
            beta = spatial_consistency(corr, self.config.sigma_d)
        centred = corr - corr.mean(dim=1, keepdim=True)
        feat = self.lift(centred.transpose(1, 2))
        for pointcn, nonlocal_block in zip(self.pointcn, self.nonlocal_blocks, strict=True):
            feat = nonlocal_block(pointcn(feat), beta)
        return nn.functional.normalize(feat.transpose(1, 2), dim=-1)
