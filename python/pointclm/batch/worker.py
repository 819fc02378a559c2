"""One scan of a batch, as every engine runs it: load, register, optional pictures, and one
record (the result or the error), so one bad scan never stops a batch. The one exception
raised is :class:`~pointclm.batch.results.OutputWriteError`: a picture or cloud that cannot
be written (a full disk) is no fault of the scan, and every later scan would fail alike.

Worker processes (process pool or Ray) keep the model's points and the loaded network in
this module between scans: both are loaded once per process, not once per scan.
"""

from __future__ import annotations

import contextlib
import errno
import os
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from .options import BatchJob, ModelPoints, scan_viewpoint
from .records import FORMAT_VERSION, error_record, registration_record
from .results import OutputWriteError, output_error

__all__ = [
    "CRASH_ENV",
    "failed_record",
    "init_process",
    "process_scan",
    "resolve_cached",
    "run_scan",
]

#: Test only: "NAME:MARKER" makes a worker process die abruptly (as a segfault or an OOM kill
#: would) when it starts the scan whose file name is NAME, the first time only (it creates
#: MARKER; once MARKER exists the scan runs). The tests use it to check that a batch outlives
#: a dead worker; never acted on in the caller's own process.
CRASH_ENV = "POINTCLM_TEST_CRASH_ONCE"

#: How often a pool worker looks whether the batch that started it is still alive.
PARENT_POLL_S = 0.5

#: Per worker process: the networks loaded so far, by name or path.
_NETWORKS: dict[str, Any] = {}
#: Per pool worker process: the job and the model's points, set by `init_process`.
_PROCESS: dict[str, Any] = {}


def resolve_cached(model: str | None) -> Any:
    """The embedding `model` names, loaded once per process."""
    from ..embedding import resolve

    if model is None:
        return None
    if model not in _NETWORKS:
        _NETWORKS[model] = resolve(model)
    return _NETWORKS[model]


def init_process(
    job: BatchJob, model_points: ModelPoints, parent: int | None = None, slots: Any = None
) -> None:
    """Process-pool initializer: what every scan of this worker shares, loaded once.
    `parent`: the batch process's pid; this worker exits when that process is gone.
    `slots`: a shared array of (pid, position) pairs, one per worker, where this worker
    records the scan it is running (so a worker's death is charged to its own scan)."""
    if parent is not None:
        _exit_with_parent(parent)
    if slots is not None:
        with slots.get_lock():
            free = [i for i in range(0, len(slots), 2) if slots[i] == 0]
            if free:
                slots[free[0]], slots[free[0] + 1] = os.getpid(), -1
                _PROCESS["slot"] = (slots, free[0] + 1)
    _PROCESS.update(
        job=job, model_points=model_points, embedding=resolve_cached(job.options["model"])
    )


def _exit_with_parent(parent: int) -> None:
    """Ends this worker process when the batch process `parent` is gone. A pool's workers
    wait on a queue whose writing end they hold themselves, so a batch killed with SIGKILL
    would otherwise leave them running (and registering) forever. The pid is the caller's,
    not read here: a batch killed while this worker started has already handed it on."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="pointclm-parent-watch", daemon=True).start()


def process_scan(scan: str, picture: str, position: int = -1) -> dict[str, Any]:
    """`run_scan` in a pool worker, with what `init_process` loaded; `position` (the scan's
    in the batch) stays in this worker's slot while it runs, and after, if the process dies."""
    slots, at = _PROCESS.get("slot", (None, 0))
    if slots is not None:
        slots[at] = position
    crash_for_tests(scan)
    record = run_scan(
        _PROCESS["job"], _PROCESS["model_points"], _PROCESS["embedding"], scan, picture
    )
    if slots is not None:
        slots[at] = -1
    return record


def run_scan(
    job: BatchJob, model_points: ModelPoints, embedding: Any, scan: str, picture: str
) -> dict[str, Any]:
    """The record of one scan: ``status`` "ok" with the registration, or "error" with the
    exception's class and message. `picture` is the file name (no suffix) of its PNG/PLY."""
    t0 = time.perf_counter()
    try:
        body = _register_scan(job, model_points, embedding, scan, picture)
    except OutputWriteError:
        raise  # the batch stops: not this scan's fault
    except Exception as e:  # recorded for this scan; the batch goes on
        body = {"status": "error", **error_record(e)}
    return {**_head(job, scan), **body, "seconds": time.perf_counter() - t0}


