//! A model's proper symmetries (`pointclm::symmetry`): the group declared ones generate, the
//! ones detected on a model, and canonical poses. A symmetry crosses the boundary as a dict
//! `{"discrete": (S, 4, 4), "axes": (A, 3), "offsets": (A, 3)}` (the Python module
//! `pointclm.symmetry` reads BOP's form into it).

use nalgebra::Vector3;
use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray3, PyReadonlyArray2, PyReadonlyArray3};
use pointclm::kabsch::RigidTransform;
use pointclm::symmetry::{self, Axis, ModelSymmetry, Symmetry};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::args;
use crate::convert::points as rows3;
use crate::errors::{to_py_err, InputError};
use crate::pointcloud::rigid_poses;
use crate::pools::{guarded, pool};

/// The (S, 4, 4) transforms as rows of homogeneous matrices, checked for shape only (the core
/// checks the rest).
fn matrices(a: &PyReadonlyArray3<'_, f64>) -> PyResult<Vec<[[f64; 4]; 4]>> {
    let v = a.as_array();
    if v.shape()[1..] != [4, 4] {
        return Err(InputError::new_err(format!(
            "symmetries_discrete must be 4 x 4 transforms, got shape {:?}",
            v.shape()
        )));
    }
    Ok((0..v.shape()[0])
        .map(|k| std::array::from_fn(|i| std::array::from_fn(|j| v[[k, i, j]])))
        .collect())
}

/// The axes from `(A, 3)` directions and offsets.
fn axes(
    directions: &PyReadonlyArray2<'_, f64>,
    offsets: &PyReadonlyArray2<'_, f64>,
) -> PyResult<Vec<Axis>> {
    let (d, o) = (directions.as_array(), offsets.as_array());
    if d.ncols() != 3 || o.ncols() != 3 || d.nrows() != o.nrows() {
        return Err(InputError::new_err(format!(
            "symmetries_continuous: axes and offsets must both be (A, 3), got {:?} and {:?}",
            d.shape(),
            o.shape()
        )));
    }
    Ok((0..d.nrows())
        .map(|k| Axis {
            direction: Vector3::new(d[[k, 0]], d[[k, 1]], d[[k, 2]]),
            offset: Vector3::new(o[[k, 0]], o[[k, 1]], o[[k, 2]]),
        })
        .collect())
}

/// The symmetry a dict of this module's form declares.
fn declared(d: &Bound<'_, PyDict>) -> PyResult<Symmetry> {
    let item = |key: &str| {
        d.get_item(key)?
            .ok_or_else(|| InputError::new_err(format!("a symmetry dict needs the key {key:?}")))
    };
    let discrete: PyReadonlyArray3<'_, f64> = args::tensor3(&item("discrete")?, "discrete")?;
    let directions = args::matrix(&item("axes")?, "axes")?;
    let offsets = args::matrix(&item("offsets")?, "offsets")?;
    Symmetry::from_matrices(&matrices(&discrete)?, &axes(&directions, &offsets)?).map_err(to_py_err)
}

/// `"auto"` or a symmetry dict, as `register_scan` takes it.
pub fn model_symmetry(obj: Option<&Bound<'_, PyAny>>) -> PyResult<Option<ModelSymmetry>> {
    let Some(obj) = obj.filter(|o| !o.is_none()) else {
        return Ok(None);
    };
    if let Ok(s) = obj.extract::<String>() {
        if s == "auto" {
            return Ok(Some(ModelSymmetry::Detect));
        }
        return Err(InputError::new_err(format!(
            "symmetry must be \"auto\", a symmetry dict or None, got {s:?}"
        )));
    }
    let d = obj
        .cast::<PyDict>()
        .map_err(|_| InputError::new_err("symmetry must be \"auto\", a symmetry dict or None"))?;
    Ok(Some(ModelSymmetry::Declared(declared(d)?)))
}

