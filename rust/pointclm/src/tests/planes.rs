use super::*;

/// The surface of an axis-aligned box of `size` centred at the origin, sampled every `step`,
/// with outward normals.
pub(crate) fn box_surface(size: [f64; 3], step: f64) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let mut points = Vec::new();
    let mut normals = Vec::new();
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let nu = (size[u] / step).round() as usize;
        let nv = (size[v] / step).round() as usize;
        for side in [-1.0, 1.0] {
            for i in 0..=nu {
                for j in 0..=nv {
                    let mut p = [0.0; 3];
                    p[axis] = side * size[axis] / 2.0;
                    p[u] = -size[u] / 2.0 + size[u] * i as f64 / nu as f64;
                    p[v] = -size[v] / 2.0 + size[v] * j as f64 / nv as f64;
                    let mut n = [0.0; 3];
                    n[axis] = side;
                    points.push(p);
                    normals.push(n);
                }
            }
        }
    }
    (points, normals)
}

/// `box_surface` sampled finely, downsampled at `voxel` and given normals away from its
/// centre, as the pipeline describes a model.
pub(crate) fn described_box(size: [f64; 3], voxel: f64) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let (fine, _) = box_surface(size, voxel / 4.0);
    let points = super::super::voxel_downsample(&fine, voxel).unwrap();
    let index = PointIndex::new(&points).unwrap();
    let normals = super::super::estimate_normals(
        &points,
        &index,
        2.0 * voxel,
        30,
        super::super::Orientation::AwayFrom([0.0; 3]),
    )
    .unwrap();
    (points, normals)
}

fn segmenter(points: &[[f64; 3]], normals: &[[f64; 3]], voxel: f64) -> PlaneSegmenter {
    let index = PointIndex::new(points).unwrap();
    let tol = PlaneTolerances::calibrated(voxel, 0.0, 2.0 * voxel).unwrap();
    PlaneSegmenter::new(points, normals, &index, 2.0 * voxel, tol, 16).unwrap()
}

#[test]
fn a_box_has_six_faces_with_their_sizes_and_outward_normals() {
    let size = [0.095, 0.036, 0.068];
    let voxel = 0.003;
    let (points, normals) = described_box(size, voxel);
    let patches = segmenter(&points, &normals, voxel).patches(None).unwrap();
    assert_eq!(
        patches.len(),
        6,
        "{:?}",
        patches.iter().map(|p| p.extents).collect::<Vec<_>>()
    );
    for patch in &patches {
        let axis = (0..3).max_by(|&a, &b| patch.normal[a].abs().total_cmp(&patch.normal[b].abs()));
        let axis = axis.unwrap();
        assert!(patch.normal[axis].abs() > 0.999);
        // Outward: the normal points the way the face lies from the centre.
        assert!(patch.normal[axis] * patch.centroid[axis] > 0.0);
        let mut sides = [size[(axis + 1) % 3], size[(axis + 2) % 3]];
        sides.sort_by(|a, b| b.total_cmp(a));
        for k in 0..2 {
            assert!(
                (patch.extents[k] - sides[k]).abs() <= 2.0 * voxel,
                "face {axis}: {:?} vs {sides:?}",
                patch.extents
            );
        }
        let handed = cross(patch.axes[0], patch.axes[1]);
        assert!(dot(handed, patch.normal) > 0.999);
    }
}

#[test]
fn a_tilted_square_gets_its_rectangle_not_its_bounding_box() {
    let (c, s) = (0.6f64.cos(), 0.6f64.sin());
    let mut points = Vec::new();
    for i in 0..=40 {
        for j in 0..=20 {
            let (x, y) = (i as f64 * 0.05, j as f64 * 0.05);
            points.push([c * x - s * y, s * x + c * y]);
        }
    }
    let (angle, lo, hi) = min_area_rectangle(&points).unwrap();
    let mut sides = [hi[0] - lo[0], hi[1] - lo[1]];
    sides.sort_by(|a, b| b.total_cmp(a));
    assert!((sides[0] - 2.0).abs() < 1e-9 && (sides[1] - 1.0).abs() < 1e-9);
    assert!(angle.is_finite());
}

#[test]
fn free_rows_limit_the_patches_and_the_result_is_the_same_on_any_thread_count() {
    let voxel = 0.003;
    let (points, normals) = box_surface([0.095, 0.036, 0.068], voxel);
    let run = |threads: usize, free: Option<&[bool]>| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| segmenter(&points, &normals, voxel).patches(free).unwrap())
    };
    assert_eq!(run(1, None), run(2, None));
    // Only the +y face free: one patch, of its points.
    let free: Vec<bool> = points.iter().map(|p| p[1] > 0.0179).collect();
    let one = run(2, Some(&free));
    assert_eq!(one.len(), 1);
    assert!(one[0].rows.iter().all(|&r| free[r]));
}

#[test]
fn bad_inputs_are_typed_errors() {
    let voxel = 0.003;
    let (points, normals) = box_surface([0.03, 0.03, 0.03], voxel);
    let index = PointIndex::new(&points).unwrap();
    let tol = PlaneTolerances::calibrated(voxel, 0.0, 2.0 * voxel).unwrap();
    let short = &normals[..10];
    assert!(matches!(
        PlaneSegmenter::new(&points, short, &index, 2.0 * voxel, tol, 16),
        Err(Error::LengthMismatch { .. })
    ));
    assert!(matches!(
        PlaneSegmenter::new(&points, &normals, &index, 2.0 * voxel, tol, 2),
        Err(Error::InvalidParameter {
            name: "min_points",
            ..
        })
    ));
    assert!(matches!(
        PlaneSegmenter::new(&points, &normals, &index, -1.0, tol, 16),
        Err(Error::InvalidParameter { .. })
    ));
    assert!(matches!(
        PlaneTolerances::calibrated(voxel, f64::NAN, 2.0 * voxel),
        Err(Error::InvalidParameter { name: "noise", .. })
    ));
    let seg = PlaneSegmenter::new(&points, &normals, &index, 2.0 * voxel, tol, 16).unwrap();
    assert!(matches!(
        seg.patches(Some(&[true; 3])),
        Err(Error::LengthMismatch { .. })
    ));
}

#[test]
fn the_tolerances_grow_with_the_noise_from_their_floors() {
    let voxel = 0.003;
    let clean = PlaneTolerances::calibrated(voxel, 0.0, 2.0 * voxel).unwrap();
    assert!((clean.distance - MIN_DISTANCE_VOXELS * voxel).abs() < 1e-15);
    assert!((clean.angle - MIN_ANGLE_RAD).abs() < 1e-15);
    let noisy = PlaneTolerances::calibrated(voxel, 0.5 * voxel, 2.0 * voxel).unwrap();
    assert!((noisy.distance - 1.5 * voxel).abs() < 1e-12);
    assert!(noisy.angle > clean.angle);
}
