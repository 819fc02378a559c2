use super::*;
use crate::pointcloud::fpfh::fpfh;

/// A jittered sphere of radius 1 about (0.3, -0.2, 2), dense enough to downsample.
fn sphere(n: usize) -> Vec<[f64; 3]> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt() * (1.0 + 0.01 * ((i * 7 % 5) as f64 - 2.0));
            let a = golden * i as f64;
            [0.3 + r * a.cos(), -0.2 + r * a.sin(), 2.0 + z]
        })
        .collect()
}

/// The three stages run separately, each search over its own k-d tree.
fn separately(points: &[[f64; 3]], p: &DescribeParams) -> (Vec<[f64; 3]>, Vec<[f64; 3]>, Features) {
    let pts = match p.voxel_size {
        Some(v) => voxel_downsample(points, v).unwrap(),
        None => points.to_vec(),
    };
    let nrm = estimate_normals(
        &pts,
        &PointIndex::new(&pts).unwrap(),
        p.normal_radius,
        p.normal_max_nn,
        p.orientation,
    )
    .unwrap();
    let desc = fpfh(
        &pts,
        &nrm,
        &PointIndex::new(&pts).unwrap(),
        p.feature_radius,
        p.feature_max_nn,
        p.variant,
    )
    .unwrap();
    let flat = desc.iter().flat_map(|d| d.iter().copied()).collect();
    (pts, nrm, Features::new(flat, FPFH_DIM).unwrap())
}

#[test]
fn equals_the_stages_run_separately() {
    let pts = sphere(4000);
    let centre = [0.3, -0.2, 2.0];
    let base = DescribeParams::for_voxel(0.05);
    for p in [
        base,
        DescribeParams {
            orientation: Orientation::AwayFrom(centre),
            variant: FpfhVariant::Pcl,
            ..base
        },
        DescribeParams {
            voxel_size: None,
            normal_max_nn: 12,
            feature_max_nn: 40,
            ..base
        },
    ] {
        let d = describe(&pts, None, &p).unwrap();
        let (points, normals, descriptors) = separately(&pts, &p);
        assert_eq!(d.points, points);
        assert_eq!(d.normals, normals);
        assert_eq!(d.descriptors, descriptors);
        assert_eq!(d.descriptors.len(), d.points.len());
        let t = d.timings;
        assert!(t.downsample >= 0.0 && t.normals >= 0.0 && t.fpfh >= 0.0);
    }
    // The sign rules: towards the origin (below the sphere), away from its centre.
    let towards = describe(
        &pts,
        None,
        &DescribeParams {
            voxel_size: None,
            ..base
        },
    )
    .unwrap();
    let away = describe(
        &pts,
        None,
        &DescribeParams {
            voxel_size: None,
            orientation: Orientation::AwayFrom(centre),
            ..base
        },
    )
    .unwrap();
    let dot = |a: &[f64; 3], b: [f64; 3]| (0..3).map(|k| a[k] * b[k]).sum::<f64>();
    for ((p, t), a) in pts.iter().zip(&towards.normals).zip(&away.normals) {
        assert!(dot(t, [-p[0], -p[1], -p[2]]) >= 0.0);
        assert!(dot(a, [p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]]) >= 0.0);
    }
}

#[test]
fn given_normals_are_kept_and_described() {
    let pts = sphere(1500);
    let normals: Vec<[f64; 3]> = pts
        .iter()
        .map(|p| {
            let d = [p[0] - 0.3, p[1] + 0.2, p[2] - 2.0];
            let n = (0..3).map(|k| d[k] * d[k]).sum::<f64>().sqrt();
            d.map(|v| v / n)
        })
        .collect();
    let p = DescribeParams {
        voxel_size: None,
        ..DescribeParams::for_voxel(0.08)
    };
    let d = describe(&pts, Some(&normals), &p).unwrap();
    assert_eq!(d.points, pts);
    assert_eq!(d.normals, normals);
    let index = PointIndex::new(&pts).unwrap();
    let want = fpfh(&pts, &normals, &index, 0.4, 100, FpfhVariant::Open3d).unwrap();
    for (i, w) in want.iter().enumerate() {
        assert_eq!(d.descriptors.row(i), &w[..]);
    }
}

#[test]
fn counts_beyond_the_cloud_are_lowered_and_small_clouds_described() {
    let pts = sphere(60);
    let p = DescribeParams {
        voxel_size: None,
        ..DescribeParams::for_voxel(0.5)
    };
    let huge = DescribeParams {
        normal_max_nn: usize::MAX,
        feature_max_nn: usize::MAX,
        ..p
    };
    let exact = DescribeParams {
        normal_max_nn: 60,
        feature_max_nn: 60,
        ..p
    };
    let (a, b) = (
        describe(&pts, None, &huge).unwrap(),
        describe(&pts, None, &exact).unwrap(),
    );
    assert_eq!(a.normals, b.normals);
    assert_eq!(a.descriptors, b.descriptors);
    // Two points: too few for a plane, (0, 0, 1) oriented, as in Open3D; not an error.
    let two = describe(&pts[..2], None, &p).unwrap();
    assert_eq!(two.points.len(), 2);
    assert!(two
        .normals
        .iter()
        .all(|n| n[0] == 0.0 && n[1] == 0.0 && n[2].abs() == 1.0));
}

#[test]
fn bad_inputs_are_typed_errors() {
    let pts = sphere(300);
    let p = DescribeParams::for_voxel(0.1);
    let raw = DescribeParams {
        voxel_size: None,
        ..p
    };
    let normals = vec![[0.0, 0.0, 1.0]; 300];
    assert!(matches!(
        describe(&[], None, &p),
        Err(Error::TooFewPoints { .. })
    ));
    let mut nan = pts.clone();
    nan[5][2] = f64::NAN;
    assert!(matches!(
        describe(&nan, None, &p),
        Err(Error::NonFinite { row: 5, .. })
    ));
    assert!(matches!(
        describe(&pts, Some(&normals), &p),
        Err(Error::InvalidParameter {
            name: "voxel_size",
            ..
        })
    ));
    assert!(matches!(
        describe(&pts, Some(&normals[..299]), &raw),
        Err(Error::LengthMismatch {
            expected: 300,
            got: 299,
            ..
        })
    ));
    let mut bad_normals = normals.clone();
    bad_normals[9][0] = f64::INFINITY;
    assert!(matches!(
        describe(&pts, Some(&bad_normals), &raw),
        Err(Error::NonFinite { row: 9, .. })
    ));
    for bad in [
        DescribeParams {
            voxel_size: Some(0.0),
            ..p
        },
        DescribeParams {
            normal_radius: -1.0,
            ..p
        },
        DescribeParams {
            feature_radius: f64::NAN,
            ..p
        },
        DescribeParams {
            normal_max_nn: 2,
            ..p
        },
        DescribeParams {
            feature_max_nn: 1,
            ..p
        },
    ] {
        assert!(
            matches!(
                describe(&pts, None, &bad),
                Err(Error::InvalidParameter { .. })
            ),
            "{bad:?}"
        );
    }
    let nowhere = DescribeParams {
        orientation: Orientation::Towards([f64::NAN, 0.0, 0.0]),
        ..p
    };
    assert!(matches!(
        describe(&pts, None, &nowhere),
        Err(Error::NonFinite { .. })
    ));
}
