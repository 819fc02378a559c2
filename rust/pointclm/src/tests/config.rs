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
