//! Python `Config` (passed as a dict of its fields) -> core `Config`, refusing unknown keys.

use pointclm::{Assignment, Config, Pruning};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::errors::{to_py_err, ConfigError};

pub fn from_dict(d: Option<&Bound<'_, PyDict>>) -> PyResult<Config> {
    let mut c = Config::default();
    let Some(d) = d else {
        return Ok(c);
    };
    for (k, v) in d.iter() {
        let key: String = k
            .extract()
            .map_err(|_| ConfigError::new_err(format!("config keys must be str, got {k}")))?;
        let bad = |e: PyErr| ConfigError::new_err(format!("config field {key}: {e}"));
        match key.as_str() {
            "sigma_d" => c.sigma_d = v.extract().map_err(bad)?,
            "pruning" => {
                let s: String = v.extract().map_err(bad)?;
                c.pruning = match s.as_str() {
                    "paper" => Pruning::Paper,
                    "authors" => Pruning::AuthorsCode,
                    "none" => Pruning::Disabled,
                    other => {
                        return Err(ConfigError::new_err(format!(
                            "config field pruning: expected 'paper', 'authors' or 'none', got {other:?}"
                        )))
                    }
                }
            }
            "tau_s" => c.tau_s = v.extract().map_err(bad)?,
            "tau_n" => c.tau_n = v.extract().map_err(bad)?,
            "beta_threshold" => c.beta_threshold = v.extract().map_err(bad)?,
            "feature_threshold" => c.feature_threshold = v.extract().map_err(bad)?,
            "min_count" => c.min_count = v.extract().map_err(bad)?,
            "max_kept" => c.max_kept = v.extract().map_err(bad)?,
            "affinity_sigma" => c.affinity_sigma = v.extract().map_err(bad)?,
            "max_instances" => c.max_instances = v.extract().map_err(bad)?,
            "max_rounds" => c.max_rounds = v.extract().map_err(bad)?,
            "cluster_level" => c.cluster_level = v.extract().map_err(bad)?,
            "assignment" => {
                let s: String = v.extract().map_err(bad)?;
                c.assignment = assignment(&s, ConfigError::new_err)?
            }
            "kmeans_restarts" => c.kmeans_restarts = v.extract().map_err(bad)?,
            "min_cluster_size" => c.min_cluster_size = v.extract().map_err(bad)?,
            "ransac_iterations" => c.ransac_iterations = v.extract().map_err(bad)?,
            "ransac_confidence" => c.ransac_confidence = v.extract().map_err(bad)?,
            "max_nfa" => c.max_nfa = v.extract().map_err(bad)?,
            "inlier_threshold" => c.inlier_threshold = v.extract().map_err(bad)?,
            "refine" => c.refine = v.extract().map_err(bad)?,
            "merge_duplicates" => c.merge_duplicates = v.extract().map_err(bad)?,
            other => {
                return Err(ConfigError::new_err(format!(
                    "unknown config field {other:?}"
                )))
            }
        }
    }
    c.validate().map_err(to_py_err)?;
    Ok(c)
}

/// An assignment by name, or `error` (InputError for `spectral_clustering`'s argument,
/// ConfigError for the config field).
pub fn assignment(s: &str, error: fn(String) -> PyErr) -> PyResult<Assignment> {
    match s {
        "kmeans" => Ok(Assignment::KMeans),
        "discretize" => Ok(Assignment::Discretize),
        other => Err(error(format!(
            "assignment: expected 'kmeans' or 'discretize', got {other:?}"
        ))),
    }
}

/// The defaults, as a dict, so the Python dataclass can be checked against them.
pub fn defaults<'py>(py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
    to_dict(py, &Config::default())
}

/// A config as the dict of `pointclm.Config`'s fields.
pub fn to_dict<'py>(py: Python<'py>, c: &Config) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("sigma_d", c.sigma_d)?;
    let pruning = match c.pruning {
        Pruning::Paper => "paper",
        Pruning::AuthorsCode => "authors",
        Pruning::Disabled => "none",
    };
    d.set_item("pruning", pruning)?;
    d.set_item("tau_s", c.tau_s)?;
    d.set_item("tau_n", c.tau_n)?;
    d.set_item("beta_threshold", c.beta_threshold)?;
    d.set_item("feature_threshold", c.feature_threshold)?;
    d.set_item("min_count", c.min_count)?;
    d.set_item("max_kept", c.max_kept)?;
    d.set_item("affinity_sigma", c.affinity_sigma)?;
    d.set_item("max_instances", c.max_instances)?;
    d.set_item("max_rounds", c.max_rounds)?;
    d.set_item("cluster_level", c.cluster_level)?;
    let assignment = match c.assignment {
        Assignment::KMeans => "kmeans",
        Assignment::Discretize => "discretize",
    };
    d.set_item("assignment", assignment)?;
    d.set_item("kmeans_restarts", c.kmeans_restarts)?;
    d.set_item("min_cluster_size", c.min_cluster_size)?;
    d.set_item("ransac_iterations", c.ransac_iterations)?;
    d.set_item("ransac_confidence", c.ransac_confidence)?;
    d.set_item("max_nfa", c.max_nfa)?;
    d.set_item("inlier_threshold", c.inlier_threshold)?;
    d.set_item("refine", c.refine)?;
    d.set_item("merge_duplicates", c.merge_duplicates)?;
    Ok(d)
}
