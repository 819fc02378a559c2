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

#[test]
fn similarity_is_checked_and_carried_by_clones() {
    let p = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let c = Correspondences::new(&p, &p).unwrap();
    assert_eq!(c.similarity(), None);
    assert!(matches!(
        c.clone().with_similarity(&[0.5, 0.5]),
        Err(Error::LengthMismatch {
            expected: 3,
            got: 2,
            ..
        })
    ));
    assert!(matches!(
        c.clone().with_similarity(&[0.5, f64::NAN, 0.5]),
        Err(Error::NonFinite {
            what: "similarity",
            row: 1
        })
    ));
    let s = c.with_similarity(&[0.25, 0.5, 1.0]).unwrap();
    assert_eq!(s.similarity(), Some(&[0.25, 0.5, 1.0][..]));
    let both = s.clone().with_normals(&p[..], &p[..], 0.5);
    // zero normals are refused; unit ones keep the similarity
    assert!(both.is_err());
    let up = [[0.0, 0.0, 1.0]; 3];
    let both = s.clone().with_normals(&up, &up, 0.5).unwrap();
    assert_eq!(both.similarity(), s.similarity());
    assert_eq!(both.clone(), both);
}
