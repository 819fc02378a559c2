//! Cooperative cancellation: a caller that gives up on a long call (Ctrl-C in Python, a
//! deadline in a service) sets a [`CancelToken`]; the entry points check it between stages,
//! scenes and network layers and return [`Error::Cancelled`], so the abandoned work stops soon
//! instead of holding its threads until it finishes.
//!
//! The token is ambient rather than an argument, so that the public signatures stay as they
//! are: [`CancelToken::run`] makes it current on the calling thread for the duration of a
//! closure, and the entry points hand it on to the pool threads they fan out to.
//!
//! ```
//! use pointclm::cancel::CancelToken;
//! use pointclm::{register, Config, Correspondences, Error};
//!
//! let src: Vec<[f64; 3]> = (0..12).map(|i| [i as f64, (i * i) as f64, 1.0]).collect();
//! let corr = Correspondences::new(&src, &src)?;
//! let token = CancelToken::new();
//! token.cancel();
//! let r = token.run(|| register(&corr, None, &Config::default(), 0));
//! assert_eq!(r, Err(Error::Cancelled));
//! # Ok::<(), pointclm::Error>(())
//! ```

use std::cell::RefCell;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use crate::error::{Error, Result};

/// A shared flag: clones observe the same cancellation.
#[derive(Debug, Clone, Default)]
pub struct CancelToken(Arc<AtomicBool>);

thread_local! {
    static CURRENT: RefCell<Option<CancelToken>> = const { RefCell::new(None) };
}

impl CancelToken {
    /// A token that is not cancelled.
    pub fn new() -> Self {
        Self::default()
    }

    /// Asks every call running under this token to stop at its next check.
    pub fn cancel(&self) {
        self.0.store(true, Ordering::Relaxed);
    }

    /// Whether [`CancelToken::cancel`] was called.
    pub fn is_cancelled(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }

    /// Runs `f` with this token current on this thread (the previous one is restored after,
    /// also when `f` panics).
    pub fn run<T>(&self, f: impl FnOnce() -> T) -> T {
        within(Some(self.clone()), f)
    }
}

/// Restores the previous token when dropped.
struct Restore(Option<CancelToken>);

impl Drop for Restore {
    fn drop(&mut self) {
        let previous = self.0.take();
        CURRENT.with(|c| *c.borrow_mut() = previous);
    }
}

/// Runs `f` with `token` current on this thread (for handing the caller's token to a pool
/// thread).
pub(crate) fn within<T>(token: Option<CancelToken>, f: impl FnOnce() -> T) -> T {
    let previous = CURRENT.with(|c| std::mem::replace(&mut *c.borrow_mut(), token));
    let _restore = Restore(previous);
    f()
}

/// The token current on this thread, if any (to hand it on to another pool's threads).
pub fn current() -> Option<CancelToken> {
    CURRENT.with(|c| c.borrow().clone())
}

/// `Err(Error::Cancelled)` when the current token was cancelled.
pub fn check() -> Result<()> {
    let cancelled = CURRENT.with(|c| c.borrow().as_ref().is_some_and(CancelToken::is_cancelled));
    if cancelled {
        Err(Error::Cancelled)
    } else {
        Ok(())
    }
}
