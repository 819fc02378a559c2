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

#[test]
fn edge_on_scores_are_the_ranked_cosines_of_each_eye() {
    // A bumpy patch facing +z, with normals from its slope.
    let (points, normals): (Vec<[f64; 3]>, Vec<[f64; 3]>) = (0..400)
        .map(|k| {
            let (x, y) = ((k % 20) as f64 * 0.1, (k / 20) as f64 * 0.1);
            let (gx, gy) = (0.3 * (3.0 * x).cos(), -0.2 * (2.0 * y).sin());
            let len = (gx * gx + gy * gy + 1.0f64).sqrt();
            (
                [x, y, 0.1 * (3.0 * x).sin() + 0.1 * (2.0 * y).cos()],
                [-gx / len, -gy / len, 1.0 / len],
            )
        })
        .unzip();
    // Above (normals seen head-on), level with the patch (edge-on), and on a point itself.
    let eyes = [[1.0, 1.0, 5.0], [30.0, 1.0, 0.1], points[7]];
    let rank = 39;
    let scores = edge_on_scores(&points, &normals, &eyes, rank).unwrap();
    for (eye, &score) in eyes.iter().zip(&scores) {
        let mut cos: Vec<f64> = points
            .iter()
            .zip(&normals)
            .map(|(p, n)| {
                let s = [eye[0] - p[0], eye[1] - p[1], eye[2] - p[2]];
                let len = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2])
                    .sqrt()
                    .max(f64::MIN_POSITIVE);
                (s[0] * n[0] + s[1] * n[1] + s[2] * n[2]).abs() / len
            })
            .collect();
        cos.sort_by(f64::total_cmp);
        assert_eq!(score, cos[rank]);
    }
    assert!(scores[0] > 0.8 && scores[1] < 0.2, "{scores:?}");
    // The same on any number of threads.
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let again = pool.install(|| edge_on_scores(&points, &normals, &eyes, rank).unwrap());
        assert_eq!(again, scores);
    }
    assert!(edge_on_scores(&points, &normals, &[], 0)
        .unwrap()
        .is_empty());
    assert!(edge_on_scores(&points, &normals[1..], &eyes, 0).is_err());
    assert!(edge_on_scores(&points, &normals, &eyes, 400).is_err());
    assert!(edge_on_scores(&[], &[], &eyes, 0).is_err());
    assert!(edge_on_scores(&points, &normals, &[[f64::NAN, 0.0, 0.0]], 0).is_err());
}
