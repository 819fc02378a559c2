use nalgebra::{Matrix3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::testing::random_rotation;

/// `n` points drawn uniformly on the faces of a box of `sides` centred on `centre`, seeded.
fn box_points(sides: [f64; 3], centre: [f64; 3], n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let areas = [
        sides[1] * sides[2],
        sides[0] * sides[2],
        sides[0] * sides[1],
    ];
    let total: f64 = areas.iter().sum::<f64>() * 2.0;
    (0..n)
        .map(|_| {
            let mut pick = rng.random::<f64>() * total;
            let mut axis = 0;
            while axis < 2 && pick >= 2.0 * areas[axis] {
                pick -= 2.0 * areas[axis];
                axis += 1;
            }
            let mut p = [0.0; 3];
            for (k, v) in p.iter_mut().enumerate() {
                *v = (rng.random::<f64>() - 0.5) * sides[k];
            }
            p[axis] = if rng.random::<bool>() { 0.5 } else { -0.5 } * sides[axis];
            [p[0] + centre[0], p[1] + centre[1], p[2] + centre[2]]
        })
        .collect()
}

/// `n` points on a closed cylinder (radius 0.5, height 2) along z, seeded.
fn cylinder_points(n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (r, h) = (0.5, 2.0);
    let side = std::f64::consts::TAU * r * h;
    let cap = std::f64::consts::PI * r * r;
    (0..n)
        .map(|_| {
            let th = rng.random::<f64>() * std::f64::consts::TAU;
            if rng.random::<f64>() * (side + 2.0 * cap) < side {
                [r * th.cos(), r * th.sin(), (rng.random::<f64>() - 0.5) * h]
            } else {
                let rho = r * rng.random::<f64>().sqrt();
                let z = if rng.random::<bool>() {
                    h / 2.0
                } else {
                    -h / 2.0
                };
                [rho * th.cos(), rho * th.sin(), z]
            }
        })
        .collect()
}

fn rotated(points: &[[f64; 3]], r: &Matrix3<f64>) -> Vec<[f64; 3]> {
    points
        .iter()
        .map(|p| (r * Vector3::from(*p)).into())
        .collect()
}

fn detect(points: &[[f64; 3]]) -> Symmetry {
    let tol = default_tolerance(points).unwrap();
    detect_symmetries(points, tol).unwrap()
}

#[test]
fn a_box_of_three_distinct_sides_has_four() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let pts = rotated(
        &box_points([1.0, 2.0, 3.0], [0.0; 3], 3000, 2),
        &random_rotation(&mut rng),
    );
    let sym = detect(&pts);
    assert_eq!(sym.order(), Some(4));
    // Each is a half turn (or the identity) mapping the box onto itself.
    for s in sym.discrete() {
        let trace = s.rotation.trace();
        assert!(
            (trace - 3.0).abs() < 1e-2 || (trace + 1.0).abs() < 1e-2,
            "{trace}"
        );
    }
}

#[test]
fn a_square_section_box_has_eight() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let r = random_rotation(&mut rng);
    let pts = rotated(&box_points([1.0, 1.0, 2.5], [0.0; 3], 3000, 4), &r);
    assert_eq!(detect(&pts).order(), Some(8));
}

#[test]
fn a_cube_has_twenty_four() {
    let pts = box_points([1.0, 1.0, 1.0], [0.0; 3], 4000, 5);
    assert_eq!(detect(&pts).order(), Some(24));
}

#[test]
fn a_cylinder_has_a_continuous_axis_and_a_flip() {
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let r = random_rotation(&mut rng);
    let pts = rotated(&cylinder_points(3000, 7), &r);
    let sym = detect(&pts);
    assert_eq!(sym.continuous().len(), 1);
    let along = (r * Vector3::z()).dot(&sym.continuous()[0].direction).abs();
    assert!(along > 0.999, "axis off by {along}");
    assert_eq!(sym.discrete().len(), 2);
    assert_eq!(sym.order(), None);
}

#[test]
fn a_box_with_a_block_on_a_corner_has_none() {
    let mut pts = box_points([1.0, 2.0, 3.0], [0.0; 3], 3000, 8);
    pts.extend(box_points([0.4, 0.4, 0.4], [0.3, 0.8, 1.3], 300, 9));
    assert!(detect(&pts).is_trivial());
}

#[test]
fn detection_is_off_centre_too() {
    let pts = box_points([1.0, 2.0, 3.0], [5.0, -2.0, 10.0], 3000, 10);
    let sym = detect(&pts);
    assert_eq!(sym.order(), Some(4));
    for s in sym.discrete() {
        let c = Vector3::new(5.0, -2.0, 10.0);
        assert!((s.rotation * c + s.translation - c).norm() < 0.05);
    }
}

fn box_group() -> Symmetry {
    let half = |axis: Vector3<f64>| RigidTransform {
        rotation: half_turn(&axis),
        translation: Vector3::zeros(),
    };
    Symmetry::new(&[half(Vector3::x()), half(Vector3::y())], &[]).unwrap()
}

#[test]
fn declared_generators_close_into_the_group() {
    let sym = box_group();
    assert_eq!(sym.order(), Some(4)); // the z half turn is their product
}

