//! Argument conversion with one error family: every bad argument of a `_core` function (a
//! wrong type, a negative or huge int, a float32 or list where float64 is expected) is a
//! `pointclm.errors.InputError` (a ValueError) naming the argument, never PyO3's TypeError or
//! OverflowError.
//!
//! Each argument gets a converter named after it (`#[pyo3(from_py_with = args::seed)]`):
//! PyO3 prefixes only TypeErrors with the argument's name, so the name must be in our own
//! message.

use numpy::{
    PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2,
    PyReadonlyArray3,
};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyList};

use crate::errors::{ConfigError, InputError};

/// More threads than this is a mistake, not a configuration (each costs a stack and a spawn).
pub const MAX_THREADS: usize = 256;

fn repr(obj: &Bound<'_, PyAny>) -> String {
    let r = obj
        .repr()
        .map(|r| r.to_string())
        .unwrap_or_else(|_| "<unprintable>".into());
    if r.chars().count() > 80 {
        format!("{}...", r.chars().take(77).collect::<String>())
    } else {
        r
    }
}

/// An int (anything with `__index__`, not a bool) in `min..=max`.
pub fn count(obj: &Bound<'_, PyAny>, name: &str, min: u128, max: u128) -> PyResult<u128> {
    let bad = || {
        InputError::new_err(format!(
            "{name} must be an int in [{min}, {max}], got {}",
            repr(obj)
        ))
    };
    if obj.is_instance_of::<PyBool>() {
        return Err(bad());
    }
    let v: i128 = obj.extract().map_err(|_| bad())?;
    u128::try_from(v)
        .ok()
        .filter(|v| (min..=max).contains(v))
        .ok_or_else(bad)
}

fn optional<'py, T>(
    obj: &Bound<'py, PyAny>,
    f: impl FnOnce(&Bound<'py, PyAny>) -> PyResult<T>,
) -> PyResult<Option<T>> {
    if obj.is_none() {
        Ok(None)
    } else {
        f(obj).map(Some)
    }
}

fn usize_in(obj: &Bound<'_, PyAny>, name: &str, min: usize, max: usize) -> PyResult<usize> {
    count(obj, name, min as u128, max as u128).map(|v| v as usize)
}

/// A finite or infinite real number (the core checks the range and says what it must be).
pub fn real(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<f64> {
    let bad = || InputError::new_err(format!("{name} must be a number, got {}", repr(obj)));
    if obj.is_instance_of::<PyBool>() {
        return Err(bad());
    }
    obj.extract::<f64>().map_err(|_| bad())
}

fn flag(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<bool> {
    obj.extract::<bool>().map_err(|_| {
        InputError::new_err(format!("{name} must be True or False, got {}", repr(obj)))
    })
}

fn text(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<String> {
    obj.extract::<String>()
        .map_err(|_| InputError::new_err(format!("{name} must be a str, got {}", repr(obj))))
}

/// numpy's view of `obj` as a float64 array of `ndim` dimensions: float64 arrays pass
/// through without a copy; other real dtypes (float32, ints) and nested sequences are
/// converted, never modified in place.
fn float_array<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    ndim: usize,
) -> PyResult<Bound<'py, PyAny>> {
    let py = obj.py();
    let np = py.import("numpy")?;
    let a = np
        .call_method1("asarray", (obj,))
        .map_err(|e| InputError::new_err(format!("{name} could not be read as an array: {e}")))?;
    let kind: String = a.getattr("dtype")?.getattr("kind")?.extract()?;
    if !["f", "i", "u"].contains(&kind.as_str()) {
        return Err(InputError::new_err(format!(
            "{name} must hold real numbers, got dtype {}",
            a.getattr("dtype")?
        )));
    }
    let dims: usize = a.getattr("ndim")?.extract()?;
    if dims != ndim {
        return Err(InputError::new_err(format!(
            "{name} must be a {ndim}-D array, got shape {}",
            a.getattr("shape")?
        )));
    }
    let kwargs = PyDict::new(py);
    kwargs.set_item("dtype", np.getattr("float64")?)?;
    np.call_method("asarray", (a,), Some(&kwargs))
}

pub fn vector<'py>(obj: &Bound<'py, PyAny>, name: &str) -> PyResult<PyReadonlyArray1<'py, f64>> {
    if let Ok(a) = obj.cast::<PyArray1<f64>>() {
        return Ok(a.readonly());
    }
    let a = float_array(obj, name, 1)?;
    Ok(a.cast_into::<PyArray1<f64>>()?.readonly())
}

