//! The scan's sensor and its description: where the sensor stood (given, or guessed from the
//! scan for the first pass to confirm), and the scan's normals facing it, with FPFH.
//!
//! Why the viewpoint matters: the normals' sign decides the descriptors (FPFH of a surface
//! seen from behind is another descriptor), and verification judges a pose by what the sensor
//! could see of the copy, which needs its position.

use crate::correspondences::Features;
use crate::error::Result;
use crate::matching::nearest_sources;
use crate::pointcloud::{
    describe, estimate_normals, estimate_sensor, estimate_viewpoint, looks_like_one_view,
    terraces::resolving_terraces, DescribeParams, Described, FpfhVariant, Orientation, PointIndex,
    RefineParams, SensorEstimate,
};

use super::{mean_point, median, SceneRules};

/// At most this many scan descriptors (a stride) are compared with the model's when the
/// descriptors pick the normals' sign: a median, settled long before every row is used.
pub const SIGN_SAMPLE: usize = 2000;

/// The scan described, and where the call takes its sensor to be.
#[derive(Debug, Clone)]
pub struct DescribedScan {
    /// The points (as given: already downsampled), normals and FPFH.
    pub cloud: Described,
    /// How its normals were oriented, in words.
    pub orientation: String,
    /// The sensor position verification judges by (given, or guessed); `None`: none.
    pub viewpoint: Option<[f64; 3]>,
    /// Whether `viewpoint` is a guess the first pass must confirm.
    pub guessed: bool,
}

/// The downsampled scan `points` described at `voxel`, its normals facing the sensor:
/// towards `viewpoint` when given. Without one, the sensor is guessed: a scan in its sensor's
/// frame (one view from the origin, [`looks_like_one_view`], and [`in_front`] of it) has its
/// sensor at the origin, unless it is one object alone whose descriptors say it was seen from
/// behind ([`seen_from_behind`]: then its sensor is estimated on its other side); otherwise
/// the normals are oriented from the origin when the scan is one view from it, else from a
/// point that orients them consistently
/// ([`estimate_viewpoint`]); either fixes them up to one global sign. Outside surfaces face
/// the sensor, so the sign kept is the side the sensor stood on ([`side_by_sight`], for a scan
/// that spans a scene), else the sign whose descriptors lie nearer the model's (the median
/// distance from each scan descriptor to its nearest model descriptor). A sensor estimated on
/// that side is the guess when the scan looks like one view from it.
///
/// Flipping every normal only reindexes FPFH ([`flip_fpfh`]), so both signs cost one FPFH
/// pass.
pub fn describe_scan(
    points: &[[f64; 3]],
    voxel: f64,
    viewpoint: Option<[f64; 3]>,
    model: &Described,
    scene: &SceneRules,
) -> Result<DescribedScan> {
    let params = scan_params(voxel, Orientation::Towards(viewpoint.unwrap_or([0.0; 3])));
    let t0 = std::time::Instant::now();
    let index = PointIndex::new(points)?;
    if let Some(view) = viewpoint {
        let fine = fine_normals(points, &index, &params)?;
        let (normals, steps) = resolving_steps(points, &index, &params, fine, view)?;
        let normals_time = t0.elapsed().as_secs_f64();
        let mut cloud = describe(points, Some(&normals), &params)?;
        cloud.timings.normals += normals_time;
        return Ok(DescribedScan {
            cloud,
            orientation: with_steps(format!("towards the viewpoint {}", xyz(view)), steps),
            viewpoint: Some(view),
            guessed: false,
        });
    }
    let origin = [0.0; 3];
    let fine = fine_normals(points, &index, &params)?;
    let rules = RefineParams::for_voxel(voxel);
    // One view from the origin orients the normals consistently (up to one sign); with every
    // point in front of it, the sign too (see `in_front`).
    let one_view = looks_like_one_view(points, origin, &rules)?;
    let sensor_frame = one_view && in_front(points);
    let eye = if one_view {
        origin
    } else {
        estimate_viewpoint(points, &fine, 256)?
    };
    let (raw, steps) = resolving_steps(points, &index, &params, fine, eye)?;
    let normals: Vec<[f64; 3]> = points
        .iter()
        .zip(&raw)
        .map(|(p, n)| facing(p, n, eye))
        .collect();
    let normals_time = t0.elapsed().as_secs_f64();
    let mut cloud = describe(points, Some(&normals), &params)?;
    cloud.timings.normals += normals_time;
    // Only a lone object (not a scene) seen from the origin can be seen from behind it.
    let behind = match sensor_frame && !spans_a_scene(points, &model.points, scene.scene_extent) {
        true => seen_from_behind(model, &cloud)?,
        false => None,
    };
    if let Some((rows, of)) = behind {
        // A lone object's view looks alike from its sensor and from behind its surface; the
        // origin stands behind it when its descriptors match the model's only flipped.
        let centre = mean_point(points);
        let sensor = estimate_sensor(points, voxel, centre.map(|c| 2.0 * c))?.position;
        let guess = looks_like_one_view(points, sensor, &rules)?.then_some(sensor);
        let orientation = format!(
            "no viewpoint: away from the origin, as the scan (one object, one view from the \
             origin) matches the model's descriptors flipped for {rows} of {of} rows: seen \
             from its other side, where the sensor is estimated at {}",
            xyz(sensor)
        );
        return Ok(DescribedScan {
            cloud: flipped_cloud(cloud),
            orientation: with_steps(orientation, steps),
            viewpoint: guess,
            guessed: guess.is_some(),
        });
    }
    if sensor_frame {
        let orientation =
            "no viewpoint: towards the origin, a sensor's position (the scan is one view from it)";
        return Ok(DescribedScan {
            cloud,
            orientation: with_steps(orientation.into(), steps),
            viewpoint: Some(origin),
            guessed: true,
        });
    }
    if one_view {
        // The origin orients them up to one sign, and is not the sensor (some point is
        // behind it): the descriptors pick the sign, and nothing is guessed.
        let (flipped, orientation) = signed_by_descriptors(model, &cloud, eye)?;
        return Ok(DescribedScan {
            cloud: if flipped { flipped_cloud(cloud) } else { cloud },
            orientation: with_steps(orientation, steps),
            viewpoint: None,
            guessed: false,
        });
    }
    let centre = mean_point(points);
    let mirror = [0, 1, 2].map(|k| 2.0 * centre[k] - eye[k]);
    let sides = [
        estimate_sensor(points, voxel, eye)?,
        estimate_sensor(points, voxel, mirror)?,
    ];
    let one_view_from = |s: usize| looks_like_one_view(points, sides[s].position, &rules);
    let by_sight = if spans_a_scene(points, &model.points, scene.scene_extent) {
        side_by_sight(&sides, &one_view_from)?
    } else {
        None
    };
    let (flipped, orientation) = match by_sight {
        Some(side) => (
            side == 1,
            format!(
                "no viewpoint: towards the estimated sensor position {}, from which the scan \
                 hides the fewest of its own points",
                xyz(sides[side].position)
            ),
        ),
        None => signed_by_descriptors(model, &cloud, eye)?,
    };
    let side = usize::from(flipped);
    let guess = one_view_from(side)?.then_some(sides[side].position);
    Ok(DescribedScan {
        cloud: if flipped { flipped_cloud(cloud) } else { cloud },
        orientation: with_steps(orientation, steps),
        viewpoint: guess,
        guessed: guess.is_some(),
    })
}

