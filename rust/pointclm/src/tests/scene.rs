use crate::config::{Declared, Unit, Value};
use crate::kabsch::RigidTransform;
use crate::pointcloud::{PointIndex, RefineParams};
use crate::scene::peeling::{not_duplicates, unexplained};
use crate::scene::ranking::{fit_tightness, loose_poses, relative_to_median, stability_factor};
use crate::scene::SceneRules;

/// A bumpy blob, distinctive for FPFH: `columns x rows` samples over the sphere's angles,
/// the radius varied by a few low-frequency terms.
fn bumpy_blob(columns: usize, rows: usize) -> Vec<[f64; 3]> {
    (0..columns * rows)
        .map(|i| {
            let u = (i % columns) as f64 / columns as f64;
            let v = (i / columns) as f64 / rows as f64;
            let (th, ph) = (u * std::f64::consts::TAU, v * std::f64::consts::PI);
            let d = [ph.sin() * th.cos(), ph.sin() * th.sin(), ph.cos()];
            let r = 1.0 + 0.3 * (3.0 * d[0]).sin() * (2.0 * d[1]).cos() + 0.2 * d[2];
            [r * d[0], r * d[1], r * d[2]]
        })
        .collect()
}

#[test]
fn every_declared_default_lies_in_its_range_and_every_field_is_named_once() {
    for fields in [SceneRules::FIELDS, RefineParams::FIELDS] {
        let mut names: Vec<&str> = fields.iter().map(|f| f.name).collect();
        let n = names.len();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), n);
        assert!(fields.iter().all(|f| !f.doc.trim().is_empty()));
    }
    assert!(SceneRules::default().out_of_range().is_none());
    assert!(RefineParams::default().out_of_range().is_none());
    // Scene rules are ratios, counts and shares: nothing is scaled with the data.
    assert!(SceneRules::FIELDS.iter().all(|f| f.unit == Unit::Unitless));
}

#[test]
fn refine_params_for_a_voxel_scale_the_declared_lengths_only() {
    let p = RefineParams::for_voxel(0.02);
    assert_eq!(p.radii(), vec![3.0 * 0.02, 2.0 * 0.02, 1.5 * 0.02]);
    assert_eq!(p.fit_radius, 1.5 * 0.02);
    assert_eq!(p.trust_cell, 0.02);
    assert_eq!(p.min_visible_fitness, 0.85);
    assert_eq!(p.max_incidence_deg, 75.0);
    assert!(RefineParams { icp: false, ..p }.radii().is_empty());
}

#[test]
fn a_value_out_of_its_declared_range_is_named() {
    let mut p = SceneRules::default();
    assert!(p.set("max_stray_share", Value::Float(1.5)));
    let (field, value) = p.out_of_range().unwrap();
    assert_eq!((field.name, value), ("max_stray_share", Value::Float(1.5)));
    assert!(!p.set("max_stray_share", Value::Count(1)), "wrong kind");
    assert!(!p.set("no_such_rule", Value::Float(0.0)));
    let mut r = RefineParams::default();
    assert!(r.set("min_seen", Value::Float(f64::NAN)));
    assert!(r.out_of_range().is_some());
}

#[test]
fn ranking_compares_with_the_median_of_known_values() {
    let rmse = [1.0, 1.0, 1.1, 0.9, 1.25, 2.0];
    assert_eq!(
        loose_poses(&rmse, 1.3, 3),
        [false, false, false, false, false, true]
    );
    // With two known values the median says nothing.
    assert!(loose_poses(&[1.0, f64::NAN, 5.0], 1.3, 3)
        .iter()
        .all(|&l| !l));
    assert_eq!(fit_tightness(&[1.0, 1.0, 1.0, 1.0, 1.25, 2.0], 3)[4], 0.8);
    assert_eq!(
        fit_tightness(&[0.0, 0.0, 0.0, 1.0], 3),
        [1.0, 1.0, 1.0, 0.0]
    );
    assert_eq!(
        stability_factor(&[0.2, 0.2, 0.1, 0.4], 3),
        [1.0, 1.0, 0.5, 1.0]
    );
    assert!(relative_to_median(&[], 3).is_empty());
}