pub fn matrix<'py>(obj: &Bound<'py, PyAny>, name: &str) -> PyResult<PyReadonlyArray2<'py, f64>> {
    if let Ok(a) = obj.cast::<PyArray2<f64>>() {
        return Ok(a.readonly());
    }
    let a = float_array(obj, name, 2)?;
    Ok(a.cast_into::<PyArray2<f64>>()?.readonly())
}

pub fn tensor3<'py>(obj: &Bound<'py, PyAny>, name: &str) -> PyResult<PyReadonlyArray3<'py, f64>> {
    if let Ok(a) = obj.cast::<PyArray3<f64>>() {
        return Ok(a.readonly());
    }
    let a = float_array(obj, name, 3)?;
    Ok(a.cast_into::<PyArray3<f64>>()?.readonly())
}

fn point(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<[f64; 3]> {
    let bad = || InputError::new_err(format!("{name} must be 3 numbers, got {}", repr(obj)));
    let v: Vec<f64> = obj.extract().map_err(|_| bad())?;
    <[f64; 3]>::try_from(v).map_err(|_| bad())
}

/// Converters named after the arguments they read.
macro_rules! converters {
    ($($arg:ident -> $ty:ty = |$o:ident| $body:expr;)*) => {
        $(
            pub fn $arg(obj: &Bound<'_, PyAny>) -> PyResult<$ty> {
                let $o = obj;
                $body
            }
        )*
    };
}

converters! {
    num_threads -> Option<usize> = |o| optional(o, |o| usize_in(o, "num_threads", 1, MAX_THREADS));
    seed -> u64 = |o| count(o, "seed", 0, u128::from(u64::MAX)).map(|v| v as u64);
    max_nn -> usize = |o| usize_in(o, "max_nn", 0, usize::MAX);
    min_neighbours -> usize = |o| usize_in(o, "min_neighbours", 0, usize::MAX);
    top_k -> usize = |o| usize_in(o, "top_k", 0, usize::MAX);
    k -> usize = |o| usize_in(o, "k", 1, usize::MAX);
    rank -> usize = |o| usize_in(o, "rank", 0, usize::MAX);
    offset -> usize = |o| usize_in(o, "offset", 0, usize::MAX);
    max_poses -> usize = |o| usize_in(o, "max_poses", 1, 1_000_000);
    reference_stride -> usize = |o| usize_in(o, "reference_stride", 1, 1_000_000);
    diameter -> f64 = |o| real(o, "diameter");
    viewpoint -> Option<[f64; 3]> = |o| optional(o, |o| point(o, "viewpoint"));
    n_samples -> Option<usize> = |o| optional(o, |o| usize_in(o, "n_samples", 0, usize::MAX));
    n_clusters -> Option<usize> = |o| optional(o, |o| usize_in(o, "n_clusters", 1, usize::MAX));
    max_clusters -> Option<usize> = |o| optional(o, |o| usize_in(o, "max_clusters", 1, usize::MAX));
    restarts -> usize =
        |o| usize_in(o, "restarts", 1, pointclm::config::bounds::KMEANS_RESTARTS);
    sigma_d -> f64 = |o| real(o, "sigma_d");
    radius -> f64 = |o| real(o, "radius");
    voxel_size -> f64 = |o| real(o, "voxel_size");
    icp -> bool = |o| flag(o, "icp");
    mutual -> bool = |o| flag(o, "mutual");
    assignment -> String = |o| text(o, "assignment");
    variant -> String = |o| text(o, "variant");
    towards -> Option<[f64; 3]> = |o| optional(o, |o| point(o, "towards"));
    eye -> [f64; 3] = |o| point(o, "eye");
    away_from -> Option<[f64; 3]> = |o| optional(o, |o| point(o, "away_from"));
    optional_voxel_size -> Option<f64> = |o| optional(o, |o| real(o, "voxel_size"));
    normal_radius -> Option<f64> = |o| optional(o, |o| real(o, "normal_radius"));
    feature_radius -> Option<f64> = |o| optional(o, |o| real(o, "feature_radius"));
    normal_max_nn -> usize = |o| usize_in(o, "normal_max_nn", 0, usize::MAX);
    feature_max_nn -> usize = |o| usize_in(o, "feature_max_nn", 0, usize::MAX);
    path -> std::path::PathBuf = |o| o.extract().map_err(|_| {
        InputError::new_err(format!("path must be a str or os.PathLike, got {}", repr(o)))
    });
}

/// Array converters named after the arguments they read.
macro_rules! array_converters {
    ($($arg:ident: $conv:ident -> $ty:ident;)*) => {
        $(
            pub fn $arg<'py>(obj: &Bound<'py, PyAny>) -> PyResult<$ty<'py, f64>> {
                $conv(obj, stringify!($arg))
            }
        )*
    };
}