def failed_record(job: BatchJob, scan: str, error: str, message: str) -> dict[str, Any]:
    """The record of a scan that an engine could not run (its worker kept dying)."""
    return {
        **_head(job, scan),
        "status": "error",
        "error": error,
        "message": message,
        "seconds": 0.0,
    }


def _head(job: BatchJob, scan: str) -> dict[str, Any]:
    return {
        "format_version": FORMAT_VERSION,
        "scan": scan,
        **({"models": job.models} if job.more_models else {"model": job.model_file}),
        "network": job.options.get("model"),
        "options": job.recorded,
    }


def _register_scan(
    job: BatchJob, model_points: ModelPoints, embedding: Any, scan: str, picture: str
) -> dict[str, Any]:
    from ..point_clouds import register_point_clouds
    from .scans import load_scan_points

    t0 = time.perf_counter()
    points = load_scan_points(scan)
    options = {**job.options, "model": embedding}
    options["viewpoint"] = scan_viewpoint(options.get("viewpoint"), scan)
    t_load = time.perf_counter() - t0
    if isinstance(model_points, list):
        return {"status": "ok", "results": _joint(job, model_points, points, options, t_load)}
    reg = register_point_clouds(model_points, points, **options)
    record = _loaded_in(registration_record(reg, reg.diagnosis), t_load)
    return {"status": "ok", **record, **_pictures(job, reg, scan, picture)}


def _loaded_in(record: dict[str, Any], t_load: float) -> dict[str, Any]:
    """`record` with the scan's load time: it was read here, not by the registration."""
    record["timings_s"]["load"] = t_load
    record["timings_s"]["total"] = record["timings_s"].get("total", 0.0) + t_load
    return record


def _joint(
    job: BatchJob,
    models: list[np.ndarray],
    points: np.ndarray,
    options: dict[str, Any],
    t_load: float,
) -> list[dict[str, Any]]:
    """One record per model, their copies judged together (`register_models`)."""
    from ..clouds.joint import register_models

    regs = register_models(models, points, **options)
    return [
        {"model": name, **_loaded_in(registration_record(reg, reg.diagnosis), t_load)}
        for name, reg in zip(job.models, regs, strict=True)
    ]


def _pictures(job: BatchJob, reg: Any, scan: str, picture: str) -> dict[str, str]:
    from ..visualize import save_ply, save_registration_png

    written = {}
    if job.png_dir is not None:
        path = os.path.join(job.png_dir, picture + ".png")
        title = f"{Path(job.model_file).name} in {Path(scan).name}"
        with _writing(path) as tmp:
            save_registration_png(tmp, reg, title=title)
        written["png"] = path
    if job.ply_dir is not None:
        path = os.path.join(job.ply_dir, picture + ".ply")
        with _writing(path) as tmp:
            save_ply(
                tmp, reg.target_points, reg.source_points, reg.transformations, 1.5 * reg.voxel_size
            )
        written["ply"] = path
    return written


@contextlib.contextmanager
def _writing(path: str) -> Iterator[Path]:
    """`atomic_path(path)`, where a failure to write is an :class:`OutputWriteError`. The
    writers check their folder before writing and say so with a ValueError: a folder made
    read-only after the temporary file was created is the output's fault, not the scan's."""
    from ..io.files import atomic_path

    try:
        with atomic_path(path) as tmp:
            yield tmp
    except OSError as e:
        raise output_error(e, path) from None
    except ValueError:
        folder = os.path.dirname(path) or "."
        if os.access(folder, os.W_OK | os.X_OK):
            raise
        raise OutputWriteError(errno.EACCES, os.strerror(errno.EACCES), path) from None


def crash_for_tests(scan: str) -> None:
    """Exit the process at once where `CRASH_ENV` asks it to (worker processes only)."""
    spec = os.environ.get(CRASH_ENV)
    if not spec:
        return
    name, _, marker = spec.partition(":")
    if Path(scan).name != name:
        return
    try:
        os.close(os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return
    os._exit(70)
