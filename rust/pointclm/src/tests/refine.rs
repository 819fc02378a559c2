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
    let out = refine_poses(&model, &scene, None, &[start], None, &params())
        .unwrap()
        .poses;
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
    let out = refine_poses(&model, &scene, None, &[far, a, b, near_a], None, &params())
        .unwrap()
        .poses;
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
    let both = refine_poses(&model, &scene, None, &[b, a], None, &loose)
        .unwrap()
        .poses;
    assert_eq!(
        both.iter().map(|r| r.origin).collect::<Vec<_>>(),
        vec![1, 0]
    );
    assert!(both[1].fitness < 0.8 * both[0].fitness);
    let strict = RefineParams {
        min_relative_fitness: 0.8,
        ..loose
    };
    let kept = refine_poses(&model, &scene, None, &[b, a], None, &strict)
        .unwrap()
        .poses;
    assert_eq!(kept.len(), 1);
    assert_eq!(kept[0].origin, 1);
}

#[test]
fn same_result_on_one_thread_and_many() {
    let model = blob(16);
    let truth = motion([1.0, 1.0, 0.0], 25.0, [1.0, 2.0, 3.0]);
    let scene = sensed(&moved(&blob(60), &truth), 0.06);
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
            .install(|| {
                refine_poses(
                    &model,
                    &scene,
                    None,
                    &starts,
                    Some([0.0, 0.0, -50.0]),
                    &params(),
                )
                .unwrap()
            })
    };
    let one = run(1);
    assert!(one.by_visibility && !one.poses.is_empty());
    assert_eq!(one, run(4));
}

#[test]
fn bad_inputs_are_typed_errors() {
    let model = blob(8);
    let ok = RigidTransform::identity();
    let mut nan = model.clone();
    nan[3][1] = f64::NAN;
    assert!(matches!(
        refine_poses(&nan, &model, None, &[ok], None, &params()),
        Err(Error::NonFinite { row: 3, .. })
    ));
    assert!(matches!(
        refine_poses(&model, &model[..2], None, &[ok], None, &params()),
        Err(Error::TooFewPoints { .. })
    ));
    let bad_pose = RigidTransform {
        translation: Vector3::new(f64::INFINITY, 0.0, 0.0),
        ..ok
    };
    assert!(matches!(
        refine_poses(&model, &model, None, &[ok, bad_pose], None, &params()),
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
            icp_radius_middle: f64::NAN,
            ..params()
        },
        RefineParams {
            max_contradiction: -0.1,
            ..params()
        },
        RefineParams {
            depth_tolerance: 0.0,
            ..params()
        },
    ] {
        assert!(matches!(
            refine_poses(&model, &model, None, &[ok], None, &bad),
            Err(Error::InvalidParameter { .. })
        ));
    }
    assert!(matches!(
        refine_poses(
            &model,
            &model,
            None,
            &[ok],
            Some([0.0, f64::NAN, 0.0]),
            &params()
        ),
        Err(Error::NonFinite { .. })
    ));
    assert!(refine_poses(&model, &model, None, &[], None, &params())
        .unwrap()
        .poses
        .is_empty());
}

/// The sensor: far along -z, looking at +z (rays nearly parallel, so a test can tell what it
/// sees by the sign of a normal's z and by x/y alone).
const EYE: [f64; 3] = [0.0, 0.0, -200.0];

/// What the sensor at [`EYE`] sees of `surfaces`: a z-buffer along z with square pixels of
/// `pixel` (the sensor is far enough for its rays to be parallel), keeping the points
/// within a pixel of the nearest in theirs.
fn sensed(surfaces: &[[f64; 3]], pixel: f64) -> Vec<[f64; 3]> {
    let key = |p: &[f64; 3]| ((p[0] / pixel).floor() as i64, (p[1] / pixel).floor() as i64);
    let mut nearest = std::collections::HashMap::new();
    for p in surfaces {
        let z = nearest.entry(key(p)).or_insert(f64::INFINITY);
        *z = p[2].min(*z);
    }
    surfaces
        .iter()
        .filter(|p| p[2] <= nearest[&key(p)] + pixel)
        .copied()
        .collect()
}

