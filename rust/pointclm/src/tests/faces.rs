use super::*;
use crate::pointcloud::planes::tests::{box_surface, described_box};
use crate::scene::{register_point_clouds, SceneOptions};
use nalgebra::Rotation3;

const SIZE: [f64; 3] = [0.095, 0.036, 0.068];
const VOXEL: f64 = 0.003;

/// A box lying on its large face (model y up, along world z), turned by `yaw` about the
/// vertical and centred at `at` (its bottom on z = `at.z - 0.018`).
fn lying(yaw: f64, at: [f64; 3]) -> RigidTransform {
    let up = Rotation3::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2);
    let turn = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw);
    RigidTransform {
        rotation: *(turn * up).matrix(),
        translation: Vector3::from(at),
    }
}

/// What a depth camera at `eye` looking down -z sees of boxes posed by `poses` (axis-aligned
/// in their own frames, of `SIZE`) on the floor z = 0: the first hit of each ray of a grid of
/// `step` radians.
fn depth_view(poses: &[RigidTransform], eye: [f64; 3], step: f64) -> Vec<[f64; 3]> {
    let half = SIZE.map(|s| s / 2.0);
    let mut out = Vec::new();
    let n = (0.45 / step) as i64;
    for i in -n..=n {
        for j in -n..=n {
            let d = Vector3::new(i as f64 * step, j as f64 * step, -1.0).normalize();
            let o = Vector3::from(eye);
            let mut best = -o.z / d.z;
            for pose in poses {
                // The ray in the box's frame, then the slab test.
                let ro = pose.rotation.transpose() * (o - pose.translation);
                let rd = pose.rotation.transpose() * d;
                let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
                for k in 0..3 {
                    let (a, b) = ((-half[k] - ro[k]) / rd[k], (half[k] - ro[k]) / rd[k]);
                    t0 = t0.max(a.min(b));
                    t1 = t1.min(a.max(b));
                }
                if t0 <= t1 && t0 > 0.0 && t0 < best {
                    best = t0;
                }
            }
            let p = o + d * best;
            out.push([p.x, p.y, p.z]);
        }
    }
    out
}

/// Whether `pose` places the box where `truth` does, whatever the box's half turns: its
/// posed sample within a voxel of the truth's on average.
fn same_placement(pose: &RigidTransform, truth: &RigidTransform, model: &PointIndex) -> bool {
    within(pose, truth, model, VOXEL)
}

/// Whether `pose`'s posed sample lies within `radius` of `truth`'s on average.
fn within(pose: &RigidTransform, truth: &RigidTransform, model: &PointIndex, radius: f64) -> bool {
    let (points, _) = box_surface(SIZE, 0.01);
    let mean: f64 = points
        .iter()
        .map(|&p| {
            let q = truth.rotation.transpose() * (Vector3::from(pose.apply(p)) - truth.translation);
            model.nearest(&[q[0], q[1], q[2]]).1.sqrt()
        })
        .sum::<f64>()
        / points.len() as f64;
    mean <= radius
}

/// `face_poses` as the proposer calls it: every extent with its bias added.
fn proposed(faces: &[Patch], patches: &[Patch]) -> Vec<FacePose> {
    let bias = EXTENT_BIAS_VOXELS * VOXEL;
    let faces: Vec<Patch> = faces.iter().map(|f| unbiased(f.clone(), bias)).collect();
    let patches: Vec<Patch> = patches.iter().map(|p| unbiased(p.clone(), bias)).collect();
    face_poses(&faces, &patches, SIZE_TOLERANCE_VOXELS * VOXEL).unwrap()
}

