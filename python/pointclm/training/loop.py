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
from .banks import realistic_banks, training_bank, validation_bank
from .checkpoint import load_checkpoint, save_checkpoint
from .config import TrainConfig
from .data import ShapeBank, make_batch
from .realistic import SceneBank, bank_cues, realistic_sample, score_bank

__all__ = [
    "realistic_banks",
    "train",
    "training_bank",
    "validate",
    "validate_realistic",
    "validation_bank",
]


def _seed_for(base: int, *parts: int) -> int:
    return int(np.random.SeedSequence([base, *parts]).generate_state(1, np.uint64)[0])


Group = tuple[np.ndarray, np.ndarray]


class _Batches:
    """Map-style dataset: item i is the whole batch of iteration i (order-preserving with
    workers, so resuming at iteration i sees exactly the batches an uninterrupted run would).

    A batch is a list of groups of equal-sized scenes: the synthetic scenes stacked, then each
    realistic scene alone (their correspondence counts differ)."""

    def __init__(self, cfg: TrainConfig, bank: ShapeBank | None, scenes: SceneBank | None) -> None:
        self.cfg, self.bank, self.scenes = cfg, bank, scenes

    def __len__(self) -> int:
        return self.cfg.iterations

    def __getitem__(self, i: int) -> list[Group]:
        c = self.cfg
        scenes = self.scenes
        n_real = round(c.batch_size * c.realistic_fraction) if scenes is not None else 0
        groups: list[Group] = []
        if c.batch_size > n_real:
            assert self.bank is not None  # realistic_fraction < 1 builds one
            groups.append(
                make_batch(
                    self.bank,
                    c.train_shapes,
                    _seed_for(c.seed, 1, i),
                    c.batch_size - n_real,
                    c.n_correspondences,
                    c.train_outlier_blocks,
                    c.wrong_match_fraction,
                )
            )
        rng = np.random.default_rng(_seed_for(c.seed, 6, i))
        samples = []
        for _ in range(n_real):
            assert scenes is not None  # n_real > 0 only with a bank
            samples.append(
                realistic_sample(
                    scenes, rng, c.sigma_d, c.n_correspondences, c.realistic_ignore_voxels, c.inputs
                )
            )
        return groups + stacked_by_size(samples, c.realistic_group, rng)


def stacked_by_size(samples: list[Group], size: int, rng: np.random.Generator) -> list[Group]:
    """Realistic samples (row counts differ) as groups of up to `size` scenes stacked into one
    batch: sorted by row count, so each group's scenes are close in size, and each cut to the
    group's smallest count by a random subset of its rows. Fewer, larger batches keep a GPU
    busy where one small scene per batch leaves it waiting on kernel launches. Size 1 keeps
    every scene whole and alone."""
    order = sorted(range(len(samples)), key=lambda k: len(samples[k][1]))
    out: list[Group] = []
    for start in range(0, len(order), size):
        part = [samples[k] for k in order[start : start + size]]
        n = min(len(y) for _, y in part)
        keep = [
            np.sort(rng.choice(len(y), n, replace=False)) if len(y) > n else np.arange(n)
            for _, y in part
        ]
        out.append(
            (
                np.stack([x[k] for (x, _), k in zip(part, keep, strict=True)]),
                np.stack([y[k] for (_, y), k in zip(part, keep, strict=True)]),
            )
        )
    return out


def validation_scenes(cfg: TrainConfig, bank: ShapeBank | None) -> list[Any]:
    """The synthetic validation scenes; none when training is realistic only."""
    if bank is None:
        return []
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


def validate(
    model: Any, scenes: list[Any], device: str, config: Config | None = None
) -> dict[str, float]:
    """Paper MR/MP/MF and strict F1 with the embedding as features (model in eval mode)."""
    import torch

    config = config or Config()
    model.eval()
    scores = []
    with torch.no_grad():
        for s in scenes:
            x = torch.tensor(s.correspondences, dtype=torch.float32, device=device)[None]
            feats = model(x)[0].double().cpu().numpy()
            r = register(s.correspondences, feats, config, seed=0)
            scores.append(score_scene(r.transformations, s.poses))
    model.train()
    return summarize(scores).as_dict()


def validate_realistic(
    model: Any, bank: SceneBank, device: str, config: Config | None = None
) -> dict[str, float]:
    """The same on realistic scenes, in real units (:func:`score_bank`), with the cues the
    network takes."""
    import torch

    from ..cues import pack
    from ..embedding import network_units
    from ..point_clouds import scaled_config

    inputs = tuple(getattr(model.config, "inputs", ()))
    model.eval()
    feats, pipeline_normals = [], []
    with torch.no_grad():
        for i in range(len(bank)):
            sigma_d = scaled_config(float(bank.voxels[i])).sigma_d
            x = network_units(bank.correspondences[i], sigma_d, model.config.sigma_d)
            normals, sims = bank_cues(bank, i, inputs)
            x = pack(x, inputs, normals, sims)
            out = model(torch.tensor(x, dtype=torch.float32, device=device)[None])[0]
            feats.append(out.double().cpu().numpy())
            pipeline_normals.append(normals)  # as register_point_clouds gives them
    model.train()
    return score_bank(bank, feats, config, pipeline_normals)


