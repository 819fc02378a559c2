use super::*;
use crate::pointcloud::normals::{estimate_normals, Orientation};

fn sphere(n: usize) -> Vec<[f64; 3]> {
    // Fibonacci sphere: near-uniform, deterministic.
    let golden = PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let y = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - y * y).sqrt();
            let t = golden * i as f64;
            [r * t.cos(), y, r * t.sin()]
        })
        .collect()
}

#[test]
fn each_angle_histogram_sums_to_200() {
    // SPFH sums to 100 per angle, the weighted neighbour part is renormalised to 100.
    let pts = sphere(800);
    let index = PointIndex::new(&pts).unwrap();
    let normals = estimate_normals(&pts, &index, 0.2, 30, Orientation::AwayFrom([0.0; 3])).unwrap();
    let d = fpfh(&pts, &normals, &index, 0.3, 100, FpfhVariant::Open3d).unwrap();
    for h in &d {
        for a in 0..3 {
            let s: f64 = h[a * BINS..(a + 1) * BINS].iter().sum();
            assert!((s - 200.0).abs() < 1e-9, "{s}");
        }
    }
}

#[test]
fn pcl_variant_drops_only_the_own_histogram() {
    let pts = sphere(600);
    let index = PointIndex::new(&pts).unwrap();
    let normals = estimate_normals(&pts, &index, 0.2, 30, Orientation::AwayFrom([0.0; 3])).unwrap();
    let o3d = fpfh(&pts, &normals, &index, 0.3, 100, FpfhVariant::Open3d).unwrap();
    let pcl = fpfh(&pts, &normals, &index, 0.3, 100, FpfhVariant::Pcl).unwrap();
    let hoods = index.neighbourhoods(&pts, 0.3, 100).unwrap();
    for i in [0, 17, 599] {
        let own = spfh_of(i, &pts, &normals, &hoods, &mut Vec::new());
        for f in 0..FPFH_DIM {
            assert!((o3d[i][f] - pcl[i][f] - own[f]).abs() < 1e-9);
        }
        let s: f64 = pcl[i][..BINS].iter().sum();
        assert!((s - 100.0).abs() < 1e-9);
    }
}

#[test]
fn invariant_to_rigid_motion() {
    let pts = sphere(500);
    let index = PointIndex::new(&pts).unwrap();
    let normals =
        estimate_normals(&pts, &index, 0.25, 30, Orientation::AwayFrom([0.0; 3])).unwrap();
    let a = fpfh(&pts, &normals, &index, 0.35, 100, FpfhVariant::Open3d).unwrap();
    let (c, s) = (0.6f64.cos(), 0.6f64.sin());
    let rot = |p: &[f64; 3]| [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]];
    let moved: Vec<[f64; 3]> = pts
        .iter()
        .map(|p| {
            let r = rot(p);
            [r[0] + 3.0, r[1] - 1.0, r[2] + 0.5]
        })
        .collect();
    let moved_normals: Vec<[f64; 3]> = normals.iter().map(rot).collect();
    let index2 = PointIndex::new(&moved).unwrap();
    let b = fpfh(
        &moved,
        &moved_normals,
        &index2,
        0.35,
        100,
        FpfhVariant::Open3d,
    )
    .unwrap();
    let mut worst: f64 = 0.0;
    for (x, y) in a.iter().zip(&b) {
        for f in 0..FPFH_DIM {
            worst = worst.max((x[f] - y[f]).abs());
        }
    }
    assert!(worst < 1e-6, "{worst}");
}

#[test]
fn pair_features_are_symmetric_and_degenerate_safe() {
    let p1 = [0.0, 0.0, 0.0];
    let p2 = [1.0, 0.2, 0.1];
    let n1 = [0.0, 0.0, 1.0];
    let n2 = {
        let v = [0.3f64, 0.1, 0.9];
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        v.map(|x| x / l)
    };
    let a = pair_features(&p1, &n1, &p2, &n2);
    let b = pair_features(&p2, &n2, &p1, &n1);
    for k in 0..3 {
        assert!((a[k] - b[k]).abs() < 1e-12);
    }
    assert_eq!(pair_features(&p1, &n1, &p1, &n2), [0.0; 3]);
    // The normal along the connecting line leaves no frame.
    assert_eq!(
        pair_features(&p1, &[1.0, 0.0, 0.0], &[2.0, 0.0, 0.0], &n1),
        [0.0; 3]
    );
}

#[test]
fn bad_inputs_are_typed_errors() {
    let pts = sphere(50);
    let index = PointIndex::new(&pts).unwrap();
    let normals = vec![[0.0, 0.0, 1.0]; 50];
    assert!(matches!(
        fpfh(&pts, &normals[..49], &index, 0.3, 100, FpfhVariant::Open3d),
        Err(Error::LengthMismatch { .. })
    ));
    let mut bad = normals.clone();
    bad[7][1] = f64::NAN;
    assert!(matches!(
        fpfh(&pts, &bad, &index, 0.3, 100, FpfhVariant::Open3d),
        Err(Error::NonFinite { row: 7, .. })
    ));
    assert!(matches!(
        fpfh(&pts, &normals, &index, 0.0, 100, FpfhVariant::Open3d),
        Err(Error::InvalidParameter { .. })
    ));
    // A lone point has no neighbours: zero descriptor, not an error.
    let lone = [[0.0; 3]];
    let i1 = PointIndex::new(&lone).unwrap();
    assert_eq!(
        fpfh(
            &lone,
            &[[0.0, 0.0, 1.0]],
            &i1,
            0.3,
            100,
            FpfhVariant::Open3d
        )
        .unwrap()[0],
        [0.0; FPFH_DIM]
    );
}

#[test]
fn atan_polynomial_stays_within_its_bound() {
    let steps = 2_000_000;
    let mut worst = 0.0f64;
    for i in 0..=steps {
        let a = i as f64 / steps as f64;
        let mut p = ATAN_COEFFS[7];
        for c in ATAN_COEFFS[..7].iter().rev() {
            p = p * a * a + c;
        }
        worst = worst.max((p * a - a.atan()).abs());
    }
    assert!(worst < ATAN_ERROR, "{worst}");
}

#[test]
fn theta_bin_is_the_library_atan2_bin() {
    use rand::{Rng, SeedableRng};
    let exact = |y: f64, x: f64| bin((y.atan2(x) + PI) / (2.0 * PI));
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let mut checked = 0;
    // Random directions and magnitudes, and angles within a few ulps of every bin boundary
    // (where the library decides), both signs of zero and non-finite arguments.
    for _ in 0..200_000 {
        let (y, x) = (rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        let s: f64 = 10f64.powi(rng.random_range(-5..5));
        assert_eq!(theta_bin(y * s, x * s), exact(y * s, x * s), "{y} {x}");
        checked += 1;
    }
    for k in 0..=BINS {
        let edge = -PI + 2.0 * PI * k as f64 / BINS as f64;
        for ulps in -40i64..=40 {
            let t = f64::from_bits((edge.to_bits() as i64 + ulps) as u64);
            for r in [1e-3, 0.7, 1.0, 3e4] {
                let (y, x) = (r * t.sin(), r * t.cos());
                assert_eq!(theta_bin(y, x), exact(y, x), "{t} {r}");
                checked += 1;
            }
        }
    }
    let odd = [
        0.0,
        -0.0,
        1.0,
        -1.0,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NAN,
        1e-320,
    ];
    for y in odd {
        for x in odd {
            assert_eq!(theta_bin(y, x), exact(y, x), "{y} {x}");
        }
    }
    assert!(checked > 200_000);
}