/// A plane `z = z0` sampled every `step` over the x and y ranges.
fn wall(x: (f64, f64), y: (f64, f64), z0: f64, step: f64) -> Vec<[f64; 3]> {
    let (nx, ny) = (((x.1 - x.0) / step) as usize, ((y.1 - y.0) / step) as usize);
    (0..=nx)
        .flat_map(|i| (0..=ny).map(move |j| [x.0 + i as f64 * step, y.0 + j as f64 * step, z0]))
        .collect()
}

/// Copy a of `blob(24)` (turned 20 degrees about y, at the origin) before a wall at depth
/// `z` spanning `x` by `y`, seen from `EYE`: (a, scene).
fn copy_before_wall(x: (f64, f64), y: (f64, f64), z: f64) -> (RigidTransform, Vec<[f64; 3]>) {
    let a = motion([0.0, 1.0, 0.0], 20.0, [0.0, 0.0, 0.0]);
    let mut surfaces = moved(&blob(60), &a);
    surfaces.extend(wall(x, y, z, 0.05));
    (a, sensed(&surfaces, 0.06))
}

/// Two copies of `blob(24)` at poses `a` and `b` seen from `EYE`, with a board in front of
/// copy b that hides all of it but a strip on its right: (model, a, b, scene).
fn hidden_copy_scene() -> (Vec<[f64; 3]>, RigidTransform, RigidTransform, Vec<[f64; 3]>) {
    let (a, b) = (
        motion([0.0, 1.0, 0.0], 20.0, [0.0, 0.0, 0.0]),
        motion([1.0, 0.0, 0.0], 50.0, [4.0, 0.0, 0.0]),
    );
    let mut surfaces = moved(&blob(60), &a);
    surfaces.extend(moved(&blob(60), &b));
    surfaces.extend(wall((2.5, 4.6), (-2.0, 2.0), -3.0, 0.05));
    (blob(24), a, b, sensed(&surfaces, 0.06))
}

#[test]
fn a_mostly_hidden_copy_is_kept_by_what_the_sensor_could_see() {
    let (model, a, b, scene) = hidden_copy_scene();
    let seen = refine_poses(
        &model,
        &scene,
        None,
        &[a, b],
        Some(EYE),
        &RefineParams::for_voxel(0.1),
    )
    .unwrap();
    assert!(seen.by_visibility);
    let mut origins: Vec<usize> = seen.poses.iter().map(|r| r.origin).collect();
    origins.sort_unstable();
    assert_eq!(origins, vec![0, 1]);
    let of = |origin: usize| seen.poses.iter().find(|r| r.origin == origin).unwrap();
    let (open, hidden) = (of(0), of(1));
    assert!(hidden.fitness < 0.8 * open.fitness);
    assert!(hidden.seen < 0.6 * open.seen);
    assert!(hidden.visible_fitness > 0.8 && hidden.contradiction < 0.05);
    // Both copies' visible sides lie on the scan alike, within the scan's sampling.
    for r in [open, hidden] {
        assert!(
            r.visible_rmse.is_finite() && r.visible_rmse < 0.1,
            "{}",
            r.visible_rmse
        );
    }
    assert!(hidden.visible_rmse < 1.5 * open.visible_rmse);
    // Judged by the share of the best copy's fitness, the hidden copy goes.
    let blind = refine_poses(
        &model,
        &scene,
        None,
        &[a, b],
        None,
        &RefineParams::for_voxel(0.1),
    )
    .unwrap();
    assert!(!blind.by_visibility);
    assert_eq!(
        blind.poses.iter().map(|r| r.origin).collect::<Vec<_>>(),
        vec![0]
    );
    assert!(blind.poses[0].visible_rmse.is_nan());
}

