//! `pointclm._core`: the thin PyO3 layer over the `pointclm` crate. Conversions, GIL release,
//! error mapping and result classes live here; all the method lives in the core crate.

mod args;
mod config;
mod convert;
mod errors;
mod network;
mod pointcloud;
mod pools;
mod result;
mod scene;
mod symmetry;

use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray2};
use pointclm::{Correspondences, Scene};
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use convert::{correspondences, features, mat_to_py, matrix4, points, square};
use errors::{prefixed, to_py_err, ConfigError, InputError};
use network::PyNetwork;
use pools::{guarded, guarded_dense, pool};
use result::{PyInstance, PyRegistration};

/// `network=`: None or a loaded `Network`.
fn network_arg<'py>(obj: &Bound<'py, PyAny>) -> PyResult<Option<Bound<'py, PyNetwork>>> {
    if obj.is_none() {
        return Ok(None);
    }
    obj.cast::<PyNetwork>()
        .map(|n| Some(n.clone()))
        .map_err(|_| InputError::new_err("network must be a pointclm.Network or None"))
}

#[pyfunction]
#[pyo3(signature = (correspondences, features=None, config=None, seed=0, num_threads=None, network=None))]
fn register(
    py: Python<'_>,
    #[pyo3(from_py_with = args::correspondences)] correspondences: PyReadonlyArray2<'_, f64>,
    #[pyo3(from_py_with = args::features)] features: Option<PyReadonlyArray2<'_, f64>>,
    #[pyo3(from_py_with = args::config)] config: Option<Bound<'_, PyDict>>,
    #[pyo3(from_py_with = args::seed)] seed: u64,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
    #[pyo3(from_py_with = network_arg)] network: Option<Bound<'_, PyNetwork>>,
) -> PyResult<PyRegistration> {
    let c = convert::correspondences(&correspondences)?;
    let f = convert::features(features.as_ref())?;
    let cfg = config::from_dict(config.as_ref())?;
    let p = num_threads.map(pool).transpose()?;
    let net = network.map(|n| n.get().inner.clone());
    if net.is_some() && f.is_some() {
        return Err(InputError::new_err(
            "pass either features or network, not both",
        ));
    }
    let r = guarded(py, p, move || match net {
        Some(net) => pointclm::register_with_network(&c, &net, &cfg, seed),
        None => pointclm::register(&c, f.as_ref(), &cfg, seed),
    })?;
    PyRegistration::new(py, r)
}

/// One item of `register_batch`'s list: `(correspondences, features or None)`.
fn scene_item(k: usize, item: &Bound<'_, PyAny>, with_network: bool) -> PyResult<Scene> {
    let at = |e: PyErr| prefixed(item.py(), e, &format!("scene {k}: "));
    let (corr, feats): (Bound<'_, PyAny>, Bound<'_, PyAny>) = item.extract().map_err(|_| {
        InputError::new_err(format!(
            "scene {k}: expected a (correspondences, features or None) pair"
        ))
    })?;
    let corr = args::correspondences(&corr).map_err(at)?;
    let feats = args::features(&feats).map_err(at)?;
    let features = features(feats.as_ref()).map_err(at)?;
    if with_network && features.is_some() {
        return Err(InputError::new_err(format!(
            "scene {k}: pass either features or network, not both"
        )));
    }
    Ok(Scene {
        correspondences: correspondences(&corr).map_err(at)?,
        features,
    })
}

#[pyfunction]
#[pyo3(signature = (scenes, config=None, seed=0, num_threads=None, network=None))]
fn register_batch(
    py: Python<'_>,
    #[pyo3(from_py_with = args::scenes)] scenes: Bound<'_, PyList>,
    #[pyo3(from_py_with = args::config)] config: Option<Bound<'_, PyDict>>,
    #[pyo3(from_py_with = args::seed)] seed: u64,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
    #[pyo3(from_py_with = network_arg)] network: Option<Bound<'_, PyNetwork>>,
) -> PyResult<Vec<PyRegistration>> {
    let cfg = config::from_dict(config.as_ref())?;
    let batch = scenes
        .iter()
        .enumerate()
        .map(|(k, item)| scene_item(k, &item, network.is_some()))
        .collect::<PyResult<Vec<_>>>()?;
    let threads = num_threads.unwrap_or(0);
    let net = network.map(|n| n.get().inner.clone());
    let results = guarded(py, None, move || match net {
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
            let r = r.map_err(|e| prefixed(py, to_py_err(e), &format!("scene {k}: ")))?;
            PyRegistration::new(py, r)
        })
        .collect()
}

