//! Result classes in Open3D's vocabulary (`transformation`, `fitness`, `inlier_rmse`,
//! `correspondence_set`).

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert::{indices, matrices4, matrix4};

/// One registered copy of the source in the target.
#[pyclass(frozen, module = "pointclm._core", name = "Instance")]
pub struct PyInstance {
    transformation: [[f64; 4]; 4],
    inliers: Vec<usize>,
    #[pyo3(get)]
    fitness: f64,
    #[pyo3(get)]
    inlier_rmse: f64,
}

#[pymethods]
impl PyInstance {
    /// `T_target_source` (4x4): maps source points onto this copy.
    #[getter]
    fn transformation<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        matrix4(py, &self.transformation)
    }

    /// Indices of the correspondences explained by this instance.
    #[getter]
    fn inliers<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i64>> {
        indices(py, &self.inliers)
    }

    /// `(K, 2)` pairs (source row, target row), as Open3D reports them; with
    /// correspondences given as rows both columns hold the same row index.
    #[getter]
    fn correspondence_set<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<i64>> {
        Array2::from_shape_fn((self.inliers.len(), 2), |(i, _)| self.inliers[i] as i64)
            .into_pyarray(py)
    }

    fn __len__(&self) -> usize {
        self.inliers.len()
    }

    fn __repr__(&self) -> String {
        let t = &self.transformation;
        format!(
            "Instance(inliers={}, fitness={:.4}, inlier_rmse={:.4}, translation=[{:.4}, {:.4}, {:.4}])",
            self.inliers.len(),
            self.fitness,
            self.inlier_rmse,
            t[0][3],
            t[1][3],
            t[2][3]
        )
    }
}

/// Every instance found in one scene, plus a label per correspondence.
#[pyclass(frozen, module = "pointclm._core", name = "RegistrationResult")]
pub struct PyRegistration {
    instances: Vec<Py<PyInstance>>,
    matrices: Vec<[[f64; 4]; 4]>,
    labels: Vec<i64>,
    kept: Vec<usize>,
    #[pyo3(get)]
    n_clusters: usize,
    timings: pointclm::StageTimings,
}

impl PyRegistration {
    pub fn new(py: Python<'_>, r: pointclm::Registration) -> PyResult<Self> {
        let matrices: Vec<_> = r.instances.iter().map(|i| i.pose.to_matrix()).collect();
        let instances = r
            .instances
            .into_iter()
            .zip(&matrices)
            .map(|(i, m)| {
                Py::new(
                    py,
                    PyInstance {
                        transformation: *m,
                        inliers: i.inliers,
                        fitness: i.fitness,
                        inlier_rmse: i.inlier_rmse,
                    },
                )
            })
            .collect::<PyResult<_>>()?;
        Ok(Self {
            instances,
            matrices,
            labels: r.labels,
            kept: r.kept,
            n_clusters: r.n_clusters,
            timings: r.timings,
        })
    }
}

#[pymethods]
impl PyRegistration {
    /// The registered instances, most inliers first.
    #[getter]
    fn instances(&self, py: Python<'_>) -> Vec<Py<PyInstance>> {
        self.instances.iter().map(|i| i.clone_ref(py)).collect()
    }

    /// `(M, 4, 4)` stack of `T_target_source`, in the order of `instances`.
    #[getter]
    fn transformations<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray3<f64>> {
        matrices4(py, &self.matrices)
    }

    /// `(N,)`: -1 for an outlier, k for `instances[k]`.
    #[getter]
    fn labels<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i64>> {
        self.labels.clone().into_pyarray(py)
    }

    /// Indices of the correspondences that survived density pruning.
    #[getter]
    fn kept<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i64>> {
        indices(py, &self.kept)
    }

    /// Seconds per stage: embedding (with a Rust network only), pruning, clustering, poses.
    #[getter]
    fn timings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        if self.timings.embedding > 0.0 {
            d.set_item("embedding", self.timings.embedding)?;
        }
        d.set_item("pruning", self.timings.pruning)?;
        d.set_item("clustering", self.timings.clustering)?;
        d.set_item("poses", self.timings.poses)?;
        Ok(d)
    }

    fn __len__(&self) -> usize {
        self.instances.len()
    }

    fn __getitem__(&self, py: Python<'_>, index: isize) -> PyResult<Py<PyInstance>> {
        let n = self.instances.len() as isize;
        let k = if index < 0 { index + n } else { index };
        if !(0..n).contains(&k) {
            return Err(pyo3::exceptions::PyIndexError::new_err(format!(
                "instance index {index} out of range for {n} instances"
            )));
        }
        Ok(self.instances[k as usize].clone_ref(py))
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        let outliers = self.labels.iter().filter(|&&l| l < 0).count();
        let mut s = format!(
            "RegistrationResult({} instances, {} correspondences, {} kept after pruning, {} outliers)",
            self.instances.len(),
            self.labels.len(),
            self.kept.len(),
            outliers
        );
        for (k, inst) in self.instances.iter().enumerate() {
            s.push_str(&format!("\n  [{k}] {}", inst.borrow(py).__repr__()));
        }
        s
    }
}
