//! Point cloud processing and descriptor matching: voxel downsampling, normals, FPFH, and
//! descriptor matches (the inputs `register` needs when the user has clouds, not matches).

use nalgebra::{Matrix3, Vector3};
use numpy::ndarray::Array2;
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2,
    PyReadonlyArray3,
};
use pointclm::kabsch::RigidTransform;
use pointclm::pointcloud::{self, FpfhVariant, Orientation, PointIndex, RefineParams};
use pointclm::scene;
use pointclm::{Features, MatchingConfig, NearestSources};
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rayon::prelude::*;
use std::sync::Arc;

use crate::args;
use crate::config::declared_from_dict;
use crate::convert::{indices, matrices4, points as rows3};
use crate::errors::{to_py_err_at, InputError};
use crate::pools::{guarded, pool};

pub(crate) fn rows_to_py<'py, const K: usize>(
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
    Features::new(v.iter().copied().collect(), v.ncols()).map_err(|e| to_py_err_at(what, e))
}

/// `max_nn` capped by the number of points (a point cannot have more neighbours), so that a
/// huge count cannot size buffers; counts too small are left for the core to refuse.
fn neighbours_at_most(max_nn: usize, points: usize) -> usize {
    max_nn.min(points.max(2))
}

/// Centroid of each occupied voxel, ordered by voxel index.
#[pyfunction]
pub fn voxel_downsample<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::voxel_size)] voxel_size: f64,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let p = rows3(&points, "points")?;
    let out = guarded(py, None, move || {
        pointcloud::voxel_downsample(&p, voxel_size)
    })?;
    rows_to_py(py, &out)
}

/// Which points have fewer than `min_neighbours` other points within `radius`: stray points
/// among the points of a surface.
#[pyfunction]
#[pyo3(signature = (points, radius, min_neighbours=3, num_threads=None))]
pub fn isolated_points<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::radius)] radius: f64,
    #[pyo3(from_py_with = args::min_neighbours)] min_neighbours: usize,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
) -> PyResult<Bound<'py, PyArray1<bool>>> {
    let p = rows3(&points, "points")?;
    let threads = num_threads.map(pool).transpose()?;
    let out = guarded(py, threads, move || {
        pointcloud::isolated_points(&p, radius, min_neighbours)
    })?;
    Ok(out.into_pyarray(py))
}

/// PCA normals over hybrid neighbourhoods, signed towards `towards` or away from
/// `away_from` (exactly one of the two).
#[pyfunction]
#[pyo3(signature = (points, radius, max_nn=30, towards=None, away_from=None, num_threads=None))]
pub fn estimate_normals<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::radius)] radius: f64,
    #[pyo3(from_py_with = args::max_nn)] max_nn: usize,
    #[pyo3(from_py_with = args::towards)] towards: Option<[f64; 3]>,
    #[pyo3(from_py_with = args::away_from)] away_from: Option<[f64; 3]>,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let orientation = match (towards, away_from) {
        (Some(v), None) => Orientation::Towards(v),
        (None, Some(v)) => Orientation::AwayFrom(v),
        _ => {
            return Err(InputError::new_err(
                "give exactly one of towards= (a viewpoint) or away_from= (an inner point)",
            ))
        }
    };
    let p = rows3(&points, "points")?;
    let max_nn = neighbours_at_most(max_nn, p.len());
    let threads = num_threads.map(pool).transpose()?;
    let out = guarded(py, threads, move || {
        let index = PointIndex::new(&p)?;
        pointcloud::estimate_normals(&p, &index, radius, max_nn, orientation)
    })?;
    rows_to_py(py, &out)
}

/// How far the scan's depth steps make flat terraces at `radius` seen from `eye`
/// (`pointcloud::terraced_share`, over normals within `radius`, at most 30 points):
/// above `MAX_TERRACED_SHARE` pointclm fits the scan's normals within twice `radius`.
#[pyfunction]
#[pyo3(signature = (points, radius, eye, num_threads=None))]
pub fn terraced_share(
    py: Python<'_>,
    #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'_, f64>,
    #[pyo3(from_py_with = args::radius)] radius: f64,
    #[pyo3(from_py_with = args::eye)] eye: [f64; 3],
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
) -> PyResult<f64> {
    let p = rows3(&points, "points")?;
    let threads = num_threads.map(pool).transpose()?;
    guarded(py, threads, move || {
        let index = PointIndex::new(&p)?;
        let towards = Orientation::Towards(eye);
        let normals = pointcloud::estimate_normals(&p, &index, radius, 30, towards)?;
        pointcloud::terraced_share(&p, &index, &normals, radius, eye)
    })
}

/// For each eye (rows of `eyes`), the `rank`-th smallest |cos| between a normal and its
/// point's line of sight from the eye (`pointclm.preprocessing.estimate_viewpoint`).
#[pyfunction]
#[pyo3(signature = (points, normals, eyes, rank, num_threads=None))]
pub fn edge_on_scores<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::normals)] normals: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::eyes)] eyes: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::rank)] rank: usize,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let p = rows3(&points, "points")?;
    let n = rows3(&normals, "normals")?;
    let e = rows3(&eyes, "eyes")?;
    let threads = num_threads.map(pool).transpose()?;
    let out = guarded(py, threads, move || {
        pointcloud::edge_on_scores(&p, &n, &e, rank)
    })?;
    Ok(out.into_pyarray(py))
}

