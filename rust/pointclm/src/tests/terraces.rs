use super::*;

/// A plane through `(0, 0, depth)` turned `slope_deg` about y, sampled every `step` over
/// [-2, 2]^2, seen from the origin along z: each point's depth rounded to a multiple of `steps`
/// (0: none) or jittered by up to `jitter` (a deterministic pattern), as a depth sensor returns.
fn sensed_slope(slope_deg: f64, depth: f64, step: f64, steps: f64, jitter: f64) -> Vec<[f64; 3]> {
    let n = (4.0 / step) as usize;
    let tan = slope_deg.to_radians().tan();
    let mut pts = Vec::new();
    for i in 0..=n {
        for j in 0..=n {
            let (x, y) = (-2.0 + i as f64 * step, -2.0 + j as f64 * step);
            let mut z = depth + x * tan;
            if steps > 0.0 {
                z = (z / steps).round() * steps;
            }
            let k = (i * 31 + j * 17) % 13;
            z += jitter * (k as f64 / 6.0 - 1.0);
            pts.push([x, y, z]);
        }
    }
    pts
}

fn normals_of(pts: &[[f64; 3]], index: &PointIndex, radius: f64) -> Vec<[f64; 3]> {
    let towards = crate::pointcloud::Orientation::Towards([0.0; 3]);
    crate::pointcloud::estimate_normals(pts, index, radius, 30, towards).unwrap()
}

#[test]
fn depth_steps_on_a_turned_surface_are_terraces_and_noise_is_not() {
    let (voxel, radius) = (0.1, 0.2);
    let cases = [
        // Steps three voxels deep on a surface turned 45 degrees: terraces three voxels
        // wide, within which a normal over two voxels faces the sensor.
        (sensed_slope(45.0, 5.0, voxel, 0.3, 0.0), true),
        // The same surface with noise of the same size: normals turn every way.
        (sensed_slope(45.0, 5.0, voxel, 0.0, 0.15), false),
        // Steps on a surface facing the sensor lie in it: nothing turns.
        (sensed_slope(0.0, 5.05, voxel, 0.3, 0.0), false),
        // Steps far finer than the normals' disc.
        (sensed_slope(45.0, 5.0, voxel, 0.02, 0.0), false),
    ];
    for (k, (pts, terraced)) in cases.iter().enumerate() {
        let index = PointIndex::new(pts).unwrap();
        let normals = normals_of(pts, &index, radius);
        let share = terraced_share(pts, &index, &normals, radius, [0.0; 3]).unwrap();
        // Far from the threshold either way: 0.72 against at most 0.04.
        let clear = if *terraced {
            share > 0.5
        } else {
            share.abs() < 0.05
        };
        assert!(clear, "case {k}: {share}");
        let chosen = scan_normal_radius(pts, &index, &normals, radius, [0.0; 3]).unwrap();
        assert_eq!(
            chosen,
            if *terraced { 2.0 * radius } else { radius },
            "case {k}"
        );
    }
    // Seen from elsewhere the terraces are not turned towards the line of sight.
    let pts = &cases[0].0;
    let index = PointIndex::new(pts).unwrap();
    let normals = normals_of(pts, &index, radius);
    let aside = terraced_share(pts, &index, &normals, radius, [40.0, 0.0, 5.0]).unwrap();
    assert!(aside <= MAX_TERRACED_SHARE, "{aside}");
    // Degenerate input: no share, no panic.
    let two = PointIndex::new(&pts[..2]).unwrap();
    assert_eq!(
        terraced_share(&pts[..2], &two, &normals[..2], radius, [0.0; 3]).unwrap(),
        0.0
    );
    // Inputs that do not belong together are errors, not a share.
    assert!(terraced_share(&pts[..2], &index, &normals[..2], radius, [0.0; 3]).is_err());
    assert!(terraced_share(pts, &index, &normals[..2], radius, [0.0; 3]).is_err());
    assert!(terraced_share(pts, &index, &normals, -radius, [0.0; 3]).is_err());
}

#[test]
fn over_twice_the_radius_the_normals_of_a_terraced_surface_are_the_surfaces() {
    let (voxel, radius) = (0.1, 0.2);
    let pts = sensed_slope(45.0, 5.0, voxel, 0.3, 0.0);
    let index = PointIndex::new(&pts).unwrap();
    let truth = nalgebra::Vector3::new(-1.0, 0.0, 1.0).normalize();
    let within_30 = |normals: &[[f64; 3]]| {
        let cos = 30f64.to_radians().cos();
        let n = normals
            .iter()
            .filter(|n| truth.dot(&nalgebra::Vector3::from(**n)).abs() >= cos);
        n.count() as f64 / normals.len() as f64
    };
    let towards = crate::pointcloud::Orientation::Towards([0.0; 3]);
    let wide = crate::pointcloud::estimate_normals(&pts, &index, 2.0 * radius, 120, towards);
    let (fine, wide) = (
        within_30(&normals_of(&pts, &index, radius)),
        within_30(&wide.unwrap()),
    );
    assert!(fine < 0.1 && wide > 0.9, "{fine} {wide}");
}

#[test]
fn resolving_terraces_refits_only_a_terraced_scan() {
    let (voxel, radius) = (0.1, 0.2);
    let towards = crate::pointcloud::Orientation::Towards([0.0; 3]);
    for (pts, terraced) in [
        (sensed_slope(45.0, 5.0, voxel, 0.3, 0.0), true),
        (sensed_slope(45.0, 5.0, voxel, 0.0, 0.15), false),
    ] {
        let index = PointIndex::new(&pts).unwrap();
        let fine = normals_of(&pts, &index, radius);
        let shape = (radius, 30);
        let (got, refitted) =
            resolving_terraces(&pts, &index, fine.clone(), shape, towards, [0.0; 3]).unwrap();
        assert_eq!(refitted, terraced);
        let want = if terraced {
            crate::pointcloud::estimate_normals(&pts, &index, 2.0 * radius, 120, towards).unwrap()
        } else {
            fine
        };
        assert_eq!(got, want);
    }
}
