"""Contrastive training of the learned local descriptor (``pointclm train-descriptor``).

What is learned: a point's neighbourhood as the core's
:class:`LearnedDescriptor <pointclm.descriptors>` reads it. Each of ``neighbours`` neighbours
within ``radius_voxels`` (taken evenly spaced in distance order among the ``candidates``
nearest, so that they cover the whole radius) is seen from the point as its point pair feature
(distance, the angles of both normals to the line between them and to each other, the height
over the point's tangent plane), which no rotation changes. A small MLP lifts each
neighbour; the maximum and the mean over the neighbourhood, with the share of neighbours found,
go through a second MLP to a unit vector.

The data is what the descriptor meets at run time: a complete model (normals outwards) against
a partial scan of several copies among clutter (normals towards the sensor), built by
:func:`pointclm.datasets.scenes.make_realistic_scene` at random voxel sizes (1/30 to 1/60 of
the model's diagonal) and noise levels, on the VALIDATION models and procedural shapes only:
the held-out models never train or pick anything. A scan point on a copy whose true pose puts
a model point within 1.5 voxels of it is a positive pair.

The loss is InfoNCE both ways (scan point against every model point, model point against the
sampled scan points), with the points within 2 voxels of the true partner left out of the
negatives: neighbouring points are not wrong answers, only imprecise ones.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["DescriptorTrainConfig", "pair_features", "train_descriptor"]


@dataclass(frozen=True)
class DescriptorTrainConfig:
    """A descriptor training run: the network's shape, the data and the optimisation."""

    neighbours: int = 32
    candidates: int = 128
    radius_voxels: float = 7.5
    widths: tuple[int, int, int, int] = (32, 64, 64, 32)
    scenes: int = 300
    epochs: int = 8
    lr: float = 2e-3
    temperature: float = 0.07
    positives: int = 256
    negatives: int = 1024
    seed: int = 0


