//! Fuzzing of the entry points that take user data beyond `register`'s rows (those are in
//! `hardening`): point clouds of any floats and lengths through downsampling, the index,
//! normals, FPFH, the scale estimates and the sensor estimate; `register_point_clouds` with
//! any options and scene rules; `register` with any features and any config; the network on
//! any correspondences; `register_batch`. Each must return a result or an `Err`, never panic.
//!
//! Budgets: `CASES` per property (raise with `PROPTEST_CASES=N`), small clouds, so that the
//! module adds well under a minute to a debug `cargo test`.

use proptest::prelude::*;

use super::hardening::{arbitrary_config, coordinate, count, shipped_weights};
use super::*;
use crate::config::{Declared, Kind, Value};
use crate::network::Network;
use crate::pointcloud::{
    estimate_normals, estimate_sensor, fpfh, voxel_downsample, FpfhVariant, Orientation, PointIndex,
};
use crate::scene::voxel::{default_voxel_size, scan_scales};
use crate::scene::{register_point_clouds, SceneOptions, SceneRules};
use crate::testing::random_scene;

const CASES: u32 = 256;

/// `n` cases, or `PROPTEST_CASES` when set (a longer hunt).
fn cases(n: u32) -> u32 {
    std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(n)
}

fn point() -> impl Strategy<Value = [f64; 3]> {
    prop::array::uniform3(coordinate())
}

/// Any points (`coordinate`'s whole range), or a finite blob, at any small length.
fn cloud(max: usize) -> impl Strategy<Value = Vec<[f64; 3]>> {
    prop_oneof![
        prop::collection::vec(point(), 0..max),
        prop::collection::vec(prop::array::uniform3(-1.0f64..1.0), 0..max),
    ]
}

/// Mostly `usual` (so that most cases reach the later stages), sometimes anything `other`.
fn mostly<T: Clone + std::fmt::Debug + 'static>(
    usual: T,
    other: impl Strategy<Value = T> + 'static,
) -> BoxedStrategy<T> {
    prop_oneof![3 => Just(usual), 1 => other].boxed()
}

/// A small object: `n` points of a random blob (seeded), in a unit cube.
fn object() -> impl Strategy<Value = Vec<[f64; 3]>> {
    (3usize..60, any::<u64>()).prop_map(|(n, seed)| {
        let scene = random_scene(n.max(3), 1, 0.0, seed);
        (0..scene.corr.len())
            .map(|i| scene.corr.source(i))
            .collect()
    })
}

/// Any float, weighted towards the edges a length or a ratio meets.
fn float() -> impl Strategy<Value = f64> {
    prop_oneof![
        2 => 1e-3f64..10.0,
        1 => any::<f64>(),
        1 => Just(0.0),
        1 => Just(-1.0),
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(f64::MIN_POSITIVE),
        1 => Just(1e300),
    ]
}

