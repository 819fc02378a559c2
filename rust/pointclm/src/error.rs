//! Typed errors: every bad input maps to one of these, never to a panic.

/// Everything that can go wrong in `pointclm`, with enough context to fix the input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// Fewer correspondences than a rigid pose needs.
    #[error("need at least {min} correspondences, got {got}")]
    TooFewCorrespondences { got: usize, min: usize },

    /// Descriptor matching between a model and a scan left too few pairs for a pose. The
    /// scene pipeline does not return it (too few matches there is an empty result whose
    /// first pass says how few); kept for callers that match descriptors themselves.
    #[error(
        "only {got} correspondences survived matching: the clouds share too few similar local \
         shapes (try mutual=False, a smaller voxel_size, or check the units)"
    )]
    TooFewMatches { got: usize },

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

    /// A count of the configuration outside its documented range (see
    /// [`config::bounds`](crate::config::bounds)).
    #[error("invalid config: {field} = {value} (must lie in {min}..={max})")]
    ConfigOutOfRange {
        field: &'static str,
        value: u128,
        min: usize,
        max: usize,
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

    /// A weight file, or the JSON of its architecture beside it, that does not exist or
    /// cannot be read.
    #[error("no weights at {path}: {reason}")]
    WeightsNotFound { path: String, reason: String },

    /// A weight file or its JSON that exists but is not a valid network: not safetensors,
    /// invalid JSON, a bad architecture, a tensor of an unsupported dtype or with non-finite
    /// values, or a tensor the architecture has no place for.
    #[error("malformed weights {path}: {reason}")]
    WeightsMalformed { path: String, reason: String },

    /// A tensor the architecture needs that the weight file lacks.
    #[error("weights {path} lack tensor {name} (the file does not match its architecture)")]
    TensorMissing { path: String, name: String },

    /// A tensor whose shape differs from the one the architecture implies.
    #[error(
        "weights {path}: tensor {name} has shape {got:?}, the architecture needs {expected:?}"
    )]
    TensorShape {
        path: String,
        name: String,
        expected: Vec<usize>,
        got: Vec<usize>,
    },

    /// An input that the embedding network was trained with (its architecture's `inputs`) and
    /// that the correspondences lack; `hint` says how to give it.
    #[error("the network needs the input {input:?}, which the correspondences lack: {hint}")]
    MissingInput {
        input: &'static str,
        hint: &'static str,
    },

    /// More correspondences than the embedding network's dense attention takes, for input
    /// whose consistent pairs are too many for its sparse attention (see
    /// [`network::MAX_DENSE_ATTENTION_ROWS`](crate::network::MAX_DENSE_ATTENTION_ROWS)).
    #[error(
        "the learned embedding takes at most {max} correspondences when many of their pairs \
         are length-consistent (more than 1/{share_denominator} of all pairs, or more than \
         {max_pairs} pairs: its dense attention, whose time grows as N^2, runs), got {n}; \
         give fewer correspondences (keep the best matches, or match fewer points), or \
         register without the learned model (model=None, the training-free pipeline)"
    )]
    TooManyForDenseAttention {
        n: usize,
        max: usize,
        share_denominator: usize,
        max_pairs: usize,
    },

    /// An allocation sized by the input that the system refused (or that could not even be
    /// sized without overflow): the input is too large for this machine's memory.
    #[error("{what}: cannot allocate {bytes} bytes (input too large for the available memory)")]
    Allocation { what: &'static str, bytes: u128 },

    /// The call was cancelled through a [`CancelToken`](crate::cancel::CancelToken) (e.g.
    /// Ctrl-C in Python) before it finished.
    #[error("cancelled")]
    Cancelled,

    /// Coordinates and lengths whose magnitudes no common scale brings within what `f64`
    /// arithmetic (squared distances, their ratios and sums) can hold.
    #[error("{what}: magnitudes from {smallest:e} to {largest:e} span more than f64 squared distances can hold; shift or rescale the input and config")]
    MagnitudeRange {
        what: &'static str,
        smallest: f64,
        largest: f64,
    },
}

/// Shorthand for `Result<T, pointclm::Error>`.
pub type Result<T> = std::result::Result<T, Error>;

/// `vec![value; n]`, or [`Error::Allocation`] naming `what` when the system refuses the
/// memory: sizes that come from the input must never abort the process.
pub fn try_filled<T: Clone>(what: &'static str, n: usize, value: T) -> Result<Vec<T>> {
    let mut v = Vec::new();
    v.try_reserve_exact(n).map_err(|_| Error::Allocation {
        what,
        bytes: n as u128 * std::mem::size_of::<T>() as u128,
    })?;
    v.resize(n, value);
    Ok(v)
}

/// The product of `dims` (a number of elements), or [`Error::Allocation`] when it overflows.
pub fn checked_elements(what: &'static str, dims: &[usize], elem_bytes: usize) -> Result<usize> {
    dims.iter()
        .try_fold(1usize, |acc, &d| acc.checked_mul(d))
        .filter(|n| n.checked_mul(elem_bytes).is_some())
        .ok_or_else(|| Error::Allocation {
            what,
            bytes: dims
                .iter()
                .fold(elem_bytes as u128, |acc, &d| acc.saturating_mul(d as u128)),
        })
}
