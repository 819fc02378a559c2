"""SCNonlocal (from PointDSC), the correspondence embedding network of PointCLM.

Input: the 6-vector of each correspondence minus the scene mean. A 1x1 convolution lifts it to
`width` channels, then `depth` blocks of [1x1 conv + BatchNorm + ReLU, then a non-local block
whose attention logits `q_i . k_j / sqrt(width)` are scaled by the spatial consistency
`beta_ij`]. The output is L2-normalised per correspondence (no projection head). With the
defaults (12 blocks, 128 channels) it has 1,048,448 parameters, as the paper's.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import torch
from torch import nn

__all__ = ["EmbeddingConfig", "SCNonlocal", "normal_consistency", "spatial_consistency"]


@dataclass(frozen=True)
class EmbeddingConfig:
    """Architecture of the network and the beta it attends with.

    `inputs` names what the network takes besides coordinates (:mod:`pointclm.cues`):
    "normals" adds 6 channels and the normal term (tolerance `normal_tolerance` on cosines)
    to beta, "similarity" adds one channel."""

    depth: int = 12
    width: int = 128
    sigma_d: float = 0.05
    inputs: tuple[str, ...] = ()
    normal_tolerance: float = 0.5

    def __post_init__(self) -> None:
        from ..cues import check_inputs

        if self.depth < 1 or self.width < 4 or self.width % 2:
            raise ValueError(f"need depth >= 1 and an even width >= 4, got {self}")
        if not self.sigma_d > 0:
            raise ValueError(f"sigma_d must be > 0, got {self.sigma_d}")
        if not 0 < self.normal_tolerance <= 2:
            raise ValueError(f"normal_tolerance must lie in (0, 2], got {self.normal_tolerance}")
        object.__setattr__(self, "inputs", check_inputs(self.inputs))

    @property
    def input_channels(self) -> int:
        from ..cues import input_channels

        return input_channels(self.inputs)

    def as_dict(self) -> dict[str, Any]:
        """The JSON `architecture`; a plain network's is the 6-d one's, key for key."""
        d: dict[str, Any] = asdict(self)
        if not self.inputs:
            del d["inputs"], d["normal_tolerance"]
        else:
            d["inputs"] = list(self.inputs)
        return d


def normal_consistency(
    corr: torch.Tensor, normals: torch.Tensor, sigma_d: float, tolerance: float
) -> torch.Tensor:
    """beta with the normal term of the core's ``Correspondences::with_normals``, for
    (B, N, 6) coordinates and (B, N, 6) unit normals -> (B, N, N): the length term times
    ``[1 - (da / tol)^2]_+`` for the cosines between the normals and, for each point's
    distance from the other's tangent plane, ``[1 - (dh / (tol * l + sigma_d))^2]_+``
    (``l`` the pair's mean length). Absolute values, as the core: normal signs are not
    trusted."""
    src, dst = corr[..., :3], corr[..., 3:6]
    ns, nt = normals[..., :3], normals[..., 3:6]
    exact = "donot_use_mm_for_euclid_dist"
    ls = torch.cdist(src, src, compute_mode=exact)
    lt = torch.cdist(dst, dst, compute_mode=exact)
    length = torch.clamp(1.0 - (ls - lt) ** 2 / (sigma_d * sigma_d), min=0.0)
    da = (ns @ ns.transpose(1, 2)).abs() - (nt @ nt.transpose(1, 2)).abs()
    # n_i . (x_j - x_i) = n_i . x_j - n_i . x_i, for every pair at once
    ps = ns @ src.transpose(1, 2) - (ns * src).sum(-1, keepdim=True)
    pt = nt @ dst.transpose(1, 2) - (nt * dst).sum(-1, keepdim=True)
    dp = ps.abs() - pt.abs()  # row i's normal against the line to j
    dq = dp.transpose(1, 2)  # row j's normal against the same line
    w = tolerance * 0.5 * (ls + lt) + sigma_d
    planes = torch.clamp(1.0 - (dp / w) ** 2, min=0.0) * torch.clamp(1.0 - (dq / w) ** 2, min=0.0)
    angle = torch.clamp(1.0 - (da / tolerance) ** 2, min=0.0)
    return length * angle * planes


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
        self.lift = nn.Conv1d(self.config.input_channels, w, 1)
        self.pointcn = nn.ModuleList(
            nn.Sequential(nn.Conv1d(w, w, 1), nn.BatchNorm1d(w), nn.ReLU(inplace=True))
            for _ in range(self.config.depth)
        )
        self.nonlocal_blocks = nn.ModuleList(NonLocalBlock(w) for _ in range(self.config.depth))

    def forward(self, corr: torch.Tensor, beta: torch.Tensor | None = None) -> torch.Tensor:
        """(B, N, C) rows packed as :func:`pointclm.cues.pack` packs them (C = 6 for a plain
        network) -> (B, N, width) unit embeddings."""
        cfg = self.config
        if corr.shape[-1] != cfg.input_channels:
            raise ValueError(
                f"this network takes {cfg.input_channels} columns per correspondence "
                f"(coordinates{''.join(', ' + i for i in cfg.inputs)}), got {corr.shape[-1]}"
            )
        xyz = corr[..., :6]
        normals = None
        if "normals" in cfg.inputs:
            pairs = corr[..., 6:12].reshape(*corr.shape[:-1], 2, 3)
            normals = nn.functional.normalize(pairs, dim=-1).reshape(*corr.shape[:-1], 6)
        if beta is None:
            beta = (
                spatial_consistency(xyz, cfg.sigma_d)
                if normals is None
                else normal_consistency(xyz, normals, cfg.sigma_d, cfg.normal_tolerance)
            )
        # Only coordinates are centred: a normal or a similarity has no origin.
        parts = [xyz - xyz.mean(dim=1, keepdim=True)]
        if normals is not None:
            parts.append(normals)
        if "similarity" in cfg.inputs:
            parts.append(corr[..., -1:])
        centred = parts[0] if len(parts) == 1 else torch.cat(parts, dim=-1)
        feat = self.lift(centred.transpose(1, 2))
        for pointcn, nonlocal_block in zip(self.pointcn, self.nonlocal_blocks, strict=True):
            feat = nonlocal_block(pointcn(feat), beta)
        return nn.functional.normalize(feat.transpose(1, 2), dim=-1)