/// FPFH descriptors (N, 33) over hybrid neighbourhoods (at most `max_nn` within `radius`).
#[pyfunction]
#[pyo3(
    signature = (points, normals, radius, max_nn=100, variant="open3d".to_string(), num_threads=None),
    text_signature = "(points, normals, radius, max_nn=100, variant='open3d', num_threads=None)"
)]
pub fn compute_fpfh<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::normals)] normals: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::radius)] radius: f64,
    #[pyo3(from_py_with = args::max_nn)] max_nn: usize,
    #[pyo3(from_py_with = args::variant)] variant: String,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let variant = fpfh_variant(&variant)?;
    let p = rows3(&points, "points")?;
    let n = rows3(&normals, "normals")?;
    let max_nn = neighbours_at_most(max_nn, p.len());
    let threads = num_threads.map(pool).transpose()?;
    let out = guarded(py, threads, move || {
        let index = PointIndex::new(&p)?;
        pointcloud::fpfh(&p, &n, &index, radius, max_nn, variant)
    })?;
    rows_to_py(py, &out)
}

/// Learned descriptors (N, D) of `points` with their unit `normals`, described at `voxel`,
/// by the descriptor network in `weights` (a `.safetensors` file with its `.json` beside it).
#[pyfunction]
#[pyo3(signature = (points, normals, voxel_size, weights, num_threads=None))]
pub fn learned_descriptors<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::normals)] normals: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::voxel_size)] voxel_size: f64,
    weights: std::path::PathBuf,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let p = rows3(&points, "points")?;
    let n = rows3(&normals, "normals")?;
    let threads = num_threads.map(pool).transpose()?;
    let out = guarded(py, threads, move || {
        let net = pointclm::network::LearnedDescriptor::from_file(&weights)?;
        let index = PointIndex::new(&p)?;
        net.describe(&p, &n, &index, voxel_size)
    })?;
    let flat: Vec<f64> = (0..out.len()).flat_map(|i| out.row(i).to_vec()).collect();
    Array2::from_shape_vec((out.len(), out.dim()), flat)
        .map(|a| a.into_pyarray(py))
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

type MatchArrays<'py> = (
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<f64>>,
);

/// Each target descriptor's `k` nearest source descriptors; the `top_k` closest matches kept
/// (mutual only, if asked), then `n_samples` drawn with `seed`. Returns (source rows, target
/// rows, descriptor distances), closest first.
#[pyfunction]
#[pyo3(signature = (source, target, top_k=10_000, mutual=false, n_samples=Some(1000), seed=0, num_threads=None, k=1, nearest=None))]
#[allow(clippy::too_many_arguments)]
pub fn match_features<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::source)] source: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::target)] target: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::top_k)] top_k: usize,
    #[pyo3(from_py_with = args::mutual)] mutual: bool,
    #[pyo3(from_py_with = args::n_samples)] n_samples: Option<usize>,
    #[pyo3(from_py_with = args::seed)] seed: u64,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
    #[pyo3(from_py_with = args::k)] k: usize,
    #[pyo3(from_py_with = nearest_arg)] nearest: Option<NearestSources>,
) -> PyResult<MatchArrays<'py>> {
    let s = descriptors(&source, "source descriptors")?;
    let t = descriptors(&target, "target descriptors")?;
    let cfg = MatchingConfig {
        top_k,
        mutual,
        k,
        n_samples,
    };
    let threads = num_threads.map(pool).transpose()?;
    let m = guarded(py, threads, move || match &nearest {
        Some(near) => pointclm::match_features_given(&s, &t, near, &cfg, seed),
        None => pointclm::match_features(&s, &t, &cfg, seed),
    })?;
    Ok((
        indices(py, &m.source),
        indices(py, &m.target),
        m.distance.into_pyarray(py),
    ))
}

/// `nearest` of `match_features`: (source rows, squared distances), two (n, k) arrays of
/// int64 and float64, row for row with the target descriptors, as `nearest_descriptors`
/// returns them.
fn nearest_arg(obj: &Bound<'_, PyAny>) -> PyResult<Option<NearestSources>> {
    if obj.is_none() {
        return Ok(None);
    }
    let bad = || {
        InputError::new_err(
            "nearest must be None or (source rows, squared distances): an int64 and a float64 \
             array of shape (target rows, k), as nearest_descriptors returns them",
        )
    };
    let (rows, dist2): (Bound<'_, PyAny>, Bound<'_, PyAny>) = obj.extract().map_err(|_| bad())?;
    let rows = rows.cast::<PyArray2<i64>>().map_err(|_| bad())?.readonly();
    let dist2 = dist2.cast::<PyArray2<f64>>().map_err(|_| bad())?.readonly();
    let (r, d) = (rows.as_array(), dist2.as_array());
    if r.dim() != d.dim() || r.iter().any(|&v| v < 0) {
        return Err(bad());
    }
    Ok(Some(NearestSources {
        k: r.ncols(),
        source: r.iter().map(|&v| v as usize).collect(),
        dist2: d.iter().copied().collect(),
    }))
}

type NearestDescriptors<'py> = (Bound<'py, PyArray2<i64>>, Bound<'py, PyArray2<f64>>);

