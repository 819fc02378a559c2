"""SCNonlocal (from PointDSC), the correspondence embedding network of PointCLM.

Input: per correspondence, its 6 coordinates (source xyz | target xyz) minus their scene
mean, then, for a network with `inputs` beyond them and not centred:

- ``"normals"``: the unit surface normals at both ends (source normal | target normal, 6
  channels), each rotated with its side's coordinates. Callers pass unit normals; the
  network rescales them to unit length anyway (as the Rust core's
  `Correspondences::with_normals` does), so that both see the same values.
- ``"similarity"``: the descriptor similarity of the match (1 channel; the training data
  defines it, in (0, 1]).

A 1x1 convolution lifts the `input_channels` to `width` channels, then `depth` blocks of
[1x1 conv + BatchNorm + ReLU, then a non-local block whose attention logits
`q_i . k_j / sqrt(width)` are scaled by the spatial consistency `beta_ij`]. With the
"normals" input `beta_ij` also carries the normal term of spatial consistency
(`normal_consistency`), with the tolerance `normal_tolerance`. The output is L2-normalised
per correspondence (no projection head). With the defaults (12 blocks, 128 channels, no
inputs beyond the coordinates) it has 1,048,448 parameters, as the paper's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch import nn

# The inputs beyond the coordinates, in the order of their input channels: one definition,
# shared with the data side.
from ..cues import INPUTS, input_channels

__all__ = [
    "INPUTS",
    "NORMALIZATIONS",
    "EmbeddingConfig",
    "SCNonlocal",
    "normal_consistency",
    "spatial_consistency",
]

#: What the BatchNorms normalise with at inference (see `EmbeddingConfig`).
NORMALIZATIONS = ("running", "scene")


@dataclass(frozen=True)
class EmbeddingConfig:
    """Architecture of the network and the beta it attends with.

    `inputs` is a subset of `INPUTS` (stored in that order); `normal_tolerance` is the
    cosine tolerance of beta's normal term, in (0, 2], used with "normals" only.

    `normalization` says what every BatchNorm normalises with at inference: "running" (the
    statistics gathered in training, folded into the convolutions: the paper's and the
    shipped networks') or "scene" (the mean and variance over the scene's own rows, as in
    training when each batch holds one scene). Realistic scenes differ so much from one
    another (extent, density, inlier share) that averaged statistics fit none of them: a
    network trained one scene per batch collapses every embedding to one vector with them.
    """

    depth: int = 12
    width: int = 128
    sigma_d: float = 0.05
    inputs: tuple[str, ...] = ()
    normal_tolerance: float = 0.5
    normalization: str = "running"

    def __post_init__(self) -> None:
        if self.depth < 1 or self.width < 4 or self.width % 2:
            raise ValueError(f"need depth >= 1 and an even width >= 4, got {self}")
        if not self.sigma_d > 0:
            raise ValueError(f"sigma_d must be > 0, got {self.sigma_d}")
        if isinstance(self.inputs, str):
            raise ValueError(f"inputs must be a sequence of input names, got {self.inputs!r}")
        names = list(self.inputs)
        unknown = [n for n in names if n not in INPUTS]
        if unknown:
            raise ValueError(f"unknown network inputs {unknown}; known: {', '.join(INPUTS)}")
        if len(set(names)) != len(names):
            raise ValueError(f"inputs lists an input twice: {names}")
        # canonical order, so that configs (and the channels they imply) compare equal
        object.__setattr__(self, "inputs", tuple(n for n in INPUTS if n in names))
        if not 0 < self.normal_tolerance <= 2:
            raise ValueError(f"normal_tolerance must lie in (0, 2], got {self.normal_tolerance}")
        if self.normalization not in NORMALIZATIONS:
            raise ValueError(
                f"normalization must be one of {NORMALIZATIONS}, got {self.normalization!r}"
            )

    @property
    def input_channels(self) -> int:
        """6 coordinates, then 6 for "normals" and 1 for "similarity"."""
        return input_channels(self.inputs)

    def as_dict(self) -> dict[str, Any]:
        """The weights' `architecture`: without `inputs` and `normal_tolerance` for the plain
        network, so that its metadata is what it was before inputs existed."""
        d: dict[str, Any] = {"depth": self.depth, "width": self.width, "sigma_d": self.sigma_d}
        if self.inputs:
            d["inputs"] = list(self.inputs)
            d["normal_tolerance"] = self.normal_tolerance
        if self.normalization != "running":
            d["normalization"] = self.normalization
        return d


def spatial_consistency(corr: torch.Tensor, sigma_d: float) -> torch.Tensor:
    """``beta_ij = [1 - d_ij^2 / sigma_d^2]_+`` for (B, N, 6) correspondences -> (B, N, N).

    The same formula as the Rust core (`pointclm.staged.spatial_consistency`); a test checks
    they agree.
    """
    src, dst = corr[..., :3], corr[..., 3:]
    exact = "donot_use_mm_for_euclid_dist"  # matmul-based cdist loses ~1e-11
    d = torch.cdist(src, src, compute_mode=exact) - torch.cdist(dst, dst, compute_mode=exact)
    return torch.clamp(1.0 - d * d / (sigma_d * sigma_d), min=0.0)


def _pair_dots(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a_i . b_j`` (B, N, N), summed component by component in index order (not a matmul:
    that could run in TF32 on a GPU, and its sums in another order)."""
    out = a[..., :, None, 0] * b[..., None, :, 0]
    for k in (1, 2):
        out = out + a[..., :, None, k] * b[..., None, :, k]
    return out