fn scan_patches(scan: &[[f64; 3]], eye: [f64; 3]) -> Vec<Patch> {
    let index = PointIndex::new(scan).unwrap();
    let normals = crate::pointcloud::estimate_normals(
        scan,
        &index,
        2.0 * VOXEL,
        30,
        crate::pointcloud::Orientation::Towards(eye),
    )
    .unwrap();
    let tol = PlaneTolerances::calibrated(VOXEL, 0.0, 2.0 * VOXEL).unwrap();
    PlaneSegmenter::new(scan, &normals, &index, 2.0 * VOXEL, tol, MIN_PATCH_POINTS)
        .unwrap()
        .patches(None)
        .unwrap()
}

#[test]
fn a_box_seen_from_above_gets_a_face_pose_near_its_truth() {
    let (model, normals) = described_box(SIZE, VOXEL);
    let (faces, share) = model_faces(&model, &normals, VOXEL).unwrap();
    assert_eq!(faces.len(), 6);
    assert!(share > 0.8, "{share}");
    let truth = lying(0.4, [0.01, -0.02, 0.018]);
    let eye = [0.0, 0.0, 0.6];
    let scan =
        crate::pointcloud::voxel_downsample(&depth_view(&[truth], eye, 0.001), VOXEL).unwrap();
    let patches = scan_patches(&scan, eye);
    let poses = proposed(&faces, &patches);
    let index = PointIndex::new(&box_surface(SIZE, 0.001).0).unwrap();
    assert!(
        poses
            .iter()
            .any(|p| same_placement(&p.pose, &truth, &index)),
        "{} poses, none on the box",
        poses.len()
    );
}

#[test]
fn flush_copies_in_a_row_are_each_a_tile_of_their_joined_top() {
    let (model, normals) = described_box(SIZE, VOXEL);
    let (faces, _) = model_faces(&model, &normals, VOXEL).unwrap();
    let yaw = 0.3f64;
    let along = [yaw.cos() * SIZE[0], yaw.sin() * SIZE[0]];
    let truths: Vec<RigidTransform> = (0..3)
        .map(|k| {
            let s = k as f64 - 1.0;
            lying(yaw, [s * along[0], s * along[1], 0.018])
        })
        .collect();
    let eye = [0.0, 0.0, 0.6];
    let scan =
        crate::pointcloud::voxel_downsample(&depth_view(&truths, eye, 0.001), VOXEL).unwrap();
    let patches = scan_patches(&scan, eye);
    let poses = proposed(&faces, &patches);
    let index = PointIndex::new(&box_surface(SIZE, 0.001).0).unwrap();
    for (k, truth) in truths.iter().enumerate() {
        let tiled = poses
            .iter()
            .any(|p| p.tiled && same_placement(&p.pose, truth, &index));
        assert!(tiled, "copy {k} is no tile");
    }
}

#[test]
fn distinct_placements_drop_a_box_turned_onto_itself() {
    let (model, _) = box_surface(SIZE, VOXEL);
    let index = PointIndex::new(&model).unwrap();
    let a = lying(0.2, [0.0, 0.0, 0.018]);
    let half_turn = Rotation3::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI);
    let b = RigidTransform {
        rotation: *half_turn.matrix() * a.rotation,
        translation: a.translation,
    };
    let c = lying(0.2, [0.05, 0.0, 0.018]);
    let sample: Vec<[f64; 3]> = model.iter().step_by(7).copied().collect();
    let kept = distinct_placements(&[a, b, c], &sample, &index, [0.0; 3], VOXEL, 10);
    assert_eq!(kept, vec![0, 2]);
    let one = distinct_placements(&[a, b, c], &sample, &index, [0.0; 3], VOXEL, 1);
    assert_eq!(one, vec![0]);
}

#[test]
fn bad_values_are_typed_errors() {
    assert!(matches!(
        Proposals::from_name("planes"),
        Err(Error::InvalidParameter {
            name: "proposals",
            ..
        })
    ));
    for name in Proposals::NAMES {
        assert_eq!(Proposals::from_name(name).unwrap().name(), name);
    }
    assert!(matches!(
        face_poses(&[], &[], -1.0),
        Err(Error::InvalidParameter {
            name: "size_tolerance",
            ..
        })
    ));
}