array_converters! {
    correspondences: matrix -> PyReadonlyArray2;
    points: matrix -> PyReadonlyArray2;
    normals: matrix -> PyReadonlyArray2;
    eyes: matrix -> PyReadonlyArray2;
    source: matrix -> PyReadonlyArray2;
    target: matrix -> PyReadonlyArray2;
    reference: matrix -> PyReadonlyArray2;
    queries: matrix -> PyReadonlyArray2;
    affinity: matrix -> PyReadonlyArray2;
    transformations: tensor3 -> PyReadonlyArray3;
}

/// A 1-D array (or sequence) of non-negative ints: rows of a cloud.
pub fn rows(obj: &Bound<'_, PyAny>) -> PyResult<Vec<usize>> {
    let py = obj.py();
    let np = py.import("numpy")?;
    let bad = |why: String| InputError::new_err(format!("rows must be a 1-D array of ints, {why}"));
    let a = np
        .call_method1("asarray", (obj,))
        .map_err(|e| bad(format!("could not be read: {e}")))?;
    let kind: String = a.getattr("dtype")?.getattr("kind")?.extract()?;
    let dims: usize = a.getattr("ndim")?.extract()?;
    let empty = a.getattr("size")?.extract::<usize>()? == 0;
    if dims != 1 || !(["i", "u"].contains(&kind.as_str()) || empty) {
        return Err(bad(format!(
            "got dtype {} and shape {}",
            a.getattr("dtype")?,
            a.getattr("shape")?
        )));
    }
    let kwargs = PyDict::new(py);
    kwargs.set_item("dtype", np.getattr("int64")?)?;
    let a = np.call_method("asarray", (a,), Some(&kwargs))?;
    let a = a.cast_into::<PyArray1<i64>>()?.readonly();
    a.as_array()
        .iter()
        .map(|&v| usize::try_from(v).map_err(|_| bad(format!("got the negative row {v}"))))
        .collect()
}

pub fn optional_normals<'py>(
    obj: &Bound<'py, PyAny>,
) -> PyResult<Option<PyReadonlyArray2<'py, f64>>> {
    optional(obj, |o| matrix(o, "normals"))
}

pub fn optional_similarity<'py>(
    obj: &Bound<'py, PyAny>,
) -> PyResult<Option<PyReadonlyArray1<'py, f64>>> {
    optional(obj, |o| vector(o, "similarity"))
}

pub fn optional_target_normals<'py>(
    obj: &Bound<'py, PyAny>,
) -> PyResult<Option<PyReadonlyArray2<'py, f64>>> {
    optional(obj, |o| matrix(o, "target_normals"))
}

pub fn features<'py>(obj: &Bound<'py, PyAny>) -> PyResult<Option<PyReadonlyArray2<'py, f64>>> {
    optional(obj, |o| matrix(o, "features"))
}

/// `matrix` is also a function name above; the eigh argument is read by this one.
pub fn matrix_arg<'py>(obj: &Bound<'py, PyAny>) -> PyResult<PyReadonlyArray2<'py, f64>> {
    matrix(obj, "matrix")
}

pub fn config<'py>(obj: &Bound<'py, PyAny>) -> PyResult<Option<Bound<'py, PyDict>>> {
    optional(obj, |o| {
        o.cast::<PyDict>().cloned().map_err(|_| {
            ConfigError::new_err(format!("config must be a dict or None, got {}", repr(o)))
        })
    })
}

pub fn scenes<'py>(obj: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyList>> {
    obj.cast::<PyList>()
        .cloned()
        .map_err(|_| InputError::new_err(format!("scenes must be a list, got {}", repr(obj))))
}