/// Scene rules with a few fields set to any value of their kind (in range or not).
fn scene_rules() -> impl Strategy<Value = SceneRules> {
    let n = SceneRules::FIELDS.len();
    prop::collection::vec((0..n, float(), count(), any::<bool>(), any::<bool>()), 0..4).prop_map(
        |edits| {
            let mut rules = SceneRules::default();
            for (k, f, c, b, none) in edits {
                let field = &SceneRules::FIELDS[k];
                let value = if none && field.optional {
                    Value::None
                } else {
                    match field.kind {
                        Kind::Float => Value::Float(f),
                        Kind::Count => Value::Count(c),
                        Kind::Bool => Value::Bool(b),
                        Kind::Choice(names) => Value::Choice(names[c % names.len()]),
                    }
                };
                let _ = rules.set(field.name, value);
            }
            rules
        },
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(4 * CASES), ..ProptestConfig::default() })]

    #[test]
    fn point_cloud_stages_return_a_result_or_an_error(
        points in cloud(48),
        voxel in float(),
        radius in float(),
        max_nn in prop_oneof![0usize..40, Just(usize::MAX)],
        anchor in point(),
        towards in any::<bool>(),
        scale in proptest::option::of(float()),
    ) {
        let _ = voxel_downsample(&points, voxel);
        let _ = scan_scales(&points, scale);
        let _ = default_voxel_size(&points, Some(&points), &SceneRules::default());
        let _ = estimate_sensor(&points, voxel, anchor);
        let Ok(index) = PointIndex::new(&points) else {
            prop_assert!(points.is_empty() || points.iter().flatten().any(|v| !v.is_finite()));
            return Ok(());
        };
        let orientation = if towards { Orientation::Towards(anchor) } else { Orientation::AwayFrom(anchor) };
        let normals = match estimate_normals(&points, &index, radius, max_nn, orientation) {
            Ok(n) => {
                prop_assert_eq!(n.len(), points.len());
                n
            }
            Err(_) => vec![[0.0, 0.0, 1.0]; points.len()],
        };
        if let Ok(f) = fpfh(&points, &normals, &index, radius, max_nn, FpfhVariant::Open3d) {
            prop_assert_eq!(f.len(), points.len());
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(CASES), ..ProptestConfig::default() })]

    #[test]
    fn register_point_clouds_with_any_options_returns_a_result_or_an_error(
        model in prop_oneof![3 => object(), 1 => cloud(40)],
        scan in cloud(80),
        copies in prop_oneof![3 => Just(true), 1 => Just(false)],
        voxel in mostly(None, proptest::option::of(float())),
        viewpoint in mostly(None, proptest::option::of(point())),
        top_k in mostly(10_000, prop_oneof![0usize..50, Just(usize::MAX)]),
        k in mostly(1, prop_oneof![0usize..4, Just(usize::MAX)]),
        n_samples in mostly(Some(1000), proptest::option::of(prop_oneof![0usize..50, Just(usize::MAX)])),
        config in mostly(None, proptest::option::of(arbitrary_config())),
        flags in (any::<bool>(), proptest::option::of(any::<bool>()), any::<bool>()),
        heap_rank in mostly(Some(64), proptest::option::of(prop_oneof![0usize..100, Just(usize::MAX)])),
        seed in any::<u64>(),
        scene in mostly(SceneRules::default(), scene_rules()),
    ) {
        // The scan holds the model twice (the second copy turned and shifted) with a few
        // other points, or is unrelated: both the early refusals and the later stages run.
        let scan: Vec<[f64; 3]> = if copies && !model.is_empty() {
            model.iter().copied()
                .chain(model.iter().map(|p| [-p[1] + 3.0, p[0], p[2]]))
                .chain(scan.iter().copied().take(10))
                .collect()
        } else {
            scan
        };
        let mut options = SceneOptions {
            voxel_size: voxel,
            viewpoint,
            config,
            peel: flags.0,
            heap: flags.1,
            heap_rank,
            seed,
            scene,
            ..SceneOptions::default()
        };
        options.matching.top_k = top_k;
        options.matching.k = k;
        options.matching.n_samples = n_samples;
        options.matching.mutual = flags.2;
        if let Ok(r) = register_point_clouds(&model, &scan, &options) {
            prop_assert!(r.voxel_size.is_finite() && r.voxel_size > 0.0);
            for c in &r.candidates {
                prop_assert!(c.pose.translation.iter().all(|t| t.is_finite()));
            }
        }
    }

    #[test]
    fn register_with_any_features_and_config_returns_a_result_or_an_error(
        planted in 0u64..1000,
        dim in prop_oneof![3 => 1usize..4, 1 => Just(0usize), 1 => Just(usize::MAX)],
        values in prop::collection::vec(coordinate(), 0..4),
        cut in mostly(0usize, 0usize..80),
        config in mostly(Config { min_cluster_size: 5, ..Config::default() }, arbitrary_config()),
        seed in any::<u64>(),
    ) {
        let scene = random_scene(40, 2, 0.5, planted);
        // One row of features per correspondence (a few too few with `cut`), any values.
        let rows = scene.corr.len().saturating_sub(cut);
        let data = (0..rows * dim.min(4)).map(|i| if values.is_empty() { i as f64 } else { values[i % values.len()] }).collect();
        let features = Features::new(data, dim);
        match register(&scene.corr, features.as_ref().ok(), &config, seed) {
            Ok(r) => prop_assert_eq!(r.labels.len(), scene.corr.len()),
            Err(e) => prop_assert!(!e.to_string().is_empty()),
        }
        let scenes = vec![
            Scene { correspondences: scene.corr.clone(), features: features.ok() };
            2
        ];
        let _ = register_batch(&scenes, &config, seed, 2);
    }

    #[test]
    fn the_network_embeds_any_finite_correspondences_or_refuses_them(
        rows in prop_oneof![
            prop::collection::vec(prop::array::uniform6(coordinate()), 0..64),
            prop::collection::vec(prop::array::uniform6(-1.0f64..1.0), 3..64),
        ],
        planted in proptest::option::of(0u64..1000),
    ) {
        let (bytes, meta) = shipped_weights();
        let net = Network::from_bytes(&bytes, &meta, "default").unwrap();
        let c = match planted {
            Some(seed) => random_scene(rows.len().max(10), 2, 0.5, seed).corr,
            None => match Correspondences::from_rows(&rows) {
                Ok(c) => c,
                Err(_) => return Ok(()),
            },
        };
        if let Ok(f) = net.embed(&c) {
            prop_assert_eq!(f.len(), c.len());
            let config = net.recommended_config();
            let _ = register(&c, Some(&f), &config, 0);
        }
    }
}
