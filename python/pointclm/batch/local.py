"""The local engine: scans one after the other in this process, or spread over a pool of
worker processes that each load the model and the network once.

A worker process that dies (a crash, the OOM killer) breaks Python's process pool; the scans
it held are run again in a new pool, and a scan whose worker dies `MAX_ATTEMPTS` times is
recorded as failed, so one scan that crashes its worker cannot stop the batch.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
from collections import Counter, deque
from collections.abc import Callable, Generator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from functools import partial
from typing import Any

from ..errors import PointclmError
from .options import BatchJob, ModelPoints
from .worker import failed_record, init_process, process_scan, resolve_cached, run_scan

__all__ = ["MAX_ATTEMPTS", "Task", "run_in_pool", "run_in_process"]

#: Tries a scan gets when its worker process dies under it (Ray's engine: the same).
MAX_ATTEMPTS = 3

#: (position in the scan list, scan path, picture name)
Task = tuple[int, str, str]
Done = Generator[tuple[int, dict[str, Any]], None, None]


def run_in_process(job: BatchJob, model_points: ModelPoints, tasks: list[Task]) -> Done:
    """Each scan in turn, here; yields (position, record)."""
    embedding = resolve_cached(job.options["model"])
    for position, scan, picture in tasks:
        yield position, run_scan(job, model_points, embedding, scan, picture)


def run_in_pool(job: BatchJob, model_points: ModelPoints, tasks: list[Task], workers: int) -> Done:
    """The scans over `workers` processes (spawned: no state forked from the caller); yields
    (position, record) as each completes, in any order."""
    todo = deque(tasks)
    attempts: Counter[int] = Counter()
    context = multiprocessing.get_context("spawn")
    started, failed_starts = False, 0
    while todo:
        slots = context.Array("q", 2 * workers)  # (pid, position of the scan it runs)
        pool = ProcessPoolExecutor(
            workers,
            mp_context=context,
            initializer=init_process,
            initargs=(job, model_points, os.getpid(), slots),
        )
        try:
            if _started(pool):
                started, failed_starts = True, 0
                culprits = partial(_culprits, pool, pool._processes, slots)
                yield from _drain(pool, todo, 2 * workers, attempts, job, culprits)
            else:
                failed_starts += 1
                _check_restart(started, failed_starts)
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


def _culprits(pool: ProcessPoolExecutor, processes: Any, slots: Any) -> set[int]:
    """The positions of the scans that workers were running when they died on their own,
    once the pool is down. Python's pool ends the other workers with SIGTERM when one dies:
    their scans are not to blame. `processes`: the pool's own map of its workers."""
    pool.shutdown(wait=True, cancel_futures=True)  # every worker has exited: exit codes known
    died = {pid for pid, p in dict(processes).items() if p.exitcode != -signal.SIGTERM}
    return {
        int(slots[i + 1]) for i in range(0, len(slots), 2) if slots[i] in died and slots[i + 1] >= 0
    }


def _started(pool: ProcessPoolExecutor) -> bool:
    """Whether the pool's workers start and run a task."""
    try:
        pool.submit(int).result()
    except BrokenProcessPool:
        return False
    return True


def _check_restart(started: bool, failed_starts: int) -> None:
    """Stop once the workers failed to start `MAX_ATTEMPTS` times in a row: otherwise every
    scan would be tried three times and recorded as failed for what is not the scan's
    fault. Fewer failures are tried again: a worker killed as it started is no reason to
    give up."""
    if failed_starts < MAX_ATTEMPTS:
        return
    if not started:
        raise PointclmError(
            f"the batch's worker processes died {failed_starts} times as they started (their "
            "error, if any, is above); a script that runs a batch with workers > 1 must do so "
            "under `if __name__ == '__main__':` (worker processes are spawned and import it)"
        )
    raise PointclmError(
        f"the batch's worker processes died {failed_starts} times in a row while starting "
        "again after a worker died; the lines written are whole: run it again with "
        "--resume (resume=True) to add the rest"
    )


def _drain(
    pool: ProcessPoolExecutor,
    todo: deque[Task],
    window: int,
    attempts: Counter[int],
    job: BatchJob,
    culprits: Callable[[], set[int]] | None = None,
) -> Done:
    """Runs `todo` on `pool`, at most `window` scans submitted at a time (so results waiting
    for an earlier one stay few); returns early, with the lost scans put back, if it breaks.
    `culprits`: after a break, the scans whose worker died under them (see `_requeue`)."""
    running: dict[Future[dict[str, Any]], Task] = {}
    while todo or running:
        try:
            while todo and len(running) < window:
                running[pool.submit(process_scan, todo[0][1], todo[0][2], todo[0][0])] = todo[0]
                todo.popleft()
        except BrokenProcessPool:  # a worker died since the last wait
            yield from _requeue(running, todo, attempts, job, culprits)
            return
        done, _ = wait(running, return_when=FIRST_COMPLETED)
        if any(isinstance(f.exception(), BrokenProcessPool) for f in done):
            yield from _requeue(running, todo, attempts, job, culprits)
            return
        for future in done:
            yield running.pop(future)[0], future.result()


def _requeue(
    running: dict[Future[dict[str, Any]], Task],
    todo: deque[Task],
    attempts: Counter[int],
    job: BatchJob,
    culprits: Callable[[], set[int]] | None = None,
) -> Done:
    """After a worker died: the finished scans' records, and every other scan in flight back
    at the head of the queue. The scans `culprits` names (those whose worker died under
    them) count a try, and one that has had `MAX_ATTEMPTS` is recorded as failed; the rest
    (queued, or ended with the pool) go back free. Where no scan can be named (no
    `culprits`, or a worker that died between scans), every scan in flight counts a try,
    so a batch that keeps losing workers still ends."""
    lost = []
    for future, task in running.items():
        if future.done() and future.exception() is None:
            yield task[0], future.result()
        else:
            lost.append(task)
    named = culprits() if culprits is not None else set()
    charged = named & {t[0] for t in lost} or {t[0] for t in lost}
    for task in sorted(lost, reverse=True):
        if task[0] in charged:
            attempts[task[0]] += 1
        if attempts[task[0]] < MAX_ATTEMPTS:
            todo.appendleft(task)
        else:
            message = f"the worker process died while registering this scan ({MAX_ATTEMPTS} tries)"
            yield task[0], failed_record(job, task[1], "WorkerCrashedError", message)
