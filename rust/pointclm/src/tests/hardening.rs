//! Hardening of the entry points: property tests that feed the weights reader,
//! `Config::validate` and `register` arbitrary input and assert a typed error or a result,
//! never a panic; and unit tests of cancellation, extreme magnitudes and size checks.
//!
//! Case counts are capped (`CASES`) so that the whole suite stays fast; raise them with
//! `PROPTEST_CASES=N` for a longer local run.

use proptest::prelude::*;
use serde_json::{json, Value};

use super::*;
use crate::cancel::CancelToken;
use crate::config::{bounds, Assignment, Pruning};
use crate::network::Network;
use crate::testing::random_scene;

/// Cases per property (proptest's default is 256; these run every `cargo test`).
const CASES: u32 = 64;

pub(super) fn shipped_weights() -> (Vec<u8>, String) {
    let dir = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../python/pointclm/weights/"
    );
    (
        std::fs::read(format!("{dir}default.safetensors")).unwrap(),
        std::fs::read_to_string(format!("{dir}default.json")).unwrap(),
    )
}

// ---- the weights reader ----

/// Any JSON value, a few levels deep.
fn json_value() -> impl Strategy<Value = Value> {
    let leaf = prop_oneof![
        Just(Value::Null),
        any::<bool>().prop_map(Value::from),
        any::<i64>().prop_map(Value::from),
        any::<u64>().prop_map(Value::from),
        any::<f64>().prop_map(|v| json!(v)),
        "[a-z_]{0,12}".prop_map(Value::from),
    ];
    leaf.prop_recursive(3, 24, 6, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..6).prop_map(Value::from),
            prop::collection::btree_map("[a-z_]{1,16}", inner, 0..6)
                .prop_map(|m| Value::Object(m.into_iter().collect())),
        ]
    })
}

/// Sizes that probe the edges: tiny, plausible, and absurd (the depth of the hardening tests).
fn size() -> impl Strategy<Value = Value> {
    prop_oneof![
        (0u64..10).prop_map(Value::from),
        Just(json!(32)),
        Just(json!(1_000_000_000u64)),
        Just(json!(u64::MAX)),
        any::<u64>().prop_map(Value::from),
        any::<i64>().prop_map(Value::from),
        any::<f64>().prop_map(|v| json!(v)),
    ]
}

/// Metadata that is mostly well-formed, so that the reader gets past the JSON checks.
fn metadata() -> impl Strategy<Value = String> {
    prop_oneof![
        json_value().prop_map(|v| v.to_string()),
        (
            size(),
            size(),
            any::<f64>(),
            proptest::option::of(json_value())
        )
            .prop_map(|(depth, width, sigma_d, rec)| {
                let mut m =
                    json!({"architecture": {"depth": depth, "width": width, "sigma_d": sigma_d}});
                if let Some(r) = rec {
                    m["recommended_config"] = r;
                }
                m.to_string()
            }),
        ".{0,64}",
    ]
}

/// Safetensors bytes: random, or the shipped file truncated and with bytes overwritten.
fn weight_bytes() -> impl Strategy<Value = Vec<u8>> {
    let (shipped, _) = shipped_weights();
    let len = shipped.len();
    prop_oneof![
        prop::collection::vec(any::<u8>(), 0..256),
        (0..=len, prop::collection::vec((0..len, any::<u8>()), 0..8)).prop_map(
            move |(cut, edits)| {
                let mut b = shipped.clone();
                for (at, v) in edits {
                    b[at] = v;
                }
                b.truncate(cut);
                b
            }
        ),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: CASES, ..ProptestConfig::default() })]

    #[test]
    fn weights_reader_returns_a_network_or_a_typed_error(
        bytes in weight_bytes(),
        meta in metadata(),
    ) {
        match Network::from_bytes(&bytes, &meta, "fuzzed") {
            Ok(net) => prop_assert!(net.architecture().depth >= 1),
            Err(Error::WeightsMalformed { .. } | Error::TensorMissing { .. } | Error::TensorShape { .. }) => {}
            Err(e) => prop_assert!(false, "unexpected error kind: {e}"),
        }
    }

    #[test]
    fn shipped_tensors_with_any_architecture_load_or_fail_typed(
        depth in size(),
        width in size(),
    ) {
        let (bytes, _) = shipped_weights();
        let meta = json!({"architecture": {"depth": depth, "width": width, "sigma_d": 0.05}});
        match Network::from_bytes(&bytes, &meta.to_string(), "shipped") {
            Ok(net) => prop_assert!(net.architecture().depth <= 64),
            Err(Error::WeightsMalformed { .. } | Error::TensorMissing { .. } | Error::TensorShape { .. }) => {}
            Err(e) => prop_assert!(false, "unexpected error kind: {e}"),
        }
    }
}