/// The scan's normals as `params` fit them (over 2 voxels), or over 4 where its depth steps
/// seen from `eye` make terraces at 2 ([`resolving_terraces`]); true for those. `fine`: the
/// former, already fitted.
fn resolving_steps(
    points: &[[f64; 3]],
    index: &PointIndex,
    params: &DescribeParams,
    fine: Vec<[f64; 3]>,
    eye: [f64; 3],
) -> Result<(Vec<[f64; 3]>, bool)> {
    let shape = (params.normal_radius, params.normal_max_nn);
    resolving_terraces(points, index, fine, shape, params.orientation, eye)
}

/// The scan's normals as `params` fit them: over 2 voxels, signed by its orientation.
fn fine_normals(
    points: &[[f64; 3]],
    index: &PointIndex,
    params: &DescribeParams,
) -> Result<Vec<[f64; 3]>> {
    let (radius, max_nn) = (params.normal_radius, params.normal_max_nn);
    estimate_normals(points, index, radius, max_nn, params.orientation)
}

/// `orientation`, saying when the normals were fitted over 4 voxels.
fn with_steps(orientation: String, steps: bool) -> String {
    if steps {
        orientation + "; fitted over 4 voxels, as the scan's depth steps make flat terraces at 2"
    } else {
        orientation
    }
}

/// How a scan is described: normals over 2 voxels, FPFH over 5 (the points are downsampled
/// already).
fn scan_params(voxel: f64, orientation: Orientation) -> DescribeParams {
    DescribeParams {
        voxel_size: None,
        normal_radius: 2.0 * voxel,
        normal_max_nn: 30,
        feature_radius: 5.0 * voxel,
        feature_max_nn: 100,
        variant: FpfhVariant::Open3d,
        orientation,
    }
}

/// `n` with its sign flipped to face `eye` from `p`.
fn facing(p: &[f64; 3], n: &[f64; 3], eye: [f64; 3]) -> [f64; 3] {
    let dot = (eye[0] - p[0]) * n[0] + (eye[1] - p[1]) * n[1] + (eye[2] - p[2]) * n[2];
    if dot >= 0.0 {
        *n
    } else {
        n.map(|v| -v)
    }
}

