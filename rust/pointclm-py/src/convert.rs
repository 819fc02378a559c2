//! numpy <-> core conversions. The Python layer has already coerced inputs to C-contiguous
//! float64; these still check shapes so that a direct `_core` caller gets an InputError too.

use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArray1, PyReadonlyArray2};
use pointclm::correspondences::DEFAULT_NORMAL_TOLERANCE;
use pointclm::{Correspondences, Features};
use pyo3::prelude::*;

use crate::errors::{to_py_err, InputError};

/// (N, 6) rows (source xyz | target xyz), or (N, 12) rows that add the unit normals at both
/// ends (| source normal | target normal), which switch on the normal term of spatial
/// consistency (`Correspondences::with_normals`, default tolerance).
pub fn correspondences(a: &PyReadonlyArray2<'_, f64>) -> PyResult<Correspondences> {
    let v = a.as_array();
    if v.ncols() != 6 && v.ncols() != 12 {
        return Err(InputError::new_err(format!(
            "correspondences must have shape (N, 6) = (source xyz | target xyz), or (N, 12) with \
             the normals at both ends (| source normal | target normal), got {:?}",
            v.shape()
        )));
    }
    let column = |c: usize| -> Vec<[f64; 3]> {
        v.rows()
            .into_iter()
            .map(|r| [r[c], r[c + 1], r[c + 2]])
            .collect()
    };
    let c = Correspondences::new(&column(0), &column(3)).map_err(to_py_err)?;
    if v.ncols() == 6 {
        return Ok(c);
    }
    with_pair_normals(c, &column(6), &column(9), DEFAULT_NORMAL_TOLERANCE)
}

/// `c` with the normals `ns` (source ends) and `nt` (target ends), non-finite ones named as
/// `normals` (the argument they came from).
fn with_pair_normals(
    c: Correspondences,
    ns: &[[f64; 3]],
    nt: &[[f64; 3]],
    tolerance: f64,
) -> PyResult<Correspondences> {
    if let Some(row) = ns
        .iter()
        .chain(nt)
        .position(|n| !n.iter().all(|x| x.is_finite()))
    {
        return Err(to_py_err(pointclm::Error::NonFinite {
            what: "normals",
            row: row % ns.len().max(1),
        }));
    }
    c.with_normals(ns, nt, tolerance).map_err(to_py_err)
}

/// `c` with the inputs of `Network.embed` beyond the coordinates: `normals` (N, 6) = (source
/// normal | target normal), with `tolerance` (the network's, which its `beta` uses anyway),
/// and `similarity` (N,).
pub fn network_inputs(
    c: Correspondences,
    normals: Option<&PyReadonlyArray2<'_, f64>>,
    similarity: Option<&PyReadonlyArray1<'_, f64>>,
    tolerance: f64,
) -> PyResult<Correspondences> {
    let n = c.len();
    let mut c = c;
    if let Some(a) = normals {
        let v = a.as_array();
        if v.shape() != [n, 6] {
            return Err(InputError::new_err(format!(
                "normals must have shape (N, 6) = (source normal | target normal) with N = {n} \
                 correspondences, got {:?}",
                v.shape()
            )));
        }
        if c.has_normals() {
            return Err(InputError::new_err(
                "pass the normals either as columns 7-12 of correspondences or as normals=, \
                 not both",
            ));
        }
        let side = |k: usize| -> Vec<[f64; 3]> {
            v.rows()
                .into_iter()
                .map(|r| [r[k], r[k + 1], r[k + 2]])
                .collect()
        };
        c = with_pair_normals(c, &side(0), &side(3), tolerance)?;
    }
    if let Some(a) = similarity {
        let v = a.as_array();
        if v.len() != n {
            return Err(InputError::new_err(format!(
                "similarity must have shape (N,) = one value per correspondence with N = {n}, \
                 got {:?}",
                v.shape()
            )));
        }
        c = c
            .with_similarity(&v.iter().copied().collect::<Vec<_>>())
            .map_err(to_py_err)?;
    }
    Ok(c)
}

pub fn features(a: Option<&PyReadonlyArray2<'_, f64>>) -> PyResult<Option<Features>> {
    a.map(|a| {
        let v = a.as_array();
        let dim = v.ncols();
        Features::new(v.iter().copied().collect(), dim).map_err(to_py_err)
    })
    .transpose()
}

pub fn points(a: &PyReadonlyArray2<'_, f64>, what: &str) -> PyResult<Vec<[f64; 3]>> {
    let v = a.as_array();
    if v.ncols() != 3 {
        return Err(InputError::new_err(format!(
            "{what} must have shape (N, 3), got {:?}",
            v.shape()
        )));
    }
    Ok(v.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect())
}

pub fn square(a: &PyReadonlyArray2<'_, f64>) -> PyResult<faer::Mat<f64>> {
    let v = a.as_array();
    let (r, c) = v.dim();
    if r != c {
        return Err(InputError::new_err(format!(
            "expected a square matrix, got shape ({r}, {c})"
        )));
    }
    Ok(faer::Mat::from_fn(r, c, |i, j| v[(i, j)]))
}

pub fn mat_to_py<'py>(py: Python<'py>, m: faer::MatRef<'_, f64>) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_fn((m.nrows(), m.ncols()), |(i, j)| m[(i, j)]).into_pyarray(py)
}

pub fn matrix4<'py>(py: Python<'py>, m: &[[f64; 4]; 4]) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_fn((4, 4), |(i, j)| m[i][j]).into_pyarray(py)
}

/// A stack of 4x4 matrices as an `(M, 4, 4)` array.
pub fn matrices4<'py>(py: Python<'py>, m: &[[[f64; 4]; 4]]) -> Bound<'py, PyArray3<f64>> {
    Array3::from_shape_fn((m.len(), 4, 4), |(k, i, j)| m[k][i][j]).into_pyarray(py)
}

pub fn indices<'py>(py: Python<'py>, v: &[usize]) -> Bound<'py, PyArray1<i64>> {
    v.iter()
        .map(|&i| i as i64)
        .collect::<Vec<_>>()
        .into_pyarray(py)
}
