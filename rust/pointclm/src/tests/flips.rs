use nalgebra::{Matrix3, Rotation3, Unit, Vector3};

use super::*;

/// Points every `step` on the faces of the box `lo`..`hi` (edges once).
fn box_faces(lo: [f64; 3], hi: [f64; 3], step: f64) -> Vec<[f64; 3]> {
    let ticks = |a: f64, b: f64| {
        let n = ((b - a) / step).round() as usize;
        (0..=n).map(move |k| a + (b - a) * k as f64 / n as f64)
    };
    let mut pts = Vec::new();
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        for side in [lo[axis], hi[axis]] {
            for a in ticks(lo[u], hi[u]) {
                for b in ticks(lo[v], hi[v]) {
                    let mut p = [0.0; 3];
                    (p[axis], p[u], p[v]) = (side, a, b);
                    pts.push(p);
                }
            }
        }
    }
    distinct(pts)
}

/// `pts` without repeats (to a micrometre): a scan point is explained once.
fn distinct(mut pts: Vec<[f64; 3]>) -> Vec<[f64; 3]> {
    let key = |p: &[f64; 3]| p.map(|v| (v * 1e6).round() as i64);
    pts.sort_by_key(key);
    pts.dedup_by_key(|p| key(p));
    pts
}

/// A flat cuboid with a block on one corner of its top: no turn maps it onto itself.
fn box_with_a_block() -> Vec<[f64; 3]> {
    let mut pts = box_faces([0.0; 3], [1.0, 0.6, 0.2], 0.04);
    pts.extend(box_faces([0.0, 0.0, 0.2], [0.28, 0.28, 0.4], 0.04));
    distinct(pts)
}

/// A square slab with a small block (three layers of points) on two opposite corners, as the
/// Python tests' model: a quarter turn about its vertical axis moves only the blocks, a half
/// turn about it nothing.
fn slab_with_two_blocks() -> Vec<[f64; 3]> {
    let mut pts = box_faces([0.0; 3], [1.0, 1.0, 0.2], 0.04);
    for z in [0.3, 0.4, 0.5] {
        for i in 0..8 {
            for j in 0..8 {
                let (x, y) = (0.04 * i as f64, 0.04 * j as f64);
                pts.push([x, y, z]);
                pts.push([1.0 - x, 1.0 - y, z]);
            }
        }
    }
    distinct(pts)
}

fn motion(axis: [f64; 3], deg: f64, t: [f64; 3]) -> RigidTransform {
    let rot =
        Rotation3::from_axis_angle(&Unit::new_normalize(Vector3::from(axis)), deg.to_radians());
    RigidTransform {
        rotation: *rot.matrix(),
        translation: Vector3::from(t),
    }
}

fn then(a: &RigidTransform, b: &RigidTransform) -> RigidTransform {
    RigidTransform {
        rotation: a.rotation * b.rotation,
        translation: a.rotation * b.translation + a.translation,
    }
}

fn moved(pts: &[[f64; 3]], pose: &RigidTransform) -> Vec<[f64; 3]> {
    pts.iter().map(|p| pose.apply(*p)).collect()
}

/// Verification keeping every pose (scores only).
fn scored(context: &RefineContext, poses: &[RigidTransform], voxel: f64) -> Refined {
    let out = context
        .refine(poses, &keep_all(&RefineParams::for_voxel(voxel)))
        .unwrap();
    assert_eq!(out.poses.len(), poses.len());
    out
}

#[test]
fn principal_axes_ascend_and_have_a_canonical_sign() {
    let model = box_with_a_block();
    let centre = Vector3::from(mean_point(&model));
    let axes = principal_axes(&model, &centre);
    let var = |a: &Vector3<f64>| {
        model
            .iter()
            .map(|p| (Vector3::from(*p) - centre).dot(a).powi(2))
            .sum::<f64>()
    };
    assert!(var(&axes[0]) < var(&axes[1]) && var(&axes[1]) < var(&axes[2]));
    for a in &axes {
        assert!((a.norm() - 1.0).abs() < 1e-12);
        let first = a.iter().find(|v| v.abs() > AXIS_SIGN_TOLERANCE).unwrap();
        assert!(*first > 0.0);
    }
    // Either sign in, the same axis out.
    let a = Vector3::new(0.0, -0.6, 0.8);
    assert_eq!(canonical_sign(a), Vector3::new(0.0, 0.6, -0.8));
    assert_eq!(canonical_sign(-a), canonical_sign(a));
    assert_eq!(canonical_sign(Vector3::new(1e-9, -1.0, 0.0)).y, 1.0);
}

