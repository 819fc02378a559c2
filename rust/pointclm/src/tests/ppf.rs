use super::*;

/// A one-sided wavy patch with its analytic normals (+z side): no symmetry, so a pose is
/// determined.
fn patch(n: usize) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let mut pts = Vec::new();
    let mut nrm = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let x = -1.0 + 2.0 * i as f64 / (n - 1) as f64;
            let y = -1.0 + 2.0 * j as f64 / (n - 1) as f64;
            let z = 0.3 * (2.0 * x).sin() + 0.2 * (3.0 * y).cos() + 0.15 * x * y;
            let fx = 0.6 * (2.0 * x).cos() + 0.15 * y;
            let fy = -0.6 * (3.0 * y).sin() + 0.15 * x;
            let v = Vector3::new(-fx, -fy, 1.0).normalize();
            pts.push([x, y, z]);
            nrm.push([v.x, v.y, v.z]);
        }
    }
    (pts, nrm)
}

fn posed(t: &RigidTransform, pts: &[[f64; 3]], nrm: &[[f64; 3]]) -> Vec<([f64; 3], [f64; 3])> {
    pts.iter()
        .zip(nrm)
        .map(|(p, n)| {
            let m = t.rotation * Vector3::from(*n);
            (t.apply(*p), [m.x, m.y, m.z])
        })
        .collect()
}

fn pose(axis: [f64; 3], angle: f64, t: [f64; 3]) -> RigidTransform {
    let axis = nalgebra::Unit::new_normalize(Vector3::from(axis));
    RigidTransform {
        rotation: *Rotation3::from_axis_angle(&axis, angle).matrix(),
        translation: Vector3::from(t),
    }
}

fn close(a: &RigidTransform, b: &RigidTransform, dist: f64, degrees: f64) -> bool {
    let c = ((a.rotation.transpose() * b.rotation).trace() - 1.0) / 2.0;
    (a.translation - b.translation).norm() <= dist
        && c.clamp(-1.0, 1.0).acos() <= degrees.to_radians()
}

/// Two posed copies of the patch and a plane of clutter below them.
fn scene(truth: &[RigidTransform]) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let (mp, mn) = patch(41);
    let mut pts = Vec::new();
    let mut nrm = Vec::new();
    for t in truth {
        for (p, n) in posed(t, &mp, &mn) {
            pts.push(p);
            nrm.push(n);
        }
    }
    for i in 0..60 {
        for j in 0..60 {
            pts.push([-6.0 + 0.2 * i as f64, -6.0 + 0.2 * j as f64, -3.0]);
            nrm.push([0.0, 0.0, 1.0]);
        }
    }
    (pts, nrm)
}

#[test]
fn every_copy_gets_a_pose_near_its_own() {
    let (mp, mn) = patch(41);
    let diameter = 2.0 * 2f64.sqrt();
    let params = PpfParams::for_diameter(diameter);
    let model = PpfModel::new(&mp, &mn, params).unwrap();
    assert!(model.len() > 100 && model.len() < mp.len());
    let truth = [
        pose([0.2, 1.0, 0.3], 0.9, [2.5, 0.0, 0.5]),
        pose([1.0, -0.4, 0.1], 2.4, [-2.5, 1.0, 0.0]),
    ];
    let (pts, nrm) = scene(&truth);
    let rows: Vec<usize> = (0..pts.len()).collect();
    let poses = model.poses(&pts, &nrm, &rows, 0).unwrap();
    assert!(!poses.is_empty() && poses.len() <= params.max_poses);
    assert!(poses.windows(2).all(|w| w[0].votes >= w[1].votes));
    // Both copies among the most voted poses, within a sampling step and an angle bin.
    for t in &truth {
        let rank = poses
            .iter()
            .position(|p| close(&p.transform, t, params.distance_step, 12.0));
        assert!(matches!(rank, Some(r) if r < 4), "{rank:?}");
    }
    // Restricted to the first copy's rows, the second is not proposed.
    let first: Vec<usize> = (0..mp.len()).collect();
    let only = model.poses(&pts, &nrm, &first, 1).unwrap();
    assert!(close(
        &only[0].transform,
        &truth[0],
        params.distance_step,
        12.0
    ));
    assert!(!only
        .iter()
        .any(|p| close(&p.transform, &truth[1], params.cluster_distance, 24.0)));
}

#[test]
fn the_same_poses_on_any_number_of_threads() {
    let (mp, mn) = patch(31);
    let model = PpfModel::new(&mp, &mn, PpfParams::for_diameter(2.8)).unwrap();
    let (pts, nrm) = scene(&[pose([0.0, 0.0, 1.0], 1.0, [1.0, 2.0, 3.0])]);
    let rows: Vec<usize> = (0..pts.len()).step_by(2).collect();
    let once = model.poses(&pts, &nrm, &rows, 3).unwrap();
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let again = pool.install(|| model.poses(&pts, &nrm, &rows, 3).unwrap());
        assert_eq!(again, once);
    }
}

