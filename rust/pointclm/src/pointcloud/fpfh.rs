//! Fast Point Feature Histograms (Rusu et al., ICRA 2009) in Open3D's 33-bin form.
//!
//! Each point first gets a simplified histogram (SPFH) of the angles between its normal and
//! its neighbours' (three angles, 11 bins each, summing to 100 per angle); its FPFH is the
//! inverse-squared-distance weighted sum of its neighbours' SPFH, renormalised per angle,
//! plus its own SPFH. The weighting (1 / squared distance) and the renormalisation follow
//! Open3D's implementation, so that descriptors match Open3D's to rounding.
//!
//! Two variants exist in the wild: PCL (and Open3D before it added the point's own SPFH)
//! keeps only the weighted neighbour sum (each angle sums to 100); current Open3D adds the
//! point's own SPFH (each angle sums to 200). [`FpfhVariant`] selects one; the descriptors
//! differ by that term only, and matching works with either as long as both clouds use the
//! same.

use std::f64::consts::{FRAC_PI_2, PI};

use rayon::prelude::*;

use super::search::{Neighbourhoods, PointIndex};
use super::{check_count, check_index, check_normals, check_points, check_positive};
use crate::error::{Error, Result};

/// Length of an FPFH descriptor: 3 angles x 11 bins.
pub const FPFH_DIM: usize = 33;
const BINS: usize = 11;

/// Which published form of FPFH to compute (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FpfhVariant {
    /// Current Open3D (0.10 and later): neighbour sum plus the point's own SPFH.
    #[default]
    Open3d,
    /// PCL, and the descriptor files of early Open3D: the neighbour sum only.
    Pcl,
}

/// One FPFH descriptor per point, over hybrid neighbourhoods (at most `max_nn` nearest within
/// `radius`). `normals` must be unit vectors, one per point, consistently oriented (see
/// [`super::estimate_normals`]). A point without neighbours gets an all-zero descriptor.
pub fn fpfh(
    points: &[[f64; 3]],
    normals: &[[f64; 3]],
    index: &PointIndex,
    radius: f64,
    max_nn: usize,
    variant: FpfhVariant,
) -> Result<Vec<[f64; FPFH_DIM]>> {
    check_points(points, "points for FPFH", 1)?;
    check_normals(normals, points.len(), "normals", "normals (one per point)")?;
    check_index(index, points)?;
    check_positive("feature radius", radius)?;
    check_count("feature max_nn", max_nn, 2)?;
    if points.len() > u32::MAX as usize {
        return Err(Error::TooFewPoints {
            what: "points for FPFH (at most 2^32)",
            got: points.len(),
            min: 0,
        });
    }
    let hoods = index.neighbourhoods(points, radius, max_nn)?;
    let spfh: Vec<[f64; FPFH_DIM]> = (0..points.len())
        .into_par_iter()
        .map_init(Vec::new, |terms, i| {
            spfh_of(i, points, normals, &hoods, terms)
        })
        .collect();
    Ok((0..points.len())
        .into_par_iter()
        .map(|i| fpfh_of(i, &spfh, &hoods, variant))
        .collect())
}

fn spfh_of(
    i: usize,
    points: &[[f64; 3]],
    normals: &[[f64; 3]],
    hoods: &Neighbourhoods,
    terms: &mut Vec<[f64; 4]>,
) -> [f64; FPFH_DIM] {
    let mut h = [0.0; FPFH_DIM];
    let (nbrs, _) = hoods.of(i);
    if nbrs.len() < 2 {
        return h;
    }
    // The first neighbour is the point itself.
    let incr = 100.0 / (nbrs.len() - 1) as f64;
    // Every pair's terms first, then their bins: each pair is a long chain of square roots,
    // divisions and the arctangent's polynomial, and loops this short let the core work on
    // several pairs at once (one loop over both ran at the chains' latency).
    terms.clear();
    terms.extend(nbrs[1..].iter().map(|&j| {
        pair_terms(
            &points[i],
            &normals[i],
            &points[j as usize],
            &normals[j as usize],
        )
    }));
    for &[y, x, alpha, phi] in terms.iter() {
        h[theta_bin(y, x)] += incr;
        h[BINS + bin((alpha + 1.0) * 0.5)] += incr;
        h[2 * BINS + bin((phi + 1.0) * 0.5)] += incr;
    }
    h
}

fn fpfh_of(
    i: usize,
    spfh: &[[f64; FPFH_DIM]],
    hoods: &Neighbourhoods,
    variant: FpfhVariant,
) -> [f64; FPFH_DIM] {
    let mut out = [0.0; FPFH_DIM];
    let (nbrs, dist2) = hoods.of(i);
    if nbrs.len() < 2 {
        return out;
    }
    let mut sums = [0.0; 3];
    for (&j, &d2) in nbrs[1..].iter().zip(&dist2[1..]) {
        if d2 == 0.0 {
            continue;
        }
        // The same operations in the same order as one loop over `f` (each sum and each
        // bin adds its terms in order), split so that the divisions and the bins vectorise.
        let s = &spfh[j as usize];
        let mut v = [0.0; FPFH_DIM];
        for f in 0..FPFH_DIM {
            v[f] = s[f] / d2;
        }
        for f in 0..FPFH_DIM {
            out[f] += v[f];
        }
        for (sum, block) in sums.iter_mut().zip(v.chunks_exact(BINS)) {
            for x in block {
                *sum += x;
            }
        }
    }
    for s in &mut sums {
        if *s != 0.0 {
            *s = 100.0 / *s;
        }
    }
    let own = match variant {
        FpfhVariant::Open3d => 1.0,
        FpfhVariant::Pcl => 0.0,
    };
    for f in 0..FPFH_DIM {
        out[f] = out[f] * sums[f / BINS] + own * spfh[i][f];
    }
    out
}