/// Dense spatial consistency `beta` (N x N) for inspection of small inputs.
#[pyfunction]
fn spatial_consistency<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::correspondences)] correspondences: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::sigma_d)] sigma_d: f64,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let c = convert::correspondences(&correspondences)?;
    let n = c.len();
    let m = guarded_dense(py, "spatial_consistency", n, 1, move || {
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
    #[pyo3(from_py_with = args::correspondences)] correspondences: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::features)] features: Option<PyReadonlyArray2<'py, f64>>,
    #[pyo3(from_py_with = args::config)] config: Option<Bound<'py, PyDict>>,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
) -> PyResult<Bound<'py, PyArray1<i64>>> {
    let c = convert::correspondences(&correspondences)?;
    let f = convert::features(features.as_ref())?;
    let cfg = config::from_dict(config.as_ref())?;
    let p = num_threads.map(pool).transpose()?;
    let counts = guarded(py, p, move || {
        pointclm::pruning::density_counts(&c, f.as_ref(), &cfg)
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
    #[pyo3(from_py_with = args::affinity)] affinity: PyReadonlyArray2<'py, f64>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let a = square(&affinity)?;
    let n = a.nrows();
    let l = guarded_dense(py, "normalized_laplacian", n, 2, move || {
        pointclm::spectral::normalized_laplacian(a.as_ref())
    })?;
    Ok(mat_to_py(py, l.as_ref()))
}

type Eigenpairs<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray2<f64>>);

/// Eigenvalues (ascending) and eigenvectors (columns) of a symmetric matrix, via faer.
#[pyfunction]
fn eigh<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::matrix_arg)] matrix: PyReadonlyArray2<'py, f64>,
) -> PyResult<Eigenpairs<'py>> {
    let m = square(&matrix)?;
    let n = m.nrows();
    let (vals, vecs) = guarded_dense(py, "eigh", n, 4, move || {
        pointclm::spectral::symmetric_eigen(m.as_ref(), true)
    })?;
    let vecs = vecs.ok_or_else(|| PyRuntimeError::new_err("eigenvectors missing"))?;
    Ok((vals.into_pyarray(py), mat_to_py(py, vecs.as_ref())))
}

