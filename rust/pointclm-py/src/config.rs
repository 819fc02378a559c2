//! Python `Config` (passed as a dict of its fields) <-> core `Config`, field by field from the
//! core's [`Config::FIELDS`], so that a field is declared once (in the core) and this module
//! never names one.

use pointclm::config::{Declared, Field, Kind, Unit, Value};
use pointclm::{Assignment, Config};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::errors::{to_py_err, ConfigError};

pub fn from_dict(d: Option<&Bound<'_, PyDict>>) -> PyResult<Config> {
    let c = declared_from_dict(Config::default(), d, "config")?;
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

/// `base` with the fields `d` names set (by name, checked by kind); `what` names the struct
/// in errors. Ranges are the caller's to check.
pub fn declared_from_dict<T: Declared>(
    mut base: T,
    d: Option<&Bound<'_, PyDict>>,
    what: &str,
) -> PyResult<T> {
    let Some(d) = d else {
        return Ok(base);
    };
    for (k, v) in d.iter() {
        let key: String = k
            .extract()
            .map_err(|_| ConfigError::new_err(format!("{what} keys must be str, got {k}")))?;
        let field = T::FIELDS.iter().find(|f| f.name == key).ok_or_else(|| {
            let names: Vec<&str> = T::FIELDS.iter().map(|f| f.name).collect();
            ConfigError::new_err(format!(
                "unknown {what} field {key:?}; valid fields are {}",
                names.join(", ")
            ))
        })?;
        let value = extract(field, &v)
            .map_err(|e| ConfigError::new_err(format!("{what} field {key}: {e}")))?;
        let set = base.set(field.name, value);
        debug_assert!(set, "extract gives a value of the field's kind");
    }
    if let Some((field, value)) = base.out_of_range() {
        let (lo, hi) = field.range.unwrap_or((f64::NAN, f64::NAN));
        return Err(ConfigError::new_err(format!(
            "{what} field {}: {value} is out of range, must lie in [{lo}, {hi}]",
            field.name
        )));
    }
    Ok(base)
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
/// `scaled` multiplies it), unit ("length" or "unitless"), range (`(lo, hi)` or None) and doc.
pub fn schema<'py>(py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
    declared_schema(py, &Config::default())
}

/// [`schema`] of any declared struct, with `defaults` as the defaults.
pub fn declared_schema<'py, T: Declared>(
    py: Python<'py>,
    defaults: &T,
) -> PyResult<Bound<'py, PyList>> {
    let list = PyList::empty(py);
    for (f, default) in defaults.values() {
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
        let unit = match f.unit {
            Unit::Length => "length",
            Unit::Unitless => "unitless",
        };
        d.set_item("unit", unit)?;
        d.set_item("range", f.range)?;
        d.set_item("doc", f.doc)?;
        list.append(d)?;
    }
    Ok(list)
}
