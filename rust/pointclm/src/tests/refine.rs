use nalgebra::{Matrix3, Rotation3, Vector3};

use super::*;

/// A closed, curved surface (a bumpy sphere) sampled on a grid of angles: no symmetry that
/// would let ICP slide.
fn blob(n: usize) -> Vec<[f64; 3]> {
    let mut pts = Vec::new();
    for i in 0..n {
        for j in 0..2 * n {
            let (th, ph) = (
                std::f64::consts::PI * (i as f64 + 0.5) / n as f64,
                std::f64::consts::PI * j as f64 / n as f64,
            );
            let r = 1.0 + 0.25 * (3.0 * th).cos() * (2.0 * ph).sin() + 0.1 * ph.cos();
            pts.push([
                r * th.sin() * ph.cos(),
                1.3 * r * th.sin() * ph.sin(),
                r * th.cos(),
            ]);
        }
    }
    pts
}

fn motion(axis: [f64; 3], deg: f64, t: [f64; 3]) -> RigidTransform {
    let rot = Rotation3::from_axis_angle(
        &nalgebra::Unit::new_normalize(Vector3::from(axis)),
        deg.to_radians(),
    );
    RigidTransform {
        rotation: *rot.matrix(),
        translation: Vector3::from(t),
    }
}

fn moved(pts: &[[f64; 3]], pose: &RigidTransform) -> Vec<[f64; 3]> {
    pts.iter().map(|p| pose.apply(*p)).collect()
}

fn angle_deg(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    let r = a.transpose() * b;
    ((r.trace() - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

fn params() -> RefineParams {
    RefineParams {
        min_relative_fitness: 0.0,
        ..RefineParams::for_voxel(0.1)
    }
}

#[test]
fn icp_pulls_a_nearly_right_pose_onto_the_copy() {
    let model = blob(24);
    let truth = motion([0.3, 1.0, 0.2], 40.0, [5.0, -2.0, 1.0]);
    let scene = moved(&model, &truth);
    let start = RigidTransform {
        translation: truth.translation + Vector3::new(0.12, -0.08, 0.05),
        ..motion([0.3, 1.0, 0.2], 44.0, [0.0; 3])
    };
    let out = refine_poses(&model, &scene, &[start], &params()).unwrap();
    assert_eq!(out.len(), 1);
    let got = &out[0];
    assert!(angle_deg(&got.pose.rotation, &truth.rotation) < 0.2);
    assert!((got.pose.translation - truth.translation).norm() < 0.01);
    assert!(got.fitness > 0.99 && got.inlier_rmse < 0.01);
    assert_eq!(got.origin, 0);
}

#[test]
fn poses_over_empty_space_and_duplicates_are_rejected() {
    let model = blob(16);
    let (a, b) = (
        motion([0.0, 0.0, 1.0], 10.0, [0.0, 0.0, 0.0]),
        motion([1.0, 0.0, 0.0], 70.0, [6.0, 0.0, 0.0]),
    );
    let mut scene = moved(&model, &a);
    scene.extend(moved(&model, &b));
    let far = motion([0.0, 1.0, 0.0], 30.0, [0.0, 20.0, 0.0]);
    let near_a = RigidTransform {
        translation: a.translation + Vector3::new(0.05, 0.0, 0.0),
        ..a
    };
    let out = refine_poses(&model, &scene, &[far, a, b, near_a], &params()).unwrap();
    let origins: Vec<usize> = out.iter().map(|r| r.origin).collect();
    // The far pose explains nothing; the nudged copy of `a` converges onto `a` and goes as a
    // duplicate (equal fitness: input order wins).
    assert_eq!(origins, vec![1, 2]);
}

#[test]
fn relative_fitness_drops_a_pose_that_explains_much_less_than_the_best() {
    let model = blob(16);
    let (a, b) = (
        motion([0.0, 0.0, 1.0], 0.0, [0.0, 0.0, 0.0]),
        motion([0.0, 0.0, 1.0], 0.0, [6.0, 0.0, 0.0]),
    );
    // A whole copy at `a`, and only the top third of one at `b`.
    let mut scene = moved(&model, &a);
    scene.extend(moved(&model, &b).into_iter().filter(|p| p[2] > 0.5));
    let loose = RefineParams {
        min_fitness: 0.0,
        min_relative_fitness: 0.0,
        ..RefineParams::for_voxel(0.1)
    };
    let both = refine_poses(&model, &scene, &[b, a], &loose).unwrap();
    assert_eq!(
        both.iter().map(|r| r.origin).collect::<Vec<_>>(),
        vec![1, 0]
    );
    assert!(both[1].fitness < 0.8 * both[0].fitness);
    let strict = RefineParams {
        min_relative_fitness: 0.8,
        ..loose
    };
    let kept = refine_poses(&model, &scene, &[b, a], &strict).unwrap();
    assert_eq!(kept.len(), 1);
    assert_eq!(kept[0].origin, 1);
}

#[test]
fn same_result_on_one_thread_and_many() {
    let model = blob(16);
    let truth = motion([1.0, 1.0, 0.0], 25.0, [1.0, 2.0, 3.0]);
    let scene = moved(&model, &truth);
    let starts: Vec<RigidTransform> = (0..8)
        .map(|k| RigidTransform {
            translation: truth.translation + Vector3::new(0.02 * k as f64, 0.0, 0.0),
            ..truth
        })
        .collect();
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| refine_poses(&model, &scene, &starts, &params()).unwrap())
    };
    assert_eq!(run(1), run(4));
}

#[test]
fn bad_inputs_are_typed_errors() {
    let model = blob(8);
    let ok = RigidTransform::identity();
    let mut nan = model.clone();
    nan[3][1] = f64::NAN;
    assert!(matches!(
        refine_poses(&nan, &model, &[ok], &params()),
        Err(Error::NonFinite { row: 3, .. })
    ));
    assert!(matches!(
        refine_poses(&model, &model[..2], &[ok], &params()),
        Err(Error::TooFewPoints { .. })
    ));
    let bad_pose = RigidTransform {
        translation: Vector3::new(f64::INFINITY, 0.0, 0.0),
        ..ok
    };
    assert!(matches!(
        refine_poses(&model, &model, &[ok, bad_pose], &params()),
        Err(Error::NonFinite { row: 1, .. })
    ));
    for bad in [
        RefineParams {
            fit_radius: 0.0,
            ..params()
        },
        RefineParams {
            min_fitness: 1.5,
            ..params()
        },
        RefineParams {
            radii: vec![0.3, f64::NAN],
            ..params()
        },
    ] {
        assert!(matches!(
            refine_poses(&model, &model, &[ok], &bad),
            Err(Error::InvalidParameter { .. })
        ));
    }
    assert!(refine_poses(&model, &model, &[], &params())
        .unwrap()
        .is_empty());
}
