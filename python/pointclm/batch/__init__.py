"""Many scans against one model: `register_files` (and ``pointclm batch``).

One JSON line per scan, resumable, on this machine's cores or on a Ray cluster.

Design decisions
----------------
- **Lines in the order of the scan list**, each flushed and fsync'd as soon as every line
  before it is written: a batch killed and resumed writes the same file as one that ran
  through (timings aside), and ``resume`` needs only the set of scans already written. The
  price: a slow scan holds back the lines after it (they wait in memory, never lost).
- **One seed for every scan** (the caller's), not one per position or worker, so a scan's
  poses do not depend on how the batch was split; the core's results do not depend on its
  thread count either, so 1 process, N processes and Ray agree bit for bit.
- **Workers load once**: the model's points are sent to each worker process once (pool
  initializer, Ray object store) and the network is loaded once per process; each worker
  reads its own scans, so only paths travel.
- **A bad scan is a line, not a stop**: every exception of one scan is recorded with its
  class and message; a worker process that dies has its scans run again (three tries).
  Bad *options*, a bad model file or an unreadable output stop the batch before any scan.
- **Faults stop the batch, never corrupt it**: an output that cannot be written (a full disk,
  a file-size limit, a read-only folder) raises :class:`OutputWriteError` naming the file,
  with every whole line kept, so ``resume`` continues it; worker processes exit when the
  batch process is killed.
- **Ray is optional** (``pip install 'pointclm[ray]'``), imported only for ``engine="ray"``.
"""

from __future__ import annotations

from .records import TIMING_FIELDS, registration_record, without_timings
from .results import OutputWriteError
from .run import BatchSummary, register_files, run_batch
from .scans import expand_scans

__all__ = [
    "TIMING_FIELDS",
    "BatchSummary",
    "OutputWriteError",
    "expand_scans",
    "register_files",
    "registration_record",
    "run_batch",
    "without_timings",
]