/// Each target descriptor's `k` nearest source descriptors (exact), nearest first: (source
/// rows, squared distances), two (n, k) arrays; `k` is capped at the source's rows.
#[pyfunction]
#[pyo3(signature = (source, target, k=1, num_threads=None))]
pub fn nearest_descriptors<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::source)] source: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::target)] target: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::k)] k: usize,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
) -> PyResult<NearestDescriptors<'py>> {
    let s = descriptors(&source, "source descriptors")?;
    let t = descriptors(&target, "target descriptors")?;
    let n = t.len();
    let threads = num_threads.map(pool).transpose()?;
    let near = guarded(py, threads, move || pointclm::nearest_sources(&s, &t, k))?;
    let rows: Vec<i64> = near.source.iter().map(|&v| v as i64).collect();
    let shape = (n, near.k);
    let to_err = |e: numpy::ndarray::ShapeError| PyRuntimeError::new_err(e.to_string());
    Ok((
        Array2::from_shape_vec(shape, rows)
            .map_err(to_err)?
            .into_pyarray(py),
        Array2::from_shape_vec(shape, near.dist2)
            .map_err(to_err)?
            .into_pyarray(py),
    ))
}

type NearestArrays<'py> = (Bound<'py, PyArray1<i64>>, Bound<'py, PyArray1<f64>>);

/// For each query point, its nearest point of `reference`: (indices, distances).
#[pyfunction]
#[pyo3(signature = (reference, queries, num_threads=None))]
pub fn nearest_neighbours<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::reference)] reference: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::queries)] queries: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
) -> PyResult<NearestArrays<'py>> {
    let r = rows3(&reference, "reference points")?;
    let q = rows3(&queries, "query points")?;
    let threads = num_threads.map(pool).transpose()?;
    let (idx, dist) = guarded(py, threads, move || {
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
    })?;
    Ok((indices(py, &idx), dist.into_pyarray(py)))
}

/// Poses as arrays: (M, 4, 4) transformations, the eight score columns of
/// [`pose_columns`] and each pose's input index.
type PoseArrays<'py> = (
    Bound<'py, PyArray3<f64>>,
    [Bound<'py, PyArray1<f64>>; 8],
    Bound<'py, PyArray1<i64>>,
);

type RefinedArrays<'py> = (
    Bound<'py, PyArray3<f64>>,
    [Bound<'py, PyArray1<f64>>; 8],
    Bound<'py, PyArray1<i64>>,
    bool,
    Vec<(usize, &'static str, f64, f64)>,
    PoseArrays<'py>,
);

/// Rigid poses from (M, 4, 4) `T_target_source` matrices: the rotation block must be a
/// rotation up to rounding (`||R^T R - I||_F <= 1e-3`, det > 0; it is replaced by the nearest
/// rotation) and the last row (0, 0, 0, 1) to 1e-6.
pub(crate) fn rigid_poses(a: &PyReadonlyArray3<'_, f64>) -> PyResult<Vec<RigidTransform>> {
    let v = a.as_array();
    if v.shape()[1..] != [4, 4] {
        return Err(InputError::new_err(format!(
            "transformations must have shape (M, 4, 4), got {:?}",
            v.shape()
        )));
    }
    (0..v.shape()[0])
        .map(|k| {
            let m = v.index_axis(numpy::ndarray::Axis(0), k);
            if !m.iter().all(|x| x.is_finite()) {
                return Err(InputError::new_err(format!(
                    "transformations[{k}] has a non-finite value (NaN or inf)"
                )));
            }
            let bottom = [m[(3, 0)], m[(3, 1)], m[(3, 2)], m[(3, 3)] - 1.0];
            if bottom.iter().any(|x| x.abs() > 1e-6) {
                return Err(InputError::new_err(format!(
                    "transformations[{k}] is not a rigid motion: its last row must be (0, 0, 0, 1)"
                )));
            }
            let rotation = pointcloud::nearest_rotation(&Matrix3::from_fn(|i, j| m[(i, j)]))
                .map_err(|deviation| {
                    InputError::new_err(format!(
                        "transformations[{k}] is not a rigid motion: its 3x3 block must be a \
                         rotation (||R^T R - I|| = {deviation:.2e}, at most {:.0e} is taken for \
                         rounding; determinant must be positive)",
                        pointcloud::MAX_ROTATION_DEVIATION
                    ))
                })?;
            Ok(RigidTransform {
                rotation,
                translation: Vector3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]),
            })
        })
        .collect()
}

