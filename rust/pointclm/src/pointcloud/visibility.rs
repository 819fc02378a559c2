//! What a range sensor at a known position could see: the scan as a depth map around the
//! sensor, and the verdict on each point of a posed model (hidden, seen, or contradicted by
//! free space).
//!
//! Why: a copy of an object partly hidden by its neighbours shows only part of itself, so
//! the share of the model the scan explains says little about whether a pose is right. What
//! the sensor could see of the copy at that pose does: the posed model's points that face
//! the sensor and that no scan point hides. A right pose has them on the scan; a wrong one
//! puts surface where the sensor looked through to something behind (free space).
//!
//! The map is keyed by ray direction: the unit vector from the sensor, cut into cubes of side
//! `cell` radians. Unlike a pinhole frame or spherical angles this has no pole and no field
//! of view to choose. Other copies found in the scene need no special care: the scan holds
//! them, so they hide what lies behind them like any surface.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use nalgebra::Vector3;

/// A direction cell and the range along it.
type Ray = ([i32; 3], f64);

/// Ray cells to their nearest range. The keys are small integers chosen by the sensor's
/// geometry, not by an adversary, so a multiply-rotate hash (FxHash's) serves instead of the
/// default SipHash, which cost a third of a map's construction; nothing depends on the order.
type CellMap = HashMap<[i32; 3], f64, BuildHasherDefault<CellHasher>>;

/// FxHash's word mixing (as in rustc): rotate, xor the word, multiply.
#[derive(Default)]
pub(crate) struct CellHasher(u64);

impl Hasher for CellHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }

    fn write_u64(&mut self, word: u64) {
        self.0 = (self.0.rotate_left(5) ^ word).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }

    fn write_i32(&mut self, word: i32) {
        self.write_u64(u64::from(word as u32));
    }

    fn write_usize(&mut self, word: usize) {
        self.write_u64(word as u64);
    }
}

/// The nearest scan range per ray cell around a sensor.
pub struct DepthMap {
    viewpoint: [f64; 3],
    /// Cell side, in radians (as a length on the unit sphere).
    cell: f64,
    /// Ranges closer than this count as the same surface.
    tolerance: f64,
    nearest: CellMap,
}

/// What the sensor says about one model point at a pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sight {
    /// Behind the model's own surface, or behind a scan point: the sensor cannot see it.
    Hidden,
    /// On the sensor's first surface along its ray (or on a ray with no return).
    Seen,
    /// The sensor saw past it: its first return lies clearly behind the point.
    Contradicted,
    /// No return on its ray, and none on some side of it within the reach judged: the scan
    /// ends there (the sensor's field of view, a crop, its range), so it says nothing of the
    /// point.
    Unobserved,
}

impl DepthMap {
    /// The map of `scan` seen from `viewpoint`. Cells are `cell_length` wide at the scan's
    /// median range (so about one scan point per cell when `cell_length` is a little over the
    /// sampling step); ranges within `tolerance` of each other are one surface.
    pub fn new(scan: &[[f64; 3]], viewpoint: [f64; 3], cell_length: f64, tolerance: f64) -> Self {
        Self::with_rays(scan, viewpoint, cell_length, tolerance).0
    }

    /// [`DepthMap::new`] of `scan` followed by [`DepthMap::hidden_share`] of the same points,
    /// each point's ray computed once. Why: the sensor estimate ([`super::sensor`]) asks it
    /// for a hundred or more positions per scan.
    pub fn own_hidden_share(
        scan: &[[f64; 3]],
        viewpoint: [f64; 3],
        cell_length: f64,
        tolerance: f64,
    ) -> f64 {
        let (map, rays) = Self::with_rays(scan, viewpoint, cell_length, tolerance);
        map.share_hidden(rays.into_iter(), scan.len())
    }

    /// The map of `scan` and the rays of its points (those not at the sensor).
    fn with_rays(
        scan: &[[f64; 3]],
        viewpoint: [f64; 3],
        cell_length: f64,
        tolerance: f64,
    ) -> (Self, Vec<Ray>) {
        let offsets: Vec<([f64; 3], f64)> = scan.iter().map(|p| offset(p, viewpoint)).collect();
        let mut ranges: Vec<f64> = offsets.iter().map(|o| o.1).collect();
        let mid = ranges.len() / 2;
        let median = if ranges.is_empty() {
            1.0
        } else {
            *ranges.select_nth_unstable_by(mid, f64::total_cmp).1
        };
        let mut map = Self {
            viewpoint,
            cell: cell_length / median.max(f64::MIN_POSITIVE),
            tolerance,
            nearest: CellMap::default(),
        };
        let rays: Vec<Ray> = offsets
            .iter()
            .filter_map(|&(d, range)| map.ray_along(d, range))
            .collect();
        map.nearest = nearest_of(rays.iter().copied(), rays.len());
        (map, rays)
    }

