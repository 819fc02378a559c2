//! Python `Config` (passed as a dict of its fields) <-> core `Config`, field by field from the
//! core's [`Config::FIELDS`], so that a field is declared once (in the core) and this module
//! never names one.

use pointclm::config::{Field, Kind, Unit, Value};
use pointclm::{Assignment, Config};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

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
        let field = Config::FIELDS
            .iter()
            .find(|f| f.name == key)
            .ok_or_else(|| ConfigError::new_err(format!("unknown config field {key:?}")))?;
        let value = extract(field, &v)
            .map_err(|e| ConfigError::new_err(format!("config field {key}: {e}")))?;
        let set = c.set(field.name, value);
        debug_assert!(set, "extract gives a value of the field's kind");
    }
    c.validate().map_err(to_py_err)?;
    Ok(c)
}

/// A Python value as the core value of `field`, or why not (the extraction error, or the
/// names a choice may take).
fn extract(field: &Field, v: &Bound<'_, PyAny>) -> Result<Value, String> {
    if field.optional && v.is_none() {
        return Ok(Value::None);
    }
    let e = |e: PyErr| e.to_string();
    Ok(match field.kind {
        Kind::Float => Value::Float(v.extract().map_err(e)?),
        Kind::Count => Value::Count(v.extract().map_err(e)?),
        Kind::Bool => Value::Bool(v.extract().map_err(e)?),
        Kind::Choice(names) => {
            let s: String = v.extract().map_err(e)?;
            Value::Choice(choose(names, &s)?)
        }
    })
}

/// The name in `names` equal to `s`, or "expected 'a', 'b' or 'c', got \"s\"".
fn choose(names: &'static [&'static str], s: &str) -> Result<&'static str, String> {
    names
        .iter()
        .copied()
        .find(|n| *n == s)
        .ok_or_else(|| expected(names, s))
}

fn expected(names: &[&str], s: &str) -> String {
    let quoted: Vec<String> = names.iter().map(|n| format!("'{n}'")).collect();
    let list = match quoted.split_last() {
        Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
        _ => quoted.join(""),
    };
    format!("expected {list}, got {s:?}")
}

/// An assignment by name, or `error` (InputError for `spectral_clustering`'s argument).
pub fn assignment(s: &str, error: fn(String) -> PyErr) -> PyResult<Assignment> {
    Assignment::from_name(s)
        .ok_or_else(|| error(format!("assignment: {}", expected(Assignment::NAMES, s))))
}

fn to_py<'py>(py: Python<'py>, v: Value) -> PyResult<Bound<'py, PyAny>> {
    Ok(match v {
        Value::None => py.None().into_bound(py),
        Value::Float(x) => x.into_pyobject(py)?.into_any(),
        Value::Count(n) => n.into_pyobject(py)?.into_any(),
        Value::Bool(b) => b.into_pyobject(py)?.to_owned().into_any(),
        Value::Choice(s) => s.into_pyobject(py)?.into_any(),
    })
}

/// The defaults, as a dict.
pub fn defaults<'py>(py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
    to_dict(py, &Config::default())
}

pub fn to_dict<'py>(py: Python<'py>, c: &Config) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for (f, v) in c.values() {
        d.set_item(f.name, to_py(py, v)?)?;
    }
    Ok(d)
}

/// [`Config::FIELDS`] as a list of dicts, in declaration order: name, kind ("float", "count",
/// "bool" or "choice"), choices (the names, or None), optional, default, length (whether
/// `scaled` multiplies it) and doc.
pub fn schema<'py>(py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
    let list = PyList::empty(py);
    for (f, default) in Config::default().values() {
        let d = PyDict::new(py);
        d.set_item("name", f.name)?;
        let (kind, choices) = match f.kind {
            Kind::Float => ("float", None),
            Kind::Count => ("count", None),
            Kind::Bool => ("bool", None),
            Kind::Choice(names) => ("choice", Some(names.to_vec())),
        };
        d.set_item("kind", kind)?;
        d.set_item("choices", choices)?;
        d.set_item("optional", f.optional)?;
        d.set_item("default", to_py(py, default)?)?;
        d.set_item("length", f.unit == Unit::Length)?;
        d.set_item("doc", f.doc)?;
        list.append(d)?;
    }
    Ok(list)
}