/// ICP refinement of each pose against the target cloud (the schedule of
/// `RefineParams::for_voxel`; none if `icp` is false), then verification, by what the sensor
/// at `viewpoint` could see of each pose when given (and the scan is one view from it), else
/// by the share of the model explained. Returns the accepted poses (M', 4, 4), surest first;
/// per pose [confidence, fitness, visible fitness, contradiction, seen share, inlier RMSE]; the
/// index of the input pose each came from; and whether the viewpoint judged them.
#[pyfunction]
#[pyo3(signature = (source, target, transformations, voxel_size, icp, viewpoint, rules=None, target_normals=None, num_threads=None))]
#[allow(clippy::too_many_arguments)]
pub fn refine_poses<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::source)] source: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::target)] target: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::transformations)] transformations: PyReadonlyArray3<'py, f64>,
    #[pyo3(from_py_with = args::voxel_size)] voxel_size: f64,
    #[pyo3(from_py_with = args::icp)] icp: bool,
    #[pyo3(from_py_with = args::viewpoint)] viewpoint: Option<[f64; 3]>,
    rules: Option<Bound<'py, PyDict>>,
    #[pyo3(from_py_with = args::optional_target_normals)] target_normals: Option<
        PyReadonlyArray2<'py, f64>,
    >,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
) -> PyResult<RefinedArrays<'py>> {
    let s = rows3(&source, "source")?;
    let t = rows3(&target, "target")?;
    let n = target_normals
        .map(|a| rows3(&a, "target_normals"))
        .transpose()?;
    let poses = rigid_poses(&transformations)?;
    let params = refine_params(voxel_size, icp, rules.as_ref())?;
    let threads = num_threads.map(pool).transpose()?;
    let out = guarded(py, threads, move || {
        pointcloud::refine_poses(&s, &t, n.as_deref(), &poses, viewpoint, &params)
    })?;
    Ok(refined_arrays(py, &out))
}

/// Whether `points` (a scan downsampled at `voxel_size`) look like one view from
/// `viewpoint`: the test by which `refine_poses` trusts a viewpoint.
#[pyfunction]
#[pyo3(signature = (points, viewpoint, voxel_size))]
pub fn looks_like_one_view(
    py: Python<'_>,
    #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'_, f64>,
    #[pyo3(from_py_with = args::viewpoint)] viewpoint: Option<[f64; 3]>,
    #[pyo3(from_py_with = args::voxel_size)] voxel_size: f64,
) -> PyResult<bool> {
    let p = rows3(&points, "points")?;
    let Some(eye) = viewpoint else {
        return Err(InputError::new_err(
            "viewpoint must be 3 finite numbers, got None",
        ));
    };
    let params = RefineParams::for_voxel(voxel_size);
    guarded(py, None, move || {
        pointcloud::looks_like_one_view(&p, eye, &params)
    })
}

/// The position from which `points` (one range scan downsampled at `voxel_size`) hide the
/// fewest of their own points, on the side of `towards`, the share hidden from there and the
/// number of points it counts.
#[pyfunction]
#[pyo3(signature = (points, voxel_size, towards))]
pub fn estimate_sensor(
    py: Python<'_>,
    #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'_, f64>,
    #[pyo3(from_py_with = args::voxel_size)] voxel_size: f64,
    #[pyo3(from_py_with = args::viewpoint)] towards: Option<[f64; 3]>,
) -> PyResult<((f64, f64, f64), f64, usize)> {
    let p = rows3(&points, "points")?;
    let Some(towards) = towards else {
        return Err(InputError::new_err(
            "towards must be 3 finite numbers, got None",
        ));
    };
    let est = guarded(py, None, move || {
        pointcloud::estimate_sensor(&p, voxel_size, towards)
    })?;
    let [x, y, z] = est.position;
    Ok(((x, y, z), est.hidden_share, est.points))
}

/// What `refine_poses` derives from the clouds alone (the scan's index and normals, the depth
/// maps from the viewpoint, the model's normals), built once for many calls against one scan.
#[pyclass(frozen, module = "pointclm._core", name = "RefineContext")]
pub struct PyRefineContext {
    /// Shared with the worker thread of each call (which outlives no call).
    inner: Arc<pointcloud::RefineContext>,
    voxel_size: f64,
}

/// `RefineParams::for_voxel` with the caller's ICP choice and `rules` (fields of
/// `RefineParams` by name, in the clouds' units); the core checks the ranges.
fn refine_params(
    voxel_size: f64,
    icp: bool,
    rules: Option<&Bound<'_, PyDict>>,
) -> PyResult<RefineParams> {
    let mut params = declared_from_dict(RefineParams::for_voxel(voxel_size), rules, "refine rule")?;
    params.icp = icp;
    Ok(params)
}

#[pymethods]
impl PyRefineContext {
    #[new]
    #[pyo3(signature = (source, target, voxel_size, viewpoint, target_normals=None, num_threads=None))]
    fn new(
        py: Python<'_>,
        #[pyo3(from_py_with = args::source)] source: PyReadonlyArray2<'_, f64>,
        #[pyo3(from_py_with = args::target)] target: PyReadonlyArray2<'_, f64>,
        #[pyo3(from_py_with = args::voxel_size)] voxel_size: f64,
        #[pyo3(from_py_with = args::viewpoint)] viewpoint: Option<[f64; 3]>,
        #[pyo3(from_py_with = args::optional_target_normals)] target_normals: Option<
            PyReadonlyArray2<'_, f64>,
        >,
        #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
    ) -> PyResult<Self> {
        let s = rows3(&source, "source")?;
        let t = rows3(&target, "target")?;
        let n = target_normals
            .map(|a| rows3(&a, "target_normals"))
            .transpose()?;
        let params = RefineParams::for_voxel(voxel_size);
        let threads = num_threads.map(pool).transpose()?;
        let inner = guarded(py, threads, move || {
            pointcloud::RefineContext::new(&s, &t, n.as_deref(), viewpoint, &params)
        })?;
        Ok(Self {
            inner: Arc::new(inner),
            voxel_size,
        })
    }