#[test]
fn peeling_explains_what_a_posed_copy_reaches_and_drops_its_duplicates() {
    let model: Vec<[f64; 3]> = (0..10)
        .flat_map(|i| (0..10).map(move |j| [i as f64 * 0.1, j as f64 * 0.1, 0.0]))
        .collect();
    let far = RigidTransform {
        translation: nalgebra::Vector3::new(5.0, 0.0, 0.0),
        ..RigidTransform::identity()
    };
    let mut scan = model.clone();
    scan.extend(model.iter().map(|&p| far.apply(p)));
    scan.push([20.0, 20.0, 20.0]);
    let free = unexplained(&scan, &model, &[RigidTransform::identity()], 0.05).unwrap();
    assert_eq!(free.iter().filter(|&&f| f).count(), 101);
    assert!(free[..100].iter().all(|&f| !f));
    assert!(unexplained(&scan, &model, &[], 0.05)
        .unwrap()
        .iter()
        .all(|&f| f));
    // The same copy twice, then the other copy: the repeat is a duplicate.
    let index = PointIndex::with_cells(&scan, 0.05).unwrap();
    let poses = [RigidTransform::identity(), RigidTransform::identity(), far];
    let mut taken = vec![false; scan.len()];
    let keep = not_duplicates(&index, &model, &poses, 0.05, 0.5, &mut taken).unwrap();
    assert_eq!(keep, [0, 2]);
    assert_eq!(taken.iter().filter(|&&t| t).count(), 200);
    let mut short = vec![false; 3];
    assert!(not_duplicates(&index, &model, &poses, 0.05, 0.5, &mut short).is_err());
}

#[test]
fn the_scene_pipeline_finds_every_copy_of_a_distinctive_shape() {
    use crate::matching::MatchingConfig;
    use crate::scene::{register_point_clouds, MutualWindow, SceneOptions};
    use nalgebra::{Rotation3, Vector3};
    // A bumpy blob (distinctive for FPFH), three copies side by side, turned.
    let model: Vec<[f64; 3]> = bumpy_blob(60, 50);
    let truth: Vec<RigidTransform> = (0..3)
        .map(|k| RigidTransform {
            rotation: *Rotation3::from_euler_angles(0.3 * k as f64, 0.5, -0.2 * k as f64).matrix(),
            translation: Vector3::new(4.0 * k as f64, 0.0, 0.0),
        })
        .collect();
    let scan: Vec<[f64; 3]> = truth
        .iter()
        .flat_map(|t| model.iter().map(move |&p| t.apply(p)))
        .collect();
    let found = register_point_clouds(&model, &scan, &SceneOptions::default()).unwrap();
    assert_eq!(found.candidates.len(), 3);
    for t in &truth {
        assert!(found
            .candidates
            .iter()
            .any(|c| (c.pose.translation - t.translation).norm() < 0.1
                && (c.pose.rotation.transpose() * t.rotation).trace() > 2.9));
    }
    assert!(found
        .candidates
        .windows(2)
        .all(|w| w[0].confidence >= w[1].confidence));
    // Same seed, same result; a bad scene rule is a typed error, not a panic.
    let again = register_point_clouds(&model, &scan, &SceneOptions::default()).unwrap();
    // (NaN visibility scores without a viewpoint: compare what is defined.)
    let key = |c: &crate::scene::Candidate| (c.pose, c.confidence, c.pass_index, c.instance);
    assert!(found
        .candidates
        .iter()
        .zip(&again.candidates)
        .all(|(a, b)| key(a) == key(b)));
    // Said to be a heap: ranked matching and point pair voting find the same copies.
    let heap = SceneOptions {
        heap: Some(true),
        ..SceneOptions::default()
    };
    let voted = register_point_clouds(&model, &scan, &heap).unwrap();
    assert_eq!(voted.candidates.len(), 3);
    let mut bad = SceneOptions::default();
    bad.scene.max_stray_share = f64::NAN;
    assert!(register_point_clouds(&model, &scan, &bad).is_err());
    assert!(register_point_clouds(&model[..2], &scan, &SceneOptions::default()).is_err());
    // Without refinement: the correspondence stage's poses as it gave them (most inliers
    // first), one pass, every one kept.
    let raw = SceneOptions {
        refine: false,
        ..SceneOptions::default()
    };
    let unrefined = register_point_clouds(&model, &scan, &raw).unwrap();
    let stage = &unrefined.passes[0].registration.instances;
    assert_eq!(unrefined.passes.len(), 1);
    assert_eq!(unrefined.candidates.len(), stage.len());
    assert_eq!(unrefined.passes[0].added, stage.len());
    for (i, c) in unrefined.candidates.iter().enumerate() {
        assert_eq!(c.instance, i);
        assert!((c.pose.translation - stage[i].pose.translation).norm() < 1e-12);
    }
    assert!(unrefined.config.max_nfa.is_some());
    // Two model points per scan point, and the windowed mutual check (fixed and "auto"):
    // the same three copies.
    for options in [
        SceneOptions {
            matching: MatchingConfig {
                k: 2,
                mutual: true,
                ..MatchingConfig::default()
            },
            ..SceneOptions::default()
        },
        SceneOptions {
            mutual_window: Some(MutualWindow::Diagonals(1.0)),
            ..SceneOptions::default()
        },
        SceneOptions {
            mutual_window: Some(MutualWindow::Auto),
            heap: Some(true),
            ..SceneOptions::default()
        },
    ] {
        let found = register_point_clouds(&model, &scan, &options).unwrap();
        assert_eq!(found.candidates.len(), 3, "{options:?}");
    }
    // A window needs the plain mutual check, and a side.
    for (k, side) in [(2, 1.0), (1, 0.0), (1, f64::NAN)] {
        let mut windowed = SceneOptions {
            mutual_window: Some(MutualWindow::Diagonals(side)),
            ..SceneOptions::default()
        };
        windowed.matching.k = k;
        assert!(register_point_clouds(&model, &scan, &windowed).is_err());
    }
}