/// Which of two sensor estimates (on each side of the scan) is its sensor: the one the scan
/// looks like one view from (`one_view`, by index), hiding fewer of its points by more than
/// two standard errors; `None` when that does not decide (a flat scene looks alike from both
/// sides, a merged scan like one view from neither). Why: from its mirror image behind the
/// surfaces, a single view's foreground hides its background, and that count picked the
/// right side on the 15 realistic validation scans wherever it decided (the flat beds tie),
/// where the descriptors' sign test erred in 2 (BENCHMARKS.md).
pub fn side_by_sight(
    sides: &[SensorEstimate; 2],
    one_view: &dyn Fn(usize) -> Result<bool>,
) -> Result<Option<usize>> {
    let (h0, h1) = (sides[0].hidden_share, sides[1].hidden_share);
    let low = h0.min(h1);
    let n = sides[0].points.min(sides[1].points).max(1) as f64;
    let noise = 2.0 * (low * (1.0 - low) / n).sqrt();
    if (h0 - h1).abs() <= noise {
        return Ok(None);
    }
    let best = if h0 < h1 { 0 } else { 1 };
    Ok(one_view(best)?.then_some(best))
}

/// Whether the scan reaches beyond `extent` model radii from its centroid: a scene with
/// surfaces behind the copies, not one object alone. Why: the side a sensor stood on shows in
/// what the scan's surfaces hide of one another, which needs depth behind them; a single
/// object seen from behind hides little of itself, and on the Stanford bunny scans the count
/// favoured the wrong side (BENCHMARKS.md).
pub fn spans_a_scene(scan: &[[f64; 3]], model: &[[f64; 3]], extent: f64) -> bool {
    reach(scan) > extent * reach(model)
}

/// The largest distance of a point from the centroid.
fn reach(points: &[[f64; 3]]) -> f64 {
    let c = mean_point(points);
    points
        .iter()
        .map(|p| ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt())
        .fold(f64::NEG_INFINITY, f64::max)
}

/// Whether every point lies in front of the origin (within an open half-space). A scan that
/// is one view from the origin and in front of it is in its sensor's frame: the sensor saw
/// the outer side of every surface, so normals facing it need no sign test. Points all around
/// the origin may be a scan from inside a room or a closed object about its centre, which
/// want opposite signs: the descriptors decide there (a test that a scan made mostly of
/// planes leaves close to a coin toss: 32.4 against 32.6 on PCL's Kinect frame).
pub fn in_front(points: &[[f64; 3]]) -> bool {
    if points.len() < 3 {
        return false;
    }
    let mut units = Vec::with_capacity(points.len());
    for p in points {
        let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        // A point at the origin (or NaN) has no direction to be in front along.
        if r.is_nan() || r <= 0.0 {
            return false;
        }
        units.push(p.map(|v| v / r));
    }
    let mean = mean_point(&units);
    units
        .iter()
        .all(|u| u[0] * mean[0] + u[1] * mean[1] + u[2] * mean[2] > 0.0)
}

/// How many of a sample of the scan's descriptors lie nearer the model's with every normal
/// flipped, and of how many, when that is more than half by over `BEHIND_STANDARD_ERRORS`
/// standard errors (`None` otherwise): the scan was then seen from the other side of its
/// surfaces. Lone objects rendered from the origin (bunny, boxes, bracket; three views each)
/// give 10-46 % of rows (never more than half), the Stanford bunny range scans, whose scanner
/// stood on the far side of the origin, 79-88 % (17-23 standard errors), BENCHMARKS.md.
fn seen_from_behind(model: &Described, scan: &Described) -> Result<Option<(usize, usize)>> {
    let (towards, away) = both_signs(model, scan)?;
    let n = towards.len();
    let nearer = towards.iter().zip(&away).filter(|(t, a)| a < t).count();
    let excess = (nearer as f64 - n as f64 / 2.0) / ((n as f64).sqrt() / 2.0);
    Ok((excess > BEHIND_STANDARD_ERRORS).then_some((nearer, n)))
}

/// See [`seen_from_behind`]: five standard errors, a chance of 3e-7 for a scan whose
/// descriptors favour neither sign.
pub const BEHIND_STANDARD_ERRORS: f64 = 5.0;

/// Whether the scan's normals are to be flipped (they then face away from `eye`): the sign
/// whose descriptors lie nearer the model's; and how they were oriented, in words.
fn signed_by_descriptors(
    model: &Described,
    scan: &Described,
    eye: [f64; 3],
) -> Result<(bool, String)> {
    let (towards, away) = both_signs(model, scan)?;
    let (towards, away) = (median_distance(&towards), median_distance(&away));
    let side = if away < towards {
        "away from"
    } else {
        "towards"
    };
    let text = format!(
        "no viewpoint: {side} the estimated point {}, the sign whose descriptors match the \
         model's (median distance {} vs {})",
        xyz(eye),
        g3(towards.min(away)),
        g3(towards.max(away)),
    );
    Ok((away < towards, text))
}

