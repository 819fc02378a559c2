//! The scene's declared parameters and its scene-wide stages (`pointclm::scene`): schemas for
//! the Python side, what accepted copies leave unexplained, and the final ranking factors.

use numpy::{
    IntoPyArray, PyArray1, PyArray3, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3,
};
use pointclm::pointcloud::RefineParams;
use pointclm::scene::{self, SceneRules};
use pointclm::{Correspondences, Features};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::sync::{Arc, Mutex};

use crate::args;
use crate::config::{declared_from_dict, declared_schema, from_dict, to_dict};
use crate::convert::{indices, matrices4, points as rows3};
use crate::pointcloud::{rigid_poses, rows_to_py};
use crate::pools::{guarded, pool};
use crate::result::PyRegistration;
use pointclm::kabsch::RigidTransform;

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

/// The training-free scene pipeline of the core (`pointclm::scene::register_point_clouds`:
/// `register_point_clouds`' stages without a learned model), as a dict (see `_core.pyi`).
#[pyfunction]
#[pyo3(
    signature = (model, scan, voxel_size=None, viewpoint=None, seed=0, peel=true, heap=None, heap_rank=64, flips=true, top_k=10_000, mutual=true, n_samples=Some(1000), config=None, scene=None, num_threads=None, pair_normals=false, embed=None, embed_inputs=Vec::new(), refine=true, k=1, mutual_window=None, symmetry=None, proposals="auto", descriptor=None, descriptor_kind="learned"),
    text_signature = "(model, scan, voxel_size=None, viewpoint=None, seed=0, peel=True, heap=None, heap_rank=64, flips=True, top_k=10000, mutual=True, n_samples=1000, config=None, scene=None, num_threads=None, pair_normals=False, embed=None, embed_inputs=[], refine=True, k=1, mutual_window=None, symmetry=None, proposals='auto', descriptor=None, descriptor_kind='learned')"
)]
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
    flips: bool,
    top_k: usize,
    mutual: bool,
    n_samples: Option<usize>,
    config: Option<Bound<'py, PyDict>>,
    scene: Option<Bound<'py, PyDict>>,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
    pair_normals: bool,
    embed: Option<Py<PyAny>>,
    embed_inputs: Vec<String>,
    refine: bool,
    k: usize,
    mutual_window: Option<Bound<'py, PyAny>>,
    symmetry: Option<Bound<'py, PyAny>>,
    proposals: &str,
    descriptor: Option<std::path::PathBuf>,
    descriptor_kind: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let proposals = scene::Proposals::from_name(proposals).map_err(crate::errors::to_py_err)?;
    // `descriptor`: the weights of a learned descriptor; None: FPFH.
    let descriptor = match descriptor {
        None => scene::Descriptor::Fpfh,
        Some(path) => learned(path, descriptor_kind)?,
    };
    let m = rows3(&model, "model")?;
    let s = rows3(&scan, "scan")?;
    let embedder = embed.map(|callback| {
        Arc::new(PyEmbedder {
            normals: embed_inputs.iter().any(|i| i == "normals"),
            similarity: embed_inputs.iter().any(|i| i == "similarity"),
            callback,
            error: Mutex::new(None),
        })
    });
    let options = scene::SceneOptions {
        pair_normals,
        voxel_size,
        viewpoint,
        seed,
        peel,
        heap,
        // 0 or 1: the plain mutual check (None in `register_point_clouds`).
        heap_rank: Some(heap_rank).filter(|&r| r > 1),
        mutual_window: mutual_window.as_ref().map(window).transpose()?,
        refine,
        flips,
        matching: pointclm::MatchingConfig {
            top_k,
            mutual,
            k,
            n_samples,
        },
        config: config.as_ref().map(|c| from_dict(Some(c))).transpose()?,
        scene: declared_from_dict(SceneRules::default(), scene.as_ref(), "scene")?,
        symmetry: crate::symmetry::model_symmetry(symmetry.as_ref())?,
        proposals,
        descriptor,
    };
    let threads = num_threads.map(pool).transpose()?;
    let inner = embedder.clone();
    let out = guarded(py, threads, move || {
        let embedder = inner.as_deref().map(|e| e as &dyn scene::Embedder);
        scene::register_point_clouds_with(&m, &s, &options, embedder)
    });
    // The embedding's own exception, not the core's note that it failed.
    if let Some(raised) = embedder.and_then(|e| e.error.lock().ok()?.take()) {
        return Err(raised);
    }
    scene_dict(py, out?)
}