#[test]
fn a_pose_where_the_sensor_saw_free_space_is_rejected() {
    let model = blob(24);
    // Copy a stands before a back wall; the wrong pose floats in front of the wall beside
    // a, where the sensor saw the wall through empty space. It explains the wall where
    // it touches it, which the model share alone would accept at a low floor.
    let (a, scene) = copy_before_wall((-3.0, 8.0), (-3.0, 3.0), 1.6);
    let wrong = motion([0.0, 1.0, 0.0], 0.0, [4.0, 0.0, 0.7]);
    let loose = RefineParams {
        icp: false,
        min_fitness: 0.0,
        min_relative_fitness: 0.0,
        ..RefineParams::for_voxel(0.1)
    };
    let out = refine_poses(&model, &scene, None, &[wrong, a], Some(EYE), &loose).unwrap();
    assert!(out.by_visibility);
    assert_eq!(
        out.poses.iter().map(|r| r.origin).collect::<Vec<_>>(),
        vec![1]
    );
    let all = RefineParams {
        min_visible_fitness: 0.0,
        max_contradiction: 1.0,
        min_seen: 0.0,
        max_slid_fitness: 1.0,
        ..loose
    };
    let scored = refine_poses(&model, &scene, None, &[wrong, a], Some(EYE), &all).unwrap();
    assert_eq!(scored.poses.len(), 2, "{scored:?}");
    let wrong_stats = scored.poses.iter().find(|r| r.origin == 0).unwrap();
    assert!(wrong_stats.contradiction > 0.5, "{wrong_stats:?}");
    // Surest first.
    assert!(scored
        .poses
        .windows(2)
        .all(|w| w[0].confidence >= w[1].confidence));
}

#[test]
fn a_given_viewpoint_is_used_even_where_the_scan_disputes_it() {
    let model = blob(24);
    let (a, scene) = copy_before_wall((-1.5, 1.5), (-2.0, 2.0), 2.0);
    let p = RefineParams::for_voxel(0.1);
    let side = [200.0, 0.0, 0.0];
    // From the side, the wall is seen edge-on: its points hide each other.
    assert!(!looks_like_one_view(&scene, side, &p).unwrap());
    let right = refine_poses(&model, &scene, None, &[a], Some(EYE), &p).unwrap();
    let behind = refine_poses(&model, &scene, None, &[a], Some(side), &p).unwrap();
    assert!(
        right.by_visibility && behind.by_visibility,
        "{right:?} {behind:?}"
    );
    assert!(right.poses[0].visible_fitness.is_finite());
}

#[test]
fn near_rotations_are_orthonormalised_and_others_refused() {
    let r = motion([0.2, 1.0, -0.4], 33.0, [0.0; 3]).rotation;
    let rounded = r.map(|v| (v * 1e6).round() / 1e6) + Matrix3::from_element(2e-5);
    let fixed = nearest_rotation(&rounded).unwrap();
    assert!((fixed.transpose() * fixed - Matrix3::identity()).norm() < 1e-12);
    assert!((fixed - r).amax() < 1e-4 && fixed.determinant() > 0.0);
    assert!(nearest_rotation(&(r * 1.01)).is_err());
    let mirror = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
    assert!(nearest_rotation(&(r * mirror)).is_err());
}

#[test]
fn given_normals_must_match_the_scan() {
    let model = blob(8);
    let ok = RigidTransform::identity();
    let short = vec![[0.0, 0.0, 1.0]; model.len() - 1];
    assert!(matches!(
        refine_poses(&model, &model, Some(&short), &[ok], None, &params()),
        Err(Error::LengthMismatch { .. })
    ));
    let mut bad = vec![[0.0, 0.0, 1.0]; model.len()];
    bad[3][1] = f64::NAN;
    assert!(matches!(
        refine_poses(&model, &model, Some(&bad), &[ok], None, &params()),
        Err(Error::NonFinite { row: 3, .. })
    ));
}

#[test]
fn model_points_seen_edge_on_are_not_judged() {
    let flat = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let up = vec![[0.0, 0.0, 1.0]; 3];
    let above = DepthMap::new(&flat, [0.3, 0.3, 10.0], 0.1, 0.3);
    let side = DepthMap::new(&flat, [60.0, 0.0, 0.5], 0.1, 0.3);
    let sensor = |depth| Sensor {
        depth,
        model_normals: &up,
        min_cos: 75f64.to_radians().cos(),
        reach: 1.0,
    };
    let id = RigidTransform::identity();
    // From above the plane faces the sensor; from its side, at 0.5 degrees, it is edge-on.
    assert_eq!(grazing(&sensor(&above), &id, &flat), vec![false; 3]);
    assert_eq!(grazing(&sensor(&side), &id, &flat), vec![true; 3]);
    // Turned by the pose, the same normals face the side sensor.
    let turned = motion([0.0, 1.0, 0.0], 90.0, [0.0; 3]);
    let posed: Vec<[f64; 3]> = flat.iter().map(|p| turned.apply(*p)).collect();
    assert_eq!(grazing(&sensor(&side), &turned, &posed), vec![false; 3]);
    let bad = RefineParams {
        max_incidence_deg: 91.0,
        ..params()
    };
    assert!(matches!(
        refine_poses(&flat, &flat, None, &[id], None, &bad),
        Err(Error::InvalidParameter {
            name: "max_incidence_deg",
            ..
        })
    ));
}

