//! Point cloud processing and descriptor matching: voxel downsampling, normals, FPFH, and
//! descriptor matches (the inputs `register` needs when the user has clouds, not matches).

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray2};
use pointclm::pointcloud::{self, FpfhVariant, Orientation, PointIndex};
use pointclm::{Features, MatchingConfig};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use rayon::prelude::*;

use crate::convert::{indices, points as rows3};
use crate::{guarded, on_pool, pool};

fn rows_to_py<'py, const K: usize>(
    py: Python<'py>,
    rows: &[[f64; K]],
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let flat: Vec<f64> = rows.iter().flat_map(|r| r.iter().copied()).collect();
    Array2::from_shape_vec((rows.len(), K), flat)
        .map(|a| a.into_pyarray(py))
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

fn descriptors(a: &PyReadonlyArray2<'_, f64>, what: &str) -> PyResult<Features> {
    let v = a.as_array();
    Features::new(v.iter().copied().collect(), v.ncols())
        .map_err(|e| PyValueError::new_err(format!("{what}: {e}")))
}

/// Centroid of each occupied voxel, ordered by voxel index.
#[pyfunction]
pub fn voxel_downsample<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    voxel_size: f64,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let p = rows3(&points, "points")?;
    let out = guarded(py, move || pointcloud::voxel_downsample(&p, voxel_size))?;
    rows_to_py(py, &out)
}

/// PCA normals over hybrid neighbourhoods, signed towards `towards` or away from
/// `away_from` (exactly one of the two).
#[pyfunction]
#[pyo3(signature = (points, radius, max_nn=30, towards=None, away_from=None, num_threads=None))]
pub fn estimate_normals<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    radius: f64,
    max_nn: usize,
    towards: Option<[f64; 3]>,
    away_from: Option<[f64; 3]>,
    num_threads: Option<usize>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let orientation = match (towards, away_from) {
        (Some(v), None) => Orientation::Towards(v),
        (None, Some(v)) => Orientation::AwayFrom(v),
        _ => {
            return Err(PyValueError::new_err(
                "give exactly one of towards= (a viewpoint) or away_from= (an inner point)",
            ))
        }
    };
    let p = rows3(&points, "points")?;
    let threads = num_threads.map(pool).transpose()?;
    let out = guarded(py, move || {
        on_pool(threads, || {
            let index = PointIndex::new(&p)?;
            pointcloud::estimate_normals(&p, &index, radius, max_nn, orientation)
        })
    })?;
    rows_to_py(py, &out)
}

/// FPFH descriptors (N, 33) over hybrid neighbourhoods (at most `max_nn` within `radius`).
#[pyfunction]
#[pyo3(signature = (points, normals, radius, max_nn=100, variant="open3d", num_threads=None))]
pub fn compute_fpfh<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    normals: PyReadonlyArray2<'py, f64>,
    radius: f64,
    max_nn: usize,
    variant: &str,
    num_threads: Option<usize>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let variant = match variant {
        "open3d" => FpfhVariant::Open3d,
        "pcl" => FpfhVariant::Pcl,
        other => {
            return Err(PyValueError::new_err(format!(
                "variant must be 'open3d' or 'pcl', got {other:?}"
            )))
        }
    };
    let p = rows3(&points, "points")?;
    let n = rows3(&normals, "normals")?;
    let threads = num_threads.map(pool).transpose()?;
    let out = guarded(py, move || {
        on_pool(threads, || {
            let index = PointIndex::new(&p)?;
            pointcloud::fpfh(&p, &n, &index, radius, max_nn, variant)
        })
    })?;
    rows_to_py(py, &out)
}

type MatchArrays<'py> = (
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<f64>>,
);

/// Each target descriptor's nearest source descriptor; the `top_k` closest kept (mutual
/// only, if asked), then `n_samples` drawn with `seed`. Returns (source rows, target rows,
/// descriptor distances), closest first.
#[pyfunction]
#[pyo3(signature = (source, target, top_k=10_000, mutual=false, n_samples=Some(1000), seed=0, num_threads=None))]
#[allow(clippy::too_many_arguments)]
pub fn match_features<'py>(
    py: Python<'py>,
    source: PyReadonlyArray2<'py, f64>,
    target: PyReadonlyArray2<'py, f64>,
    top_k: usize,
    mutual: bool,
    n_samples: Option<usize>,
    seed: u64,
    num_threads: Option<usize>,
) -> PyResult<MatchArrays<'py>> {
    let s = descriptors(&source, "source descriptors")?;
    let t = descriptors(&target, "target descriptors")?;
    let cfg = MatchingConfig {
        top_k,
        mutual,
        n_samples,
    };
    let threads = num_threads.map(pool).transpose()?;
    let m = guarded(py, move || {
        on_pool(threads, || pointclm::match_features(&s, &t, &cfg, seed))
    })?;
    Ok((
        indices(py, &m.source),
        indices(py, &m.target),
        m.distance.into_pyarray(py),
    ))
}

type NearestArrays<'py> = (Bound<'py, PyArray1<i64>>, Bound<'py, PyArray1<f64>>);

/// For each query point, its nearest point of `reference`: (indices, distances).
#[pyfunction]
#[pyo3(signature = (reference, queries, num_threads=None))]
pub fn nearest_neighbours<'py>(
    py: Python<'py>,
    reference: PyReadonlyArray2<'py, f64>,
    queries: PyReadonlyArray2<'py, f64>,
    num_threads: Option<usize>,
) -> PyResult<NearestArrays<'py>> {
    let r = rows3(&reference, "reference points")?;
    let q = rows3(&queries, "query points")?;
    let threads = num_threads.map(pool).transpose()?;
    let (idx, dist) = guarded(py, move || {
        on_pool(threads, || {
            let index = PointIndex::new(&r)?;
            if let Some(row) = q.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
                return Err(pointclm::Error::NonFinite {
                    what: "query points",
                    row,
                });
            }
            let found: Vec<(usize, f64)> = q.par_iter().map(|p| index.nearest(p)).collect();
            Ok(found
                .into_iter()
                .map(|(i, d2)| (i, d2.sqrt()))
                .unzip::<_, _, Vec<_>, Vec<_>>())
        })
    })?;
    Ok((indices(py, &idx), dist.into_pyarray(py)))
}