/// A packed row of boxes and one apart on a floor, seen from above: registration with face
/// proposals finds the row's copies (as copies, or as poses sliding along the row) within the
/// benchmarks' tenth of a diagonal, the same on 1 and 2 threads, and the descriptors alone
/// find fewer. (The box apart is the descriptors' and verification's: a box standing on end
/// through the floor under its top shows the sensor the same surfaces.)
#[test]
fn a_packed_row_of_boxes_is_found_with_face_proposals() {
    let (model, _) = box_surface(SIZE, 0.001);
    let yaw = -0.5f64;
    let along = [yaw.cos() * SIZE[0], yaw.sin() * SIZE[0]];
    let mut truths: Vec<RigidTransform> = (0..3)
        .map(|k| {
            let s = k as f64 - 1.0;
            lying(yaw, [s * along[0] + 0.01, s * along[1] - 0.04, 0.018])
        })
        .collect();
    truths.push(lying(0.7, [-0.03, 0.09, 0.018]));
    let eye = [0.02, 0.03, 0.6];
    let scan = depth_view(&truths, eye, 0.0015);
    let run = |threads: usize, proposals: Proposals| {
        let options = SceneOptions {
            viewpoint: Some(eye),
            proposals,
            ..SceneOptions::default()
        };
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| register_point_clouds(&model, &scan, &options).unwrap())
    };
    let index = PointIndex::new(&model).unwrap();
    let found = |out: &crate::scene::SceneRegistration| {
        let poses: Vec<RigidTransform> = (out.candidates.iter().chain(&out.ambiguous))
            .map(|c| c.pose)
            .collect();
        let tenth = 0.1 * (SIZE[0].powi(2) + SIZE[1].powi(2) + SIZE[2].powi(2)).sqrt();
        truths[..3]
            .iter()
            .filter(|t| poses.iter().any(|p| within(p, t, &index, tenth)))
            .count()
    };
    let faces = run(2, Proposals::Faces);
    assert!(faces.face_proposals);
    assert_eq!(found(&faces), 3);
    let one = run(1, Proposals::Faces);
    let poses = |out: &crate::scene::SceneRegistration| {
        (out.candidates.iter().chain(&out.ambiguous))
            .map(|c| c.pose)
            .collect::<Vec<_>>()
    };
    assert_eq!(poses(&one), poses(&faces));
    let auto = run(2, Proposals::Auto);
    assert!(auto.face_proposals && auto.planar_share > 0.8);
    let descriptors = run(2, Proposals::Descriptors);
    assert!(!descriptors.face_proposals && descriptors.planar_share.is_nan());
    assert!(found(&descriptors) < 3);
}