    /// `refine_poses` of `transformations` against the context's clouds (same returns).
    #[pyo3(signature = (transformations, icp, rules=None, num_threads=None))]
    fn refine<'py>(
        &self,
        py: Python<'py>,
        #[pyo3(from_py_with = args::transformations)] transformations: PyReadonlyArray3<'py, f64>,
        #[pyo3(from_py_with = args::icp)] icp: bool,
        rules: Option<Bound<'py, PyDict>>,
        #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
    ) -> PyResult<RefinedArrays<'py>> {
        let poses = rigid_poses(&transformations)?;
        let params = refine_params(self.voxel_size, icp, rules.as_ref())?;
        let threads = num_threads.map(pool).transpose()?;
        let inner = Arc::clone(&self.inner);
        let out = guarded(py, threads, move || inner.refine(&poses, &params))?;
        Ok(refined_arrays(py, &out))
    }

    /// Verified poses (as `refine` returns them: `transformations`, the seven `columns` in its
    /// order, `origin`, `by_visibility`) with each replaced by a turned alternative the scan
    /// supports better (`pointclm::scene::flips::resolve_flips`, the scene's own turns
    /// `rotations` (K, 3, 3), `scene` rules by name), surest first; `refine`'s returns and the
    /// row of the input each came from.
    #[pyo3(signature = (transformations, columns, origin, by_visibility, rotations, scene=None, num_threads=None))]
    #[allow(clippy::too_many_arguments)]
    fn resolve_flips<'py>(
        &self,
        py: Python<'py>,
        #[pyo3(from_py_with = args::transformations)] transformations: PyReadonlyArray3<'py, f64>,
        columns: Vec<PyReadonlyArray1<'py, f64>>,
        #[pyo3(from_py_with = args::rows)] origin: Vec<usize>,
        by_visibility: bool,
        rotations: PyReadonlyArray3<'py, f64>,
        scene: Option<Bound<'py, PyDict>>,
        #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
    ) -> PyResult<(RefinedArrays<'py>, Bound<'py, PyArray1<i64>>)> {
        let poses = refined_from_arrays(&transformations, &columns, &origin, by_visibility)?;
        let turns = rotation_blocks(&rotations)?;
        let rules = declared_from_dict(scene::SceneRules::default(), scene.as_ref(), "scene")?;
        let params = RefineParams::for_voxel(self.voxel_size);
        let threads = num_threads.map(pool).transpose()?;
        let inner = Arc::clone(&self.inner);
        let (out, order) = guarded(py, threads, move || {
            scene::resolve_flips(&inner, &params, &poses, &turns, &rules)
        })?;
        Ok((refined_arrays(py, &out), indices(py, &order)))
    }

    /// The share of `points` (source frame) each of `transformations` puts strictly within
    /// `radius` of a scan point.
    #[pyo3(signature = (transformations, points, radius, num_threads=None))]
    fn near_shares<'py>(
        &self,
        py: Python<'py>,
        #[pyo3(from_py_with = args::transformations)] transformations: PyReadonlyArray3<'py, f64>,
        #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'py, f64>,
        #[pyo3(from_py_with = args::radius)] radius: f64,
        #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let poses = rigid_poses(&transformations)?;
        let pts = rows3(&points, "points")?;
        let threads = num_threads.map(pool).transpose()?;
        let inner = Arc::clone(&self.inner);
        let shares = guarded(py, threads, move || inner.near_shares(&poses, &pts, radius))?;
        Ok(shares.into_pyarray(py))
    }

    /// How firmly the scan pins each of `transformations` down (`pointclm::scene::ranking::
    /// pose_stability`), with the model's `source_normals`, counting model points within
    /// `radius` of the scan.
    #[pyo3(signature = (transformations, source_normals, radius, num_threads=None))]
    fn pose_stability<'py>(
        &self,
        py: Python<'py>,
        #[pyo3(from_py_with = args::transformations)] transformations: PyReadonlyArray3<'py, f64>,
        #[pyo3(from_py_with = args::points)] source_normals: PyReadonlyArray2<'py, f64>,
        #[pyo3(from_py_with = args::radius)] radius: f64,
        #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let poses = rigid_poses(&transformations)?;
        let normals = rows3(&source_normals, "source_normals")?;
        let threads = num_threads.map(pool).transpose()?;
        let inner = Arc::clone(&self.inner);
        let out = guarded(py, threads, move || {
            scene::ranking::pose_stability(inner.source(), &normals, inner.index(), &poses, radius)
        })?;
        Ok(out.into_pyarray(py))
    }

    /// Each of `transformations`' information (P, 6, 6), covariance (P, 6, 6), count of
    /// unobservable directions (P,) and residual variance (P,) over the model points within
    /// `radius` of the scan (`pointclm::pointcloud::covariance`; order rx, ry, rz, x, y, z).
    #[pyo3(signature = (transformations, radius, num_threads=None))]
    #[allow(clippy::type_complexity)]
    fn pose_covariances<'py>(
        &self,
        py: Python<'py>,
        #[pyo3(from_py_with = args::transformations)] transformations: PyReadonlyArray3<'py, f64>,
        #[pyo3(from_py_with = args::radius)] radius: f64,
        #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
    ) -> PyResult<(
        Bound<'py, PyArray3<f64>>,
        Bound<'py, PyArray3<f64>>,
        Bound<'py, PyArray1<i64>>,
        Bound<'py, PyArray1<f64>>,
    )> {
        let poses = rigid_poses(&transformations)?;
        let threads = num_threads.map(pool).transpose()?;
        let inner = Arc::clone(&self.inner);
        let out = guarded(py, threads, move || inner.pose_covariances(&poses, radius))?;
        let p = out.len();
        let flat = |m: &nalgebra::Matrix6<f64>| -> Vec<f64> {
            // Row-major, as numpy reads it.
            (0..36).map(|k| m[(k / 6, k % 6)]).collect()
        };
        let info: Vec<f64> = out.iter().flat_map(|c| flat(&c.information)).collect();
        let cov: Vec<f64> = out.iter().flat_map(|c| flat(&c.covariance)).collect();
        let info = numpy::ndarray::Array3::from_shape_vec((p, 6, 6), info)
            .map_err(|e| InputError::new_err(e.to_string()))?;
        let cov = numpy::ndarray::Array3::from_shape_vec((p, 6, 6), cov)
            .map_err(|e| InputError::new_err(e.to_string()))?;
        let unobservable: Vec<i64> = out.iter().map(|c| c.unobservable as i64).collect();
        let variance: Vec<f64> = out.iter().map(|c| c.residual_variance).collect();
        Ok((
            info.into_pyarray(py),
            cov.into_pyarray(py),
            unobservable.into_pyarray(py),
            variance.into_pyarray(py),
        ))
    }

    /// Per row of `points`, whether a scan point lies strictly within `radius` of it.
    #[pyo3(signature = (points, radius, num_threads=None))]
    fn near_mask<'py>(
        &self,
        py: Python<'py>,
        #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'py, f64>,
        #[pyo3(from_py_with = args::radius)] radius: f64,
        #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyArray1<bool>>> {
        let pts = rows3(&points, "points")?;
        let threads = num_threads.map(pool).transpose()?;
        let inner = Arc::clone(&self.inner);
        let mask = guarded(py, threads, move || inner.near_mask(&pts, radius))?;
        Ok(mask.into_pyarray(py))
    }

    /// The scan points (ascending) nearest, within `radius`, to a model point at
    /// `transformation`: what a pose explains.
    #[pyo3(signature = (transformation, radius))]
    fn explained_scan_points<'py>(
        &self,
        py: Python<'py>,
        #[pyo3(from_py_with = args::transformations)] transformation: PyReadonlyArray3<'py, f64>,
        #[pyo3(from_py_with = args::radius)] radius: f64,
    ) -> PyResult<Bound<'py, PyArray1<i64>>> {
        let poses = rigid_poses(&transformation)?;
        let [pose] = poses[..] else {
            return Err(InputError::new_err(
                "transformation must hold exactly one pose",
            ));
        };
        let hits = scene::peeling::explained_scan_points(
            self.inner.index(),
            self.inner.source(),
            &pose,
            radius,
        );
        Ok(hits
            .into_iter()
            .map(|i| i as i64)
            .collect::<Vec<_>>()
            .into_pyarray(py))
    }

    /// The rows of `transformations` (surest first) that are not duplicates of `taken` scan
    /// points or of a surer kept row (`pointclm::scene::peeling::not_duplicates`), and
    /// `taken` with the kept rows' points added (a new array).
    #[pyo3(signature = (transformations, radius, max_shared, taken, num_threads=None))]
    fn not_duplicates<'py>(
        &self,
        py: Python<'py>,
        #[pyo3(from_py_with = args::transformations)] transformations: PyReadonlyArray3<'py, f64>,
        #[pyo3(from_py_with = args::radius)] radius: f64,
        max_shared: f64,
        taken: PyReadonlyArray1<'py, bool>,
        #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
    ) -> PyResult<(Vec<usize>, Bound<'py, PyArray1<bool>>)> {
        let poses = rigid_poses(&transformations)?;
        let mut marks = taken.as_array().to_vec();
        let threads = num_threads.map(pool).transpose()?;
        let inner = Arc::clone(&self.inner);
        let (keep, marks) = guarded(py, threads, move || {
            let keep = scene::peeling::not_duplicates(
                inner.index(),
                inner.source(),
                &poses,
                radius,
                max_shared,
                &mut marks,
            )?;
            Ok::<_, pointclm::Error>((keep, marks))
        })?;
        Ok((keep, marks.into_pyarray(py)))
    }
}