/// At most `most` rows of `features`, evenly strided from the first.
fn strided(features: &Features, most: usize) -> Result<Features> {
    let step = features.len().div_ceil(most).max(1);
    let flat: Vec<f64> = (0..features.len())
        .step_by(step)
        .flat_map(|r| features.row(r).iter().copied())
        .collect();
    Features::new(flat, features.dim())
}

/// For a stride of at most `SIGN_SAMPLE` of the scan's descriptors, the squared distance of
/// each to its nearest model descriptor, as they are and with every normal flipped: the two
/// signs' evidence, which [`signed_by_descriptors`] and [`seen_from_behind`] weigh.
fn both_signs(model: &Described, scan: &Described) -> Result<(Vec<f64>, Vec<f64>)> {
    let rows = strided(&scan.descriptors, SIGN_SAMPLE)?;
    let towards = nearest_sources(&model.descriptors, &rows, 1)?.dist2;
    let away = nearest_sources(&model.descriptors, &flip_fpfh_rows(&rows), 1)?.dist2;
    Ok((towards, away))
}

/// The median of the distances whose squares are `dist2`.
fn median_distance(dist2: &[f64]) -> f64 {
    let mut d: Vec<f64> = dist2.iter().map(|&d2| d2.max(0.0).sqrt()).collect();
    median(&mut d)
}

/// FPFH's 33 bins are three 11-bin histograms of the pair features (f1: the angle theta,
/// f2: alpha, f3: phi). Flipping every normal negates the Darboux frame's u and v and keeps
/// w, so f1 and f3 change sign and f2 does not (PCL's `computePairFeatures`; its swap rule
/// compares absolute angles, so it is unchanged): the first and last histograms run
/// backwards. A cloud's descriptors under the opposite orientation are thus a reindexing.
pub const FLIPPED_FPFH_BINS: [usize; 33] = {
    let mut bins = [0; 33];
    let mut i = 0;
    while i < 11 {
        bins[i] = 10 - i;
        bins[11 + i] = 11 + i;
        bins[22 + i] = 32 - i;
        i += 1;
    }
    bins
};

/// The FPFH descriptors the same points would have with every normal flipped.
pub fn flip_fpfh_rows(descriptors: &Features) -> Features {
    let dim = descriptors.dim();
    let flat: Vec<f64> = (0..descriptors.len())
        .flat_map(|r| {
            let row = descriptors.row(r);
            FLIPPED_FPFH_BINS.map(|b| row[b])
        })
        .collect();
    Features::new(flat, dim).unwrap_or_else(|_| descriptors.clone())
}

/// `cloud` with every normal flipped and its descriptors reindexed to match.
fn flipped_cloud(cloud: Described) -> Described {
    Described {
        normals: cloud.normals.iter().map(|n| n.map(|v| -v)).collect(),
        descriptors: flip_fpfh_rows(&cloud.descriptors),
        ..cloud
    }
}

/// A point as `(x, y, z)` with 4 significant digits, as the Python package prints it.
pub(crate) fn xyz(p: [f64; 3]) -> String {
    let parts: Vec<String> = p.iter().map(|&v| g4(v)).collect();
    format!("({})", parts.join(", "))
}

/// `v` as Python's `format(v, ".4g")`.
fn g4(v: f64) -> String {
    general(v, 4)
}

/// `v` as Python's `format(v, ".3g")`.
fn g3(v: f64) -> String {
    general(v, 3)
}

/// `v` in C's `%.{digits}g`: scientific when the exponent is below -4 or at least `digits`,
/// trailing zeros dropped.
fn general(v: f64, digits: usize) -> String {
    if v == 0.0 || !v.is_finite() {
        return if v.is_nan() {
            "nan".into()
        } else if v.is_infinite() {
            (if v > 0.0 { "inf" } else { "-inf" }).into()
        } else {
            "0".into()
        };
    }
    let sci = format!("{:.*e}", digits - 1, v);
    let (mantissa, exp) = sci.split_once('e').unwrap_or((sci.as_str(), "0"));
    let exp: i32 = exp.parse().unwrap_or(0);
    if exp < -4 || exp >= digits as i32 {
        let m = trim_zeros(mantissa);
        format!("{m}e{}{:02}", if exp < 0 { '-' } else { '+' }, exp.abs())
    } else {
        let decimals = (digits as i32 - 1 - exp).max(0) as usize;
        trim_zeros(&format!("{v:.decimals$}")).to_string()
    }
}

fn trim_zeros(s: &str) -> &str {
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.')
    } else {
        s
    }
}