def _batch_loss(model: Any, groups: list[Any], cfg: TrainConfig, device: str, gen: Any) -> Any:
    """The contrastive loss of each group, weighted by its number of scenes."""
    import torch

    from ..model import contrastive_loss

    total: Any = 0.0
    n = 0
    stats_sum: dict[str, float] = {}
    for x, y in groups:
        x, y = torch.as_tensor(x, device=device), torch.as_tensor(y, device=device)
        loss, stats = contrastive_loss(
            model(x),
            y,
            margin_pos=cfg.margin_pos,
            margin_neg=cfg.margin_neg,
            negatives=cfg.negatives,
            generator=gen,
        )
        b = len(x)
        total = total + loss * b
        n += b
        for k, v in stats.items():
            stats_sum[k] = stats_sum.get(k, 0.0) + float(v) * b
    return total / n, {k: v / n for k, v in stats_sum.items()}


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
    """Train, writing to `out_dir`: `train_config.json`, `checkpoint.json` +
    `checkpoint-<iteration>.safetensors` (resumable, no pickle), `model.safetensors` +
    `model.json` (best validation weights) and `log.jsonl`.

    With `resume=True` a run continues from the folder's checkpoint and reproduces the
    uninterrupted run (batches are seeded by iteration; model, optimizer and RNG restored).

    `max_minutes` stops cleanly after a checkpoint once the time is spent (for machines that
    limit a command's run time); run again with `resume=True` to continue.
    """
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")  # deterministic cuBLAS
    import torch
    from tqdm import tqdm

    out = Path(out_dir)
    # The stages run in this order because each one draws from torch's RNG or restores it.
    bank, model = _setup(cfg, out, device)
    scenes, val_real = realistic_banks(cfg, out, progress)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    start, best, elapsed = _resume(out, model, opt, device) if resume else (0, None, 0.0)
    sched = _cosine_schedule(cfg, opt, start)
    validator = _Validator(cfg, validation_scenes(cfg, bank), val_real, device)
    loader = _loader(cfg, bank, scenes, start)
    log = (out / "log.jsonl").open("a")
    t0 = time.perf_counter() - elapsed
    bar = tqdm(total=cfg.iterations, initial=start, desc="train", unit="it", disable=not progress)
    model.train()
    it = start
    for it, groups in enumerate(loader, start=start + 1):
        row = _step(model, opt, sched, groups, cfg, device, it)
        bar.update(1)
        postfix = {"loss": f"{row['loss']:.4f}"}
        if it % cfg.val_every == 0 or it == cfg.iterations:
            key = validator(model, row, postfix)
            if best is None or key >= tuple(best["key"]):
                best = {"key": list(key), "iteration": it, "metrics": row["val"]}
                _save_best(model, out, cfg, row, device, time.perf_counter() - t0)
        bar.set_postfix(postfix)
        log.write(json.dumps(row) + "\n")
        if _checkpoint(out, model, opt, cfg, it, best, t0, max_minutes):
            break  # out of time: a resumed run continues from this checkpoint
    bar.close()
    log.close()
    return {
        "iteration": it,
        "finished": it >= cfg.iterations,
        "best": best,
        "seconds": time.perf_counter() - t0,
    }


def _setup(cfg: TrainConfig, out: Path, device: str) -> tuple[ShapeBank | None, Any]:
    """The run folder with its config and shape bank, torch seeded, and the network
    (initialised from the seed, or from ``cfg.init_weights``)."""
    import torch

    from ..model import EmbeddingConfig, SCNonlocal, load_model

    out.mkdir(parents=True, exist_ok=True)
    cfg.save(out / "train_config.json")
    torch.manual_seed(cfg.seed)
    torch.use_deterministic_algorithms(True, warn_only=True)
    bank = None
    if cfg.realistic_fraction < 1:  # synthetic scenes are drawn from the shape bank
        bank = (
            ShapeBank.load(cfg.shape_bank)
            if cfg.shape_bank
            else ShapeBank.build([*cfg.train_shapes, *cfg.val_shapes], cfg.data_dir, cfg.seed)
        )
        bank.save(out / "shape_bank.npz")
    arch = EmbeddingConfig(
        cfg.depth,
        cfg.width,
        cfg.sigma_d,
        inputs=cfg.inputs,
        normal_tolerance=cfg.normal_tolerance,
        normalization=cfg.normalization,
    )
    model = SCNonlocal(arch).to(device)
    if cfg.init_weights:
        init = load_model(cfg.init_weights, device=device)
        if init.config != model.config:
            raise ValueError(
                f"init_weights {cfg.init_weights!r} are a {init.config} network, the config "
                f"asks for {model.config}"
            )
        model.load_state_dict(init.state_dict())
    return bank, model