#[test]
fn an_absurd_depth_is_refused_before_allocating() {
    let (bytes, meta) = shipped_weights();
    let mut m: Value = serde_json::from_str(&meta).unwrap();
    for (depth, width) in [
        (json!(1_000_000_000u64), m["architecture"]["width"].clone()),
        (json!(1), json!(1u64 << 40)),
        (json!(usize::MAX), json!(usize::MAX - 1)),
    ] {
        m["architecture"]["depth"] = depth;
        m["architecture"]["width"] = width;
        let err = Network::from_bytes(&bytes, &m.to_string(), "x").unwrap_err();
        assert!(
            matches!(err, Error::WeightsMalformed { ref reason, .. } if reason.contains("needs")),
            "{err}"
        );
    }
}

#[test]
fn only_regular_files_are_read_as_weights() {
    let err = Network::from_file("/dev/zero").unwrap_err();
    assert!(matches!(err, Error::WeightsNotFound { ref reason, .. } if reason.contains("regular")));
    let err = Network::from_file(std::env::temp_dir()).unwrap_err();
    assert!(matches!(err, Error::WeightsNotFound { .. }));
}

// ---- Config::validate ----

pub(super) fn count() -> impl Strategy<Value = usize> {
    prop_oneof![
        0usize..64,
        any::<usize>(),
        Just(bounds::MAX_KEPT),
        Just(bounds::MAX_KEPT + 1)
    ]
}

fn length() -> impl Strategy<Value = f64> {
    prop_oneof![
        any::<f64>(),
        1e-3f64..10.0,
        Just(0.0),
        Just(f64::NAN),
        Just(f64::INFINITY)
    ]
}

prop_compose! {
    pub(super) fn arbitrary_config()(
        lengths in (length(), length(), length()),
        thresholds in (any::<f64>(), any::<f64>(), any::<f64>(), -1.0f64..1.0),
        counts in (count(), count(), count(), count(), count(), count()),
        max_instances in proptest::option::of(count()),
        flags in (any::<bool>(), any::<bool>(), any::<bool>(), 0u8..3),
    ) -> Config {
        Config {
            sigma_d: lengths.0,
            affinity_sigma: lengths.1,
            inlier_threshold: lengths.2,
            tau_s: if flags.2 { thresholds.3 } else { thresholds.0 },
            beta_threshold: thresholds.1,
            feature_threshold: thresholds.2,
            tau_n: counts.0,
            min_count: counts.1,
            max_kept: counts.2,
            kmeans_restarts: counts.3,
            min_cluster_size: counts.4,
            ransac_iterations: counts.5,
            ransac_confidence: if flags.1 { 1.0 } else { thresholds.1 },
            max_nfa: max_instances.map(|m| m as f64 * 1e-3),
            max_rounds: counts.0,
            cluster_level: max_instances.map(|m| (0.1 * m as f64).min(1.9)),
            max_instances,
            pruning: [Pruning::Paper, Pruning::AuthorsCode, Pruning::Disabled][flags.3 as usize],
            assignment: if flags.0 { Assignment::KMeans } else { Assignment::Discretize },
            refine: flags.1,
            merge_duplicates: flags.0,
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 4 * CASES, ..ProptestConfig::default() })]

    #[test]
    fn validate_accepts_only_bounded_configs(c in arbitrary_config()) {
        match c.validate() {
            Ok(()) => {
                for v in [c.sigma_d, c.affinity_sigma, c.inlier_threshold] {
                    prop_assert!(v.is_finite() && v > 0.0);
                }
                prop_assert!(c.ransac_iterations <= bounds::RANSAC_ITERATIONS);
                prop_assert!(c.kmeans_restarts <= bounds::KMEANS_RESTARTS);
                prop_assert!(c.max_kept <= bounds::MAX_KEPT);
                prop_assert!((1..=bounds::MAX_ROUNDS).contains(&c.max_rounds));
                prop_assert!(c.ransac_confidence > 0.0 && c.ransac_confidence <= 1.0);
                prop_assert!((3..=c.max_kept).contains(&c.min_cluster_size));
                prop_assert!(c.max_instances.is_none_or(|m| (1..=bounds::MAX_INSTANCES).contains(&m)));
            }
            Err(Error::InvalidConfig { .. } | Error::ConfigOutOfRange { .. }) => {}
            Err(e) => prop_assert!(false, "unexpected error kind: {e}"),
        }
    }
}

