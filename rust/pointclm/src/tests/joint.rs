use super::*;

/// The surface of an axis-aligned box `[0, a] x [0, b] x [0, c]`, sampled every `step`.
fn box_surface(a: f64, b: f64, c: f64, step: f64) -> Vec<[f64; 3]> {
    let mut pts = Vec::new();
    let n = |l: f64| (l / step).round() as usize;
    for i in 0..=n(a) {
        for j in 0..=n(b) {
            let (x, y) = (i as f64 * step, j as f64 * step);
            pts.push([x, y, 0.0]);
            pts.push([x, y, c]);
        }
        for k in 0..=n(c) {
            let (x, z) = (i as f64 * step, k as f64 * step);
            pts.push([x, 0.0, z]);
            pts.push([x, b, z]);
        }
    }
    for j in 0..=n(b) {
        for k in 0..=n(c) {
            let (y, z) = (j as f64 * step, k as f64 * step);
            pts.push([0.0, y, z]);
            pts.push([a, y, z]);
        }
    }
    pts
}

fn moved(t: [f64; 3]) -> RigidTransform {
    RigidTransform {
        translation: t.into(),
        ..RigidTransform::identity()
    }
}

#[test]
fn a_small_box_on_a_long_box_loses_to_the_long_box() {
    let long = box_surface(4.0, 1.0, 1.0, 0.1);
    let small = box_surface(1.0, 1.0, 1.0, 0.1);
    // The scan: the long box, and a small box beside it.
    let mut scan = long.clone();
    scan.extend(small.iter().map(|&p| moved([6.0, 0.0, 0.0]).apply(p)));
    // The small box's proposals: the right one, and one lying on the long box's end (it
    // explains part of what the long box's pose does).
    let on_long = moved([0.0, 0.0, 0.0]);
    let models = [
        ModelPoses {
            model: &small,
            radius: 0.15,
            copies: vec![(moved([6.0, 0.0, 0.0]), f64::NAN), (on_long, 0.0)],
            ambiguous: vec![(moved([2.0, 0.0, 0.0]), 0.0)],
        },
        ModelPoses {
            model: &long,
            radius: 0.15,
            copies: vec![(RigidTransform::identity(), 0.0)],
            ambiguous: vec![],
        },
    ];
    let verdict = judge_jointly(&scan, &models, 0.5).unwrap();
    assert_eq!(verdict.copies, vec![vec![true, false], vec![true]]);
    // An ambiguous pose never displaces a copy: the one inside the long box goes.
    assert_eq!(verdict.ambiguous, vec![vec![false], vec![]]);
    // Two products of one shape on the same copy: the one that contradicts what the sensor
    // saw loses, whatever the model order.
    let twin = |contradiction: f64| ModelPoses {
        copies: vec![(RigidTransform::identity(), contradiction)],
        ..models[1].clone()
    };
    let verdict = judge_jointly(&scan, &[twin(0.9), twin(0.0)], 0.5).unwrap();
    assert_eq!(verdict.copies, vec![vec![false], vec![true]]);
    let verdict = judge_jointly(&scan, &[twin(0.0), twin(0.9)], 0.5).unwrap();
    assert_eq!(verdict.copies, vec![vec![true], vec![false]]);
}

#[test]
fn bad_joint_inputs_are_typed_errors() {
    let small = box_surface(1.0, 1.0, 1.0, 0.25);
    let one = |radius: f64| ModelPoses {
        model: &small,
        radius,
        copies: vec![],
        ambiguous: vec![],
    };
    assert!(judge_jointly(&small, &[one(0.0)], 0.5).is_err());
    assert!(judge_jointly(&small, &[one(0.1)], 1.5).is_err());
    assert!(judge_jointly(&[], &[one(0.1)], 0.5).is_err());
    assert!(judge_jointly(&[[f64::NAN, 0.0, 0.0]], &[one(0.1)], 0.5).is_err());
    assert!(register_models(&[], &small, &SceneOptions::default()).is_err());
    // Nothing to judge is a valid empty verdict.
    let none = judge_jointly(&small, &[one(0.1)], 0.5).unwrap();
    assert_eq!(none.copies, vec![Vec::<bool>::new()]);
}