    fn ray(&self, p: &[f64; 3]) -> Option<Ray> {
        let (d, range) = offset(p, self.viewpoint);
        self.ray_along(d, range)
    }

    /// The ray of the offset `d` from the sensor, of length `range`; `None` at the sensor.
    fn ray_along(&self, d: [f64; 3], range: f64) -> Option<Ray> {
        if !(range > 0.0 && range.is_finite()) {
            return None;
        }
        let key = d.map(|c| (c / range / self.cell).floor() as i32);
        Some((key, range))
    }

    /// Each point's ray, `None` where the model itself hides it (a nearer point of `posed`
    /// on the same ray, more than the tolerance ahead) or where it has none (at the sensor).
    fn own_view(&self, posed: &[[f64; 3]]) -> Vec<Option<Ray>> {
        let rays: Vec<Option<Ray>> = posed.iter().map(|p| self.ray(p)).collect();
        let own = match NearestBox::of(&rays) {
            Some(cells) => Nearest::Cells(cells),
            None => Nearest::Map(nearest_of(rays.iter().flatten().copied(), posed.len())),
        };
        rays.into_iter()
            .map(|ray| ray.filter(|(key, range)| own.get(key) >= range - self.tolerance))
            .collect()
    }

    /// The sensor's position.
    pub fn viewpoint(&self) -> [f64; 3] {
        self.viewpoint
    }

    /// The share of scan points that lie clearly behind another scan point on their ray. A
    /// single view taken from this viewpoint has almost none (only grazing surfaces and
    /// edges); a scan merged from several views, or a wrong viewpoint, has many.
    pub fn hidden_share(&self, scan: &[[f64; 3]]) -> f64 {
        self.share_hidden(scan.iter().filter_map(|p| self.ray(p)), scan.len())
    }

    /// The share of `total` points whose `rays` lie clearly behind the map's nearest range.
    fn share_hidden(&self, rays: impl Iterator<Item = Ray>, total: usize) -> f64 {
        if total == 0 {
            return 0.0;
        }
        let hidden = rays
            .filter(|(key, range)| self.nearest[key] < range - self.tolerance)
            .count();
        hidden as f64 / total as f64
    }

    /// Which points of `posed` (a model already moved by a pose) the model itself hides from
    /// the sensor: a nearer point of it lies on the same ray, more than the tolerance ahead
    /// (its far side). A point at the sensor is hidden.
    pub fn self_hidden(&self, posed: &[[f64; 3]]) -> Vec<bool> {
        self.own_view(posed).iter().map(Option::is_none).collect()
    }

    /// The verdict on each point of `posed` (a model already moved by a pose): hidden by the
    /// model itself ([`DepthMap::self_hidden`]) or by the scan; else contradicted when the
    /// scan's first return on that ray lies clearly behind it; else seen, or unobserved where
    /// its ray has no return and the scan has none on some side of it within `reach`
    /// ([`DepthMap::covered`]).
    pub fn judge(&self, posed: &[[f64; 3]], reach: f64) -> Vec<Sight> {
        self.own_view(posed)
            .into_iter()
            .zip(posed)
            .map(|(ray, p)| {
                let Some((key, range)) = ray else {
                    return Sight::Hidden;
                };
                match self.nearest.get(&key) {
                    Some(&scan) if scan < range - self.tolerance => Sight::Hidden,
                    Some(&scan) if scan > range + self.tolerance => Sight::Contradicted,
                    Some(_) => Sight::Seen,
                    None if self.covered(p, range, reach) => Sight::Seen,
                    None => Sight::Unobserved,
                }
            })
            .collect()
    }