def _plane_dots(n: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """``n_i . (p_j - p_i)`` (B, N, N): the signed distance of p_j from i's tangent plane,
    summed in index order like the Rust forward pass."""
    out = n[..., :, None, 0] * (p[..., None, :, 0] - p[..., :, None, 0])
    for k in (1, 2):
        out = out + n[..., :, None, k] * (p[..., None, :, k] - p[..., :, None, k])
    return out


def normal_consistency(
    corr: torch.Tensor, normals: torch.Tensor, sigma_d: float, tolerance: float = 0.5
) -> torch.Tensor:
    """Spatial consistency times its normal term, for (B, N, 6) correspondences and their
    (B, N, 6) unit normals (source normal | target normal) -> (B, N, N).

    The formula of the Rust core's `Correspondences::with_normals`: with ``ds = src_j -
    src_i``, ``dt = dst_j - dst_i``, ``l_s = |ds|``, ``l_t = |dt|``, ``beta`` is the length
    term ``[1 - (l_s - l_t)^2 / sigma_d^2]_+`` times ``[1 - da^2 / tolerance^2]_+`` for the
    cosines ``da = |ns_i . ns_j| - |nt_i . nt_j|`` times ``[1 - dp^2 / w^2]_+ [1 - dq^2 /
    w^2]_+`` for the plane distances ``dp = |ns_i . ds| - |nt_i . dt|`` and ``dq = |ns_j .
    ds| - |nt_j . dt|``, ``w = tolerance (l_s + l_t) / 2 + sigma_d``. Rotating each side's
    points and normals together leaves it unchanged. Each operation is in the order the Rust
    forward pass does it, so that the two agree to f32 rounding. Memory: about 8 (B, N, N)
    tensors at once.
    """
    src, dst = corr[..., :3], corr[..., 3:6]
    ns, nt = normals[..., :3], normals[..., 3:6]
    exact = "donot_use_mm_for_euclid_dist"
    ls = torch.cdist(src, src, compute_mode=exact)
    lt = torch.cdist(dst, dst, compute_mode=exact)
    d = ls - lt
    beta = torch.clamp(1.0 - d * d / (sigma_d * sigma_d), min=0.0)
    da = _pair_dots(ns, ns).abs() - _pair_dots(nt, nt).abs()
    beta = beta * torch.clamp(1.0 - da * da / (tolerance * tolerance), min=0.0)
    w = tolerance * 0.5 * (ls + lt) + sigma_d
    del d, da, ls, lt
    dp = _plane_dots(ns, src).abs() - _plane_dots(nt, dst).abs()
    plane = torch.clamp(1.0 - dp * dp / (w * w), min=0.0)
    # dq_ij = dp_ji exactly (n_j . (p_i - p_j) negates n_j . (p_j - p_i) term by term), so the
    # two plane terms are `plane` and its transpose; their product first, as in the core
    return beta * (plane * plane.transpose(-1, -2))


class SceneBatchNorm(nn.BatchNorm1d):
    """BatchNorm1d that, with ``per_scene``, normalises each scene of a batch by the
    statistics of its own rows, in training as at inference: scenes can share a batch, and
    none changes another's embedding. Its buffers stay those of BatchNorm1d (unused with
    ``per_scene``), so weight files of either kind load alike."""

    per_scene = False

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.per_scene:
            return super().forward(x)
        return nn.functional.instance_norm(
            x, weight=self.weight, bias=self.bias, use_input_stats=True, eps=self.eps
        )


class NonLocalBlock(nn.Module):
    def __init__(self, width: int) -> None:
        super().__init__()
        half = width // 2
        self.q = nn.Conv1d(width, width, 1)
        self.k = nn.Conv1d(width, width, 1)
        self.v = nn.Conv1d(width, width, 1)
        self.message = nn.Sequential(
            nn.Conv1d(width, half, 1),
            SceneBatchNorm(half),
            nn.ReLU(inplace=True),
            nn.Conv1d(half, half, 1),
            SceneBatchNorm(half),
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
    """Correspondences (B, N, input_channels) -> unit-norm embeddings (B, N, width).

    The columns of the input: source xyz, target xyz, then the source normal and target
    normal for "normals" and the similarity for "similarity" (see the module docstring).
    """

    def __init__(self, config: EmbeddingConfig | None = None) -> None:
        super().__init__()
        self.config = config or EmbeddingConfig()
        w = self.config.width
        self.lift = nn.Conv1d(self.config.input_channels, w, 1)
        self.pointcn = nn.ModuleList(
            nn.Sequential(nn.Conv1d(w, w, 1), SceneBatchNorm(w), nn.ReLU(inplace=True))
            for _ in range(self.config.depth)
        )
        self.nonlocal_blocks = nn.ModuleList(NonLocalBlock(w) for _ in range(self.config.depth))
        for m in self.modules():
            if isinstance(m, SceneBatchNorm):
                m.per_scene = self.config.normalization == "scene"

    def _unit_normals(self, x: torch.Tensor) -> torch.Tensor | None:
        """The (B, N, 6) normals of the packed input rescaled to unit length, if it has them."""
        if "normals" not in self.config.inputs:
            return None
        unit = nn.functional.normalize
        return torch.cat([unit(x[..., 6:9], dim=-1), unit(x[..., 9:12], dim=-1)], dim=-1)

    def consistency(self, x: torch.Tensor) -> torch.Tensor:
        """The (B, N, N) beta that `forward` attends with, for a packed input `x`."""
        return self._beta(x[..., :6], self._unit_normals(x))

    def _beta(self, corr: torch.Tensor, normals: torch.Tensor | None) -> torch.Tensor:
        cfg = self.config
        if normals is None:
            return spatial_consistency(corr, cfg.sigma_d)
        return normal_consistency(corr, normals, cfg.sigma_d, cfg.normal_tolerance)

    def forward(self, x: torch.Tensor, beta: torch.Tensor | None = None) -> torch.Tensor:
        cfg = self.config
        if x.shape[-1] != cfg.input_channels:
            named = "".join(f" + {n}" for n in cfg.inputs)
            raise ValueError(
                f"the network reads {cfg.input_channels} input channels (coordinates{named}), "
                f"got {x.shape[-1]}"
            )
        xyz, normals = x[..., :6], self._unit_normals(x)
        if beta is None:
            beta = self._beta(xyz, normals)
        # only the coordinates are centred; the plain network's input is exactly `centred`
        centred = xyz - xyz.mean(dim=1, keepdim=True)
        if normals is not None:
            centred = torch.cat([centred, normals, x[..., 12:]], dim=-1)
        elif cfg.inputs:  # the similarity alone
            centred = torch.cat([centred, x[..., 6:]], dim=-1)
        feat = self.lift(centred.transpose(1, 2))
        for pointcn, nonlocal_block in zip(self.pointcn, self.nonlocal_blocks, strict=True):
            feat = nonlocal_block(pointcn(feat), beta)
        return nn.functional.normalize(feat.transpose(1, 2), dim=-1)