/// `refine`'s poses back from its arrays (`columns`: confidence, fitness, visible fitness,
/// contradiction, seen, inlier RMSE, visible RMSE), each rotation block kept as given (it must
/// be a rotation up to rounding): a pose that comes back unchanged comes back bit for bit.
fn refined_from_arrays(
    transformations: &PyReadonlyArray3<'_, f64>,
    columns: &[PyReadonlyArray1<'_, f64>],
    origin: &[usize],
    by_visibility: bool,
) -> PyResult<pointcloud::Refined> {
    let mut poses = rigid_poses(transformations)?;
    let m = transformations.as_array();
    for (k, pose) in poses.iter_mut().enumerate() {
        pose.rotation = Matrix3::from_fn(|i, j| m[(k, i, j)]);
    }
    let n = poses.len();
    let columns: Vec<Vec<f64>> = columns.iter().map(|c| c.as_array().to_vec()).collect();
    if columns.len() != 7 || columns.iter().any(|c| c.len() != n) || origin.len() != n {
        return Err(InputError::new_err(format!(
            "poses need 7 score columns and an origin of {n} values each (one per \
             transformation), got {} columns",
            columns.len()
        )));
    }
    let poses = poses
        .into_iter()
        .enumerate()
        .map(|(k, pose)| pointcloud::RefinedPose {
            pose,
            confidence: columns[0][k],
            fitness: columns[1][k],
            visible_fitness: columns[2][k],
            contradiction: columns[3][k],
            seen: columns[4][k],
            inlier_rmse: columns[5][k],
            visible_rmse: columns[6][k],
            slid_fitness: f64::NAN,
            origin: origin[k],
        })
        .collect();
    Ok(pointcloud::Refined {
        poses,
        by_visibility,
        rejected: Vec::new(),
        sliding: Vec::new(),
    })
}

/// (K, 3, 3) matrices (the core checks that they are rotations).
fn rotation_blocks(a: &PyReadonlyArray3<'_, f64>) -> PyResult<Vec<Matrix3<f64>>> {
    let v = a.as_array();
    if v.shape()[1..] != [3, 3] {
        return Err(InputError::new_err(format!(
            "rotations must have shape (K, 3, 3), got {:?}",
            v.shape()
        )));
    }
    Ok((0..v.shape()[0])
        .map(|k| Matrix3::from_fn(|i, j| v[(k, i, j)]))
        .collect())
}

/// `refine_poses`' result as arrays (see its documentation): the kept poses, whether the
/// viewpoint judged, the rejections and the sliding poses.
fn refined_arrays<'py>(py: Python<'py>, out: &pointcloud::Refined) -> RefinedArrays<'py> {
    let (mats, columns, origin) = pose_columns(py, &out.poses);
    (
        mats,
        columns,
        origin,
        out.by_visibility,
        out.rejected
            .iter()
            .map(|r| (r.origin, r.rule, r.value, r.threshold))
            .collect(),
        pose_columns(py, &out.sliding),
    )
}