/// A box sampled coarser than the voxel (its edge voxels' normals bent over two voxels), seen
/// from above by its top alone: the model's top measures as the scan's does, so it is laid on
/// it, for boxes whose sides divide one another, of square section, and cubes.
#[test]
fn a_box_seen_by_its_top_alone_gets_its_top_laid_on_it() {
    let voxel = 0.0059;
    for size in [
        [0.2, 0.12, 0.03],
        [0.12, 0.04, 0.04],
        [0.1, 0.05, 0.05],
        [0.1, 0.1, 0.1],
    ] {
        let (coarse, _) = box_surface(size, 0.004);
        let params = DescribeParams {
            orientation: crate::pointcloud::Orientation::AwayFrom([0.0; 3]),
            ..DescribeParams::for_voxel(voxel)
        };
        let model = crate::pointcloud::describe(&coarse, None, &params).unwrap();
        let (faces, _) = model_faces(&model.points, &model.normals, voxel).unwrap();
        let up = faces.iter().find(|f| f.normal[2] > 0.99).unwrap();
        let sides = [size[0].max(size[1]), size[0].min(size[1])];
        for (got, want) in up.extents.iter().zip(sides) {
            assert!((got - want).abs() <= voxel, "{size:?}: {:?}", up.extents);
        }
        let (fine, _) = box_surface(size, 0.001);
        let top: Vec<[f64; 3]> = (fine.into_iter())
            .filter(|p| p[2] > size[2] / 2.0 - 1e-9)
            .collect();
        let scan = crate::pointcloud::voxel_downsample(&top, voxel).unwrap();
        let index = PointIndex::new(&scan).unwrap();
        let eye = [0.0, 0.0, 1.0];
        let towards = crate::pointcloud::Orientation::Towards(eye);
        let normals =
            crate::pointcloud::estimate_normals(&scan, &index, 2.0 * voxel, 30, towards).unwrap();
        let tol = PlaneTolerances::calibrated(voxel, 0.0, 2.0 * voxel).unwrap();
        let segmenter =
            PlaneSegmenter::new(&scan, &normals, &index, 2.0 * voxel, tol, MIN_PATCH_POINTS);
        let patches = segmenter.unwrap().patches(None).unwrap();
        let bias = EXTENT_BIAS_VOXELS * voxel;
        let faces: Vec<Patch> = faces.into_iter().map(|f| unbiased(f, bias)).collect();
        let patches: Vec<Patch> = patches.into_iter().map(|p| unbiased(p, bias)).collect();
        let poses = face_poses(&faces, &patches, SIZE_TOLERANCE_VOXELS * voxel).unwrap();
        // Where the box is, whatever its symmetries: its corners posed onto its corners.
        let corners: Vec<[f64; 3]> = (0..8)
            .map(|k| [0, 1, 2].map(|a| if k >> a & 1 == 1 { size[a] } else { -size[a] } / 2.0))
            .collect();
        let on_box = |pose: &RigidTransform| {
            corners.iter().all(|&c| {
                let q = pose.apply(c);
                (corners.iter()).any(|&d| dist(q, d) <= 2.0 * voxel)
            })
        };
        assert!(
            poses.iter().any(|p| p.tiled && on_box(&p.pose)),
            "{size:?}: {} poses, none on the box",
            poses.len()
        );
    }
}

/// A rectangle of `extents` (long side first) about `centre` with `normal`, its long side
/// along `axis`, as the segmenter measures one.
fn rectangle(extents: [f64; 2], centre: [f64; 3], normal: [f64; 3], axis: [f64; 3]) -> Patch {
    Patch {
        normal,
        centroid: centre,
        centre,
        axes: [axis, cross(normal, axis)],
        extents,
        rows: Vec::new(),
    }
}

/// The six faces of a box of `size` centred at the origin, measured exactly.
fn exact_faces(size: [f64; 3]) -> Vec<Patch> {
    let mut faces = Vec::new();
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let (long, short) = if size[u] >= size[v] { (u, v) } else { (v, u) };
        for side in [-1.0, 1.0] {
            let mut normal = [0.0; 3];
            normal[axis] = side;
            let mut along = [0.0; 3];
            along[long] = 1.0;
            let centre = scale(normal, size[axis] / 2.0);
            faces.push(rectangle([size[long], size[short]], centre, normal, along));
        }
    }
    faces
}

/// A box whose long side four times over is its top: the top laid on the top, not four of the
/// long side standing on end (each a body through what holds the box up).
#[test]
fn a_face_that_divides_another_does_not_displace_it() {
    let size = [0.2, 0.12, 0.03];
    let faces = exact_faces(size);
    let top = rectangle(
        [0.2, 0.12],
        [0.0, 0.0, 0.015],
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0],
    );
    let poses = face_poses(&faces, &[top], 2.0 * VOXEL).unwrap();
    assert!(!poses.is_empty());
    for pose in &poses {
        assert!(
            pose.tiled && faces[pose.face].normal[2].abs() > 0.99,
            "{pose:?}"
        );
        assert!(Vector3::from(pose.pose.translation).norm() < 1e-9);
    }
}