#[test]
fn a_context_refines_as_each_call_would() {
    let (model, _, b, scene) = hidden_copy_scene();
    let nudged = [
        motion([0.0, 1.0, 0.0], 23.0, [0.05, 0.0, 0.0]),
        b,
        motion([0.0, 0.0, 1.0], 90.0, [9.0, 9.0, 0.0]),
    ];
    let base = RefineParams::for_voxel(0.1);
    for eye in [Some(EYE), None] {
        let context = RefineContext::new(&model, &scene, None, eye, &base).unwrap();
        // Several calls on one context, with other thresholds and without ICP: each as the
        // one-shot function gives it.
        let no_icp = RefineParams {
            icp: false,
            ..base.clone()
        };
        let lax = RefineParams {
            min_visible_fitness: 0.0,
            min_fitness: 0.0,
            max_shared: 1.0,
            ..base.clone()
        };
        for params in [&base, &no_icp, &lax, &base] {
            let once = refine_poses(&model, &scene, None, &nudged, eye, params).unwrap();
            let again = context.refine(&nudged, params).unwrap();
            assert_eq!(once.by_visibility, again.by_visibility);
            assert_eq!(once.poses.len(), again.poses.len());
            for (x, y) in once.poses.iter().zip(&again.poses) {
                assert_eq!(
                    (x.origin, x.confidence, x.fitness),
                    (y.origin, y.confidence, y.fitness)
                );
                assert_eq!(x.pose.rotation, y.pose.rotation);
                assert_eq!(x.pose.translation, y.pose.translation);
            }
        }
        // Lengths other than the context's are refused.
        let other = RefineParams::for_voxel(0.2);
        assert!(matches!(
            context.refine(&nudged, &other),
            Err(Error::InvalidParameter { .. })
        ));
    }
}

#[test]
fn near_shares_count_what_each_pose_holds_before_icp() {
    let (model, a, b, scene) = hidden_copy_scene();
    let far = motion([0.0, 0.0, 1.0], 90.0, [9.0, 9.0, 0.0]);
    let poses = [a, far, b];
    let context = RefineContext::new(
        &model,
        &scene,
        None,
        Some(EYE),
        &RefineParams::for_voxel(0.1),
    )
    .unwrap();
    for radius in [0.05, 0.3, 2.0] {
        let shares = context.near_shares(&poses, &model, radius).unwrap();
        // The definition, by brute force over the scan.
        for (pose, share) in poses.iter().zip(&shares) {
            let near = moved(&model, pose)
                .iter()
                .filter(|q| {
                    scene
                        .iter()
                        .any(|p| crate::grid::dist_sq(p, q) < radius * radius)
                })
                .count();
            assert_eq!(*share, near as f64 / model.len() as f64);
        }
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| context.near_shares(&poses, &model, radius).unwrap());
        assert_eq!(one, shares);
    }
    // The seen copy's pose holds its visible side, the hidden copy's less, a pose over empty
    // space nothing.
    let shares = context.near_shares(&poses, &model, 0.3).unwrap();
    assert!(shares[0] > 0.3 && shares[0] > shares[2] && shares[1] == 0.0);
    assert!(context.near_shares(&[], &model, 0.3).unwrap().is_empty());
    for bad in [0.0, -1.0, f64::NAN] {
        assert!(matches!(
            context.near_shares(&poses, &model, bad),
            Err(Error::InvalidParameter { .. })
        ));
    }
    assert!(context.near_shares(&poses, &[], 0.3).is_err());
}