#[test]
fn turns_that_map_the_model_onto_itself_are_not_tried() {
    let model = box_with_a_block();
    let centre = Vector3::from(mean_point(&model));
    let half = flip_turns(&model, 0.04, 0.01).unwrap();
    assert_eq!(half.len(), 3);
    for turn in &half {
        let r = turn.rotation;
        assert!((r * r - Matrix3::identity()).norm() < 1e-12);
        assert!((r.trace() + 1.0).abs() < 1e-12);
        assert!((r * centre + turn.translation - centre).norm() < 1e-12);
    }
    // A plain cuboid is its own half turns, and every quarter turn moves most of it.
    let cuboid = box_faces([0.0; 3], [1.0, 0.4, 0.2], 0.04);
    assert!(flip_turns(&cuboid, 0.04, 0.01).unwrap().is_empty());
    assert!(quarter_turns(&cuboid, 0.04, 0.01, 0.5).unwrap().is_empty());
    // The slab with two blocks: a half turn about its vertical axis moves nothing, the
    // quarter turns about it move only the blocks (both ways, +90 degrees first).
    let slab = slab_with_two_blocks();
    let quarter = quarter_turns(&slab, 0.04, 0.01, 0.5).unwrap();
    assert_eq!(quarter.len(), 2);
    let vertical = Vector3::new(0.0, 0.0, 1.0);
    assert!((quarter[0].rotation * Vector3::x() - Vector3::y()).norm() < 1e-9);
    assert!((quarter[1].rotation * Vector3::x() + Vector3::y()).norm() < 1e-9);
    assert!(quarter
        .iter()
        .all(|q| (q.rotation * vertical - vertical).norm() < 1e-9));
    let bad = flip_turns(&slab, 0.0, 0.01).unwrap_err();
    assert!(matches!(
        bad,
        Error::InvalidParameter {
            name: "voxel_size",
            ..
        }
    ));
    assert!(quarter_turns(&slab, 0.04, 0.01, 1.5).is_err());
}

#[test]
fn a_half_turned_pose_is_turned_back_and_a_right_pose_stays() {
    let (model, voxel) = (box_with_a_block(), 0.04);
    let truth = motion([0.3, 1.0, 0.2], 40.0, [0.5, -0.2, 0.1]);
    let scan = moved(&model, &truth);
    let params = RefineParams::for_voxel(voxel);
    let context = RefineContext::new(&model, &scan, None, None, &params).unwrap();
    let rules = SceneRules::default();
    let wrong: Vec<RigidTransform> = flip_turns(&model, voxel, rules.min_flip_change_by_fitness)
        .unwrap()
        .iter()
        .map(|t| then(&truth, t))
        .collect();
    assert_eq!(wrong.len(), 3);
    let refined = scored(&context, &wrong, voxel);
    assert!(refined
        .poses
        .iter()
        .all(|p| angle_deg(&p.pose.rotation, &truth.rotation) > 90.0));
    let (fixed, order) = resolve_flips(&context, &params, &refined, &[], &rules).unwrap();
    let mut sorted = order.clone();
    sorted.sort_unstable();
    assert_eq!(sorted, [0, 1, 2]);
    for (p, &k) in fixed.poses.iter().zip(&order) {
        assert!(angle_deg(&p.pose.rotation, &truth.rotation) < 5.0);
        assert!(p.fitness >= refined.poses[k].fitness);
        assert_eq!(p.origin, refined.poses[k].origin);
    }
    assert!(fixed
        .poses
        .windows(2)
        .all(|w| w[0].confidence >= w[1].confidence));
    // The right pose: no turn is surer or told apart by the scan; it stays as it is.
    let right = scored(&context, &[truth], voxel);
    let (kept, order) = resolve_flips(&context, &params, &right, &[], &rules).unwrap();
    assert_eq!(order, [0]);
    let (k, r) = (&kept.poses[0], &right.poses[0]);
    assert_eq!(
        (k.pose, k.confidence, k.fitness),
        (r.pose, r.confidence, r.fitness)
    );
}