/// `poses` as arrays: transformations; confidence, fitness, visible fitness, contradiction,
/// seen, inlier RMSE, visible RMSE and slid fitness; origins.
fn pose_columns<'py>(py: Python<'py>, poses: &[pointcloud::RefinedPose]) -> PoseArrays<'py> {
    let mats: Vec<_> = poses.iter().map(|r| r.pose.to_matrix()).collect();
    let column = |f: fn(&pointcloud::RefinedPose) -> f64| {
        poses.iter().map(f).collect::<Vec<_>>().into_pyarray(py)
    };
    (
        matrices4(py, &mats),
        [
            column(|r| r.confidence),
            column(|r| r.fitness),
            column(|r| r.visible_fitness),
            column(|r| r.contradiction),
            column(|r| r.seen),
            column(|r| r.inlier_rmse),
            column(|r| r.visible_rmse),
            column(|r| r.slid_fitness),
        ],
        indices(py, &poses.iter().map(|r| r.origin).collect::<Vec<_>>()),
    )
}

type DescribedArrays<'py> = (
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyDict>,
);

/// The whole preprocessing of one cloud over one k-d tree: downsampled to `voxel_size` (None:
/// as given), normals estimated (unless given, which needs no downsampling) and signed towards
/// `towards` or away from `away_from` (neither: towards the origin), then FPFH. Radii default
/// to 2 (normals) and 5 (FPFH) voxels. Returns (points, normals, descriptors (N, 33), seconds
/// per stage).
#[pyfunction]
#[pyo3(
    signature = (points, voxel_size=None, normals=None, towards=None, away_from=None, normal_radius=None, normal_max_nn=30, feature_radius=None, feature_max_nn=100, variant="open3d".to_string(), num_threads=None),
    text_signature = "(points, voxel_size=None, normals=None, towards=None, away_from=None, normal_radius=None, normal_max_nn=30, feature_radius=None, feature_max_nn=100, variant='open3d', num_threads=None)"
)]
#[allow(clippy::too_many_arguments)]
pub fn describe<'py>(
    py: Python<'py>,
    #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'py, f64>,
    #[pyo3(from_py_with = args::optional_voxel_size)] voxel_size: Option<f64>,
    #[pyo3(from_py_with = args::optional_normals)] normals: Option<PyReadonlyArray2<'py, f64>>,
    #[pyo3(from_py_with = args::towards)] towards: Option<[f64; 3]>,
    #[pyo3(from_py_with = args::away_from)] away_from: Option<[f64; 3]>,
    #[pyo3(from_py_with = args::normal_radius)] normal_radius: Option<f64>,
    #[pyo3(from_py_with = args::normal_max_nn)] normal_max_nn: usize,
    #[pyo3(from_py_with = args::feature_radius)] feature_radius: Option<f64>,
    #[pyo3(from_py_with = args::feature_max_nn)] feature_max_nn: usize,
    #[pyo3(from_py_with = args::variant)] variant: String,
    #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
) -> PyResult<DescribedArrays<'py>> {
    let orientation = orientation(towards, away_from)?;
    let by_voxel = |k: f64| voxel_size.map(|v| k * v);
    let (normal_radius, feature_radius) = match (
        normal_radius.or(by_voxel(2.0)),
        feature_radius.or(by_voxel(5.0)),
    ) {
        (Some(n), Some(f)) => (n, f),
        // Given normals need no normal radius: the value is not used.
        (None, Some(f)) if normals.is_some() => (f, f),
        _ => {
            return Err(InputError::new_err(
                "without voxel_size, give feature_radius (and normal_radius or normals)",
            ))
        }
    };
    let params = pointcloud::DescribeParams {
        voxel_size,
        normal_radius,
        normal_max_nn,
        feature_radius,
        feature_max_nn,
        variant: fpfh_variant(&variant)?,
        orientation,
    };
    let p = rows3(&points, "points")?;
    let n = normals.map(|a| rows3(&a, "normals")).transpose()?;
    let threads = num_threads.map(pool).transpose()?;
    let d = guarded(py, threads, move || {
        pointcloud::describe(&p, n.as_deref(), &params)
    })?;
    let flat: Vec<f64> = (0..d.descriptors.len())
        .flat_map(|i| d.descriptors.row(i).iter().copied())
        .collect();
    let descriptors = Array2::from_shape_vec((d.descriptors.len(), d.descriptors.dim()), flat)
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    let timings = PyDict::new(py);
    timings.set_item("downsample", d.timings.downsample)?;
    timings.set_item("normals", d.timings.normals)?;
    timings.set_item("fpfh", d.timings.fpfh)?;
    Ok((
        rows_to_py(py, &d.points)?,
        rows_to_py(py, &d.normals)?,
        descriptors.into_pyarray(py),
        timings,
    ))
}