/// A part made of two square plates at a right angle (one in the plane z = 0, one in x = 0
/// reaching behind it), lying with its first plate on a large table seen from [`EYE`]: the
/// second plate is hidden behind the table, the first is explained wherever it lies on it.
fn plate_on_a_table() -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let mut part = wall((0.0, 1.0), (0.0, 1.0), 0.0, 0.05);
    part.extend(
        wall((0.0, 1.0), (0.0, 1.0), 0.0, 0.05)
            .iter()
            .map(|p| [0.0, p[1], p[0] + 0.05]),
    );
    let table = sensed(&wall((-3.0, 3.0), (-3.0, 3.0), 0.0, 0.05), 0.06);
    (part, table)
}

#[test]
fn a_face_lying_on_a_larger_surface_fits_anywhere_and_comes_back_apart() {
    let (part, table) = plate_on_a_table();
    let pose = RigidTransform::identity();
    let base = RefineParams {
        icp: false,
        ..RefineParams::for_voxel(0.1)
    };
    let off = RefineParams {
        max_slid_fitness: 1.0,
        ..base.clone()
    };
    for eye in [Some(EYE), None] {
        // Every other rule keeps it: what the sensor could see of it is all on the table.
        let kept = refine_poses(&part, &table, None, &[pose], eye, &off).unwrap();
        assert_eq!(kept.poses.len(), 1, "{eye:?}");
        assert_eq!(kept.by_visibility, eye.is_some());
        assert!(kept.poses[0].slid_fitness.is_nan() && kept.sliding.is_empty());
        let judged = refine_poses(&part, &table, None, &[pose], eye, &base).unwrap();
        assert!(judged.poses.is_empty(), "{eye:?}: {judged:?}");
        // Not an error but an ambiguity: returned apart, less sure by the slide.
        assert_eq!(judged.rejected[0].rule, "max_slid_fitness");
        assert_eq!(judged.sliding.len(), 1, "{eye:?}: {judged:?}");
        let (slid, plain) = (&judged.sliding[0], &kept.poses[0]);
        assert!(slid.slid_fitness > base.max_slid_fitness, "{slid:?}");
        let factor = ((1.0 - slid.slid_fitness) / (1.0 - base.max_slid_fitness)).clamp(0.0, 1.0);
        assert!((slid.confidence - plain.confidence * factor).abs() < 1e-12);
        assert_eq!((slid.pose, slid.fitness), (plain.pose, plain.fitness));
        // Two of them on the same spot: the second only repeats the first.
        let twice = refine_poses(&part, &table, None, &[pose, pose], eye, &base).unwrap();
        assert_eq!(twice.sliding.len(), 1, "{eye:?}: {twice:?}");
    }
    // The same part on a table just its size, bounded by free space, is where the scan says.
    let small = sensed(&wall((0.0, 1.0), (0.0, 1.0), 0.0, 0.05), 0.06);
    let fits = refine_poses(&part, &small, None, &[pose], Some(EYE), &base).unwrap();
    assert_eq!(fits.poses.len(), 1, "{fits:?}");
    assert!(fits.poses[0].slid_fitness <= base.max_slid_fitness);
    assert!(fits.sliding.is_empty());
}

#[test]
fn a_scan_looks_like_one_view_only_from_its_sensor() {
    let (_, scene) = copy_before_wall((-1.5, 1.5), (-2.0, 2.0), 2.0);
    let p = RefineParams::for_voxel(0.1);
    assert!(looks_like_one_view(&scene, EYE, &p).unwrap());
    // From the side, the wall is seen edge-on: its points hide each other. (From behind, a
    // view is its own mirror image: one view too.)
    assert!(!looks_like_one_view(&scene, [200.0, 0.0, 0.0], &p).unwrap());
    assert!(looks_like_one_view(&scene, [0.0, f64::NAN, 0.0], &p).is_err());
    assert!(looks_like_one_view(&[[f64::INFINITY, 0.0, 0.0]], EYE, &p).is_err());
    assert!(looks_like_one_view(&scene, EYE, &RefineParams::for_voxel(-0.1)).is_err());
}

