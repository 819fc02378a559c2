use nalgebra::{Rotation3, Unit, Vector3};

use super::*;
use crate::pointcloud::{estimate_normals, Orientation};

fn wavy_sheet(n: usize) -> Vec<[f64; 3]> {
    let mut pts = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let (x, y) = (i as f64 / n as f64, j as f64 / n as f64);
            pts.push([x, y, 0.15 * (5.0 * x).sin() * (4.0 * y).cos() + 0.1 * x * y]);
        }
    }
    pts
}

fn turned(deg: f64, t: [f64; 3]) -> RigidTransform {
    let axis = Unit::new_normalize(Vector3::new(0.2, 1.0, 0.4));
    RigidTransform {
        rotation: *Rotation3::from_axis_angle(&axis, deg.to_radians()).matrix(),
        translation: Vector3::from(t),
    }
}

fn normals_of(points: &[[f64; 3]], index: &PointIndex) -> Vec<[f64; 3]> {
    estimate_normals(
        points,
        index,
        0.08,
        30,
        Orientation::Towards([0.0, 0.0, 5.0]),
    )
    .unwrap()
}

#[test]
fn point_to_plane_settles_a_nearly_right_pose_in_a_few_steps() {
    let model = wavy_sheet(40);
    let truth = turned(25.0, [1.0, -0.5, 0.3]);
    let scene: Vec<[f64; 3]> = model.iter().map(|p| truth.apply(*p)).collect();
    let index = PointIndex::new(&scene).unwrap();
    let normals = normals_of(&scene, &index);
    let start = RigidTransform {
        translation: truth.translation + Vector3::new(0.03, -0.02, 0.04),
        ..turned(28.0, [0.0; 3])
    };
    // One stage of five steps.
    let got = icp(&model, &scene, &normals, &index, start, &[0.15], 5);
    let turn = (got.rotation.transpose() * truth.rotation).trace();
    assert!(((turn - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees() < 0.1);
    assert!((got.translation - truth.translation).norm() < 2e-3);
}

#[test]
fn a_flat_patch_keeps_the_step_defined_and_lands_on_the_plane() {
    // On a plane the tangent distances leave the in-plane motion free; the point term pins it.
    let plane: Vec<[f64; 3]> = (0..900)
        .map(|k| [(k % 30) as f64 / 30.0, (k / 30) as f64 / 30.0, 0.0])
        .collect();
    let index = PointIndex::new(&plane).unwrap();
    let normals = vec![[0.0, 0.0, 1.0]; plane.len()];
    let start = RigidTransform {
        translation: Vector3::new(0.01, 0.005, 0.05),
        ..RigidTransform::identity()
    };
    let got = icp(&plane, &plane, &normals, &index, start, &[0.1, 0.05], 10);
    assert!(got.translation.iter().all(|v| v.is_finite()));
    assert!(
        got.translation.z.abs() < 1e-3,
        "off the plane: {}",
        got.translation
    );
    assert!(
        got.translation.xy().norm() <= 0.0112 + 1e-9,
        "slid: {}",
        got.translation
    );
}

#[test]
fn a_pose_far_from_the_scan_is_kept_as_given() {
    let model = wavy_sheet(10);
    let index = PointIndex::new(&model).unwrap();
    let normals = normals_of(&model, &index);
    let far = turned(10.0, [50.0, 0.0, 0.0]);
    let got = icp(&model, &model, &normals, &index, far, &[0.3], 10);
    assert_eq!(got, far);
}