/// `towards=` / `away_from=`: at most one (neither: towards the origin).
fn orientation(towards: Option<[f64; 3]>, away_from: Option<[f64; 3]>) -> PyResult<Orientation> {
    match (towards, away_from) {
        (None, None) => Ok(Orientation::Towards([0.0; 3])),
        (Some(v), None) => Ok(Orientation::Towards(v)),
        (None, Some(v)) => Ok(Orientation::AwayFrom(v)),
        (Some(_), Some(_)) => Err(InputError::new_err("give towards= or away_from=, not both")),
    }
}

/// `variant=`: "open3d" or "pcl".
fn fpfh_variant(variant: &str) -> PyResult<FpfhVariant> {
    match variant {
        "open3d" => Ok(FpfhVariant::Open3d),
        "pcl" => Ok(FpfhVariant::Pcl),
        other => Err(InputError::new_err(format!(
            "variant must be 'open3d' or 'pcl', got {other:?}"
        ))),
    }
}

/// Voted poses (K, 4, 4) and their votes (K,).
type VotedArrays<'py> = (Bound<'py, PyArray3<f64>>, Bound<'py, PyArray1<i64>>);

/// A model's point pair features tabled for voting (Drost et al., CVPR 2010): pose
/// hypotheses of the copies in a scan, by `poses`.
#[pyclass(frozen, module = "pointclm._core", name = "PpfModel")]
pub struct PyPpfModel {
    inner: Arc<pointcloud::PpfModel>,
}

#[pymethods]
impl PyPpfModel {
    #[new]
    #[pyo3(signature = (points, normals, diameter, max_poses=200, reference_stride=5))]
    fn new(
        py: Python<'_>,
        #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'_, f64>,
        #[pyo3(from_py_with = args::normals)] normals: PyReadonlyArray2<'_, f64>,
        #[pyo3(from_py_with = args::diameter)] diameter: f64,
        #[pyo3(from_py_with = args::max_poses)] max_poses: usize,
        #[pyo3(from_py_with = args::reference_stride)] reference_stride: usize,
    ) -> PyResult<Self> {
        let p = rows3(&points, "points")?;
        let n = rows3(&normals, "normals")?;
        let params = pointcloud::PpfParams {
            max_poses,
            reference_stride,
            ..pointcloud::PpfParams::for_diameter(diameter)
        };
        let inner = guarded(py, None, move || pointcloud::PpfModel::new(&p, &n, params))?;
        Ok(Self {
            inner: Arc::new(inner),
        })
    }

    /// The number of sampled model points tabled.
    fn __len__(&self) -> usize {
        self.inner.len()
    }

    /// Pose hypotheses `T_scene_model` (K, 4, 4) for the scene points `rows`, and their votes
    /// (K,), most voted first.
    #[pyo3(signature = (points, normals, rows, offset=0, num_threads=None))]
    fn poses<'py>(
        &self,
        py: Python<'py>,
        #[pyo3(from_py_with = args::points)] points: PyReadonlyArray2<'py, f64>,
        #[pyo3(from_py_with = args::normals)] normals: PyReadonlyArray2<'py, f64>,
        #[pyo3(from_py_with = args::rows)] rows: Vec<usize>,
        #[pyo3(from_py_with = args::offset)] offset: usize,
        #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
    ) -> PyResult<VotedArrays<'py>> {
        let p = rows3(&points, "points")?;
        let n = rows3(&normals, "normals")?;
        let model = Arc::clone(&self.inner);
        let threads = num_threads.map(pool).transpose()?;
        let found = guarded(py, threads, move || model.poses(&p, &n, &rows, offset))?;
        let mats: Vec<_> = found.iter().map(|h| h.transform.to_matrix()).collect();
        let votes: Vec<i64> = found.iter().map(|h| i64::from(h.votes)).collect();
        Ok((matrices4(py, &mats), votes.into_pyarray(py)))
    }
}
