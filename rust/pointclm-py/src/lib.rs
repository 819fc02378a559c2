//! `pointclm._core`: the thin PyO3 layer over the `pointclm` crate. Conversions, GIL release,
//! error mapping and result classes live here; all the method lives in the core crate.

mod config;
mod convert;
mod network;
mod pointcloud;
mod result;

use std::collections::HashMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::{Arc, Mutex, OnceLock};

use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray2};
use pointclm::{Correspondences, Scene};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use convert::{correspondences, features, mat_to_py, matrix4, points, square, to_py_err};
use network::PyNetwork;
use result::{PyInstance, PyRegistration};

/// Runs core code with the GIL released and any panic turned into a Python exception, so a
/// bug can never abort the interpreter or escape `except Exception`.
fn guarded<T: Send>(py: Python<'_>, f: impl FnOnce() -> pointclm::Result<T> + Send) -> PyResult<T> {
    py.detach(|| catch_unwind(AssertUnwindSafe(f)))
        .map_err(|_| PyRuntimeError::new_err("internal error in pointclm (please report)"))?
        .map_err(to_py_err)
}

/// More threads than this is a mistake, not a configuration (each costs a stack and a
/// spawn, and a pool is kept per count).
const MAX_THREADS: usize = 256;

fn check_threads(num_threads: usize) -> PyResult<()> {
    if !(1..=MAX_THREADS).contains(&num_threads) {
        return Err(PyValueError::new_err(format!(
            "num_threads must lie in 1..={MAX_THREADS} (or None for all cores), got {num_threads}"
        )));
    }
    Ok(())
}

/// Private pools, one per requested thread count, built once and reused.
fn pool(num_threads: usize) -> PyResult<Arc<rayon::ThreadPool>> {
    static POOLS: OnceLock<Mutex<HashMap<usize, Arc<rayon::ThreadPool>>>> = OnceLock::new();
    check_threads(num_threads)?;
    let mut pools = POOLS
        .get_or_init(Default::default)
        .lock()
        .map_err(|_| PyRuntimeError::new_err("thread pool cache poisoned"))?;
    if let Some(p) = pools.get(&num_threads) {
        return Ok(p.clone());
    }
    let p = Arc::new(pointclm::pipeline::thread_pool(num_threads).map_err(to_py_err)?);
    pools.insert(num_threads, p.clone());
    Ok(p)
}

/// Runs `f` on the pool for `num_threads`, or on the current (global) pool when `None`.
fn on_pool<T: Send>(pool: Option<Arc<rayon::ThreadPool>>, f: impl FnOnce() -> T + Send) -> T {
    match pool {
        None => f(),
        Some(p) => p.install(f),
    }
}

#[pyfunction]
#[pyo3(signature = (correspondences, features=None, config=None, seed=0, num_threads=None, network=None))]
fn register(
    py: Python<'_>,
    correspondences: PyReadonlyArray2<'_, f64>,
    features: Option<PyReadonlyArray2<'_, f64>>,
    config: Option<&Bound<'_, PyDict>>,
    seed: u64,
    num_threads: Option<usize>,
    network: Option<&Bound<'_, PyNetwork>>,
) -> PyResult<PyRegistration> {
    let c = convert::correspondences(&correspondences)?;
    let f = convert::features(features.as_ref())?;
    let cfg = config::from_dict(config)?;
    let p = num_threads.map(pool).transpose()?;
    let net = network.map(|n| n.get().inner.clone());
    if net.is_some() && f.is_some() {
        return Err(PyValueError::new_err(
            "pass either features or network, not both",
        ));
    }
    let r = guarded(py, move || {
        on_pool(p, || match net {
            Some(net) => pointclm::register_with_network(&c, &net, &cfg, seed),
            None => pointclm::register(&c, f.as_ref(), &cfg, seed),
        })
    })?;
    PyRegistration::new(py, r)
}

