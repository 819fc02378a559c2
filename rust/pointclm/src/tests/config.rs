//! Unit tests of `config`.

use super::*;

#[test]
fn default_is_valid() {
    Config::default().validate().unwrap();
}

#[test]
fn bad_values_are_named() {
    let c = Config {
        sigma_d: f64::NAN,
        ..Config::default()
    };
    match c.validate() {
        Err(Error::InvalidConfig { field, .. }) => assert_eq!(field, "sigma_d"),
        other => panic!("{other:?}"),
    }
    let c = Config {
        min_cluster_size: 2,
        ..Config::default()
    };
    assert!(c.validate().is_err());
}

#[test]
fn scaled_multiplies_lengths_only() {
    let c = Config::default().scaled(10.0);
    assert!((c.sigma_d - 0.5).abs() < 1e-12);
    assert!((c.inlier_threshold - 1.0).abs() < 1e-12);
    assert_eq!(c.tau_n, 10);
}

#[test]
fn fields_describe_every_field_once() {
    let c = Config::default();
    let names: Vec<&str> = Config::FIELDS.iter().map(|f| f.name).collect();
    let mut unique = names.clone();
    unique.sort_unstable();
    unique.dedup();
    assert_eq!(unique.len(), names.len());
    // the Debug output lists the struct's fields in declaration order
    let debug = format!("{c:?}");
    let mut at = 0;
    for name in &names {
        let found = debug[at..]
            .find(&format!(" {name}: "))
            .unwrap_or_else(|| panic!("{name}"));
        at += found + 1;
    }
    assert_eq!(debug.matches(": ").count(), names.len());
    for f in Config::FIELDS {
        assert!(!f.doc.trim().is_empty(), "{} has no doc", f.name);
        let value = c.get(f.name).unwrap();
        assert_eq!(f.optional, matches!(value, Value::None) || f.optional);
        if f.unit == Unit::Length {
            assert!(
                matches!(value, Value::Float(_)) && !f.optional,
                "{}",
                f.name
            );
        }
    }
    assert_eq!(c.get("nope"), None);
}

#[test]
fn set_and_get_round_trip_and_refuse_other_kinds() {
    let mut c = Config::default();
    for f in Config::FIELDS {
        let v = c.get(f.name).unwrap();
        assert!(c.set(f.name, v), "{}", f.name);
    }
    assert_eq!(c, Config::default());
    assert!(c.set("tau_n", Value::Count(3)));
    assert_eq!(c.tau_n, 3);
    assert!(c.set("pruning", Value::Choice("authors")));
    assert_eq!(c.pruning, Pruning::AuthorsCode);
    assert!(c.set("max_nfa", Value::None));
    assert_eq!(c.max_nfa, None);
    assert!(c.set("max_instances", Value::Count(4)));
    assert_eq!(c.max_instances, Some(4));
    let before = c.clone();
    assert!(!c.set("tau_n", Value::Float(3.0)));
    assert!(!c.set("tau_n", Value::None));
    assert!(!c.set("pruning", Value::Choice("nope")));
    assert!(!c.set("nope", Value::Bool(true)));
    assert_eq!(c, before);
}

#[test]
fn choices_have_names_both_ways() {
    for &name in Pruning::NAMES {
        assert_eq!(Pruning::from_name(name).unwrap().name(), name);
    }
    for &name in Assignment::NAMES {
        assert_eq!(Assignment::from_name(name).unwrap().name(), name);
    }
    assert_eq!(Pruning::from_name("Paper"), None);
    let pruning = Config::FIELDS.iter().find(|f| f.name == "pruning").unwrap();
    assert_eq!(pruning.kind, Kind::Choice(&["paper", "authors", "none"]));
}

#[test]
fn scaled_multiplies_exactly_the_length_fields() {
    let (c, s) = (Config::default(), Config::default().scaled(4.0));
    for f in Config::FIELDS {
        let (a, b) = (c.get(f.name).unwrap(), s.get(f.name).unwrap());
        match (f.unit, a, b) {
            (Unit::Length, Value::Float(a), Value::Float(b)) => assert_eq!(b, a * 4.0),
            (Unit::Unitless, a, b) => assert_eq!(a, b, "{}", f.name),
            other => panic!("{}: {other:?}", f.name),
        }
    }
}