/// The learned descriptor in the weights file `path`, used as `kind` says: "learned" (alone),
/// "fpfh+learned" (beside FPFH) or "auto" (decided by the model's shape).
fn learned(path: std::path::PathBuf, kind: &str) -> PyResult<scene::Descriptor> {
    let make: fn(Arc<_>) -> scene::Descriptor = match kind {
        "learned" => scene::Descriptor::Learned,
        "fpfh+learned" => scene::Descriptor::FpfhAndLearned,
        "auto" => scene::Descriptor::Auto,
        other => {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "descriptor_kind must be 'learned', 'fpfh+learned' or 'auto', got {other:?}"
            )))
        }
    };
    let net =
        pointclm::network::LearnedDescriptor::from_file(path).map_err(crate::errors::to_py_err)?;
    Ok(make(Arc::new(net)))
}

/// `mutual_window` as the core takes it: a side in model diagonals, or "auto".
fn window(value: &Bound<'_, PyAny>) -> PyResult<scene::MutualWindow> {
    if let Ok(text) = value.extract::<String>() {
        if text == "auto" {
            return Ok(scene::MutualWindow::Auto);
        }
    } else if let Ok(side) = value.extract::<f64>() {
        return Ok(scene::MutualWindow::Diagonals(side));
    }
    Err(pyo3::exceptions::PyValueError::new_err(format!(
        "mutual_window must be a number, \"auto\" or None, got {value}"
    )))
}

/// The learned embedding as a Python callable computes it: `callback(correspondences (N, 6),
/// normals (N, 6) or None, similarity (N,) or None) -> (N, C)`, called with the GIL taken
/// from the core's worker thread. Its exception is kept to be raised as it was.
struct PyEmbedder {
    callback: Py<PyAny>,
    normals: bool,
    similarity: bool,
    error: Mutex<Option<PyErr>>,
}

impl scene::Embedder for PyEmbedder {
    fn takes_normals(&self) -> bool {
        self.normals
    }

    fn takes_similarity(&self) -> bool {
        self.similarity
    }

    fn embed(&self, c: &Correspondences) -> pointclm::Result<Features> {
        Python::attach(|py| self.call(py, c)).map_err(|e| {
            if let Ok(mut kept) = self.error.lock() {
                *kept = Some(e);
            }
            pointclm::Error::InvalidParameter {
                name: "embed",
                value: "a Python callable".into(),
                reason: "raised an exception",
            }
        })
    }
}

impl PyEmbedder {
    fn call(&self, py: Python<'_>, c: &Correspondences) -> PyResult<Features> {
        let rows =
            |f: &dyn Fn(usize) -> [f64; 6]| -> Vec<[f64; 6]> { (0..c.len()).map(f).collect() };
        let pair = |a: [f64; 3], b: [f64; 3]| [a[0], a[1], a[2], b[0], b[1], b[2]];
        let corr = rows_to_py(py, &rows(&|i| pair(c.source(i), c.target(i))))?;
        let normals = match c.has_normals() && self.normals {
            true => Some(rows_to_py(
                py,
                &rows(&|i| {
                    let (a, b) = c.normals(i).unwrap_or_default();
                    pair(a, b)
                }),
            )?),
            false => None,
        };
        let similarity = c.similarity().map(|v| v.to_vec().into_pyarray(py));
        let out = self.callback.call1(py, (corr, normals, similarity))?;
        let array: PyReadonlyArray2<'_, f64> = out.extract(py)?;
        let view = array.as_array();
        let width = view.ncols();
        if view.nrows() != c.len() {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "the embedding gave {} rows for {} correspondences",
                view.nrows(),
                c.len()
            )));
        }
        Features::new(view.iter().copied().collect(), width).map_err(crate::errors::to_py_err)
    }
}