#[test]
fn every_count_has_a_bound_named_in_the_message() {
    let base = Config::default();
    let cases: [(&str, Config); 6] = [
        (
            "ransac_iterations",
            Config {
                ransac_iterations: 1_000_000_000_000,
                ..base.clone()
            },
        ),
        (
            "kmeans_restarts",
            Config {
                kmeans_restarts: bounds::KMEANS_RESTARTS + 1,
                ..base.clone()
            },
        ),
        (
            "max_kept",
            Config {
                max_kept: bounds::MAX_KEPT + 1,
                ..base.clone()
            },
        ),
        (
            "tau_n",
            Config {
                tau_n: usize::MAX,
                ..base.clone()
            },
        ),
        (
            "min_count",
            Config {
                min_count: usize::MAX,
                ..base.clone()
            },
        ),
        (
            "max_instances",
            Config {
                max_instances: Some(usize::MAX),
                ..base.clone()
            },
        ),
    ];
    for (field, c) in cases {
        let msg = c.validate().unwrap_err().to_string();
        assert!(msg.contains(field) && msg.contains("..="), "{msg}");
    }
}

// ---- register on arbitrary arrays ----

/// Coordinates across f64's whole range, non-finite values included.
pub(super) fn coordinate() -> impl Strategy<Value = f64> {
    prop_oneof![
        4 => -10.0f64..10.0,
        2 => any::<f64>(),
        1 => (-1074i32..1024, any::<bool>()).prop_map(|(e, neg)| {
            let v = 2f64.powi(e / 2) * 2f64.powi(e - e / 2);
            if neg { -v } else { v }
        }),
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(0.0),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: CASES, ..ProptestConfig::default() })]

    #[test]
    fn register_never_panics(
        rows in prop::collection::vec(prop::array::uniform6(coordinate()), 0..40),
        scale in prop_oneof![Just(1.0), any::<f64>().prop_filter("positive", |v| *v > 0.0)],
        seed in any::<u64>(),
    ) {
        let Ok(c) = Correspondences::from_rows(&rows) else {
            // non-finite values and too few rows are refused at construction
            prop_assert!(rows.len() < 3 || rows.iter().flatten().any(|v| !v.is_finite()));
            return Ok(());
        };
        let config = Config { min_cluster_size: 3, tau_n: 2, ..Config::default() }.scaled(scale);
        match register(&c, None, &config, seed) {
            Ok(r) => {
                prop_assert_eq!(r.labels.len(), c.len());
                for inst in &r.instances {
                    prop_assert!(inst.pose.translation.iter().all(|t| t.is_finite()));
                }
            }
            Err(Error::InvalidConfig { .. } | Error::ConfigOutOfRange { .. } | Error::MagnitudeRange { .. }) => {}
            Err(e) => prop_assert!(false, "unexpected error kind: {e}"),
        }
    }

    #[test]
    fn registration_is_equivariant_under_extreme_scales(
        exponent in prop_oneof![-1000i32..-300, 300i32..1000],
        seed in 0u64..1000,
    ) {
        let scene = random_scene(120, 2, 0.4, seed);
        let config = Config { min_cluster_size: 5, ..Config::default() };
        let base = register(&scene.corr, None, &config, 0).unwrap();
        let factor = |x: f64| magnitude::times_pow2(x, exponent);
        let rows: Vec<[f64; 6]> = (0..scene.corr.len())
            .map(|i| {
                let (s, t) = (scene.corr.source(i), scene.corr.target(i));
                [s[0], s[1], s[2], t[0], t[1], t[2]].map(factor)
            })
            .collect();
        let c = Correspondences::from_rows(&rows).unwrap();
        let scaled_config = Config {
            sigma_d: factor(config.sigma_d),
            affinity_sigma: factor(config.affinity_sigma),
            inlier_threshold: factor(config.inlier_threshold),
            ..config
        };
        let r = register(&c, None, &scaled_config, 0).unwrap();
        prop_assert_eq!(&r.labels, &base.labels);
        prop_assert_eq!(r.instances.len(), base.instances.len());
        for (a, b) in r.instances.iter().zip(&base.instances) {
            prop_assert_eq!(a.pose.rotation, b.pose.rotation);
            prop_assert_eq!(a.pose.translation, b.pose.translation.map(factor));
        }
    }
}