#[test]
fn a_quarter_turned_pose_is_turned_back_by_the_evidence_or_by_the_scenes_own_turn() {
    let (model, voxel) = (slab_with_two_blocks(), 0.04);
    let truth = motion([0.2, 0.3, 1.0], 25.0, [0.4, -0.1, 0.3]);
    let scan = moved(&model, &truth);
    let params = RefineParams::for_voxel(voxel);
    let context = RefineContext::new(&model, &scan, None, None, &params).unwrap();
    let rules = SceneRules::default();
    let turn = quarter_turns(&model, voxel, 0.01, 0.5).unwrap()[0];
    let refined = scored(&context, &[then(&truth, &turn)], voxel);
    assert!(angle_deg(&refined.poses[0].pose.rotation, &truth.rotation) > 80.0);
    let back = |out: &Refined| {
        let posed = moved(&model, &out.poses[0].pose);
        let index = PointIndex::new(&scan).unwrap();
        posed
            .iter()
            .map(|p| index.nearest(p).1.sqrt())
            .fold(0.0, f64::max)
            < 0.25 * voxel
    };
    let (fixed, _) = resolve_flips(&context, &params, &refined, &[], &rules).unwrap();
    assert!(back(&fixed) && fixed.poses[0].fitness == 1.0);
    // Without the principal-axis quarter turns it stays wrong, unless the turn back comes as
    // one of the scene's own.
    let no_quarters = SceneRules {
        max_quarter_turn_change: 0.0,
        ..rules.clone()
    };
    let (stays, _) = resolve_flips(&context, &params, &refined, &[], &no_quarters).unwrap();
    assert!(!back(&stays));
    let undo = turn.rotation.transpose();
    let (fixed, _) = resolve_flips(&context, &params, &refined, &[undo], &no_quarters).unwrap();
    assert!(back(&fixed));
    // Not rotations: an error naming them.
    let scaled = Matrix3::identity() * 1.01;
    let err = resolve_flips(&context, &params, &refined, &[undo, scaled], &rules).unwrap_err();
    assert!(err.to_string().contains("rotations") && err.to_string().contains("row 1"));
    let nan = Matrix3::from_element(f64::NAN);
    let err = resolve_flips(&context, &params, &refined, &[nan], &rules).unwrap_err();
    assert_eq!(
        err,
        Error::NonFinite {
            what: "rotations",
            row: 0
        }
    );
}

#[test]
fn an_undecided_pose_stays_and_says_so_in_its_confidence() {
    // The blocks out of the scan: nothing tells the pose from its quarter turns.
    let (model, voxel) = (slab_with_two_blocks(), 0.04);
    let truth = motion([0.2, 0.3, 1.0], 25.0, [0.4, -0.1, 0.3]);
    let slab: Vec<[f64; 3]> = model.iter().filter(|p| p[2] < 0.25).copied().collect();
    let scan = moved(&slab, &truth);
    let params = RefineParams::for_voxel(voxel);
    let context = RefineContext::new(&model, &scan, None, None, &params).unwrap();
    let alone = scored(&context, &[truth], voxel);
    let (unsure, _) =
        resolve_flips(&context, &params, &alone, &[], &SceneRules::default()).unwrap();
    assert_eq!(unsure.poses[0].pose, alone.poses[0].pose);
    assert!(unsure.poses[0].confidence <= alone.poses[0].confidence / 2.0);
}

