"""The Ray engine: one task per scan on a Ray cluster (an existing one, or a local one).

The model's points go into the object store once; each worker process loads the network
once (`worker.resolve_cached`); a task whose worker dies is retried elsewhere (Ray's
``max_retries``), and one that dies every time is recorded as failed. Results stream back
as they complete. Every node must have pointclm installed and see the scan paths (a shared
folder), as the workers read the scans themselves.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from typing import Any

from .local import MAX_ATTEMPTS, Done, Task
from .options import BatchJob, ModelPoints
from .results import OutputWriteError
from .worker import crash_for_tests, failed_record, resolve_cached, run_scan

__all__ = ["run_on_ray"]


def _scan_task(job: BatchJob, model_points: ModelPoints, scan: str, picture: str) -> dict[str, Any]:
    crash_for_tests(scan)
    return run_scan(job, model_points, resolve_cached(job.options["model"]), scan, picture)


def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ImportError("engine='ray' needs ray: pip install 'pointclm[ray]'") from None
    return ray


def run_on_ray(
    job: BatchJob, model_points: ModelPoints, tasks: list[Task], workers: int, address: str | None
) -> Done:
    """The scans as Ray tasks; yields (position, record) as each completes. Connects to the
    cluster at `address` (as ``ray.init(address=...)``), or to the one this process is
    already connected to, or else starts a local one of `workers` CPUs (stopped at the end)."""
    ray = _import_ray()
    started = not ray.is_initialized()
    if started:
        if address is None:
            ray.init(num_cpus=workers, include_dashboard=False, logging_level="warning")
        else:
            ray.init(address=address, logging_level="warning")
    try:
        yield from _stream(ray, job, ray.put(model_points), tasks)
    finally:
        if started:
            ray.shutdown()


def _stream(ray: Any, job: BatchJob, model_ref: Any, tasks: list[Task]) -> Iterator[Any]:
    threads = job.options.get("num_threads") or 1
    remote = ray.remote(_scan_task).options(num_cpus=threads, max_retries=MAX_ATTEMPTS - 1)
    # A bounded number of tasks in flight: ray.wait over every scan of a large batch would
    # cost time per call in proportion to the batch.
    window = 2 * max(1, int(ray.cluster_resources().get("CPU", 1))) + 2
    todo = deque(tasks)
    running: dict[Any, Task] = {}
    while todo or running:
        while todo and len(running) < window:
            task = todo.popleft()
            running[remote.remote(job, model_ref, task[1], task[2])] = task
        ready, _ = ray.wait(list(running), num_returns=1)
        for ref in ready:
            position, scan, _ = running.pop(ref)
            try:
                yield position, ray.get(ref)
            except ray.exceptions.RayTaskError as e:
                if isinstance(e.cause, OutputWriteError):
                    raise e.cause from None  # the batch stops, as in the local engine
                message = f"Ray could not run this scan ({MAX_ATTEMPTS} tries): {e}"
                yield position, failed_record(job, scan, type(e).__name__, message)
            except ray.exceptions.RayError as e:
                message = f"Ray could not run this scan ({MAX_ATTEMPTS} tries): {e}"
                yield position, failed_record(job, scan, type(e).__name__, message)
