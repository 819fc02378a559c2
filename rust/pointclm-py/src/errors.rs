//! Errors as the exception classes of `pointclm.errors`: the classes are defined in Python
//! (a missing weight file must be both a ValueError and a FileNotFoundError, two bases that
//! `create_exception!` cannot give) and imported here the first time one is raised.
//!
//! Every error this module raises keeps the core's message; only the class is chosen here.

use pyo3::exceptions::{PyKeyboardInterrupt, PyMemoryError};
use pyo3::prelude::*;

pyo3::import_exception!(pointclm.errors, PointclmError);
pyo3::import_exception!(pointclm.errors, InputError);
pyo3::import_exception!(pointclm.errors, ConfigError);
pyo3::import_exception!(pointclm.errors, NumericalError);
pyo3::import_exception!(pointclm.errors, WeightsError);
pyo3::import_exception!(pointclm.errors, WeightsNotFoundError);

/// The exception for core error `e`, with message `msg`: a refused allocation is MemoryError,
/// a cancelled call KeyboardInterrupt (it was cancelled by Ctrl-C), everything else a
/// subclass of `pointclm.errors.PointclmError` (a ValueError).
fn raise(e: &pointclm::Error, msg: String) -> PyErr {
    use pointclm::Error as E;
    match e {
        E::Allocation { .. } => PyMemoryError::new_err(msg),
        E::Cancelled => PyKeyboardInterrupt::new_err(msg),
        E::TooFewCorrespondences { .. }
        | E::TooFewMatches { .. }
        | E::TooFewPoints { .. }
        | E::NonFinite { .. }
        | E::LengthMismatch { .. }
        | E::InvalidParameter { .. }
        | E::MissingInput { .. }
        | E::TooManyForDenseAttention { .. }
        | E::InvalidMatrix(_) => InputError::new_err(msg),
        E::InvalidConfig { .. } | E::ConfigOutOfRange { .. } => ConfigError::new_err(msg),
        E::EigenNoConvergence { .. } | E::MagnitudeRange { .. } => NumericalError::new_err(msg),
        E::WeightsNotFound { .. } => WeightsNotFoundError::new_err(msg),
        E::WeightsMalformed { .. } | E::TensorMissing { .. } | E::TensorShape { .. } => {
            WeightsError::new_err(msg)
        }
        // the system would not start the threads: not the input's fault; the base class
        // (still a ValueError, as before) for it and for variants added to the core later
        _ => PointclmError::new_err(msg),
    }
}

/// Core error `e` as the Python exception of its kind (see [`raise`]).
pub fn to_py_err(e: pointclm::Error) -> PyErr {
    let msg = e.to_string();
    raise(&e, msg)
}

/// [`to_py_err`] with `what: ` before the message, to name the argument at fault.
pub fn to_py_err_at(what: &str, e: pointclm::Error) -> PyErr {
    let msg = format!("{what}: {e}");
    raise(&e, msg)
}

/// `e` of the same class with `prefix` before its message ("scene 3: need at least ...").
pub fn prefixed(py: Python<'_>, e: PyErr, prefix: &str) -> PyErr {
    PyErr::from_type(e.get_type(py), format!("{prefix}{}", e.value(py)))
}
