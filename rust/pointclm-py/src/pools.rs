//! Where core calls run: on cached private rayon pools (never rayon's global pool, which a
//! library must not configure and which cannot be rebuilt after `fork`), on a worker thread
//! that the calling Python thread watches, so that Ctrl-C interrupts any call at once.
//!
//! - Ctrl-C: the calling thread waits for the worker in short slices with the GIL released
//!   and runs Python's signal handlers in between; on KeyboardInterrupt it cancels the call's
//!   token (the core stops at its next check, between stages, scenes or network layers) and
//!   raises at once, without waiting for the worker.
//! - fork: a child inherits the parent's pool objects but none of their threads, so the first
//!   job would wait forever. The cache is tagged with the pid; in a child the parent's pools
//!   are forgotten (not dropped: dropping would signal threads that do not exist, through
//!   locks that may have been held at the fork) and new ones are built.
//! - Bounded: at most [`CACHED_POOLS`] pools and [`cached_threads`] threads are kept (least
//!   recently used goes first; a pool larger than the whole budget serves its call and is
//!   not kept). A pool that leaves the cache is shut down by whoever holds it last: the
//!   eviction itself, or the call using it when that call returns, which joins the pool's
//!   threads before returning. Threads alive after any sequence of calls are therefore at
//!   most the cache's budget plus the pools of calls still running, never the threads of
//!   pools already given up (rayon lets a dropped pool's threads exit in the background,
//!   so a loop over many thread counts would otherwise run ahead of their exits).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::mpsc::{sync_channel, RecvTimeoutError};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use pointclm::cancel::CancelToken;
use pyo3::exceptions::{PyMemoryError, PyRuntimeError};
use pyo3::prelude::*;
use rayon::ThreadPool;

use crate::args::MAX_THREADS;
use crate::errors::{to_py_err, InputError};

/// Pools kept for reuse: the default one plus a few explicit `num_threads` values covers
/// every realistic caller; a loop over many values churns pools instead of leaking threads.
pub const CACHED_POOLS: usize = 4;

/// Threads the cache may keep alive in all: a few pools of the machine's size.
fn cached_threads() -> usize {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    (2 * cores).max(64)
}

/// How often a waiting call looks for Ctrl-C (the issue asks for under about a second).
const SIGNAL_POLL: Duration = Duration::from_millis(50);

/// A private rayon pool that knows its threads, so that shutting it down can wait for them.
pub struct Pool {
    pool: ThreadPool,
    threads: Mutex<Vec<JoinHandle<()>>>,
}

impl std::ops::Deref for Pool {
    type Target = ThreadPool;

    fn deref(&self) -> &ThreadPool {
        &self.pool
    }
}

impl Pool {
    /// A pool of `num_threads` threads (0: rayon's default count), each spawned here so that
    /// its handle is kept.
    fn new(num_threads: usize) -> pointclm::Result<Self> {
        let threads = Mutex::new(Vec::new());
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(num_threads)
            .spawn_handler(|thread| {
                let mut b = std::thread::Builder::new();
                if let Some(name) = thread.name() {
                    b = b.name(name.to_owned());
                }
                if let Some(size) = thread.stack_size() {
                    b = b.stack_size(size);
                }
                let handle = b.spawn(|| thread.run())?;
                threads
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .push(handle);
                Ok(())
            })
            .build()
            .map_err(|e| pointclm::Error::ThreadPool {
                threads: num_threads,
                reason: e.to_string(),
            })?;
        Ok(Self { pool, threads })
    }

    /// Stops the pool and waits until its threads have exited (its work is done: the caller
    /// holds the last reference, and every call waits for its job before letting go).
    fn shut_down(self) {
        let Self { pool, threads } = self;
        drop(pool);
        let me = std::thread::current().id();
        for handle in threads.into_inner().unwrap_or_else(|e| e.into_inner()) {
            if handle.thread().id() != me {
                let _ = handle.join();
            }
        }
    }
}

/// Lets go of `pool`, shutting it down ([`Pool::shut_down`]) when this was the last
/// reference: the cache no longer holds it and no other call uses it.
fn release(pool: Arc<Pool>) {
    if let Some(p) = Arc::into_inner(pool) {
        p.shut_down();
    }
}

struct Cache {
    pid: u32,
    /// `(num_threads, pool)`, most recently used last; 0 is rayon's default count.
    pools: Vec<(usize, Arc<Pool>)>,
}

static CACHE: Mutex<Cache> = Mutex::new(Cache {
    pid: 0,
    pools: Vec::new(),
});

fn lock() -> MutexGuard<'static, Cache> {
    // A poisoned lock only means a panic while it was held; the cache itself stays valid.
    let mut cache = CACHE.lock().unwrap_or_else(|e| e.into_inner());
    let pid = std::process::id();
    if cache.pid != pid {
        std::mem::forget(std::mem::take(&mut cache.pools));
        cache.pid = pid;
    }
    cache
}