#[test]
fn bad_input_is_an_error_and_an_empty_scene_no_pose() {
    let (mp, mn) = patch(11);
    let params = PpfParams::for_diameter(2.8);
    assert!(PpfModel::new(&mp, &mn[1..], params).is_err());
    assert!(PpfModel::new(&mp[..1], &mn[..1], params).is_err());
    let mut nan = mp.clone();
    nan[3][1] = f64::NAN;
    assert!(PpfModel::new(&nan, &mn, params).is_err());
    for bad in [
        PpfParams {
            angle_bins: 0,
            ..params
        },
        PpfParams {
            distance_step: -1.0,
            ..params
        },
        PpfParams {
            reference_stride: 0,
            ..params
        },
        PpfParams {
            max_distance: f64::INFINITY,
            ..params
        },
    ] {
        assert!(PpfModel::new(&mp, &mn, bad).is_err(), "{bad:?}");
    }
    let model = PpfModel::new(&mp, &mn, params).unwrap();
    assert!(model.poses(&mp, &mn, &[0, mp.len()], 0).is_err());
    assert!(model.poses(&mp, &mn[1..], &[0], 0).is_err());
    assert!(model.poses(&mp, &mn, &[], 0).unwrap().is_empty());
    assert!(model.poses(&mp, &mn, &[4], 0).unwrap().is_empty());
}

#[test]
fn turns_between_angles_wrap_around_the_circle() {
    let bins = 30u64;
    let bin = |a: f64, b: f64| {
        PpfParams::bin_of(
            PpfParams::in_turns(a).wrapping_sub(PpfParams::in_turns(b)),
            bins,
        )
    };
    let step = TAU / bins as f64;
    // Across zero either way, and angles given outside [0, 2 pi).
    assert_eq!(bin(0.01, TAU - 0.01), 0);
    assert_eq!(bin(TAU - 0.01, 0.01), 29);
    assert_eq!(bin(-0.5 * step, 0.0), 29);
    assert_eq!(bin(2.5 * step + TAU, 0.0), 2);
    for k in 0..30 {
        assert_eq!(bin((k as f64 + 0.5) * step + 1.0, 1.0), k);
    }
}

/// The surface of an axis-aligned box of sides `size` centred at the origin, sampled on a
/// grid of step `step`, with outward normals.
fn box_surface(size: [f64; 3], step: f64) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let (mut pts, mut nrm) = (Vec::new(), Vec::new());
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let (nu, nv) = (
            (size[u] / step).round() as usize,
            (size[v] / step).round() as usize,
        );
        for side in [-1.0, 1.0] {
            for i in 0..=nu {
                for j in 0..=nv {
                    let mut p = [0.0; 3];
                    p[axis] = side * size[axis] / 2.0;
                    p[u] = -size[u] / 2.0 + size[u] * i as f64 / nu as f64;
                    p[v] = -size[v] / 2.0 + size[v] * j as f64 / nv as f64;
                    let mut n = [0.0; 3];
                    n[axis] = side;
                    pts.push(p);
                    nrm.push(n);
                }
            }
        }
    }
    (pts, nrm)
}

#[test]
fn pairs_on_one_plane_are_not_tabled_and_a_box_is_found_on_a_floor() {
    let size = [0.095, 0.036, 0.068];
    let (mp, mn) = box_surface(size, 0.002);
    let diameter = Vector3::from(size).norm();
    let params = PpfParams::for_diameter(diameter);
    let model = PpfModel::new(&mp, &mn, params).unwrap();
    // Two points of one face: the feature is on the table's blind side.
    let key = feature_key(&mp[0], &mn[0], &mp[40], &mn[40], &params, &model.cos_edges).unwrap();
    assert!(params.is_coplanar(key) && !model.table.contains_key(&key));
    // A pair across an edge is tabled.
    let top = mn.iter().position(|n| n[2] == 1.0).unwrap();
    let key = feature_key(
        &mp[0],
        &mn[0],
        &mp[top],
        &mn[top],
        &params,
        &model.cos_edges,
    );
    assert!(key.is_some_and(|k| !params.is_coplanar(k)));
    // The box lying on a floor ten times its size, its bottom face unseen.
    let truth = pose([0.0, 0.0, 1.0], 0.7, [0.3, -0.2, size[2] / 2.0]);
    let (mut pts, mut nrm): (Vec<_>, Vec<_>) = posed(&truth, &mp, &mn)
        .into_iter()
        .filter(|(_, n)| n[2] > -0.5)
        .unzip();
    for i in 0..300 {
        for j in 0..300 {
            pts.push([-0.5 + 0.004 * i as f64, -0.8 + 0.004 * j as f64, 0.0]);
            nrm.push([0.0, 0.0, 1.0]);
        }
    }
    let rows: Vec<usize> = (0..pts.len()).collect();
    let poses = model.poses(&pts, &nrm, &rows, 0).unwrap();
    // Right up to the box's half turns (its four proper symmetries).
    let turns = [
        [1.0, 1.0, 1.0],
        [1.0, -1.0, -1.0],
        [-1.0, 1.0, -1.0],
        [-1.0, -1.0, 1.0],
    ];
    let right = |p: &PpfPose| {
        turns.iter().any(|d| {
            let flip = nalgebra::Matrix3::from_diagonal(&Vector3::from(*d));
            let t = RigidTransform {
                rotation: truth.rotation * flip,
                translation: truth.translation,
            };
            close(&p.transform, &t, params.distance_step, 12.0)
        })
    };
    let rank = poses.iter().position(right);
    assert!(
        matches!(rank, Some(r) if r < 3),
        "{rank:?} of {}",
        poses.len()
    );
}
