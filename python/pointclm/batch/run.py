"""`register_files`: one model against many scans, one JSON line per scan, resumable, on this
machine's cores or a Ray cluster."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from typing import Any

from ..errors import InputError
from .local import Done, Task, run_in_pool, run_in_process
from .options import BatchJob, ModelPoints, check_models, check_options, recorded_options
from .ray_engine import run_on_ray
from .results import OrderedWriter, open_results
from .scans import expand_scans, picture_names

__all__ = ["ENGINES", "BatchSummary", "register_files", "run_batch"]

ENGINES = ("local", "ray")

Paths = str | os.PathLike[str] | Iterable[str | os.PathLike[str]]
#: One model file, or several (a list): their copies found in each scan and judged together.
Models = str | os.PathLike[str] | list[str | os.PathLike[str]] | tuple[str | os.PathLike[str], ...]


@dataclass(frozen=True)
class BatchSummary:
    """What a batch run did: scans registered (``done``), recorded with an error
    (``failed``), already in the output and left alone (``skipped``), in ``seconds``."""

    done: int
    failed: int
    skipped: int
    seconds: float
    out: str

    def __str__(self) -> str:
        ran = self.done + self.failed
        rate = f", {ran / self.seconds:.2f} scans/s" if ran and self.seconds > 0 else ""
        return (
            f"{self.done} registered, {self.failed} failed, {self.skipped} skipped (already in "
            f"{self.out}) in {self.seconds:.1f} s{rate}"
        )


def register_files(
    model_file: Models,
    scans: Paths,
    out: str | os.PathLike[str],
    *,
    resume: bool = False,
    engine: str = "local",
    workers: int = 1,
    ray_address: str | None = None,
    png_dir: str | os.PathLike[str] | None = None,
    ply_dir: str | os.PathLike[str] | None = None,
    progress: bool = True,
    **options: Any,
) -> BatchSummary:
    """Find the copies of the model in `model_file` in every scan of `scans`, writing one JSON
    line per scan to `out` (JSON Lines) as each completes: ``status`` "ok" with its
    ``instances`` (``T_target_source`` 4x4, scores), ``diagnosis`` and timings, as
    ``pointclm register --out`` writes them, or "error" with the ``error`` class and
    ``message`` (a bad scan is recorded and the batch goes on). Lines follow the order of
    `scans` and each is synced to disk, so a killed batch loses only the scans in flight.

    `scans`: files, folders (their point-cloud files, sorted) or glob patterns, repeats
    dropped. `resume`: skip the scans `out` already holds (a line cut short by a kill is
    written again); without it an existing non-empty `out` is an error. `engine` "local"
    runs `workers` processes (1: in this process), "ray" one task per scan on the Ray
    cluster at `ray_address` (default: the connected one, else a local one of `workers`
    CPUs). `png_dir`, `ply_dir`: a picture or coloured cloud per scan, named by the scan.
    `options`: :func:`pointclm.register_point_clouds`' keyword options (``voxel_size``,
    ``config``, ``seed``, ``model``, ``viewpoint``, ...), the same for every scan; with no
    ``viewpoint`` a PCD scan's ``VIEWPOINT`` is used, ``viewpoint="none"`` ignores it (then,
    as without one, a position guessed from the scan may be confirmed and used). Every
    scan gets the same seed, so its poses are the same bit for bit whichever engine, worker
    or position ran it. Worker processes use ``num_threads=1`` unless given; they are
    spawned, so a script calling this with ``workers > 1`` does so under
    ``if __name__ == "__main__":``. Each line also records the model file, the network and
    the options; `resume` refuses an `out` written with others.

    Several models (`model_file` a list): each scan runs :func:`pointclm.register_models`,
    its models' copies judged together, and its line holds ``models`` (the files) and, for
    status "ok", ``results``: one entry per model, in order, as a one-model line holds it
    (without pictures: `png_dir` and `ply_dir` draw one model). ``symmetry`` is then one value
    for every model, or a list of one per model.

    Returns a :class:`BatchSummary`.
    """
    return run_batch(
        model_file,
        scans,
        out,
        resume=resume,
        engine=engine,
        workers=workers,
        ray_address=ray_address,
        png_dir=png_dir,
        ply_dir=ply_dir,
        progress=progress,
        options=options,
        diagnosis=_python_names,
    )


def _python_names(diagnosis: str) -> str:
    # In a batch, viewpoint=None means "the PCD file's VIEWPOINT"; "none" means no viewpoint.
    return diagnosis.replace("viewpoint=None", 'viewpoint="none"')


def run_batch(
    model_file: Models,
    scans: Paths,
    out: str | os.PathLike[str],
    *,
    options: dict[str, Any],
    resume: bool = False,
    engine: str = "local",
    workers: int = 1,
    ray_address: str | None = None,
    png_dir: str | os.PathLike[str] | None = None,
    ply_dir: str | os.PathLike[str] | None = None,
    progress: bool = True,
    diagnosis: Callable[[str], str] | None = None,
) -> BatchSummary:
    """`register_files` with its options as a dict; `diagnosis` rewrites each line's
    diagnosis before it is written (the CLI names its flags there)."""
    from tqdm import tqdm

    t0 = time.perf_counter()
    _check_engine(engine, workers, ray_address)
    job = _job(model_file, png_dir, ply_dir, options)
    scan_list = expand_scans(scans)
    model_points = _load_models(job)
    fh, present = open_results(out, resume, _identity(job))
    try:
        _make_output_folders(job)  # only now: a failed check leaves no empty folder behind
    except BaseException:
        fh.close()
        raise
    names = picture_names(scan_list)
    tasks = [(i, s, names[i]) for i, s in enumerate(scan_list) if s not in present]
    writer = OrderedWriter(fh, [t[0] for t in tasks])
    counts = {"ok": 0, "error": 0}
    bar = tqdm(total=len(tasks), desc="batch", unit="scan", disable=not (progress and tasks))
    done = _engine(engine, job, model_points, tasks, workers, ray_address)
    try:
        for position, record in done:
            for result in [record, *record.get("results", [])]:
                if diagnosis is not None and "diagnosis" in result:
                    result["diagnosis"] = diagnosis(result["diagnosis"])
            writer.add(position, record)
            counts["ok" if record["status"] == "ok" else "error"] += 1
            bar.set_postfix(failed=counts["error"], refresh=False)
            bar.update()
    finally:
        # On an error the engine's workers stop now, not whenever the generator is collected.
        done.close()
        bar.close()
        writer.close()
    skipped = len(scan_list) - len(tasks)
    elapsed = time.perf_counter() - t0
    return BatchSummary(counts["ok"], counts["error"], skipped, elapsed, os.fspath(out))


def _check_engine(engine: str, workers: int, ray_address: str | None) -> None:
    if engine not in ENGINES:
        raise InputError(f"engine must be one of {', '.join(ENGINES)}, got {engine!r}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise InputError(f"workers must be an int >= 1, got {workers!r}")
    if ray_address is not None and engine != "ray":
        raise InputError("ray_address (--ray-address) needs engine='ray' (--engine ray)")


def _job(
    model_file: Models,
    png_dir: str | os.PathLike[str] | None,
    ply_dir: str | os.PathLike[str] | None,
    options: dict[str, Any],
) -> BatchJob:
    if isinstance(model_file, list | tuple):
        files = [os.fspath(f) for f in model_file]
    else:
        files = [os.fspath(model_file)]
    if not files:
        raise InputError("model_file: no model given (a file, or a list of several)")
    if len(files) > 1 and (png_dir is not None or ply_dir is not None):
        raise InputError(
            "png_dir and ply_dir (--png-dir, --ply-dir) draw one model's result: with "
            f"{len(files)} models, leave them out"
        )
    if png_dir is not None:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            raise ImportError(
                "png_dir (--png-dir) needs matplotlib: pip install 'pointclm[viz]'"
            ) from None
    checked = check_models(check_options(options), len(files))
    return BatchJob(
        files[0],
        checked,
        recorded_options(checked),
        None if png_dir is None else _check_output_folder(png_dir, "png_dir"),
        None if ply_dir is None else _check_output_folder(ply_dir, "ply_dir"),
        tuple(files[1:]),
    )


def _identity(job: BatchJob) -> dict[str, Any]:
    """What every line of one batch shares (a resumed batch must match it), as read back
    from JSON (tuples as lists)."""
    models: dict[str, Any] = (
        {"models": job.models} if job.more_models else {"model": job.model_file}
    )
    identity = {**models, "network": job.options["model"], "options": job.recorded}
    return dict(json.loads(json.dumps(identity)))


def _check_output_folder(path: str | os.PathLike[str], what: str) -> str:
    """`path` checked to be a writable folder, or one that can be made (its nearest existing
    parent is a writable folder); nothing is made here (see `_make_output_folders`)."""
    folder = os.fspath(path)
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise InputError(f"{what} {folder} exists and is not a folder")
    existing = os.path.abspath(folder)
    while not os.path.exists(existing):
        existing = os.path.dirname(existing)
    if not os.path.isdir(existing):
        raise InputError(f"{what} {folder}: {existing} is not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise InputError(f"{what} {folder}: {existing} is not writable")
    return folder


def _make_output_folders(job: BatchJob) -> None:
    """The picture and cloud folders made (with their parents) once every check has passed."""
    for folder, what in ((job.png_dir, "png_dir"), (job.ply_dir, "ply_dir")):
        if folder is not None:
            try:
                os.makedirs(folder, exist_ok=True)
            except OSError as e:
                raise InputError(f"{what} {folder} could not be made: {e}") from None


def _load_models(job: BatchJob) -> ModelPoints:
    """The model's points, or with several models each one's."""
    from ..io import load_points

    if job.more_models:
        return [load_points(f) for f in job.models]
    return load_points(job.model_file)


def _engine(
    engine: str,
    job: BatchJob,
    model_points: ModelPoints,
    tasks: list[Task],
    workers: int,
    ray_address: str | None,
) -> Done:
    if engine == "local" and workers == 1:
        return run_in_process(job, model_points, tasks)
    # Worker processes share the cores: one thread each unless the caller says otherwise.
    threads = job.options.get("num_threads") or 1
    job = replace(job, options={**job.options, "num_threads": threads})
    if engine == "local":
        return run_in_pool(job, model_points, tasks, workers)
    return run_on_ray(job, model_points, tasks, workers, ray_address)
