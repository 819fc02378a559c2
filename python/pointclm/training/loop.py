"""The training loop: seeded on-the-fly data, Adam, periodic validation (MR/MP/MF with the
embedding driving pruning), checkpoints every few hundred steps, resume, best weights kept."""

from __future__ import annotations

import json
import math
import os
import platform
import time
from pathlib import Path
from typing import Any, cast

import numpy as np

from ..config import Config
from ..datasets import make_scene
from ..metrics import score_scene, summarize
from ..registration import register
from .config import TrainConfig
from .data import ShapeBank, make_batch

__all__ = ["train", "validate"]


def _seed_for(base: int, *parts: int) -> int:
    return int(np.random.SeedSequence([base, *parts]).generate_state(1, np.uint64)[0])


class _Batches:
    """Map-style dataset: item i is the whole batch of iteration i (order-preserving with
    workers, so resuming at iteration i sees exactly the batches an uninterrupted run would)."""

    def __init__(self, cfg: TrainConfig, bank: ShapeBank) -> None:
        self.cfg, self.bank = cfg, bank

    def __len__(self) -> int:
        return self.cfg.iterations

    def __getitem__(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        c = self.cfg
        return make_batch(
            self.bank,
            c.train_shapes,
            _seed_for(c.seed, 1, i),
            c.batch_size,
            c.n_correspondences,
            c.train_outlier_blocks,
            c.wrong_match_fraction,
        )


def validation_scenes(cfg: TrainConfig, bank: ShapeBank) -> list[Any]:
    rng = np.random.default_rng(_seed_for(cfg.seed, 2))
    scenes = []
    for k in range(cfg.val_scenes):
        cloud = bank[cfg.val_shapes[k % len(cfg.val_shapes)]]
        cloud = cloud[rng.permutation(len(cloud))]
        scenes.append(
            make_scene(
                _seed_for(cfg.seed, 3, k), shape=cloud, n_outlier_blocks=cfg.val_outlier_blocks
            )
        )
    return scenes


def validate(model: Any, scenes: list[Any], device: str) -> dict[str, float]:
    """Paper MR/MP/MF and strict F1 with the embedding as features (model in eval mode)."""
    import torch

    model.eval()
    scores = []
    with torch.no_grad():
        for s in scenes:
            x = torch.tensor(s.correspondences, dtype=torch.float32, device=device)[None]
            feats = model(x)[0].double().cpu().numpy()
            r = register(s.correspondences, feats, Config(), seed=0)
            scores.append(score_scene(r.transformations, s.poses))
    model.train()
    return summarize(scores).as_dict()


def _environment(device: str) -> dict[str, Any]:
    import torch

    env = {
        "device": device,
        "torch": torch.__version__,
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
    }
    if device.startswith("cuda") and torch.cuda.is_available():
        env["gpu"] = torch.cuda.get_device_name(0)
    return env


def train(
    cfg: TrainConfig,
    out_dir: str | Path,
    *,
    device: str = "cpu",
    resume: bool = False,
    max_minutes: float | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Train, writing to `out_dir`: `train_config.json`, `checkpoint.pt` (resumable),
    `model.safetensors` + `model.json` (best validation weights) and `log.jsonl`.

    `max_minutes` stops cleanly after a checkpoint once the time is spent (for machines that
    limit a command's run time); run again with `resume=True` to continue.
    """
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")  # deterministic cuBLAS
    import torch
    from tqdm import tqdm

    from ..model import EmbeddingConfig, SCNonlocal, contrastive_loss, save_model

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cfg.save(out / "train_config.json")
    torch.manual_seed(cfg.seed)
    torch.use_deterministic_algorithms(True, warn_only=True)
    bank = (
        ShapeBank.load(cfg.shape_bank)
        if cfg.shape_bank
        else ShapeBank.build([*cfg.train_shapes, *cfg.val_shapes], cfg.data_dir, cfg.seed)
    )
    bank.save(out / "shape_bank.npz")
    model = SCNonlocal(EmbeddingConfig(cfg.depth, cfg.width, cfg.sigma_d)).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    start, best, elapsed = 0, None, 0.0
    ckpt = out / "checkpoint.pt"
    if resume and ckpt.is_file():
        state = torch.load(ckpt, map_location=device, weights_only=False)
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        start, best, elapsed = state["iteration"], state["best"], state["elapsed"]
        torch.set_rng_state(state["torch_rng"].cpu())
    # Cosine decay computed from the iteration, so a resumed run may change the total.
    for group in opt.param_groups:
        group.setdefault("initial_lr", cfg.lr)
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt,
        lambda i: 0.5 * (1 + math.cos(math.pi * min(i, cfg.iterations) / cfg.iterations)),
        last_epoch=start - 1,
    )
    val_scenes = validation_scenes(cfg, bank)
    loader: Any = torch.utils.data.DataLoader(
        # any object with __len__/__getitem__ serves as a map-style dataset
        torch.utils.data.Subset(cast(Any, _Batches(cfg, bank)), range(start, cfg.iterations)),
        batch_size=None,
        shuffle=False,
        num_workers=cfg.num_workers,
        multiprocessing_context="spawn" if cfg.num_workers > 0 else None,
        persistent_workers=False,
    )
    log = (out / "log.jsonl").open("a")
    t0 = time.perf_counter() - elapsed
    bar = tqdm(total=cfg.iterations, initial=start, desc="train", unit="it", disable=not progress)
    model.train()
    it = start
    for it, (x, y) in enumerate(loader, start=start + 1):
        x, y = torch.as_tensor(x, device=device), torch.as_tensor(y, device=device)
        gen = torch.Generator(device=device).manual_seed(_seed_for(cfg.seed, 4, it) % 2**63)
        loss, stats = contrastive_loss(
            model(x),
            y,
            margin_pos=cfg.margin_pos,
            margin_neg=cfg.margin_neg,
            negatives=cfg.negatives,
            generator=gen,
        )
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        row: dict[str, Any] = {
            "iteration": it,
            "loss": float(loss.detach()),
            **{k: float(v) for k, v in stats.items()},
        }
        bar.update(1)
        postfix = {"loss": f"{float(loss.detach()):.4f}"}
        if it % cfg.val_every == 0 or it == cfg.iterations:
            metrics = validate(model, val_scenes, device)
            row["val"] = metrics
            key = (metrics["mean_f1"], metrics["strict_f1"])
            if best is None or key >= tuple(best["key"]):
                best = {"key": list(key), "iteration": it, "metrics": metrics}
                save_model(
                    model,
                    out / "model.safetensors",
                    extra={
                        "iteration": it,
                        "validation": metrics,
                        "train_config": cfg.to_dict(),
                        "environment": _environment(device),
                        "train_seconds": time.perf_counter() - t0,
                    },
                )
            postfix["val_MF"] = f"{100 * metrics['mean_f1']:.2f}"
        bar.set_postfix(postfix)
        log.write(json.dumps(row) + "\n")
        done = it == cfg.iterations
        out_of_time = max_minutes is not None and (time.perf_counter() - t0) > 60 * max_minutes
        if it % cfg.checkpoint_every == 0 or done or out_of_time:
            torch.save(
                {
                    "model": model.state_dict(),
                    "optimizer": opt.state_dict(),
                    "iteration": it,
                    "best": best,
                    "elapsed": time.perf_counter() - t0,
                    "torch_rng": torch.get_rng_state(),
                },
                ckpt,
            )
        if out_of_time and not done:
            break
    bar.close()
    log.close()
    return {
        "iteration": it,
        "finished": it >= cfg.iterations,
        "best": best,
        "seconds": time.perf_counter() - t0,
    }
