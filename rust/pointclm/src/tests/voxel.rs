use super::*;

#[test]
fn averages_each_voxel_and_orders_by_cell() {
    let pts = [
        [0.0, 0.0, 0.0],
        [0.2, 0.0, 0.0],
        [1.05, 0.0, 0.0],
        [1.15, 0.0, 0.0],
    ];
    let out = voxel_downsample(&pts, 0.5).unwrap();
    assert_eq!(out.len(), 2);
    assert!((out[0][0] - 0.1).abs() < 1e-12);
    assert!((out[1][0] - 1.1).abs() < 1e-12);
}

#[test]
fn independent_of_input_order() {
    let pts: Vec<[f64; 3]> = (0..200)
        .map(|i| {
            let t = i as f64 * 0.37;
            [t.sin(), t.cos(), (t * 0.3).sin()]
        })
        .collect();
    let mut rev = pts.clone();
    rev.reverse();
    let a = voxel_downsample(&pts, 0.3).unwrap();
    let b = voxel_downsample(&rev, 0.3).unwrap();
    assert_eq!(a.len(), b.len());
    for (p, q) in a.iter().zip(&b) {
        for k in 0..3 {
            assert!((p[k] - q[k]).abs() < 1e-12);
        }
    }
}

#[test]
fn bad_inputs_are_typed_errors() {
    assert!(matches!(
        voxel_downsample(&[], 0.1),
        Err(Error::TooFewPoints { .. })
    ));
    assert!(matches!(
        voxel_downsample(&[[0.0, f64::NAN, 0.0]], 0.1),
        Err(Error::NonFinite { .. })
    ));
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        assert!(matches!(
            voxel_downsample(&[[0.0; 3]], bad),
            Err(Error::InvalidParameter { .. })
        ));
    }
    assert!(matches!(
        voxel_downsample(&[[0.0; 3], [1e300, 0.0, 0.0]], 1e-300),
        Err(Error::InvalidParameter { .. })
    ));
}
