//! Unit tests of `correspondences`.

use super::*;

#[test]
fn rejects_bad_input() {
    let p = [[0.0; 3]; 3];
    assert!(matches!(
        Correspondences::new(&p[..2], &p[..2]),
        Err(Error::TooFewCorrespondences { got: 2, .. })
    ));
    assert!(matches!(
        Correspondences::new(&p, &p[..2]),
        Err(Error::LengthMismatch { .. })
    ));
    let mut q = p;
    q[1][2] = f64::NAN;
    assert!(matches!(
        Correspondences::new(&p, &q),
        Err(Error::NonFinite { row: 1, .. })
    ));
    assert!(Features::new(vec![1.0; 5], 2).is_err());
    assert!(Features::new(vec![f64::INFINITY; 4], 2).is_err());
}