def pair_features(
    points: np.ndarray,
    normals: np.ndarray,
    radius: float,
    neighbours: int,
    candidates: int,
    queries: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The network's input, as the core computes it: per query point (all by default),
    ``(neighbours, 5)`` point pair features and a mask of the neighbours found."""
    from scipy.spatial import cKDTree

    q = np.arange(len(points)) if queries is None else np.asarray(queries)
    d, idx = cKDTree(points).query(points[q], k=candidates + 1, distance_upper_bound=radius)
    d, idx = d[:, 1:], idx[:, 1:]  # the point itself
    found = np.isfinite(d).sum(1)[:, None]
    t = np.arange(neighbours)[None, :]
    pick = np.where(found > neighbours, ((2 * t + 1) * found) // (2 * neighbours), t)
    pick = np.minimum(pick, candidates - 1)
    d, idx = np.take_along_axis(d, pick, 1), np.take_along_axis(idx, pick, 1)
    mask = np.isfinite(d)
    idx = np.where(mask, idx, 0)
    p, n = points[q][:, None, :], normals[q][:, None, :]
    v = points[idx] - p
    length = np.linalg.norm(v, axis=2, keepdims=True)
    u = v / np.maximum(length, 1e-12)
    feats = np.concatenate(
        [
            length / radius,
            (u * n).sum(2, keepdims=True),
            (u * normals[idx]).sum(2, keepdims=True),
            (n * normals[idx]).sum(2, keepdims=True),
            (v * n).sum(2, keepdims=True) / radius,
        ],
        axis=2,
    ).astype(np.float32)
    feats[~mask] = 0.0
    return feats, mask


def descriptor_network(widths: tuple[int, int, int, int]) -> Any:
    """The torch module the core's forward pass mirrors (tensor names included)."""
    import torch

    h1, h2, h3, out = widths

    class DescriptorNet(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            relu = torch.nn.ReLU
            self.point = torch.nn.Sequential(
                torch.nn.Linear(5, h1), relu(), torch.nn.Linear(h1, h2), relu()
            )
            self.head = torch.nn.Sequential(
                torch.nn.Linear(2 * h2 + 1, h3), relu(), torch.nn.Linear(h3, out)
            )

        def forward(self, feats: Any, mask: Any) -> Any:
            h = self.point(feats)
            m = mask.unsqueeze(-1)
            top = torch.where(m, h, torch.zeros_like(h)).amax(1)
            count = m.sum(1).clamp(min=1)
            mean = (h * m).sum(1) / count
            share = m.sum(1).float() / feats.shape[1]
            z = self.head(torch.cat([top, mean, share], 1))
            return torch.nn.functional.normalize(z, dim=1)

    return DescriptorNet()


def training_models() -> list[str]:
    """The validation models and procedural shapes, with 8 members of each procedural family:
    never a held-out model."""
    from ..datasets.procedural import PROCEDURAL_FAMILIES
    from ..datasets.scenes import HELDOUT_MODELS, VALIDATION_MODELS

    models = [*VALIDATION_MODELS, *(f"{f}-{s}" for f in PROCEDURAL_FAMILIES for s in range(8))]
    assert not set(models) & set(HELDOUT_MODELS)
    return models


def scene_item(model: str, seed: int, cfg: DescriptorTrainConfig) -> dict[str, Any] | None:
    """One training scene as arrays: the model's and the sampled scan points' features, the
    positives and every sampled scan point's true model point (-1: none)."""
    from scipy.spatial import cKDTree

    from .. import preprocessing as pp
    from ..datasets.scenes import SceneParams, make_realistic_scene

    rng = np.random.default_rng(seed)
    params = SceneParams(
        model=model,
        voxel_fraction=1 / rng.uniform(30, 60),
        noise_voxels=rng.uniform(0.1, 0.5),
        n_correspondences=10,
    )
    scene = make_realistic_scene(seed, params)
    v = scene.voxel_size
    src = pp.describe(scene.source_points, None, normal_radius=2 * v, feature_radius=5 * v,
                      away_from=scene.source_points.mean(0))  # fmt: skip
    tgt = pp.describe(scene.target_points, None, normal_radius=2 * v, feature_radius=5 * v,
                      towards=scene.viewpoint)  # fmt: skip
    partner = np.full(len(tgt.points), -1)
    tree = cKDTree(src.points)
    for k, pose in enumerate(scene.poses):
        on = np.flatnonzero(scene.target_ids == k)
        dist, j = tree.query((tgt.points[on] - pose[:3, 3]) @ pose[:3, :3])
        partner[on[dist < 1.5 * v]] = j[dist < 1.5 * v]
    pos = np.flatnonzero(partner >= 0)
    if len(pos) < 20:
        return None
    pos = rng.choice(pos, size=min(cfg.positives, len(pos)), replace=False)
    neg = rng.choice(len(tgt.points), size=min(cfg.negatives, len(tgt.points)), replace=False)
    sampled = np.concatenate([pos, np.setdiff1d(neg, pos)])
    r = cfg.radius_voxels * v
    fm, mm = pair_features(src.points, src.normals, r, cfg.neighbours, cfg.candidates)
    fs, ms = pair_features(tgt.points, tgt.normals, r, cfg.neighbours, cfg.candidates, sampled)
    return {"fm": fm, "mm": mm, "fs": fs, "ms": ms, "n_pos": len(pos),
            "partner": partner[sampled], "model_points": src.points.astype(np.float32),
            "voxel": v}  # fmt: skip


def contrastive_loss(net: Any, item: dict[str, Any], temperature: float, device: str) -> Any:
    """InfoNCE both ways over one scene (see the module documentation)."""
    import torch
    import torch.nn.functional as F  # noqa: N812

    def t(a: np.ndarray) -> Any:
        return torch.from_numpy(a).to(device)

    zm, zs = net(t(item["fm"]), t(item["mm"])), net(t(item["fs"]), t(item["ms"]))
    n_pos, pts = item["n_pos"], t(item["model_points"])
    partner = t(item["partner"])
    truth = partner[:n_pos]
    near = 2.0 * item["voxel"]
    exact = "donot_use_mm_for_euclid_dist"  # torch's fast form is off by 1e-4
    rows = torch.arange(n_pos, device=device)
    close = torch.cdist(pts[truth], pts, compute_mode=exact) < near
    close[rows, truth] = False
    to_model = (zs[:n_pos] @ zm.T / temperature).masked_fill(close, -1e4)
    has = partner >= 0
    close = torch.cdist(pts[truth], pts[partner.clamp(min=0)], compute_mode=exact) < near
    close &= has[None, :]
    close[rows, rows] = False
    to_scan = (zm[truth] @ zs.T / temperature).masked_fill(close, -1e4)
    return 0.5 * (F.cross_entropy(to_model, truth) + F.cross_entropy(to_scan, rows))


def _items(cfg: DescriptorTrainConfig, progress: bool) -> list[dict[str, Any]]:
    from tqdm import tqdm

    models = training_models()
    out = []
    for i in tqdm(range(cfg.scenes), desc="scenes", unit="scene", disable=not progress):
        item = scene_item(models[i % len(models)], cfg.seed * 100_003 + i, cfg)
        if item is not None:
            out.append(item)
    return out


def train_descriptor(
    cfg: DescriptorTrainConfig,
    out: str | Path,
    *,
    device: str = "cpu",
    resume: bool = False,
    progress: bool = True,
) -> Path:
    """Train a descriptor into the folder `out` (a checkpoint after every epoch, so that
    ``resume`` continues a killed run); returns the descriptor file, ``descriptor.safetensors``
    with its ``descriptor.json``, which ``descriptor=`` takes."""
    import torch
    from tqdm import tqdm

    from .checkpoint import load_checkpoint, save_checkpoint

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(cfg.seed)
    net = descriptor_network(cfg.widths).to(device)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    restored = load_checkpoint(out, net, opt, device) if resume else None
    start = int(restored["iteration"]) if restored else 0
    elapsed = float(restored["elapsed"]) if restored else 0.0
    items = _items(cfg, progress) if start < cfg.epochs else []
    t0 = time.perf_counter()
    bar = tqdm(total=cfg.epochs, initial=start, desc="train", unit="epoch", disable=not progress)
    for epoch in range(start, cfg.epochs):
        lr = 0.5 * cfg.lr * (1 + np.cos(np.pi * epoch / cfg.epochs))  # cosine, per epoch
        for group in opt.param_groups:
            group["lr"] = lr
        order = np.random.default_rng([cfg.seed, epoch]).permutation(len(items))
        total = 0.0
        for i in order:
            loss = contrastive_loss(net, items[i], cfg.temperature, device)
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach())
        bar.update(1)
        bar.set_postfix(loss=f"{total / max(len(items), 1):.3f}")
        spent = elapsed + time.perf_counter() - t0
        save_checkpoint(out, net, opt, iteration=epoch + 1, best=None, elapsed=spent)
    bar.close()
    return export_descriptor(net, cfg, out / "descriptor.safetensors")


def export_descriptor(net: Any, cfg: DescriptorTrainConfig, path: Path) -> Path:
    """Write the weights the core reads (`path`, float32) and the JSON beside it."""
    from safetensors.torch import save_file

    tensors = {k: v.detach().cpu().float().contiguous() for k, v in net.state_dict().items()}
    save_file(tensors, str(path))
    meta = {
        "descriptor": {
            "neighbours": cfg.neighbours,
            "candidates": cfg.candidates,
            "radius_voxels": cfg.radius_voxels,
            "widths": list(cfg.widths),
        },
        "training": asdict(cfg),
    }
    path.with_suffix(".json").write_text(json.dumps(meta, indent=2) + "\n")
    return path
