//! RANSAC over 3-point Kabsch hypotheses within one cluster. On synthetic scenes a cluster is
//! mostly inliers and a few hypotheses suffice (paper Table 4); on real scans a cluster can be
//! four parts outliers to one part inliers, so the loop runs until it is confident (the
//! classic adaptive stopping rule) rather than a fixed count.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::correspondences::Correspondences;
use crate::kabsch::{kabsch, RigidTransform};

/// The best pose found and its inliers among `members`.
#[derive(Debug, Clone)]
pub struct RansacFit {
    pub pose: RigidTransform,
    pub inliers: Vec<usize>,
}

/// Runs at most `iterations` hypotheses on `members` and returns the pose with the most
/// inliers (residual below `threshold`), refit by least squares on its inliers when `refine`.
/// The loop stops early once, at the best inlier share `w` seen so far, `k` draws would all
/// have missed an all-inlier triplet with probability below `1 - confidence`
/// (`(1 - w^3)^k < 1 - confidence`); `confidence >= 1` runs every iteration.
/// `None` when no non-degenerate triplet was drawn.
pub fn ransac(
    c: &Correspondences,
    members: &[usize],
    iterations: usize,
    confidence: f64,
    threshold: f64,
    refine: bool,
    rng: &mut ChaCha8Rng,
) -> Option<RansacFit> {
    if members.len() < 3 {
        return None;
    }
    let thr_sq = threshold * threshold;
    let mut best: Option<(usize, f64, RigidTransform)> = None;
    let mut needed = iterations;
    let mut drawn = 0;
    while drawn < needed.min(iterations) {
        drawn += 1;
        let triplet = sample_three(members, rng);
        if !plausible_triplet(c, &triplet, threshold) {
            continue;
        }
        let Some(pose) = kabsch(c, &triplet) else {
            continue;
        };
        let (count, cost) = score(c, members, &pose, thr_sq);
        let better = match &best {
            None => true,
            Some((bc, bcost, _)) => count > *bc || (count == *bc && cost < *bcost),
        };
        if better {
            best = Some((count, cost, pose));
            needed = needed_draws(count, members.len(), confidence);
        }
    }
    let (_, _, mut pose) = best?;
    let mut inliers = inliers_of(c, members, &pose, thr_sq);
    if refine {
        // Refit on the inliers until the set stops changing (a few rounds at most).
        for _ in 0..5 {
            let Some(refit) = kabsch(c, &inliers) else {
                break;
            };
            let next = inliers_of(c, members, &refit, thr_sq);
            if next.len() < inliers.len() {
                break;
            }
            let stable = next == inliers;
            pose = refit;
            inliers = next;
            if stable {
                break;
            }
        }
    }
    Some(RansacFit { pose, inliers })
}

/// Draws after which an all-inlier triplet would have been seen with probability
/// `confidence`, when `inliers` of `members` are inliers.
fn needed_draws(inliers: usize, members: usize, confidence: f64) -> usize {
    if confidence >= 1.0 {
        return usize::MAX;
    }
    let w = inliers as f64 / members as f64;
    let all_inlier = w * w * w;
    if all_inlier >= 1.0 {
        return 1;
    }
    let k = (1.0 - confidence).ln() / (1.0 - all_inlier).ln();
    if k.is_finite() {
        k.ceil().max(1.0) as usize
    } else {
        usize::MAX
    }
}

fn sample_three(members: &[usize], rng: &mut ChaCha8Rng) -> [usize; 3] {
    let n = members.len();
    let a = rng.random_range(0..n);
    let mut b = rng.random_range(0..n - 1);
    if b >= a {
        b += 1;
    }
    let mut c = rng.random_range(0..n - 2);
    for lo in [a.min(b), a.max(b)] {
        if c >= lo {
            c += 1;
        }
    }
    [members[a], members[b], members[c]]
}

/// Cheap rejection before the SVD: a rigid motion preserves the three side lengths, and a
/// near-collinear triangle does not fix a rotation.
fn plausible_triplet(c: &Correspondences, t: &[usize; 3], threshold: f64) -> bool {
    let p = [c.source(t[0]), c.source(t[1]), c.source(t[2])];
    let q = [c.target(t[0]), c.target(t[1]), c.target(t[2])];
    let mut longest = 0.0f64;
    for (a, b) in [(0, 1), (1, 2), (0, 2)] {
        let ls = dist(p[a], p[b]);
        let lt = dist(q[a], q[b]);
        if (ls - lt).abs() > 2.0 * threshold {
            return false;
        }
        longest = longest.max(ls);
    }
    let u = sub(p[1], p[0]);
    let v = sub(p[2], p[0]);
    let cross = [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ];
    let twice_area = (cross[0].powi(2) + cross[1].powi(2) + cross[2].powi(2)).sqrt();
    // the triangle's height over its longest side must not vanish
    twice_area > 1e-3 * longest * longest
}

fn score(
    c: &Correspondences,
    members: &[usize],
    pose: &RigidTransform,
    thr_sq: f64,
) -> (usize, f64) {
    let mut count = 0;
    let mut cost = 0.0;
    for &i in members {
        let r = pose.residual_sq(c.source(i), c.target(i));
        if r < thr_sq {
            count += 1;
            cost += r;
        } else {
            cost += thr_sq;
        }
    }
    (count, cost)
}

pub(crate) fn inliers_of(
    c: &Correspondences,
    members: &[usize],
    pose: &RigidTransform,
    thr_sq: f64,
) -> Vec<usize> {
    members
        .iter()
        .copied()
        .filter(|&i| pose.residual_sq(c.source(i), c.target(i)) < thr_sq)
        .collect()
}

#[inline]
fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline]
fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = sub(a, b);
    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
}

#[cfg(test)]
#[path = "tests/ransac.rs"]
mod tests;