// ---- magnitudes, cancellation ----

#[test]
fn ordinary_magnitudes_are_not_rescaled() {
    let scene = random_scene(100, 1, 0.5, 3);
    assert_eq!(
        magnitude::scale_exponent(&scene.corr, &Config::default()),
        Ok(0)
    );
    let shifted: Vec<[f64; 6]> = (0..100)
        .map(|i| {
            let (s, t) = (scene.corr.source(i), scene.corr.target(i));
            [s[0] + 1e12, s[1], s[2], t[0] + 1e12, t[1], t[2]]
        })
        .collect();
    let c = Correspondences::from_rows(&shifted).unwrap();
    assert_eq!(magnitude::scale_exponent(&c, &Config::default()), Ok(0));
}

#[test]
fn magnitudes_no_scale_can_hold_are_a_typed_error() {
    let scene = random_scene(50, 1, 0.5, 4);
    let rows: Vec<[f64; 6]> = (0..50)
        .map(|i| {
            let (s, t) = (scene.corr.source(i), scene.corr.target(i));
            [s[0] * 1e200, s[1], s[2], t[0], t[1], t[2]]
        })
        .collect();
    let c = Correspondences::from_rows(&rows).unwrap();
    let err = register(&c, None, &Config::default(), 0).unwrap_err();
    assert!(matches!(err, Error::MagnitudeRange { .. }), "{err}");
}

#[test]
fn a_cancelled_token_stops_every_entry_point() {
    let scene = random_scene(200, 2, 0.4, 5);
    let token = CancelToken::new();
    let config = Config::default();
    assert!(token
        .run(|| register(&scene.corr, None, &config, 0))
        .is_ok());
    token.cancel();
    assert_eq!(
        token.run(|| register(&scene.corr, None, &config, 0)),
        Err(Error::Cancelled)
    );
    let scenes = vec![
        Scene {
            correspondences: scene.corr.clone(),
            features: None,
        };
        3
    ];
    assert_eq!(
        token.run(|| register_batch(&scenes, &config, 0, 2)),
        Err(Error::Cancelled)
    );
    let (bytes, meta) = shipped_weights();
    let net = Network::from_bytes(&bytes, &meta, "default").unwrap();
    assert_eq!(token.run(|| net.embed(&scene.corr)), Err(Error::Cancelled));
    // outside the token's scope nothing is cancelled
    assert!(register(&scene.corr, None, &config, 0).is_ok());
}