#[pyfunction]
#[pyo3(signature = (scenes, config=None, seed=0, num_threads=None, network=None))]
fn register_batch(
    py: Python<'_>,
    scenes: &Bound<'_, PyList>,
    config: Option<&Bound<'_, PyDict>>,
    seed: u64,
    num_threads: Option<usize>,
    network: Option<&Bound<'_, PyNetwork>>,
) -> PyResult<Vec<PyRegistration>> {
    let cfg = config::from_dict(config)?;
    let mut batch = Vec::with_capacity(scenes.len());
    for (k, item) in scenes.iter().enumerate() {
        let (corr, feats): (PyReadonlyArray2<'_, f64>, Option<PyReadonlyArray2<'_, f64>>) =
            item.extract().map_err(|e| {
                PyValueError::new_err(format!(
                    "scene {k}: expected (correspondences, features): {e}"
                ))
            })?;
        let at = |e: PyErr| PyValueError::new_err(format!("scene {k}: {e}"));
        let features = features(feats.as_ref()).map_err(at)?;
        if network.is_some() && features.is_some() {
            return Err(PyValueError::new_err(format!(
                "scene {k}: pass either features or network, not both"
            )));
        }
        batch.push(Scene {
            correspondences: correspondences(&corr).map_err(at)?,
            features,
        });
    }
    if let Some(n) = num_threads {
        check_threads(n)?;
    }
    let threads = num_threads.unwrap_or(0);
    let net = network.map(|n| n.get().inner.clone());
    let results = guarded(py, move || match net {
        Some(net) => {
            let corr: Vec<Correspondences> = batch.into_iter().map(|s| s.correspondences).collect();
            pointclm::register_batch_with_network(&corr, &net, &cfg, seed, threads)
        }
        None => pointclm::register_batch(&batch, &cfg, seed, threads),
    })?;
    results
        .into_iter()
        .enumerate()
        .map(|(k, r)| {
            let r = r.map_err(|e| PyValueError::new_err(format!("scene {k}: {e}")))?;
            PyRegistration::new(py, r)
        })
        .collect()
}

/// Dense spatial consistency `beta` (N x N) for inspection of small inputs.
#[pyfunction]
fn spatial_consistency<'py>(
    py: Python<'py>,
    correspondences: PyReadonlyArray2<'py, f64>,
    sigma_d: f64,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let c = convert::correspondences(&correspondences)?;
    let n = c.len();
    let m = guarded(py, move || {
        pointclm::consistency::spatial_consistency(&c, sigma_d)
    })?;
    let a = numpy::ndarray::Array2::from_shape_vec((n, n), m)
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    Ok(a.into_pyarray(py))
}

/// Per-row density counts under the configured pruning rule (blocked, parallel).
#[pyfunction]
#[pyo3(signature = (correspondences, features=None, config=None, num_threads=None))]
fn density_counts<'py>(
    py: Python<'py>,
    correspondences: PyReadonlyArray2<'py, f64>,
    features: Option<PyReadonlyArray2<'py, f64>>,
    config: Option<&Bound<'py, PyDict>>,
    num_threads: Option<usize>,
) -> PyResult<Bound<'py, PyArray1<i64>>> {
    let c = convert::correspondences(&correspondences)?;
    let f = convert::features(features.as_ref())?;
    let cfg = config::from_dict(config)?;
    let p = num_threads.map(pool).transpose()?;
    let counts = guarded(py, move || {
        on_pool(p, || {
            pointclm::pruning::density_counts(&c, f.as_ref(), &cfg)
        })
    })?;
    Ok(counts
        .into_iter()
        .map(i64::from)
        .collect::<Vec<_>>()
        .into_pyarray(py))
}

/// `L = I - D^-1/2 A D^-1/2` of a symmetric non-negative affinity.
#[pyfunction]
fn normalized_laplacian<'py>(
    py: Python<'py>,
    affinity: PyReadonlyArray2<'py, f64>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let a = square(&affinity)?;
    let l = guarded(py, move || {
        pointclm::spectral::normalized_laplacian(a.as_ref())
    })?;
    Ok(mat_to_py(py, l.as_ref()))
}

type Eigenpairs<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray2<f64>>);