    /// Whether the scan has a return on every side of the ray through `p` (at `range`):
    /// along each of eight directions across the ray, one within `reach` of it at that
    /// range (cell by cell). Why: a ray without a return inside the scan's coverage is a
    /// hole (a dropout, which the surfaces around fill), where the sensor looked; past the
    /// scan's edge (its field of view, a crop to a region of interest, its range) it did
    /// not look, and a model point there says nothing. Copies cut by the bin camera's view
    /// or crop lost up to a third of their visible points to it and were rejected. `reach`
    /// is the object's radius: a hole wider than the object on some side is the scan's edge.
    fn covered(&self, p: &[f64; 3], range: f64, reach: f64) -> bool {
        let (d, _) = offset(p, self.viewpoint);
        let u = Vector3::from(d) / range;
        // Two directions across the ray: from the axis least along it.
        let least = (0..3).min_by(|&a, &b| u[a].abs().total_cmp(&u[b].abs()));
        let a = u.cross(&Vector3::ith(least.unwrap_or(0), 1.0)).normalize();
        let b = u.cross(&a);
        let steps = (reach / (range * self.cell))
            .ceil()
            .clamp(1.0, MAX_COVER_STEPS) as usize;
        (0..8).all(|k| {
            let turn = f64::from(k) * std::f64::consts::FRAC_PI_4;
            let across = a * turn.cos() + b * turn.sin();
            (1..=steps).any(|s| {
                let dir = (u + across * (s as f64 * self.cell)).normalize();
                let key = [0, 1, 2].map(|i| (dir[i] / self.cell).floor() as i32);
                self.nearest.contains_key(&key)
            })
        })
    }
}

/// The most cells [`DepthMap::covered`] walks on each side of a ray: a bound on its cost
/// (eight walks per model point without a return) for a model of many cells across.
const MAX_COVER_STEPS: f64 = 64.0;

/// The offset of `p` from `viewpoint` and its length.
fn offset(p: &[f64; 3], viewpoint: [f64; 3]) -> ([f64; 3], f64) {
    let d = [
        p[0] - viewpoint[0],
        p[1] - viewpoint[1],
        p[2] - viewpoint[2],
    ];
    (d, (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt())
}

/// A posed model's nearest range per ray cell: in a dense box where its rays meet few cells,
/// else in a map.
enum Nearest {
    Cells(NearestBox),
    Map(CellMap),
}

impl Nearest {
    /// The nearest range of a cell that one of the model's rays meets.
    fn get(&self, key: &[i32; 3]) -> f64 {
        match self {
            Self::Cells(cells) => cells.get(key),
            Self::Map(map) => map[key],
        }
    }
}

/// The nearest range per ray cell of a posed model, in a dense box over the cells its rays
/// meet. Why: ICP asks for the model's own view of every point at each stage, and filling and
/// reading a box of a few thousand cells took a fraction of a hash map's time; a model seen
/// from afar meets a thin slab of cells (one or two deep along the ray).
struct NearestBox {
    low: [i32; 3],
    size: [usize; 3],
    nearest: Vec<f64>,
}

impl NearestBox {
    /// Cells a box may hold per ray: beyond, the rays spread over a box too sparse to pay
    /// (a model close to the sensor), and the hash map serves.
    const MAX_CELLS_PER_RAY: usize = 8;

    /// The box of `rays` (`None` where a ray is missing), or `None` when it would be too
    /// sparse.
    fn of(rays: &[Option<Ray>]) -> Option<Self> {
        let mut low = [i32::MAX; 3];
        let mut high = [i32::MIN; 3];
        for (key, _) in rays.iter().flatten() {
            for a in 0..3 {
                low[a] = low[a].min(key[a]);
                high[a] = high[a].max(key[a]);
            }
        }
        if low[0] > high[0] {
            return None;
        }
        let size = [0, 1, 2].map(|a| (i64::from(high[a]) - i64::from(low[a]) + 1) as usize);
        let cells = size[0].checked_mul(size[1])?.checked_mul(size[2])?;
        if cells > Self::MAX_CELLS_PER_RAY * rays.len() + 64 {
            return None;
        }
        let mut out = Self {
            low,
            size,
            nearest: vec![f64::INFINITY; cells],
        };
        for (key, range) in rays.iter().flatten() {
            let at = out.cell(key);
            out.nearest[at] = out.nearest[at].min(*range);
        }
        Some(out)
    }

    fn cell(&self, key: &[i32; 3]) -> usize {
        let at = |a: usize| (key[a] - self.low[a]) as usize;
        (at(0) * self.size[1] + at(1)) * self.size[2] + at(2)
    }

    /// The nearest range of a cell that a ray of the box meets.
    fn get(&self, key: &[i32; 3]) -> f64 {
        self.nearest[self.cell(key)]
    }
}

/// The nearest range per ray cell of `rays`.
fn nearest_of(rays: impl Iterator<Item = Ray>, capacity: usize) -> CellMap {
    let mut out = CellMap::with_capacity_and_hasher(capacity, Default::default());
    for (key, range) in rays {
        out.entry(key)
            .and_modify(|r| *r = r.min(range))
            .or_insert(range);
    }
    out
}

#[cfg(test)]
#[path = "../tests/visibility.rs"]
mod tests;