def _resume(out: Path, model: Any, opt: Any, device: str) -> tuple[int, Any, float]:
    """Iteration, best and elapsed seconds of the folder's checkpoint, with model, optimizer
    and torch's RNG restored; a fresh start when there is none."""
    # safetensors + JSON: nothing in a run folder is unpickled (training/checkpoint.py)
    restored = load_checkpoint(out, model, opt, device)
    if restored is None:
        return 0, None, 0.0
    return restored["iteration"], restored["best"], restored["elapsed"]


def _cosine_schedule(cfg: TrainConfig, opt: Any, start: int) -> Any:
    """Cosine decay computed from the iteration, so a resumed run may change the total."""
    import torch

    for group in opt.param_groups:
        group.setdefault("initial_lr", cfg.lr)
    return torch.optim.lr_scheduler.LambdaLR(
        opt,
        lambda i: 0.5 * (1 + math.cos(math.pi * min(i, cfg.iterations) / cfg.iterations)),
        last_epoch=start - 1,
    )


def _loader(cfg: TrainConfig, bank: ShapeBank | None, scenes: SceneBank | None, start: int) -> Any:
    """The batches of iterations ``start + 1 ...`` in order (seeded by iteration)."""
    import torch

    return torch.utils.data.DataLoader(
        # any object with __len__/__getitem__ serves as a map-style dataset
        torch.utils.data.Subset(
            cast(Any, _Batches(cfg, bank, scenes)), range(start, cfg.iterations)
        ),
        batch_size=None,
        shuffle=False,
        num_workers=cfg.num_workers,
        multiprocessing_context="spawn" if cfg.num_workers > 0 else None,
        persistent_workers=False,
    )


def _step(
    model: Any, opt: Any, sched: Any, groups: list[Any], cfg: TrainConfig, device: str, it: int
) -> dict[str, Any]:
    """One optimisation step on a batch; its log row."""
    import torch

    gen = torch.Generator(device=device).manual_seed(_seed_for(cfg.seed, 4, it) % 2**63)
    loss, stats = _batch_loss(model, groups, cfg, device, gen)
    opt.zero_grad(set_to_none=True)
    if loss.requires_grad:  # a batch with no inlier pair at all has nothing to learn
        loss.backward()
        opt.step()
    sched.step()
    return {
        "iteration": it,
        "loss": float(loss.detach()),
        **{k: float(v) for k, v in stats.items()},
    }


class _Validator:
    """Periodic validation: the synthetic scenes, and the realistic bank when there is one."""

    def __init__(
        self, cfg: TrainConfig, scenes: list[Any], real: SceneBank | None, device: str
    ) -> None:
        self.scenes, self.real, self.device = scenes, real, device
        self.config = Config(**cfg.val_config)
        self.real_config = Config(**cfg.val_realistic_config)

    def __call__(
        self, model: Any, row: dict[str, Any], postfix: dict[str, str]
    ) -> tuple[float, float]:
        """Validate, record the metrics in the log row and progress bar, and return the
        key the best weights are chosen by."""
        if not self.scenes:  # realistic training only: its validation alone decides
            assert self.real is not None
            real = validate_realistic(model, self.real, self.device, self.real_config)
            row["val"] = row["val_realistic"] = real
            postfix["val_real_MF"] = f"{100 * real['mean_f1']:.2f}"
            return (real["mean_f1"], real["strict_f1"])
        metrics = validate(model, self.scenes, self.device, self.config)
        row["val"] = metrics
        key = (metrics["mean_f1"], metrics["strict_f1"])
        if self.real is not None:
            real = validate_realistic(model, self.real, self.device, self.real_config)
            row["val_realistic"] = real
            postfix["val_real_MF"] = f"{100 * real['mean_f1']:.2f}"
            # both benchmarks count alike: the synthetic one must not be lost for the other
            key = (
                (metrics["mean_f1"] + real["mean_f1"]) / 2,
                (metrics["strict_f1"] + real["strict_f1"]) / 2,
            )
        postfix["val_MF"] = f"{100 * metrics['mean_f1']:.2f}"
        return key


def _checkpoint(
    out: Path,
    model: Any,
    opt: Any,
    cfg: TrainConfig,
    it: int,
    best: Any,
    t0: float,
    max_minutes: float | None,
) -> bool:
    """Checkpoint every ``checkpoint_every`` iterations, at the end, and when the time is
    spent; True when the run must stop early."""
    done = it == cfg.iterations
    out_of_time = max_minutes is not None and (time.perf_counter() - t0) > 60 * max_minutes
    if it % cfg.checkpoint_every == 0 or done or out_of_time:
        save_checkpoint(out, model, opt, iteration=it, best=best, elapsed=time.perf_counter() - t0)
    return out_of_time and not done


def _save_best(
    model: Any, out: Path, cfg: TrainConfig, row: dict[str, Any], device: str, seconds: float
) -> None:
    """The best weights so far, with what they scored and how they were trained."""
    from ..model import save_model

    save_model(
        model,
        out / "model.safetensors",
        extra={
            "iteration": row["iteration"],
            "validation": row["val"],
            **({"validation_realistic": row["val_realistic"]} if "val_realistic" in row else {}),
            "train_config": cfg.to_dict(),
            "environment": _environment(device),
            "train_seconds": seconds,
        },
    )