#[test]
fn verification_says_which_rule_rejected_each_pose() {
    use crate::pointcloud::RefineContext;
    let model: Vec<[f64; 3]> = (0..600)
        .map(|i| {
            let (th, ph) = (
                i as f64 * 2.399_963,
                (1.0 - 2.0 * (i as f64 + 0.5) / 600.0).acos(),
            );
            [ph.sin() * th.cos(), ph.sin() * th.sin(), ph.cos()]
        })
        .collect();
    let far = RigidTransform {
        translation: nalgebra::Vector3::new(10.0, 0.0, 0.0),
        ..RigidTransform::identity()
    };
    let params = RefineParams {
        icp: false,
        ..RefineParams::for_voxel(0.1)
    };
    let context = RefineContext::new(&model, &model, None, None, &params).unwrap();
    let poses = [RigidTransform::identity(), RigidTransform::identity(), far];
    let out = context.refine(&poses, &params).unwrap();
    assert_eq!(out.poses.len(), 1);
    let rules: Vec<(usize, &str)> = out.rejected.iter().map(|r| (r.origin, r.rule)).collect();
    assert_eq!(rules, [(1, "max_shared"), (2, "min_relative_fitness")]);
    assert_eq!(out.rejected[0].value, 1.0);
    assert_eq!(out.rejected[1].threshold, 0.8);
}

#[test]
fn an_embedder_sees_every_pass_with_the_cues_it_takes_and_its_errors_reach_the_caller() {
    use crate::correspondences::{Correspondences, Features};
    use crate::scene::{register_point_clouds_with, similarity, Embedder, SceneOptions};
    use crate::Error;
    use std::sync::atomic::{AtomicUsize, Ordering};

    struct Counting {
        calls: AtomicUsize,
        fail: bool,
    }
    impl Embedder for Counting {
        fn takes_normals(&self) -> bool {
            true
        }
        fn takes_similarity(&self) -> bool {
            true
        }
        fn embed(&self, c: &Correspondences) -> crate::Result<Features> {
            self.calls.fetch_add(1, Ordering::SeqCst);
            assert!(c.has_normals());
            let s = c.similarity().expect("the similarity it takes");
            assert!(s.iter().all(|&v| v > 0.0 && v <= 1.0));
            if self.fail {
                return Err(Error::InvalidParameter {
                    name: "embed",
                    value: "test".into(),
                    reason: "fails on purpose",
                });
            }
            // One unit row each: the features agree everywhere, the lengths decide.
            Features::new(vec![1.0; c.len()], 1)
        }
    }
    let model: Vec<[f64; 3]> = bumpy_blob(50, 40);
    let scan: Vec<[f64; 3]> = (0..2)
        .flat_map(|k| {
            model
                .iter()
                .map(move |p| [p[0] + 4.0 * k as f64, p[1], p[2]])
        })
        .collect();
    let embedder = Counting {
        calls: AtomicUsize::new(0),
        fail: false,
    };
    let options = SceneOptions::default();
    let found = register_point_clouds_with(&model, &scan, &options, Some(&embedder)).unwrap();
    assert_eq!(embedder.calls.load(Ordering::SeqCst), found.passes.len());
    assert!(!found.candidates.is_empty());
    let failing = Counting {
        calls: AtomicUsize::new(0),
        fail: true,
    };
    let err = register_point_clouds_with(&model, &scan, &options, Some(&failing)).unwrap_err();
    assert!(matches!(err, Error::InvalidParameter { name: "embed", .. }));
    // Similarities: the median maps to one half, exact matches to one.
    assert_eq!(similarity(&[1.0, 2.0, 3.0]), vec![2.0 / 3.0, 0.5, 0.4]);
    assert_eq!(similarity(&[0.0, 0.0, 3.0]), vec![1.0, 1.0, 1.0 / 4.0]);
    assert!(similarity(&[]).is_empty());
}

