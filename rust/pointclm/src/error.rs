//! Typed errors: every bad input maps to one of these, never to a panic.

/// Everything that can go wrong in `pointclm`, with enough context to fix the input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// Fewer correspondences than a rigid pose needs.
    #[error("need at least {min} correspondences, got {got}")]
    TooFewCorrespondences { got: usize, min: usize },

    /// A NaN or infinite coordinate or feature value.
    #[error("{what} has a non-finite value (NaN or inf) in row {row}")]
    NonFinite { what: &'static str, row: usize },

    /// Two inputs that must have matching sizes do not.
    #[error("{what}: expected {expected}, got {got}")]
    LengthMismatch {
        what: &'static str,
        expected: usize,
        got: usize,
    },

    /// A configuration value outside its valid range.
    #[error("invalid config: {field} = {value} ({reason})")]
    InvalidConfig {
        field: &'static str,
        value: String,
        reason: &'static str,
    },

    /// A matrix argument of the staged API that is not square, symmetric or finite.
    #[error("invalid matrix: {0}")]
    InvalidMatrix(String),

    /// The symmetric eigensolver did not converge (not expected for finite input).
    #[error("eigendecomposition of a {n} x {n} matrix did not converge")]
    EigenNoConvergence { n: usize },

    /// A point cloud or descriptor set with fewer points than the step needs.
    #[error("{what}: need at least {min} points, got {got}")]
    TooFewPoints {
        what: &'static str,
        got: usize,
        min: usize,
    },

    /// A parameter of point cloud processing outside its valid range.
    #[error("invalid parameter: {name} = {value} ({reason})")]
    InvalidParameter {
        name: &'static str,
        value: String,
        reason: &'static str,
    },

    /// The caller asked for a thread pool that could not be built.
    #[error("could not build a pool of {threads} threads: {reason}")]
    ThreadPool { threads: usize, reason: String },
}

/// Shorthand for `Result<T, pointclm::Error>`.
pub type Result<T> = std::result::Result<T, Error>;
