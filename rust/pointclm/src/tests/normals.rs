use super::*;

fn plane(n: usize) -> Vec<[f64; 3]> {
    (0..n * n)
        .map(|k| {
            let (i, j) = (k / n, k % n);
            // A tilted plane z = 0.5 x, jittered within the plane.
            let x = i as f64 * 0.05 + 0.01 * ((k * 7 % 5) as f64);
            let y = j as f64 * 0.05;
            [x, y, 0.5 * x + 2.0]
        })
        .collect()
}

#[test]
fn plane_normals_are_the_plane_normal_oriented_to_the_viewpoint() {
    let pts = plane(20);
    let index = PointIndex::new(&pts).unwrap();
    let want = {
        let s = (1.0f64 + 0.25).sqrt();
        [-0.5 / s, 0.0, 1.0 / s]
    };
    let up = estimate_normals(
        &pts,
        &index,
        0.15,
        30,
        Orientation::Towards([0.0, 0.0, 10.0]),
    )
    .unwrap();
    let down = estimate_normals(
        &pts,
        &index,
        0.15,
        30,
        Orientation::AwayFrom([0.0, 0.0, 10.0]),
    )
    .unwrap();
    for (u, d) in up.iter().zip(&down) {
        for k in 0..3 {
            assert!((u[k] - want[k]).abs() < 1e-9, "{u:?}");
            assert!((d[k] + want[k]).abs() < 1e-9);
        }
    }
}

#[test]
fn isolated_points_get_a_default_normal() {
    let pts = [[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]];
    let index = PointIndex::new(&pts).unwrap();
    let n = estimate_normals(&pts, &index, 0.1, 30, Orientation::Towards([0.0, 0.0, 1.0])).unwrap();
    assert_eq!(n[0], [0.0, 0.0, 1.0]);
}

#[test]
fn mismatched_index_is_an_error() {
    let pts = plane(5);
    let index = PointIndex::new(&pts[..10]).unwrap();
    assert!(estimate_normals(&pts, &index, 0.1, 30, Orientation::Towards([0.0; 3])).is_err());
    let index = PointIndex::new(&pts).unwrap();
    assert!(estimate_normals(&pts, &index, 0.1, 2, Orientation::Towards([0.0; 3])).is_err());
    assert!(estimate_normals(&pts, &index, 0.1, 30, Orientation::Towards([f64::NAN; 3])).is_err());
}