#[test]
fn the_shipped_network_embeds_every_pass_of_the_scene_pipeline() {
    use crate::network::Network;
    use crate::scene::{cloud_config, register_point_clouds_with, NetworkEmbedder, SceneOptions};
    let weights = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../python/pointclm/weights/default.safetensors");
    let network = Network::from_file(weights).unwrap();
    let model: Vec<[f64; 3]> = bumpy_blob(50, 40);
    let scan: Vec<[f64; 3]> = (0..2)
        .flat_map(|k| {
            model
                .iter()
                .map(move |p| [p[0] + 4.0 * k as f64, p[1], p[2]])
        })
        .collect();
    let voxel = 0.05;
    let config = cloud_config(voxel, Some(SceneRules::default().peel_cluster_level));
    let embedder = NetworkEmbedder {
        network: &network,
        sigma_d: config.sigma_d,
    };
    let options = SceneOptions {
        voxel_size: Some(voxel),
        config: Some(config),
        ..SceneOptions::default()
    };
    let found = register_point_clouds_with(&model, &scan, &options, Some(&embedder)).unwrap();
    assert_eq!(found.candidates.len(), 2);
    assert!(found.timings.embedding > 0.0);
    let bad = NetworkEmbedder {
        network: &network,
        sigma_d: 0.0,
    };
    assert!(register_point_clouds_with(&model, &scan, &options, Some(&bad)).is_err());
}

#[test]
fn a_scan_that_shares_no_shape_with_the_model_is_an_empty_result_not_an_error() {
    use crate::scene::{register_point_clouds, SceneOptions};
    let model: Vec<[f64; 3]> = bumpy_blob(50, 40);
    // A flat floor: every point's FPFH is the same, so the mutual check keeps at most a
    // couple of pairs, too few for a pose.
    let floor: Vec<[f64; 3]> = (0..3600)
        .map(|i| [(i % 60) as f64 * 0.05, (i / 60) as f64 * 0.05, 0.0])
        .collect();
    for refine in [true, false] {
        let options = SceneOptions {
            voxel_size: Some(0.1),
            refine,
            ..SceneOptions::default()
        };
        let found = register_point_clouds(&model, &floor, &options).unwrap();
        assert!(found.candidates.is_empty() && found.ambiguous.is_empty());
        assert_eq!(found.passes.len(), 1);
        let first = &found.passes[0];
        assert!(first.correspondences.is_none() && first.matches < 3);
        assert!(first.registration.instances.is_empty() && first.added == 0);
    }
}

#[test]
fn a_lone_view_seen_from_behind_the_origin_is_described_from_its_other_side() {
    use crate::scene::{register_point_clouds, SceneOptions};
    use nalgebra::Vector3;
    // A bumpy blob and the side of it a sensor sees from `eye` (the samples whose outward
    // direction faces it), moved by `at`.
    let model: Vec<[f64; 3]> = bumpy_blob(120, 100);
    let view = |eye: [f64; 3], at: [f64; 3]| -> Vec<[f64; 3]> {
        model
            .iter()
            .filter(|p| Vector3::from(**p).dot(&(Vector3::from(eye) - Vector3::from(**p))) > 0.0)
            .map(|p| [p[0] + at[0], p[1] + at[1], p[2] + at[2]])
            .collect()
    };
    let right = |found: &crate::scene::SceneRegistration, at: [f64; 3]| {
        found.candidates.first().is_some_and(|c| {
            (c.pose.translation - Vector3::from(at)).norm() < 0.1 && c.pose.rotation.trace() > 2.9
        })
    };
    // The blob 4 away along z. Its near side in the scan: a sensor's frame, judged from the
    // origin. Its far side instead, seen from beyond it: one view from the origin and in front
    // of it too, but its descriptors match the model's flipped.
    let at = [0.0, 0.0, 4.0];
    for (eye, said) in [(-4.0, "towards the origin"), (4.0, "away from the origin")] {
        let scan = view([0.0, 0.0, eye], at);
        let found = register_point_clouds(&model, &scan, &SceneOptions::default()).unwrap();
        assert!(found.orientation.contains(said), "{}", found.orientation);
        assert!(right(&found, at));
        if eye > 0.0 {
            let beyond = found.viewpoint.is_none_or(|v| v[2] > 5.0);
            assert!(beyond, "{:?}", found.viewpoint);
        }
    }
}
