//! Seeded planted scenes for unit tests.

use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::correspondences::Correspondences;
use crate::kabsch::RigidTransform;

pub(crate) struct PlantedScene {
    pub corr: Correspondences,
    pub labels: Vec<i64>,
    pub poses: Vec<RigidTransform>,
}

pub(crate) fn random_rotation(rng: &mut ChaCha8Rng) -> Matrix3<f64> {
    let a: f64 = rng.random::<f64>() * std::f64::consts::TAU;
    let b: f64 = rng.random::<f64>() * std::f64::consts::TAU;
    let c: f64 = rng.random::<f64>() * std::f64::consts::TAU;
    *Rotation3::from_euler_angles(a, b, c).matrix()
}

fn unit_ball(rng: &mut ChaCha8Rng) -> [f64; 3] {
    loop {
        let p = [
            rng.random::<f64>() * 2.0 - 1.0,
            rng.random::<f64>() * 2.0 - 1.0,
            rng.random::<f64>() * 2.0 - 1.0,
        ];
        if p.iter().map(|v| v * v).sum::<f64>() <= 1.0 {
            return p;
        }
    }
}

/// `n` rows: `instances` rigid copies each owning `inlier_fraction * n` noise-free rows
/// (poses with translation in [0, 5)^3), the rest uniform targets in [0, 6)^3. Rows are not
/// shuffled: instance 0 first, then 1, ..., then outliers.
pub(crate) fn random_scene(
    n: usize,
    instances: usize,
    inlier_fraction: f64,
    seed: u64,
) -> PlantedScene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let per = ((n as f64) * inlier_fraction) as usize;
    let (mut src, mut dst, mut labels, mut poses) = (vec![], vec![], vec![], vec![]);
    for k in 0..instances {
        let pose = RigidTransform {
            rotation: random_rotation(&mut rng),
            translation: Vector3::new(
                rng.random::<f64>() * 5.0,
                rng.random::<f64>() * 5.0,
                rng.random::<f64>() * 5.0,
            ),
        };
        for _ in 0..per.min(n - src.len()) {
            let x = unit_ball(&mut rng);
            src.push(x);
            dst.push(pose.apply(x));
            labels.push(k as i64);
        }
        poses.push(pose);
    }
    while src.len() < n {
        src.push(unit_ball(&mut rng));
        dst.push([
            rng.random::<f64>() * 6.0,
            rng.random::<f64>() * 6.0,
            rng.random::<f64>() * 6.0,
        ]);
        labels.push(-1);
    }
    PlantedScene {
        corr: Correspondences::new(&src, &dst).unwrap(),
        labels,
        poses,
    }
}

/// The scene's correspondences with a random unit normal at each source point, carried by the
/// true pose to the target for inliers (every third one flipped, as a model's outward normal
/// and a scan's sensor-facing one may disagree) and random for outliers.
pub(crate) fn with_normals(scene: &PlantedScene, seed: u64) -> Correspondences {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut unit = || {
        let v: [f64; 3] = std::array::from_fn(|_| rng.random::<f64>() * 2.0 - 1.0);
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        v.map(|x| x / n)
    };
    let n = scene.corr.len();
    let (mut ns, mut nt) = (vec![], vec![]);
    for i in 0..n {
        let a = unit();
        let b = match scene.labels[i] {
            k if k >= 0 => {
                let r = scene.poses[k as usize].rotation * Vector3::from(a);
                let s = if i % 3 == 0 { -1.0 } else { 1.0 };
                [s * r[0], s * r[1], s * r[2]]
            }
            _ => unit(),
        };
        ns.push(a);
        // Not unit length on purpose: the constructor rescales.
        nt.push(b.map(|x| 2.0 * x));
    }
    scene
        .corr
        .clone()
        .with_normals(&ns, &nt, crate::correspondences::DEFAULT_NORMAL_TOLERANCE)
        .unwrap()
}
