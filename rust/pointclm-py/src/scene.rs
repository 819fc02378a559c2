//! The scene's declared parameters and its scene-wide stages (`pointclm::scene`): schemas for
//! the Python side, what accepted copies leave unexplained, and the final ranking factors.

use numpy::{
    IntoPyArray, PyArray1, PyArray3, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3,
};
use pointclm::pointcloud::RefineParams;
use pointclm::scene::{self, SceneRules};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::args;
use crate::config::{declared_from_dict, declared_schema};
use crate::convert::{matrices4, points as rows3};
use crate::pointcloud::rigid_poses;
use crate::pools::{guarded, pool};

/// Every field of the core's `SceneRules`, in order (as `config_schema`).
#[pyfunction]
pub fn scene_rules_schema(py: Python<'_>) -> PyResult<Bound<'_, PyList>> {
    declared_schema(py, &SceneRules::default())
}

/// Every field of the core's `RefineParams` at a voxel of 1, in order (as `config_schema`;
/// lengths in voxels).
#[pyfunction]
pub fn refine_params_schema(py: Python<'_>) -> PyResult<Bound<'_, PyList>> {
    declared_schema(py, &RefineParams::default())
}

/// Checks scene parameters given by name (unknown names, kinds and ranges: ConfigError).
#[pyfunction]
pub fn validate_scene_rules(params: Bound<'_, PyDict>) -> PyResult<()> {
    declared_from_dict(SceneRules::default(), Some(&params), "scene").map(|_| ())
}

/// Per target point, whether it lies at least `radius` from every source point posed at each
/// of `transformations`.
#[pyfunction]
#[pyo3(signature = (target, source, transformations, radius, num_threads=None))]
pub fn unexplained_points<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::target)] target: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::source)] source: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::transformations)] transformations: PyReadonlyArray3<'py, f64>,
    #[pyo3(from_py_with = args::radius)] radius: f64,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
) -> PyResult<Bound<'py, PyArray1<bool>>> {
    let t = rows3(&target, "target")?;
    let s = rows3(&source, "source")?;
    let poses = rigid_poses(&transformations)?;
    let threads = num_threads.map(pool).transpose()?;
    let out = guarded(py, threads, move || {
        scene::peeling::unexplained(&t, &s, &poses, radius)
    })?;
    Ok(out.into_pyarray(py))
}

/// A 1-D array's values (NaN: unknown).
fn values(values: &PyReadonlyArray1<'_, f64>) -> Vec<f64> {
    values.as_array().iter().copied().collect()
}

/// Which poses fit loosely against the scene's others (`scene::ranking::loose_poses`).
#[pyfunction]
pub fn loose_poses<'py>(
    py: Python<'py>,
    visible_rmse: PyReadonlyArray1<'py, f64>,
    max_relative: f64,
    min_poses: usize,
) -> Bound<'py, PyArray1<bool>> {
    scene::ranking::loose_poses(&values(&visible_rmse), max_relative, min_poses).into_pyarray(py)
}

/// Each pose's tightness factor (`scene::ranking::fit_tightness`).
#[pyfunction]
pub fn fit_tightness<'py>(
    py: Python<'py>,
    visible_rmse: PyReadonlyArray1<'py, f64>,
    min_poses: usize,
) -> Bound<'py, PyArray1<f64>> {
    scene::ranking::fit_tightness(&values(&visible_rmse), min_poses).into_pyarray(py)
}

/// Each pose's stability factor (`scene::ranking::stability_factor`).
#[pyfunction]
pub fn stability_factor<'py>(
    py: Python<'py>,
    stability: PyReadonlyArray1<'py, f64>,
    min_poses: usize,
) -> Bound<'py, PyArray1<f64>> {
    scene::ranking::stability_factor(&values(&stability), min_poses).into_pyarray(py)
}

