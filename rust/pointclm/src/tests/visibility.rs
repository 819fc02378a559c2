use super::*;

/// Points on a unit sphere around `centre` (a closed surface: its far half is self-hidden
/// from any outside sensor), from a fixed pseudo-random sequence.
fn sphere(centre: [f64; 3], n: usize) -> Vec<[f64; 3]> {
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..n)
        .map(|_| {
            let z = 2.0 * next() - 1.0;
            let phi = std::f64::consts::TAU * next();
            let r = (1.0 - z * z).sqrt();
            [
                centre[0] + r * phi.cos(),
                centre[1] + r * phi.sin(),
                centre[2] + z,
            ]
        })
        .collect()
}

/// The self-hidden points by definition: a point of the same ray cell lies more than the
/// tolerance nearer.
fn hidden_by_definition(map: &DepthMap, posed: &[[f64; 3]]) -> Vec<bool> {
    let rays: Vec<Option<Ray>> = posed.iter().map(|p| map.ray(p)).collect();
    let mut nearest = std::collections::BTreeMap::new();
    for (key, range) in rays.iter().flatten() {
        let r = nearest.entry(*key).or_insert(f64::INFINITY);
        *r = range.min(*r);
    }
    rays.iter()
        .map(|ray| ray.is_none_or(|(key, range)| nearest[&key] < range - map.tolerance))
        .collect()
}

fn hidden_share(hidden: &[bool]) -> f64 {
    hidden.iter().filter(|&&h| h).count() as f64 / hidden.len() as f64
}

#[test]
fn the_models_own_view_is_the_same_in_a_box_of_cells_or_a_map() {
    // Far from the sensor a model's rays meet a thin box of cells (the dense box).
    let map = DepthMap::new(&sphere([0.0; 3], 50), [0.0, 0.0, 40.0], 0.2, 0.1);
    let posed = sphere([0.3, -0.2, 0.0], 600);
    let rays: Vec<Option<Ray>> = posed.iter().map(|p| map.ray(p)).collect();
    assert!(NearestBox::of(&rays).is_some());
    let hidden = map.self_hidden(&posed);
    assert_eq!(hidden, hidden_by_definition(&map, &posed));
    assert!((0.3..0.8).contains(&hidden_share(&hidden)));
    // Around the sensor they spread over a box too sparse to fill (the map): small parts
    // in eight directions.
    let map = DepthMap::new(&sphere([0.0, 0.0, 3.0], 50), [0.0; 3], 0.08, 0.05);
    let posed: Vec<[f64; 3]> = (0..8)
        .flat_map(|k| {
            let c = [k & 1, k >> 1 & 1, k >> 2 & 1].map(|b| (2.0 * b as f64 - 1.0) * 3f64.sqrt());
            sphere([0.0; 3], 400)
                .into_iter()
                .map(move |p| [0, 1, 2].map(|a| c[a] + 0.2 * p[a]))
        })
        .collect();
    let rays: Vec<Option<Ray>> = posed.iter().map(|p| map.ray(p)).collect();
    assert!(NearestBox::of(&rays).is_none());
    let hidden = map.self_hidden(&posed);
    assert_eq!(hidden, hidden_by_definition(&map, &posed));
    assert!((0.3..0.8).contains(&hidden_share(&hidden)));
}

#[test]
fn a_point_at_the_sensor_has_no_ray_and_is_hidden() {
    let map = DepthMap::new(&sphere([0.0; 3], 20), [0.0, 0.0, 10.0], 0.05, 0.1);
    let mut posed = sphere([0.0; 3], 30);
    posed.push([0.0, 0.0, 10.0]);
    let hidden = map.self_hidden(&posed);
    assert!(hidden[30]);
    assert_eq!(hidden, hidden_by_definition(&map, &posed));
}

/// A plane `z = z0` sampled every `step` over the x and y ranges, less the points `drop`
/// takes.
fn plane(x: (f64, f64), y: (f64, f64), z0: f64, drop: impl Fn(f64, f64) -> bool) -> Vec<[f64; 3]> {
    let step = 0.05;
    let (nx, ny) = (((x.1 - x.0) / step) as i32, ((y.1 - y.0) / step) as i32);
    (0..=nx)
        .flat_map(|i| (0..=ny).map(move |j| (x.0 + f64::from(i) * step, y.0 + f64::from(j) * step)))
        .filter(|&(x, y)| !drop(x, y))
        .map(|(x, y)| [x, y, z0])
        .collect()
}

#[test]
fn a_ray_without_a_return_is_seen_inside_the_scan_and_unobserved_past_its_edge() {
    // A floor cut at x = 0 (the scan's edge: a crop, the field of view) with a hole of
    // radius 0.15 at (-1, 0) (a dropout).
    let hole = |x: f64, y: f64| (x + 1.0).hypot(y) < 0.15;
    let scan = plane((-2.0, 0.0), (-2.0, 2.0), 0.0, hole);
    let map = DepthMap::new(&scan, [0.0, 0.0, 20.0], 0.1, 0.3);
    let posed = [[-1.0, 0.0, 0.0], [0.5, 0.0, 0.0], [-0.5, 0.0, 0.0]];
    let sights = map.judge(&posed, 1.0);
    assert_eq!(sights, vec![Sight::Seen, Sight::Unobserved, Sight::Seen]);
}