/// Spectral clustering of a precomputed affinity; returns (labels, n_clusters, eigenvalues).
#[pyfunction]
#[pyo3(
    signature = (affinity, n_clusters=None, max_clusters=None, assignment="kmeans".to_string(), restarts=10, seed=0),
    text_signature = "(affinity, n_clusters=None, max_clusters=None, assignment='kmeans', restarts=10, seed=0)"
)]
#[allow(clippy::type_complexity)]
fn spectral_clustering<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::affinity)] affinity: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::n_clusters)] n_clusters: Option<usize>,
    #[pyo3(from_py_with = args::max_clusters)] max_clusters: Option<usize>,
    #[pyo3(from_py_with = args::assignment)] assignment: String,
    #[pyo3(from_py_with = args::restarts)] restarts: usize,
    #[pyo3(from_py_with = args::seed)] seed: u64,
) -> PyResult<(Bound<'py, PyArray1<i64>>, usize, Bound<'py, PyArray1<f64>>)> {
    let a = square(&affinity)?;
    let n = a.nrows();
    let assign = config::assignment(&assignment, InputError::new_err)?;
    let r = guarded_dense(py, "spectral_clustering", n, 4, move || {
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
    #[pyo3(from_py_with = args::source)] source: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::target)] target: PyReadonlyArray2<'py, f64>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let (s, t) = (points(&source, "source")?, points(&target, "target")?);
    let c = Correspondences::new(&s, &t).map_err(to_py_err)?;
    let idx: Vec<usize> = (0..c.len()).collect();
    let pose = pointclm::kabsch::kabsch(&c, &idx).ok_or_else(|| {
        InputError::new_err("points are collinear or coincident: no unique rotation")
    })?;
    Ok(matrix4(py, &pose.to_matrix()))
}

/// Raises ConfigError (a ValueError) naming the first invalid field of a config dict.
#[pyfunction]
fn validate_config(
    #[pyo3(from_py_with = args::config)] config: Option<Bound<'_, PyDict>>,
) -> PyResult<()> {
    let config = config.ok_or_else(|| ConfigError::new_err("config must be a dict"))?;
    config::from_dict(Some(&config)).map(|_| ())
}

/// The Rust defaults, so that the Python dataclass can be checked against them.
#[pyfunction]
fn default_config(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    config::defaults(py)
}

/// Every field of the core's `Config`, in order: name, kind, choices, optional, default,
/// length, doc. The Python `Config` takes its defaults, checks and lengths from it.
#[pyfunction]
fn config_schema(py: Python<'_>) -> PyResult<Bound<'_, PyList>> {
    config::schema(py)
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add(
        "MAX_ROTATION_DEVIATION",
        pointclm::pointcloud::MAX_ROTATION_DEVIATION,
    )?;
    m.add_class::<PyInstance>()?;
    m.add_class::<PyRegistration>()?;
    m.add_class::<PyNetwork>()?;
    m.add_class::<pointcloud::PyRefineContext>()?;
    m.add_class::<pointcloud::PyPpfModel>()?;
    m.add_function(wrap_pyfunction!(register, m)?)?;
    m.add_function(wrap_pyfunction!(register_batch, m)?)?;
    m.add_function(wrap_pyfunction!(spatial_consistency, m)?)?;
    m.add_function(wrap_pyfunction!(density_counts, m)?)?;
    m.add_function(wrap_pyfunction!(normalized_laplacian, m)?)?;
    m.add_function(wrap_pyfunction!(eigh, m)?)?;
    m.add_function(wrap_pyfunction!(spectral_clustering, m)?)?;
    m.add_function(wrap_pyfunction!(kabsch, m)?)?;
    m.add_function(wrap_pyfunction!(default_config, m)?)?;
    m.add_function(wrap_pyfunction!(config_schema, m)?)?;
    m.add_function(wrap_pyfunction!(scene::scene_rules_schema, m)?)?;
    m.add_function(wrap_pyfunction!(scene::refine_params_schema, m)?)?;
    m.add_function(wrap_pyfunction!(scene::validate_scene_rules, m)?)?;
    m.add_function(wrap_pyfunction!(scene::unexplained_points, m)?)?;
    m.add_function(wrap_pyfunction!(scene::loose_poses, m)?)?;
    m.add_function(wrap_pyfunction!(scene::fit_tightness, m)?)?;
    m.add_function(wrap_pyfunction!(scene::stability_factor, m)?)?;
    m.add_function(wrap_pyfunction!(scene::register_scan, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::learned_descriptors, m)?)?;
    m.add_function(wrap_pyfunction!(scene::judge_jointly, m)?)?;
    m.add_function(wrap_pyfunction!(symmetry::symmetry_group, m)?)?;
    m.add_function(wrap_pyfunction!(symmetry::detect_symmetries, m)?)?;
    m.add_function(wrap_pyfunction!(symmetry::canonical_poses, m)?)?;
    m.add_function(wrap_pyfunction!(symmetry::resolve_model_symmetry, m)?)?;
    m.add_function(wrap_pyfunction!(scene::flip_turns, m)?)?;
    m.add_function(wrap_pyfunction!(scene::quarter_turns, m)?)?;
    m.add_function(wrap_pyfunction!(scene::bounding_diagonal, m)?)?;
    m.add_function(wrap_pyfunction!(scene::cloud_base_config, m)?)?;
    m.add_function(wrap_pyfunction!(scene::scan_scales, m)?)?;
    m.add("SIGMA_D_VOXELS", pointclm::scene::SIGMA_D_VOXELS)?;
    m.add("INLIER_VOXELS", pointclm::scene::INLIER_VOXELS)?;
    m.add_function(wrap_pyfunction!(scene::default_voxel_size, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::voxel_downsample, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::isolated_points, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::estimate_normals, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::compute_fpfh, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::describe, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::match_features, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::nearest_descriptors, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::nearest_neighbours, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::refine_poses, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::looks_like_one_view, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::edge_on_scores, m)?)?;
    m.add_function(wrap_pyfunction!(pointcloud::terraced_share, m)?)?;
    m.add(
        "MAX_TERRACED_SHARE",
        pointclm::pointcloud::terraces::MAX_TERRACED_SHARE,
    )?;
    m.add_function(wrap_pyfunction!(pointcloud::estimate_sensor, m)?)?;
    m.add_function(wrap_pyfunction!(validate_config, m)?)?;
    Ok(())
}
