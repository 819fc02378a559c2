//! Unit tests of `pipeline`.

use super::*;
use crate::testing::random_scene;

#[test]
fn recovers_planted_instances() {
    let scene = random_scene(1000, 6, 0.025, 4);
    let reg = register(&scene.corr, None, &Config::default(), 0).unwrap();
    assert_eq!(reg.instances.len(), 6);
    for truth in &scene.poses {
        let found = reg.instances.iter().any(|inst| {
            (inst.pose.rotation - truth.rotation).abs().max() < 1e-6
                && (inst.pose.translation - truth.translation).norm() < 1e-6
        });
        assert!(found);
    }
    for (i, &l) in reg.labels.iter().enumerate() {
        if scene.labels[i] >= 0 {
            assert!(l >= 0);
        }
    }
}

#[test]
fn same_seed_same_result_whatever_threads() {
    let scenes: Vec<Scene> = (0..6)
        .map(|s| Scene {
            correspondences: random_scene(600, 4, 0.04, s).corr,
            features: None,
        })
        .collect();
    let config = Config::default();
    let strip = |r: Registration| (r.instances, r.labels, r.kept, r.n_clusters);
    let one: Vec<_> = register_batch(&scenes, &config, 7, 1)
        .unwrap()
        .into_iter()
        .map(|r| strip(r.unwrap()))
        .collect();
    let two: Vec<_> = register_batch(&scenes, &config, 7, 2)
        .unwrap()
        .into_iter()
        .map(|r| strip(r.unwrap()))
        .collect();
    let serial: Vec<_> = scenes
        .iter()
        .map(|s| strip(register(&s.correspondences, None, &config, 7).unwrap()))
        .collect();
    assert_eq!(one, two);
    assert_eq!(one, serial);
}

#[test]
fn pure_noise_gives_a_valid_empty_result() {
    let scene = random_scene(500, 0, 0.0, 1);
    let reg = register(&scene.corr, None, &Config::default(), 0).unwrap();
    assert!(reg.instances.is_empty());
    assert!(reg.labels.iter().all(|&l| l == -1));
}

#[test]
fn bad_config_is_an_error_not_a_panic() {
    let scene = random_scene(50, 1, 0.5, 1);
    let config = Config {
        ransac_iterations: 0,
        ..Config::default()
    };
    assert!(matches!(
        register(&scene.corr, None, &config, 0),
        Err(Error::InvalidConfig { .. } | Error::ConfigOutOfRange { .. })
    ));
    let f = Features::new(vec![1.0; 10], 1).unwrap();
    assert!(matches!(
        register(&scene.corr, Some(&f), &Config::default(), 0),
        Err(Error::LengthMismatch { .. })
    ));
}