#[test]
fn a_model_cut_by_a_surface_is_rejected_by_its_normals() {
    // A copy standing on a floor, and a pose of the model sunk half into that floor: the
    // floor explains the band where the model crosses it, whose surface meets it across.
    let model = blob(24);
    let on = motion([0.0, 0.0, 1.0], 30.0, [0.0, 0.0, 1.6]);
    let mut scene = moved(&model, &on);
    scene.extend(wall((-4.0, 8.0), (-4.0, 4.0), 0.0, 0.05));
    let sunk = motion([1.0, 0.0, 0.0], 20.0, [5.0, 0.0, 0.0]);
    let rules = RefineParams {
        min_fitness: 0.0,
        min_normal_agreement: 0.4,
        ..params()
    };
    let out = refine_poses(&model, &scene, None, &[on, sunk], None, &rules).unwrap();
    assert_eq!(
        out.poses.iter().map(|r| r.origin).collect::<Vec<_>>(),
        vec![0]
    );
    let rejected: Vec<_> = out.rejected.iter().map(|r| (r.origin, r.rule)).collect();
    assert_eq!(rejected, vec![(1, "min_normal_agreement")]);
    assert!(out.rejected[0].value < 0.2, "{:?}", out.rejected[0]);
    // Off, the same pose passes (the slide test, which a band on a plane also fails, off).
    let off = RefineParams {
        min_normal_agreement: 0.0,
        max_slid_fitness: 1.0,
        ..rules
    };
    let out = refine_poses(&model, &scene, None, &[on, sunk], None, &off).unwrap();
    assert_eq!(out.poses.len(), 2);
}

#[test]
fn a_copy_cut_by_the_scans_edge_is_judged_on_what_the_scan_covers() {
    // A copy before a back wall, the scan cropped at x = 0.3 (a region of interest, the edge
    // of a field of view) through the copy's visible side.
    let model = blob(24);
    let (a, seen) = copy_before_wall((-3.0, 3.0), (-3.0, 3.0), 1.6);
    let cropped: Vec<[f64; 3]> = seen.iter().filter(|p| p[0] < 0.3).copied().collect();
    // A pose past the scan's edge, where the sensor did not look.
    let beyond = motion([0.0, 1.0, 0.0], 0.0, [3.0, 0.0, 0.0]);
    let p = RefineParams {
        icp: false,
        ..RefineParams::for_voxel(0.1)
    };
    let whole = refine_poses(&model, &seen, None, &[a], Some(EYE), &p).unwrap();
    let out = refine_poses(&model, &cropped, None, &[a, beyond], Some(EYE), &p).unwrap();
    assert_eq!(out.poses.len(), 1, "{out:?}");
    let (cut, full) = (&out.poses[0], &whole.poses[0]);
    assert_eq!(cut.origin, 0);
    // Judged on the part the scan covers: as sure of it as of the whole copy.
    assert!(cut.visible_fitness > 0.95, "{cut:?}");
    assert!(cut.seen < 0.8 * full.seen, "{cut:?} {full:?}");
    assert_eq!(out.rejected[0].origin, 1);
    assert_eq!(out.rejected[0].rule, "min_seen");
}

#[test]
fn a_copy_seen_through_depth_steps_is_kept_by_its_normals() {
    // A copy seen from the origin by a sensor whose depth steps (0.3, three voxels) make flat
    // terraces facing it on every turned surface: normals fitted within one terrace are the
    // line of sight, and the right pose seems to cross the scan.
    let model = blob(24);
    let truth = motion([0.3, 1.0, 0.0], 25.0, [0.0, 0.0, 5.0]);
    let steps = 0.3;
    let scan: Vec<[f64; 3]> = moved(&blob(60), &truth)
        .into_iter()
        .map(|[x, y, z]| [x, y, (z / steps).round() * steps])
        .collect();
    let rules = RefineParams {
        min_fitness: 0.0,
        min_normal_agreement: 0.4,
        max_slid_fitness: 1.0,
        icp: false,
        ..params()
    };
    // Normals over the usual radius, given: the pose fails the rule.
    let index = PointIndex::new(&scan).unwrap();
    let towards = Orientation::Towards([0.0; 3]);
    let fine = estimate_normals(&scan, &index, rules.normal_radius, 30, towards).unwrap();
    let given = refine_poses(&model, &scan, Some(&fine), &[truth], None, &rules).unwrap();
    assert_eq!(given.rejected[0].rule, "min_normal_agreement", "{given:?}");
    // Estimated from the scan itself: the terraces are seen, the normals fitted over twice
    // the radius, and the pose kept.
    let kept = refine_poses(&model, &scan, None, &[truth], None, &rules).unwrap();
    assert_eq!(kept.poses.len(), 1, "{kept:?}");
}