/// The bin of `x` in [0, 1] among 11, clamped at both ends.
#[inline]
fn bin(x: f64) -> usize {
    let b = BINS as f64 * x;
    // floor(b) < 0 exactly when b < 0; otherwise the cast truncates, which is the floor of a
    // non-negative number (and maps NaN to bin 0, as the floor did). Why not `floor`: on the
    // baseline x86-64 target it is a libm call per angle.
    if b < 0.0 {
        0
    } else {
        (b as usize).min(BINS - 1)
    }
}

/// Coefficients of `atan(a) ~ a * P(a^2)` on `0 <= a <= 1`, `P` of degree 7 (a least-squares
/// fit reweighted towards minimax); the error is below [`ATAN_ERROR`] (tested densely).
const ATAN_COEFFS: [f64; 8] = [
    0.999_999_335_618_348_6,
    -0.333_298_608_638_290_75,
    0.199_465_661_319_524_78,
    -0.139_086_307_140_201_8,
    0.096_421_982_479_422_84,
    -0.055_912_319_873_041_63,
    0.021_862_943_323_153_528,
    -0.004_054_561_164_841_909,
];
/// Bound of the polynomial's error in radians (3.75e-8 measured, with margin).
const ATAN_ERROR: f64 = 5e-8;
/// Distance from a bin boundary, in bins, below which the polynomial's bin is not trusted:
/// 15 times its error bound (`11 / (2 pi) * ATAN_ERROR` = 9e-8) and far above the rounding
/// of the bin arithmetic (1e-14).
const THETA_BIN_MARGIN: f64 = 1e-6;
const _: () = assert!(BINS as f64 / (2.0 * PI) * ATAN_ERROR * 10.0 < THETA_BIN_MARGIN);

/// The bin of `theta = atan2(y, x)`, exactly `bin((theta + PI) / (2 PI))` with the library's
/// `atan2`. Why: `atan2` was a third of the SPFH pass, and a bin only needs to know on which
/// side of 10 boundaries theta lies. A polynomial decides wherever it lies farther than its
/// error bound from a boundary; the library decides the rest (a few pairs in a million, and
/// every zero or non-finite argument).
#[inline]
fn theta_bin(y: f64, x: f64) -> usize {
    let (ax, ay) = (x.abs(), y.abs());
    let (lo, hi) = if ay > ax { (ax, ay) } else { (ay, ax) };
    if hi > 0.0 && hi.is_finite() {
        let a = lo / hi;
        let s = a * a;
        let mut p = ATAN_COEFFS[7];
        for c in ATAN_COEFFS[..7].iter().rev() {
            p = p * s + c;
        }
        let mut t = p * a;
        if ay > ax {
            t = FRAC_PI_2 - t;
        }
        if x < 0.0 {
            t = PI - t;
        }
        if y < 0.0 {
            t = -t;
        }
        let b = BINS as f64 * ((t + PI) / (2.0 * PI));
        if b > 0.0 {
            let whole = b as usize;
            let frac = b - whole as f64;
            if frac > THETA_BIN_MARGIN && frac < 1.0 - THETA_BIN_MARGIN {
                return whole.min(BINS - 1);
            }
        }
    }
    bin((y.atan2(x) + PI) / (2.0 * PI))
}

/// The Darboux-frame angles `(theta, alpha, phi)` of a pair of oriented points, with the
/// frame anchored at the point whose normal is more aligned with the connecting line (so the
/// features do not depend on the order of the pair), and all zero for coincident points or a
/// degenerate frame.
#[cfg(test)]
fn pair_features(p1: &[f64; 3], n1: &[f64; 3], p2: &[f64; 3], n2: &[f64; 3]) -> [f64; 3] {
    let [y, x, alpha, phi] = pair_terms(p1, n1, p2, n2);
    [y.atan2(x), alpha, phi]
}

/// [`pair_features`] with theta left as its `atan2` arguments: `[y, x, alpha, phi]`, all zero
/// for coincident points or a degenerate frame (`atan2(0, 0)` is 0).
#[inline]
fn pair_terms(p1: &[f64; 3], n1: &[f64; 3], p2: &[f64; 3], n2: &[f64; 3]) -> [f64; 4] {
    let mut d = sub(p2, p1);
    let len = dot(&d, &d).sqrt();
    if len == 0.0 {
        return [0.0; 4];
    }
    let a1 = dot(n1, &d) / len;
    let a2 = dot(n2, &d) / len;
    // acos is decreasing, so acos|a1| > acos|a2| <=> |a1| < |a2|.
    let (u, n_other, phi) = if a1.abs() < a2.abs() {
        d = d.map(|v| -v);
        (n2, n1, -a2)
    } else {
        (n1, n2, a1)
    };
    let v = cross(&d, u);
    let vn = dot(&v, &v).sqrt();
    if vn == 0.0 {
        return [0.0; 4];
    }
    let v = v.map(|x| x / vn);
    let w = cross(u, &v);
    let alpha = dot(&v, n_other);
    [dot(&w, n_other), dot(u, n_other), alpha, phi]
}

#[inline]
fn sub(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline]
fn dot(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
fn cross(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[cfg(test)]
#[path = "../tests/fpfh.rs"]
mod tests;