/// Eigenvalues (ascending) and eigenvectors (columns) of a symmetric matrix, via faer.
#[pyfunction]
fn eigh<'py>(py: Python<'py>, matrix: PyReadonlyArray2<'py, f64>) -> PyResult<Eigenpairs<'py>> {
    let m = square(&matrix)?;
    let (vals, vecs) = guarded(py, move || {
        pointclm::spectral::symmetric_eigen(m.as_ref(), true)
    })?;
    let vecs = vecs.ok_or_else(|| PyRuntimeError::new_err("eigenvectors missing"))?;
    Ok((vals.into_pyarray(py), mat_to_py(py, vecs.as_ref())))
}

/// Spectral clustering of a precomputed affinity; returns (labels, n_clusters, eigenvalues).
#[pyfunction]
#[pyo3(signature = (affinity, n_clusters=None, max_clusters=None, assignment="kmeans", restarts=10, seed=0))]
#[allow(clippy::type_complexity)]
fn spectral_clustering<'py>(
    py: Python<'py>,
    affinity: PyReadonlyArray2<'py, f64>,
    n_clusters: Option<usize>,
    max_clusters: Option<usize>,
    assignment: &str,
    restarts: usize,
    seed: u64,
) -> PyResult<(Bound<'py, PyArray1<i64>>, usize, Bound<'py, PyArray1<f64>>)> {
    let a = square(&affinity)?;
    let assign = config::assignment(assignment)?;
    if n_clusters == Some(0) || max_clusters == Some(0) || restarts == 0 {
        return Err(PyValueError::new_err(
            "n_clusters, max_clusters and restarts must be >= 1",
        ));
    }
    let r = guarded(py, move || {
        pointclm::clustering::spectral_clustering(
            a.as_ref(),
            n_clusters,
            max_clusters,
            assign,
            restarts,
            seed,
        )
    })?;
    let labels: Vec<i64> = r.labels.iter().map(|&l| l as i64).collect();
    Ok((
        labels.into_pyarray(py),
        r.n_clusters,
        r.eigenvalues.into_pyarray(py),
    ))
}

/// Least-squares rigid transform (4x4 `T_target_source`) mapping `source` rows onto `target`.
#[pyfunction]
fn kabsch<'py>(
    py: Python<'py>,
    source: PyReadonlyArray2<'py, f64>,
    target: PyReadonlyArray2<'py, f64>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let (s, t) = (points(&source, "source")?, points(&target, "target")?);
    let c = Correspondences::new(&s, &t).map_err(to_py_err)?;
    let idx: Vec<usize> = (0..c.len()).collect();
    let pose = pointclm::kabsch::kabsch(&c, &idx).ok_or_else(|| {
        PyValueError::new_err("points are collinear or coincident: no unique rotation")
    })?;
    Ok(matrix4(py, &pose.to_matrix()))
}

/// Raises ValueError naming the first invalid field of a config dict.
#[pyfunction]
fn validate_config(config: &Bound<'_, PyDict>) -> PyResult<()> {
    config::from_dict(Some(config)).map(|_| ())
}

/// The Rust defaults, so that the Python dataclass can be checked against them.
#[pyfunction]
fn default_config(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    config::defaults(py)
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<PyInstance>()?;
    m.add_class::<PyRegistration>()?;
    m.add_class::<PyNetwork>()?;
    m.add_function(wrap_pyfunction!(register, m)?)?;
    m.add_function(wrap_pyfunction!(register_batch, m)?)?;
    m.add_function(wrap_pyfunction!(spatial_consistency, m)?)?;
    m.add_function(wrap_pyfunction!(density_counts, m)?)?;
    m.add_function(wrap_pyfunction!(normalized_laplacian, m)?)?;
    m.add_function(wrap_pyfunction!(eigh, m)?)?;
    m.add_function(wrap_pyfunction!(spectral_clustering, m)?)?;
    m.add_function(wrap_pyfunction!(kabsch, m)?)?;
    m.add_function(wrap_pyfunction!(default_config, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::voxel_downsample, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::estimate_normals, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::compute_fpfh, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::match_features, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::nearest_neighbours, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::refine_poses, m)?)?;
    m.add_function(wrap_pyfunction!(validate_config, m)?)?;
    Ok(())
}