#[test]
fn a_turn_carried_onto_another_poses_copy_is_put_back() {
    let (model, voxel) = (slab_with_two_blocks(), 0.04);
    let first = motion([0.0, 0.0, 1.0], 0.0, [0.0; 3]);
    let second = motion([0.0, 0.0, 1.0], 30.0, [3.0, 0.0, 0.0]);
    let mut scan = moved(&model, &first);
    scan.extend(moved(&model, &second));
    let params = RefineParams {
        icp: false,
        ..RefineParams::for_voxel(voxel)
    };
    let context = RefineContext::new(&model, &scan, None, None, &params).unwrap();
    let poses = context.refine(&[first, second], &params).unwrap().poses;
    assert_eq!(poses.len(), 2);
    let shape = Shape::new(&model, params.fit_radius).unwrap();
    let rules = SceneRules::default();
    let evidence = Evidence {
        shape: &shape,
        context: &context,
        rules: &rules,
    };
    let turned_onto_first = || {
        let mut rows = poses.clone();
        rows[1].pose = rows[0].pose;
        rows
    };
    let mut rows = turned_onto_first();
    undo_turns_onto_other_copies(&poses, &mut rows, &[1], &evidence, 0.5);
    assert_eq!(rows[1].pose, poses[1].pose);
    // Poses that shared their copy before the turn keep it.
    let both_on_first = vec![poses[0].clone(), poses[0].clone()];
    let mut rows = turned_onto_first();
    undo_turns_onto_other_copies(&both_on_first, &mut rows, &[1], &evidence, 0.5);
    assert_eq!(rows[1].pose, poses[0].pose);
}

#[test]
fn the_scenes_own_turns_are_grouped_and_the_most_frequent_tried() {
    let model = box_with_a_block();
    let shape = Shape::new(&model, 0.06).unwrap();
    let rules = SceneRules::default();
    let tried = shape.half_turns(0.01);
    assert!(!tried.is_empty() && rules.max_scene_turns == 3);
    let rot = |axis: [f64; 3], deg: f64| motion(axis, deg, [0.0; 3]).rotation;
    let (a, b, c, d) = (
        rot([1.0, 1.0, 0.0], 120.0),
        rot([0.0, 1.0, 1.0], 100.0),
        rot([1.0, 0.0, 1.0], 70.0),
        rot([1.0, -1.0, 0.0], 140.0),
    );
    let near_a = rot([1.0, 1.0, 0.0], 120.0 + 0.5 * rules.scene_turn_deg);
    let small = rot([0.0, 0.0, 1.0], 0.5 * rules.scene_turn_deg);
    let given = [
        Matrix3::identity(),
        small,
        tried[0].rotation,
        b,
        a,
        near_a,
        a,
        c,
        c,
        c,
        d,
    ];
    let turns = shape.scene_turns(&given, &tried, 0.01, &rules);
    assert_eq!(turns.len(), 3);
    for (got, want) in turns.iter().zip([a, c, b]) {
        assert!((got.rotation - want).norm() < 1e-12);
        assert!((got.rotation * shape.centre + got.translation - shape.centre).norm() < 1e-12);
    }
    let none = SceneRules {
        max_scene_turns: 0,
        ..rules
    };
    assert!(shape.scene_turns(&given, &tried, 0.01, &none).is_empty());
}

#[test]
fn evidence_is_decisive_by_ratio_and_by_sigmas() {
    let model = box_with_a_block();
    let params = RefineParams::for_voxel(0.04);
    let context = RefineContext::new(&model, &model, None, None, &params).unwrap();
    let shape = Shape::new(&model, params.fit_radius).unwrap();
    let rules = SceneRules::default();
    let evidence = Evidence {
        shape: &shape,
        context: &context,
        rules: &rules,
    };
    assert!(evidence.decisive(60, 5));
    assert!(!evidence.decisive(20, 5), "ratio 4");
    assert!(!evidence.decisive(8, 0), "3 sigmas of 8 is 8.5");
    assert!(evidence.decisive(10, 0));
    // The model against its half turn: its own points are all on the scan, the turned
    // block's none.
    let turn = flip_turns(&model, 0.04, 0.01).unwrap()[0];
    let (own, other) = evidence.hits(&RigidTransform::identity(), &turn);
    assert!(own > 50 && other == 0, "{own} {other}");
}

fn angle_deg(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    super::angle_deg(a, b)
}