/// Copies as `register_scan` returns them: a column per field.
fn copies_dict<'py>(py: Python<'py>, c: &[scene::Candidate]) -> PyResult<Bound<'py, PyDict>> {
    let column = |f: fn(&scene::Candidate) -> f64| c.iter().map(f).collect::<Vec<f64>>();
    let mats: Vec<_> = c.iter().map(|c| c.pose.to_matrix()).collect();
    let d = PyDict::new(py);
    d.set_item("transformations", matrices4(py, &mats))?;
    d.set_item("confidence", column(|c| c.confidence).into_pyarray(py))?;
    d.set_item("fitness", column(|c| c.fitness).into_pyarray(py))?;
    d.set_item("inlier_rmse", column(|c| c.inlier_rmse).into_pyarray(py))?;
    d.set_item(
        "visible_fitness",
        column(|c| c.visible_fitness).into_pyarray(py),
    )?;
    d.set_item(
        "contradiction",
        column(|c| c.contradiction).into_pyarray(py),
    )?;
    d.set_item("seen", column(|c| c.seen).into_pyarray(py))?;
    d.set_item("visible_rmse", column(|c| c.visible_rmse).into_pyarray(py))?;
    d.set_item("slid_fitness", column(|c| c.slid_fitness).into_pyarray(py))?;
    d.set_item(
        "pass_index",
        c.iter().map(|c| c.pass_index).collect::<Vec<_>>(),
    )?;
    d.set_item("instance", c.iter().map(|c| c.instance).collect::<Vec<_>>())?;
    Ok(d)
}

