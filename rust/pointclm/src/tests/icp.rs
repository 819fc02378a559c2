use nalgebra::{Rotation3, Unit, Vector3};

use super::*;
use crate::pointcloud::visibility::DepthMap;
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
    let got = icp(&model, &scene, &normals, &index, start, &[0.15], 5, None);
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
    let got = icp(
        &plane,
        &plane,
        &normals,
        &index,
        start,
        &[0.1, 0.05],
        10,
        None,
    );
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
    let got = icp(&model, &model, &normals, &index, far, &[0.3], 10, None);
    assert_eq!(got, far);
}

/// The surface of a cube of side 1 centred at the origin, sampled every `step`.
fn cube_surface(step: f64) -> Vec<[f64; 3]> {
    let n = (1.0 / step).round() as i32;
    let mut pts = Vec::new();
    for i in 0..=n {
        for j in 0..=n {
            let (u, v) = (i as f64 * step - 0.5, j as f64 * step - 0.5);
            for s in [-0.5, 0.5] {
                pts.extend([[u, v, s], [u, s, v], [s, u, v]]);
            }
        }
    }
    pts
}

#[test]
fn with_a_sensor_the_far_side_does_not_pair_with_the_surface_beneath() {
    // A copy seen from above resting 0.08 above a wide floor: its underside (not in the scan)
    // lies within the coarse radius of the floor, as a part in a heap lies over the parts it
    // rests on.
    let sensor = [0.0, 0.0, 6.0];
    let model = cube_surface(0.05);
    let truth = turned(20.0, [0.0, 0.0, 0.0]);
    let top: Vec<[f64; 3]> = model
        .iter()
        .map(|p| truth.apply(*p))
        .filter(|p| p[2] > 0.2)
        .collect();
    let bottom = model
        .iter()
        .map(|p| truth.apply(*p)[2])
        .fold(f64::INFINITY, f64::min);
    let mut scene = top.clone();
    for i in -40..=40 {
        for j in -40..=40 {
            scene.push([i as f64 * 0.05, j as f64 * 0.05, bottom - 0.08]);
        }
    }
    let index = PointIndex::new(&scene).unwrap();
    let normals = estimate_normals(&scene, &index, 0.1, 30, Orientation::Towards(sensor)).unwrap();
    let depth = DepthMap::new(&scene, sensor, 0.075, 0.15);
    let start = RigidTransform {
        translation: truth.translation + Vector3::new(0.02, -0.02, 0.03),
        ..turned(22.0, [0.0; 3])
    };
    let radii = [0.15, 0.1, 0.075];
    let error = |pose: RigidTransform| {
        let turn = ((pose.rotation.transpose() * truth.rotation).trace() - 1.0) / 2.0;
        let degrees = turn.clamp(-1.0, 1.0).acos().to_degrees();
        (degrees, (pose.translation - truth.translation).norm())
    };
    let (deg, shift) = error(icp(
        &model,
        &scene,
        &normals,
        &index,
        start,
        &radii,
        10,
        Some(&depth),
    ));
    assert!(
        deg < 0.5 && shift < 0.01,
        "with the sensor: {deg} degrees, {shift} off"
    );
    // Without it the underside pairs with the floor and drags the copy down.
    let (_, blind) = error(icp(
        &model, &scene, &normals, &index, start, &radii, 10, None,
    ));
    assert!(
        blind > 2.0 * shift.max(0.005),
        "without the sensor: {blind} off"
    );
}