fn cached(num_threads: usize) -> PyResult<Arc<Pool>> {
    {
        let mut cache = lock();
        if let Some(k) = cache.pools.iter().position(|(n, _)| *n == num_threads) {
            let entry = cache.pools.remove(k);
            let pool = entry.1.clone();
            cache.pools.push(entry);
            return Ok(pool);
        }
    }
    // built outside the lock: spawning threads takes a while
    let pool = Arc::new(Pool::new(num_threads).map_err(to_py_err)?);
    let budget = cached_threads();
    let size = pool.current_num_threads();
    if size > budget {
        return Ok(pool);
    }
    let mut cache = lock();
    if let Some((_, p)) = cache.pools.iter().find(|(n, _)| *n == num_threads) {
        // another thread built one meanwhile: share it, shut ours down
        let shared = p.clone();
        drop(cache);
        release(pool);
        return Ok(shared);
    }
    let held = |c: &Cache| {
        c.pools
            .iter()
            .map(|(_, p)| p.current_num_threads())
            .sum::<usize>()
    };
    let mut evicted = Vec::new();
    while !cache.pools.is_empty()
        && (cache.pools.len() >= CACHED_POOLS || held(&cache) + size > budget)
    {
        evicted.push(cache.pools.remove(0).1);
    }
    cache.pools.push((num_threads, pool.clone()));
    // joined outside the lock: a pool still in use is shut down by its last call instead
    drop(cache);
    evicted.into_iter().for_each(release);
    Ok(pool)
}

/// The pool for an explicit thread count (`1..=MAX_THREADS`).
pub fn pool(num_threads: usize) -> PyResult<Arc<Pool>> {
    if !(1..=MAX_THREADS).contains(&num_threads) {
        return Err(InputError::new_err(format!(
            "num_threads must lie in 1..={MAX_THREADS} (or None for all cores), got {num_threads}"
        )));
    }
    cached(num_threads)
}

/// Runs a core call on `pool` (the default pool when `None`) with the GIL released, turning
/// a panic into RuntimeError (a bug must never abort the interpreter), a refused allocation
/// into MemoryError, and Ctrl-C into KeyboardInterrupt within [`SIGNAL_POLL`]. The call is
/// spawned onto the pool it runs on: a hop through the default pool into another costs two
/// more thread wake-ups (about 15 us measured on a 2 ms `register` call after Python work).
pub fn guarded<T: Send + 'static>(
    py: Python<'_>,
    pool: Option<Arc<Pool>>,
    f: impl FnOnce() -> pointclm::Result<T> + Send + 'static,
) -> PyResult<T> {
    let pool = match pool {
        Some(p) => p,
        None => cached(0)?,
    };
    if rayon::current_thread_index().is_some() {
        // Called from inside the core's own work (a Python callback, such as a learned
        // embedding, running on a pool's worker): spawning onto a pool whose workers are all
        // busy waiting for this call would never start, so run here, in `pool` (inline when
        // it is the caller's own). The outer call watches for Ctrl-C.
        let ran = py.detach(move || catch_unwind(AssertUnwindSafe(|| pool.install(f))));
        return match ran {
            Ok(r) => r.map_err(to_py_err),
            Err(_) => Err(PyRuntimeError::new_err(
                "internal error in pointclm (please report)",
            )),
        };
    }
    let token = CancelToken::new();
    let worker_token = token.clone();
    let (tx, mut rx) = sync_channel(1);
    pool.spawn(move || {
        let r = catch_unwind(AssertUnwindSafe(|| worker_token.run(f)));
        // the receiver is gone when the caller was interrupted: nobody wants the result
        let _ = tx.send(r);
    });
    let out = loop {
        // the receiver is moved in and out: it is Send but not Sync
        let (received, back) = py.detach(move || (rx.recv_timeout(SIGNAL_POLL), rx));
        rx = back;
        match received {
            Ok(Ok(r)) => break r.map_err(to_py_err),
            Ok(Err(_)) => {
                break Err(PyRuntimeError::new_err(
                    "internal error in pointclm (please report)",
                ))
            }
            Err(RecvTimeoutError::Timeout) => {
                if let Err(interrupt) = py.check_signals() {
                    token.cancel();
                    // not joined: the cancelled job may still run; its threads exit after it
                    return Err(interrupt);
                }
            }
            Err(RecvTimeoutError::Disconnected) => {
                break Err(PyRuntimeError::new_err(
                    "internal error in pointclm: the worker stopped without a result",
                ))
            }
        }
    };
    // the job is over: a pool that left the cache meanwhile is shut down here
    py.detach(move || release(pool));
    out
}

/// [`guarded`] for a staged function that holds `copies` dense `n x n` f64 matrices: the
/// memory is asked of the system first, so that a size it cannot give is a MemoryError
/// before any work rather than an abort in the middle.
pub fn guarded_dense<T: Send + 'static>(
    py: Python<'_>,
    what: &str,
    n: usize,
    copies: usize,
    f: impl FnOnce() -> pointclm::Result<T> + Send + 'static,
) -> PyResult<T> {
    let elements = n.checked_mul(n).and_then(|e| e.checked_mul(copies));
    let fits = elements.is_some_and(|e| {
        let mut probe: Vec<f64> = Vec::new();
        probe.try_reserve_exact(e).is_ok()
    });
    if !fits {
        return Err(PyMemoryError::new_err(format!(
            "{what}: {copies} dense {n} x {n} matrices ({} bytes) do not fit in memory",
            (n as u128) * (n as u128) * (copies as u128) * 8
        )));
    }
    guarded(py, None, f)
}
