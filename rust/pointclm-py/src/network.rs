//! `Network`: a trained embedding network, loaded and evaluated by the core crate (no torch).

use std::path::PathBuf;
use std::sync::Arc;

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};

use crate::pools::{guarded, pool};
use crate::{args, config, convert};

/// A trained SCNonlocal embedding network, read from a `.safetensors` file and the `.json`
/// of its architecture beside it. Loading fails with `pointclm.errors.WeightsNotFoundError`
/// (a FileNotFoundError) when either file is missing or unreadable, and with `WeightsError`
/// when it does not describe a valid network (both are ValueErrors).
#[pyclass(frozen, module = "pointclm._core", name = "Network")]
pub struct PyNetwork {
    pub(crate) inner: Arc<pointclm::Network>,
    path: PathBuf,
}

#[pymethods]
impl PyNetwork {
    #[new]
    fn new(py: Python<'_>, #[pyo3(from_py_with = args::path)] path: PathBuf) -> PyResult<Self> {
        let p = path.clone();
        let inner = guarded(py, None, move || pointclm::Network::from_file(&p))?;
        Ok(Self {
            inner: Arc::new(inner),
            path,
        })
    }

    /// The `.safetensors` file it was loaded from.
    #[getter]
    fn path(&self) -> PathBuf {
        self.path.clone()
    }

    /// Number of [pointcn, non-local] blocks.
    #[getter]
    fn depth(&self) -> usize {
        self.inner.architecture().depth
    }

    /// Channels per block, the dimension of the embedding.
    #[getter]
    fn width(&self) -> usize {
        self.inner.architecture().width
    }

    /// Length tolerance of the `beta` that scales the attention.
    #[getter]
    fn sigma_d(&self) -> f64 {
        self.inner.architecture().sigma_d
    }

    /// The inputs beyond the coordinates that the network reads ("normals", "similarity"), in
    /// the order of its input channels; empty for the plain network.
    #[getter]
    fn inputs<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        PyTuple::new(py, self.inner.architecture().inputs.names())
    }

    /// Cosine tolerance of the normal term of `beta` (used with the "normals" input only).
    #[getter]
    fn normal_tolerance(&self) -> f64 {
        self.inner.architecture().normal_tolerance
    }

    /// What the BatchNorms normalise with: "running" (the statistics gathered in training)
    /// or "scene" (the mean and variance over the embedded scene's own correspondences).
    #[getter]
    fn normalization(&self) -> &'static str {
        self.inner.architecture().normalization.name()
    }

    /// The config (all fields) with the thresholds recommended in the weights' metadata.
    fn recommended_config<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        config::to_dict(py, &self.inner.recommended_config())
    }

    /// (N, 6) correspondences (any real dtype; converted to float64) -> (N, width) unit-norm
    /// float64 embeddings. A network with `inputs` also needs `normals` ((N, 6), source normal
    /// | target normal, rescaled to unit length; or given as columns 7-12 of (N, 12)
    /// correspondences) and `similarity` ((N,), the descriptor similarity of each match) where
    /// it reads them; those it does not read are ignored. Where more than 1/16 of the pairs
    /// (or more than 50 million) are length-consistent, the dense attention runs (time ~ N^2)
    /// and more than 32,768 correspondences are an InputError (a ValueError).
    #[pyo3(signature = (correspondences, normals=None, similarity=None, num_threads=None))]
    fn embed<'py>(
        &self,
        py: Python<'py>,
        #[pyo3(from_py_with = args::correspondences)] correspondences: PyReadonlyArray2<'py, f64>,
        #[pyo3(from_py_with = args::optional_normals)] normals: Option<PyReadonlyArray2<'py, f64>>,
        #[pyo3(from_py_with = args::optional_similarity)] similarity: Option<
            PyReadonlyArray1<'py, f64>,
        >,
        #[pyo3(from_py_with = args::num_threads)] num_threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let c = convert::network_inputs(
            convert::correspondences(&correspondences)?,
            normals.as_ref(),
            similarity.as_ref(),
            self.inner.architecture().normal_tolerance,
        )?;
        let p = num_threads.map(pool).transpose()?;
        let net = self.inner.clone();
        let f = guarded(py, p, move || net.embed(&c))?;
        let dim = f.dim();
        let a = Array2::from_shape_fn((f.len(), dim), |(i, j)| f.row(i)[j]);
        Ok(a.into_pyarray(py))
    }

    fn __repr__(&self) -> String {
        let a = self.inner.architecture();
        let mut r = format!(
            "Network(path={:?}, depth={}, width={}, sigma_d={}",
            self.path.display().to_string(),
            a.depth,
            a.width,
            a.sigma_d
        );
        let names = a.inputs.names();
        if !names.is_empty() {
            // Python's tuple repr, one-element tuples included
            let quoted: Vec<String> = names.iter().map(|n| format!("'{n}'")).collect();
            let comma = if names.len() == 1 { "," } else { "" };
            r += &format!(
                ", inputs=({}{comma}), normal_tolerance={}",
                quoted.join(", "),
                a.normal_tolerance
            );
        }
        if a.normalization != pointclm::Normalization::Running {
            r += &format!(", normalization='{}'", a.normalization.name());
        }
        r + ")"
    }
}