/// A [`scene::SceneRegistration`] as `register_scan` returns it.
fn scene_dict(py: Python<'_>, out: scene::SceneRegistration) -> PyResult<Bound<'_, PyDict>> {
    let d = copies_dict(py, &out.candidates)?;
    d.set_item("ambiguous", copies_dict(py, &out.ambiguous)?)?;
    let symmetry = out
        .symmetry
        .as_ref()
        .map(|s| crate::symmetry::symmetry_dict(py, s))
        .transpose()?;
    d.set_item("symmetry", symmetry)?;
    let passes = PyList::empty(py);
    for pass in out.passes {
        let rows: Vec<[f64; 6]> = pass
            .correspondences
            .iter()
            .flat_map(|c| {
                (0..c.len()).map(move |i| {
                    let (a, b) = (c.source(i), c.target(i));
                    [a[0], a[1], a[2], b[0], b[1], b[2]]
                })
            })
            .collect();
        let poses = |p: &[RigidTransform]| {
            let m: Vec<_> = p.iter().map(|t| t.to_matrix()).collect();
            matrices4(py, &m)
        };
        let p = PyDict::new(py);
        p.set_item("correspondences", rows_to_py(py, &rows)?)?;
        p.set_item("matches", pass.matches)?;
        p.set_item("result", PyRegistration::new(py, pass.registration)?)?;
        p.set_item("scan_points", indices(py, &pass.scan_points))?;
        p.set_item("added", pass.added)?;
        p.set_item("voted", poses(&pass.voted))?;
        p.set_item("faces", poses(&pass.faces))?;
        p.set_item("duplicates", poses(&pass.duplicates))?;
        passes.append(p)?;
    }
    d.set_item("passes", passes)?;
    d.set_item("source_points", rows_to_py(py, &out.source.points)?)?;
    d.set_item("source_normals", rows_to_py(py, &out.source.normals)?)?;
    d.set_item("target_points", rows_to_py(py, &out.target.points)?)?;
    d.set_item("target_normals", rows_to_py(py, &out.target.normals)?)?;
    d.set_item("config", to_dict(py, &out.config)?)?;
    let (a, b, t) = (out.source.timings, out.target.timings, out.timings);
    let timings = PyDict::new(py);
    timings.set_item("downsample", a.downsample + b.downsample)?;
    timings.set_item("normals", a.normals + b.normals)?;
    timings.set_item("fpfh", a.fpfh + b.fpfh)?;
    timings.set_item("matching", t.matching)?;
    timings.set_item("embedding", t.embedding)?;
    timings.set_item("registration", t.registration)?;
    timings.set_item("refinement", t.refinement)?;
    timings.set_item("peeling", t.peeling)?;
    timings.set_item("flips", t.flips)?;
    d.set_item("timings", timings)?;
    d.set_item("voxel_size", out.voxel_size)?;
    d.set_item("by_visibility", out.by_visibility)?;
    d.set_item("viewpoint", out.viewpoint.map(|v| v.to_vec()))?;
    d.set_item(
        "unconfirmed_viewpoint",
        out.unconfirmed_viewpoint.map(|v| v.to_vec()),
    )?;
    d.set_item("orientation", out.orientation)?;
    d.set_item("viewpoint_disputed", out.viewpoint_disputed)?;
    d.set_item("face_proposals", out.face_proposals)?;
    d.set_item("planar_share", out.planar_share)?;
    d.set_item("descriptor", out.descriptor)?;
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

/// One model's poses for `judge_jointly`: its points, radius, copies and their contradictions,
/// ambiguous poses and theirs.
type JointModel<'py> = (
    PyReadonlyArray2<'py, f64>,
    f64,
    PyReadonlyArray3<'py, f64>,
    PyReadonlyArray1<'py, f64>,
    PyReadonlyArray3<'py, f64>,
    PyReadonlyArray1<'py, f64>,
);

/// Per model, which copies are kept; per model, which ambiguous poses.
type KeptMasks = (Vec<Vec<bool>>, Vec<Vec<bool>>);

/// Which copies and ambiguous poses of several models' results the joint check keeps
/// (`scene::judge_jointly`), by model.
#[pyfunction]
#[pyo3(signature = (scan, models, max_shared, num_threads=None))]
pub fn judge_jointly(
    py: Python<'_>,
    scan: PyReadonlyArray2<'_, f64>,
    models: Vec<JointModel<'_>>,
    max_shared: f64,
    num_threads: Option<usize>,
) -> PyResult<KeptMasks> {
    let scan = rows3(&scan, "scan")?;
    let posed = |t: &PyReadonlyArray3<'_, f64>, c: &PyReadonlyArray1<'_, f64>| {
        let poses = rigid_poses(t)?;
        let c = values(c);
        if c.len() != poses.len() {
            return Err(crate::errors::InputError::new_err(format!(
                "{} poses and {} contradictions: give one per pose",
                poses.len(),
                c.len()
            )));
        }
        Ok(poses.into_iter().zip(c).collect::<Vec<_>>())
    };
    let mut points = Vec::with_capacity(models.len());
    let mut lists = Vec::with_capacity(models.len());
    for (model, radius, copies, copies_c, ambiguous, ambiguous_c) in &models {
        points.push(rows3(model, "model")?);
        lists.push((
            *radius,
            posed(copies, copies_c)?,
            posed(ambiguous, ambiguous_c)?,
        ));
    }
    let threads = num_threads.map(pool).transpose()?;
    let verdict = guarded(py, threads, move || {
        let judged: Vec<scene::ModelPoses> = points
            .iter()
            .zip(lists)
            .map(|(model, (radius, copies, ambiguous))| scene::ModelPoses {
                model,
                radius,
                copies,
                ambiguous,
            })
            .collect();
        scene::judge_jointly(&scan, &judged, max_shared)
    })?;
    Ok((verdict.copies, verdict.ambiguous))
}
