//! Extreme magnitudes: data and config at 1e300 (or 1e-300) overflow (or underflow) the
//! squared distances every stage computes, which would silently empty the result. The
//! pipeline is equivariant under a common scaling of points and lengths, so such input is
//! scaled by an exact power of two into a safe window and the poses are scaled back. Ordinary
//! input already lies in the window and is not touched (scale 1: bit-identical results).

use crate::config::Config;
use crate::correspondences::Correspondences;
use crate::error::{Error, Result};

/// Coordinates and lengths with magnitudes in `[2^-WINDOW, 2^WINDOW]` are safe: squared
/// distances (`<= 2^(2 WINDOW + 2)`), their ratios to squared lengths (`<= 2^(4 WINDOW + 2)`)
/// and sums of `2^32` of them stay finite and normal in f64 (`2^±1022`).
const WINDOW: i32 = 240;

/// The largest shift: `2^±MAX_SHIFT` is a normal f64.
const MAX_SHIFT: i32 = 1020;

/// `2^exponent` by which to divide the input (0 for input already in the window), or
/// [`Error::MagnitudeRange`] when the largest magnitude (coordinate or length) and the
/// smallest length are too far apart for any common scale.
pub(crate) fn scale_exponent(c: &Correspondences, config: &Config) -> Result<i32> {
    let lengths = [
        config.sigma_d,
        config.affinity_sigma,
        config.inlier_threshold,
    ];
    let smallest = lengths.iter().copied().fold(f64::INFINITY, f64::min);
    let largest = (0..c.len())
        .flat_map(|i| c.source(i).into_iter().chain(c.target(i)))
        .chain(lengths)
        .fold(0.0f64, |m, v| m.max(v.abs()));
    let (lo, hi) = (exponent(smallest), exponent(largest));
    if lo >= -WINDOW && hi <= WINDOW {
        return Ok(0);
    }
    if hi - lo > 2 * WINDOW {
        return Err(Error::MagnitudeRange {
            what: "correspondence coordinates and config lengths",
            smallest,
            largest,
        });
    }
    // centre the range on 1 (in binary orders of magnitude)
    let e = (hi + lo).div_euclid(2);
    if e.abs() > MAX_SHIFT {
        // only lengths below f64's normal range get here
        return Err(Error::MagnitudeRange {
            what: "correspondence coordinates and config lengths",
            smallest,
            largest,
        });
    }
    Ok(e)
}

/// The binary exponent of a finite `x > 0` (`x` in `[2^e, 2^(e+1))`), subnormals included.
fn exponent(x: f64) -> i32 {
    x.log2().floor() as i32
}

/// `x * 2^e`, exact whenever the result is a normal number (two steps, since `2^e` alone may
/// not be representable for the exponents that move 1e-300 or 1e300 to 1).
pub(crate) fn times_pow2(x: f64, e: i32) -> f64 {
    let half = e / 2;
    x * 2f64.powi(half) * 2f64.powi(e - half)
}

/// The correspondences divided by `2^e`.
pub(crate) fn scaled_correspondences(c: &Correspondences, e: i32) -> Result<Correspondences> {
    let rows: Vec<[f64; 6]> = (0..c.len())
        .map(|i| {
            let (s, t) = (c.source(i), c.target(i));
            [s[0], s[1], s[2], t[0], t[1], t[2]].map(|v| times_pow2(v, -e))
        })
        .collect();
    Correspondences::from_rows(&rows)
}

/// The config with its lengths divided by `2^e` ([`Config::scaled`], so that every length
/// field is covered; `|e| <= MAX_SHIFT` keeps the factor a normal number).
pub(crate) fn scaled_config(config: &Config, e: i32) -> Config {
    config.scaled(times_pow2(1.0, -e))
}