/// The training-free scene pipeline of the core (`pointclm::scene::register_point_clouds`,
/// `register_point_clouds(..., flips=False)`'s stages), as a dict: `transformations` (M, 4, 4)
/// surest first, `confidence` (M,), `pass_index` (the pass each came from), `passes` (their
/// number), `voxel_size`, `by_visibility` (whether the sensor judged them) and
/// `viewpoint_disputed` (the scan does not look like one view from the viewpoint given).
#[pyfunction]
#[pyo3(signature = (model, scan, voxel_size=None, viewpoint=None, seed=0, peel=true, heap=None, heap_rank=64, scene=None, num_threads=None))]
#[allow(clippy::too_many_arguments)]
pub fn register_scan<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::source)] model: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::target)] scan: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::optional_voxel_size)] voxel_size: Option<f64>,
    #[pyo3(from_py_with = args::viewpoint)] viewpoint: Option<[f64; 3]>,
    #[pyo3(from_py_with = args::seed)] seed: u64,
    peel: bool,
    heap: Option<bool>,
    heap_rank: usize,
    scene: Option<Bound<'py, PyDict>>,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let m = rows3(&model, "model")?;
    let s = rows3(&scan, "scan")?;
    let options = scene::SceneOptions {
        voxel_size,
        viewpoint,
        seed,
        peel,
        heap,
        // 0 or 1: the plain mutual check (None in `register_point_clouds`).
        heap_rank: Some(heap_rank).filter(|&r| r > 1),
        scene: declared_from_dict(SceneRules::default(), scene.as_ref(), "scene")?,
        ..scene::SceneOptions::default()
    };
    let threads = num_threads.map(pool).transpose()?;
    let out = guarded(py, threads, move || {
        scene::register_point_clouds(&m, &s, &options)
    })?;
    let mats: Vec<_> = out.candidates.iter().map(|c| c.pose.to_matrix()).collect();
    let confidence: Vec<f64> = out.candidates.iter().map(|c| c.confidence).collect();
    let passes: Vec<usize> = out.candidates.iter().map(|c| c.pass_index).collect();
    let d = PyDict::new(py);
    d.set_item("transformations", matrices4(py, &mats))?;
    d.set_item("confidence", confidence.into_pyarray(py))?;
    d.set_item("pass_index", passes)?;
    d.set_item("passes", out.passes.len())?;
    d.set_item("voxel_size", out.voxel_size)?;
    d.set_item("by_visibility", out.by_visibility)?;
    d.set_item("viewpoint_disputed", out.viewpoint_disputed)?;
    Ok(d)
}

/// The length of the bounding-box diagonal of `points` (the model's size every scene rule in
/// model diagonals or radii is measured against).
#[pyfunction]
pub fn bounding_diagonal(
    #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'_, f64>,
) -> PyResult<f64> {
    Ok(scene::voxel::diagonal(&rows3(&points, "points")?))
}

/// `register_point_clouds`' default voxel (`pointclm::scene::voxel::default_voxel_size`): the
/// model's diagonal over `voxels_per_diagonal`, no finer than the scan's spacing and noise
/// allow (without `scan`, the model's rule alone).
#[pyfunction]
#[pyo3(signature = (model, scan=None, scene=None))]
pub fn default_voxel_size(
    py: Python<'_>,
    #[pyo3(from_py_with = args::source)] model: PyReadonlyArray2<'_, f64>,
    scan: Option<PyReadonlyArray2<'_, f64>>,
    scene: Option<Bound<'_, PyDict>>,
) -> PyResult<f64> {
    let m = rows3(&model, "model")?;
    let s = scan.map(|a| rows3(&a, "scan")).transpose()?;
    let rules = declared_from_dict(SceneRules::default(), scene.as_ref(), "scene")?;
    guarded(py, None, move || {
        scene::voxel::default_voxel_size(&m, s.as_deref(), &rules)
    })
}

/// The correspondence stage's thresholds for refined poses on clouds, in synthetic units
/// (`pointclm::scene::cloud_base_config`), as a config dict.
#[pyfunction]
pub fn cloud_base_config(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    crate::config::to_dict(py, &scene::cloud_base_config(None))
}

/// The median distance from a point of `points` to its nearest other point, and the standard
/// deviation of the points about their surface (at `scale`, or a fixed neighbour count
/// without one): `pointclm::scene::voxel::scan_scales`.
#[pyfunction]
#[pyo3(signature = (points, scale=None))]
pub fn scan_scales(
    py: Python<'_>,
    #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'_, f64>,
    scale: Option<f64>,
) -> PyResult<(f64, f64)> {
    let p = rows3(&points, "points")?;
    guarded(py, None, move || scene::voxel::scan_scales(&p, scale))
}

/// (F, 4, 4) half turns of `points` (a model downsampled at `voxel_size`) about its principal
/// axes through its centroid that move at least `min_change` of it farther than 1.5 voxels.
#[pyfunction]
#[pyo3(signature = (points, voxel_size, min_change))]
pub fn flip_turns<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::voxel_size)] voxel_size: f64,
    min_change: f64,
) -> PyResult<Bound<'py, PyArray3<f64>>> {
    let p = rows3(&points, "points")?;
    let turns = guarded(py, None, move || {
        scene::flip_turns(&p, voxel_size, min_change)
    })?;
    let mats: Vec<_> = turns.iter().map(|t| t.to_matrix()).collect();
    Ok(matrices4(py, &mats))
}

/// (Q, 4, 4) quarter turns of `points` either way about its principal axes through its
/// centroid that move from `min_change` to `max_change` of it farther than 1.5 voxels.
#[pyfunction]
#[pyo3(signature = (points, voxel_size, min_change, max_change))]
pub fn quarter_turns<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::voxel_size)] voxel_size: f64,
    min_change: f64,
    max_change: f64,
) -> PyResult<Bound<'py, PyArray3<f64>>> {
    let p = rows3(&points, "points")?;
    let turns = guarded(py, None, move || {
        scene::quarter_turns(&p, voxel_size, min_change, max_change)
    })?;
    let mats: Vec<_> = turns.iter().map(|t| t.to_matrix()).collect();
    Ok(matrices4(py, &mats))
}