#[test]
fn equivalent_poses_have_one_canonical_pose() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let cyl = Symmetry::new(
        &[RigidTransform {
            rotation: half_turn(&Vector3::x()),
            translation: Vector3::new(0.0, 0.0, 0.2),
        }],
        &[Axis {
            direction: Vector3::z(),
            offset: Vector3::new(0.0, 0.0, 0.1),
        }],
    )
    .unwrap();
    for sym in [box_group(), cyl] {
        for _ in 0..20 {
            let pose = RigidTransform {
                rotation: random_rotation(&mut rng),
                translation: Vector3::new(rng.random(), rng.random(), rng.random()),
            };
            let canon = canonical_pose(&pose, &sym);
            let mut equivalents: Vec<RigidTransform> =
                sym.discrete().iter().map(|s| compose(&pose, s)).collect();
            if let Some(axis) = sym.continuous().first() {
                equivalents.push(compose(&pose, &axis.turn(rng.random::<f64>() * 6.0)));
            }
            for e in equivalents {
                let other = canonical_pose(&e, &sym);
                assert!((other.rotation - canon.rotation).norm() < 1e-9);
                assert!((other.translation - canon.translation).norm() < 1e-9);
            }
            // Nearest the identity among the equivalents.
            assert!(sym.angle_to_deg(&canon.rotation) <= sym.angle_to_deg(&pose.rotation) + 1e-9);
        }
    }
}

#[test]
fn bad_declarations_are_typed_errors() {
    let skew = RigidTransform {
        rotation: Matrix3::new(1.0, 0.1, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        translation: Vector3::zeros(),
    };
    assert!(matches!(
        Symmetry::new(&[skew], &[]),
        Err(Error::InvalidParameter { .. })
    ));
    let mirror = RigidTransform {
        rotation: Matrix3::from_diagonal(&Vector3::new(-1.0, 1.0, 1.0)),
        translation: Vector3::zeros(),
    };
    assert!(Symmetry::new(&[mirror], &[]).is_err());
    let nan = RigidTransform {
        translation: Vector3::new(f64::NAN, 0.0, 0.0),
        ..RigidTransform::identity()
    };
    assert!(matches!(
        Symmetry::new(&[nan], &[]),
        Err(Error::NonFinite { .. })
    ));
    let zero = Axis {
        direction: Vector3::zeros(),
        offset: Vector3::zeros(),
    };
    assert!(Symmetry::new(&[], &[zero]).is_err());
    let apart = [
        Axis {
            direction: Vector3::z(),
            offset: Vector3::zeros(),
        },
        Axis {
            direction: Vector3::x(),
            offset: Vector3::new(0.0, 1.0, 0.0),
        },
    ];
    assert!(Symmetry::new(&[], &apart).is_err());
    // A half turn with a translation along its axis is a screw: its square is a translation.
    let screw = RigidTransform {
        rotation: half_turn(&Vector3::x()),
        translation: Vector3::new(0.5, 0.0, 0.0),
    };
    assert!(Symmetry::new(&[screw], &[]).is_err());
    // Turns of a radian about two axes generate no finite group.
    let turn = |axis: Vector3<f64>| RigidTransform {
        rotation: axis_rotation(&axis, 1.0),
        translation: Vector3::zeros(),
    };
    assert!(Symmetry::new(&[turn(Vector3::z()), turn(Vector3::x())], &[]).is_err());
    let mut m = [[0.0; 4]; 4];
    m[0][0] = 1.0;
    m[1][1] = 1.0;
    m[2][2] = 1.0;
    assert!(Symmetry::from_matrices(&[m], &[]).is_err()); // last row 0 0 0 0
    assert!(detect_symmetries(&[[0.0; 3]; 3], 0.0).is_err());
}

#[test]
fn a_sphere_is_every_rotation() {
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    // Uniform directions: points of the unit ball (rejection from the cube), normalised.
    let mut pts = Vec::new();
    while pts.len() < 4000 {
        let v = Vector3::new(
            rng.random::<f64>(),
            rng.random::<f64>(),
            rng.random::<f64>(),
        )
        .map(|x| 2.0 * x - 1.0);
        if (0.1..1.0).contains(&v.norm()) {
            pts.push((v.normalize() + Vector3::new(1.0, 2.0, 3.0)).into());
        }
    }
    let sym = detect(&pts);
    assert_eq!(sym.continuous().len(), 3);
    let pose = RigidTransform {
        rotation: random_rotation(&mut rng),
        translation: Vector3::zeros(),
    };
    let canon = canonical_pose(&pose, &sym);
    assert!((canon.rotation - Matrix3::identity()).norm() < 1e-9);
}

#[test]
fn detected_groups_are_closed_to_a_fraction_of_a_degree() {
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    for sides in [[1.0, 2.0, 3.0], [1.0, 1.0, 2.5], [1.0, 1.0, 1.0]] {
        let r = random_rotation(&mut rng);
        let sym = detect(&rotated(&box_points(sides, [0.0; 3], 4000, 14), &r));
        let g = sym.discrete();
        for a in g {
            for b in g {
                let ab = compose(a, b);
                let off = g
                    .iter()
                    .map(|c| {
                        let t = (ab.rotation.transpose() * c.rotation).trace();
                        ((t - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees()
                    })
                    .fold(f64::INFINITY, f64::min);
                assert!(
                    off < 0.5,
                    "{sides:?}: a product {off} degrees off the group"
                );
            }
        }
    }
}
