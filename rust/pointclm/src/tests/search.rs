use super::*;
use crate::error::Error;

fn grid() -> Vec<[f64; 3]> {
    let mut pts = Vec::new();
    for i in 0..10 {
        for j in 0..10 {
            for k in 0..5 {
                pts.push([i as f64 * 0.1, j as f64 * 0.1, k as f64 * 0.1]);
            }
        }
    }
    pts
}

#[test]
fn hybrid_matches_brute_force() {
    let pts = grid();
    let index = PointIndex::new(&pts).unwrap();
    for (q, radius, max_nn) in [(0usize, 0.25, 100usize), (137, 0.15, 5), (499, 0.31, 1000)] {
        let got = index.hybrid(&pts[q], radius, max_nn);
        let mut want: Vec<(usize, f64)> = pts
            .iter()
            .enumerate()
            .map(|(j, p)| (j, (0..3).map(|k| (p[k] - pts[q][k]).powi(2)).sum::<f64>()))
            .filter(|&(_, d)| d <= radius * radius)
            .collect();
        want.sort_by(|a, b| a.1.total_cmp(&b.1));
        want.truncate(max_nn);
        assert_eq!(got.len(), want.len());
        assert_eq!(got[0].0, q, "a point finds itself first");
        for (g, w) in got.iter().zip(&want) {
            assert!((g.1 - w.1).abs() < 1e-12);
        }
    }
    let (j, d) = index.nearest(&[0.51, 0.49, 0.2]);
    assert!(d < 0.0003);
    assert_eq!(pts[j], [0.5, 0.5, 0.2]);
}

#[test]
fn neighbourhoods_agree_with_single_queries() {
    let pts = grid();
    let index = PointIndex::new(&pts).unwrap();
    let hoods = index.neighbourhoods(&pts, 0.2, 12).unwrap();
    assert_eq!(hoods.len(), pts.len());
    for i in [0, 55, 321] {
        let (idx, d2) = hoods.of(i);
        let single = index.hybrid(&pts[i], 0.2, 12);
        assert_eq!(idx.len(), single.len());
        for ((a, b), s) in idx.iter().zip(d2).zip(&single) {
            assert!((*b - s.1).abs() < 1e-15);
            let _ = a;
        }
    }
    assert!(matches!(
        index.neighbourhoods(&pts, -1.0, 12),
        Err(Error::InvalidParameter { .. })
    ));
    assert!(matches!(
        index.neighbourhoods(&pts, 0.1, 0),
        Err(Error::InvalidParameter { .. })
    ));
    assert!(matches!(
        PointIndex::new(&[]),
        Err(Error::TooFewPoints { .. })
    ));
}

#[test]
fn nearest_within_is_the_nearest_point_closer_than_the_radius() {
    let pts = grid();
    let index = PointIndex::new(&pts).unwrap();
    for q in [
        [0.31, 0.47, 0.05],
        [0.5, 0.5, 0.5],
        [3.0, 3.0, 3.0],
        [-0.2, 0.1, 0.0],
    ] {
        let (j, d2) = index.nearest(&q);
        for radius in [0.01, 0.1, 0.3, 10.0] {
            let within = index.nearest_within(&q, radius);
            if d2 < radius * radius {
                let (k, e2) = within.expect("a point lies within the radius");
                assert_eq!(e2, d2);
                assert_eq!(pts[k], pts[j]);
            } else {
                assert_eq!(within, None);
            }
        }
    }
}