/// A symmetry as a dict of this module's form (the whole discrete group, identity first).
pub fn symmetry_dict<'py>(py: Python<'py>, s: &Symmetry) -> PyResult<Bound<'py, PyDict>> {
    let g = s.discrete();
    let mats: Vec<[[f64; 4]; 4]> = g.iter().map(|t| t.to_matrix()).collect();
    let discrete = Array3::from_shape_fn((mats.len(), 4, 4), |(k, i, j)| mats[k][i][j]);
    let c = s.continuous();
    let directions = Array2::from_shape_fn((c.len(), 3), |(k, i)| c[k].direction[i]);
    let offsets = Array2::from_shape_fn((c.len(), 3), |(k, i)| c[k].offset[i]);
    let d = PyDict::new(py);
    d.set_item("discrete", discrete.into_pyarray(py))?;
    d.set_item("axes", directions.into_pyarray(py))?;
    d.set_item("offsets", offsets.into_pyarray(py))?;
    Ok(d)
}

/// The group declared symmetries generate, checked (`Symmetry::from_matrices`).
#[pyfunction]
pub fn symmetry_group<'py>(
    py: Python<'py>,
    discrete: PyReadonlyArray3<'py, f64>,
    axes: PyReadonlyArray2<'py, f64>,
    offsets: PyReadonlyArray2<'py, f64>,
) -> PyResult<Bound<'py, PyDict>> {
    let s = Symmetry::from_matrices(&matrices(&discrete)?, &self::axes(&axes, &offsets)?)
        .map_err(to_py_err)?;
    symmetry_dict(py, &s)
}

/// The proper symmetries of a model (`detect_symmetries`), at `tolerance` (None: the
/// model's `default_tolerance`); the dict also holds the tolerance used.
#[pyfunction]
#[pyo3(signature = (points, tolerance=None, num_threads=None))]
pub fn detect_symmetries<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'py, f64>,
    tolerance: Option<f64>,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let p = rows3(&points, "points")?;
    let threads = num_threads.map(pool).transpose()?;
    let (s, tol) = guarded(py, threads, move || {
        let tol = match tolerance {
            Some(t) => t,
            None => symmetry::default_tolerance(&p)?,
        };
        Ok((symmetry::detect_symmetries(&p, tol)?, tol))
    })?;
    let d = symmetry_dict(py, &s)?;
    d.set_item("tolerance", tol)?;
    Ok(d)
}

/// Each pose's canonical representative among its equivalents (`canonical_pose`).
#[pyfunction]
pub fn canonical_poses<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::transformations)] transformations: PyReadonlyArray3<'py, f64>,
    symmetry: Bound<'py, PyDict>,
) -> PyResult<Bound<'py, PyArray3<f64>>> {
    let s = declared(&symmetry)?;
    let poses: Vec<RigidTransform> = rigid_poses(&transformations)?;
    let mats: Vec<[[f64; 4]; 4]> = poses
        .iter()
        .map(|p| symmetry::canonical_pose(p, &s).to_matrix())
        .collect();
    Ok(Array3::from_shape_fn((mats.len(), 4, 4), |(k, i, j)| mats[k][i][j]).into_pyarray(py))
}

/// The symmetry `symmetry` (`"auto"` or a symmetry dict) stands for on a model
/// (`ModelSymmetry::resolve`): detected on `described` (the model downsampled), or declared
/// and checked against `model`'s centroid (other units fail).
#[pyfunction]
#[pyo3(signature = (model, described, symmetry, num_threads=None))]
pub fn resolve_model_symmetry<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::source)] model: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::points)] described: PyReadonlyArray2<'py, f64>,
    symmetry: Bound<'py, PyAny>,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let m = rows3(&model, "model")?;
    let d = rows3(&described, "described")?;
    let Some(spec) = model_symmetry(Some(&symmetry))? else {
        return Err(InputError::new_err("symmetry must not be None here"));
    };
    let threads = num_threads.map(pool).transpose()?;
    let s = guarded(py, threads, move || spec.resolve(&m, &d))?;
    symmetry_dict(py, &s)
}
