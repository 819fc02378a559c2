//! The minimum-area rectangle of points in a plane, which measures a planar patch
//! ([`super::planes`]).

/// The minimum-area rectangle holding `points` (2-D): its angle (its first axis
/// `(cos, sin)`), and its low and high corners in its own axes. One of its sides lies along
/// an edge of the convex hull, so only those directions are tried.
pub(crate) fn min_area_rectangle(points: &[[f64; 2]]) -> Option<(f64, [f64; 2], [f64; 2])> {
    let hull = convex_hull(points);
    if hull.len() < 3 {
        return None;
    }
    let mut best: Option<(f64, f64, [f64; 2], [f64; 2])> = None;
    for k in 0..hull.len() {
        let (p, q) = (hull[k], hull[(k + 1) % hull.len()]);
        let angle = (q[1] - p[1]).atan2(q[0] - p[0]);
        let (c, s) = (angle.cos(), angle.sin());
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for h in &hull {
            let a = [c * h[0] + s * h[1], -s * h[0] + c * h[1]];
            for d in 0..2 {
                lo[d] = lo[d].min(a[d]);
                hi[d] = hi[d].max(a[d]);
            }
        }
        let area = (hi[0] - lo[0]) * (hi[1] - lo[1]);
        if best.is_none_or(|b| area < b.0) {
            best = Some((area, angle, lo, hi));
        }
    }
    best.map(|(_, angle, lo, hi)| (angle, lo, hi))
}

/// The convex hull of `points`, counter-clockwise, without collinear points (Andrew's
/// monotone chain).
fn convex_hull(points: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let mut pts: Vec<[f64; 2]> = points.to_vec();
    pts.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    pts.dedup();
    if pts.len() < 3 {
        return pts;
    }
    let turn = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let mut hull: Vec<[f64; 2]> = Vec::with_capacity(2 * pts.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &[f64; 2]>> = if pass == 0 {
            Box::new(pts.iter())
        } else {
            Box::new(pts.iter().rev())
        };
        for &p in iter {
            while hull.len() >= start + 2
                && turn(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0
            {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    hull
}
