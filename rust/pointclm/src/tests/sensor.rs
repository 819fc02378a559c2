use super::*;

/// One view of balls resting on a floor, ray-cast from `sensor` through a grid of points on
/// the floor's plane (as a range camera's pixels): each ray's first hit.
fn one_view(sensor: [f64; 3]) -> Vec<[f64; 3]> {
    let balls = [
        ([0.6, 0.5, 0.3], 0.3),
        ([-0.6, 0.4, 0.3], 0.3),
        ([0.5, -0.6, 0.25], 0.25),
        ([-0.5, -0.5, 0.35], 0.35),
        ([0.0, 0.0, 0.5], 0.45),
    ];
    let mut points = Vec::new();
    for i in 0..100 {
        for j in 0..100 {
            let aim = [-2.0 + 0.04 * i as f64, -2.0 + 0.04 * j as f64, 0.0];
            let (aim, eye) = (V::from(aim), V::from(sensor));
            let d = unit(aim - eye).unwrap();
            // The floor (z = 0) is hit at the aim point.
            let mut t_hit = (aim - eye).norm();
            for (c, r) in balls {
                let oc = eye - V::from(c);
                let b = oc.dot(&d);
                let disc = b * b - (oc.norm().powi(2) - r * r);
                if disc > 0.0 {
                    let t = -b - disc.sqrt();
                    if t > 0.0 && t < t_hit {
                        t_hit = t;
                    }
                }
            }
            points.push((eye + d * t_hit).into());
        }
    }
    points
}

fn angle_deg(a: V, b: V) -> f64 {
    let (a, b) = (unit(a).unwrap(), unit(b).unwrap());
    a.dot(&b).clamp(-1.0, 1.0).acos().to_degrees()
}

#[test]
fn the_sensor_of_one_view_hides_the_fewest_points() {
    for sensor in [[0.8, -1.2, 2.5], [-1.5, 0.4, 2.0], [0.2, 0.3, 3.5]] {
        let scan = one_view(sensor);
        let centre = centroid(&scan);
        // Only the side is given: straight above the scene.
        let towards = centre + V::z();
        let est = estimate_sensor(&scan, 0.04, towards.into()).unwrap();
        let (truth, found) = (V::from(sensor) - centre, V::from(est.position) - centre);
        let angle = angle_deg(truth, found);
        let ratio = found.norm() / truth.norm();
        assert!(angle < 5.0, "{sensor:?}: {angle} degrees off ({est:?})");
        // Farther eyes hide about as little (cells straddling an edge count less there): the
        // estimate may lie beyond the sensor, never much nearer.
        assert!(
            (0.9..3.0).contains(&ratio),
            "{sensor:?}: distance ratio {ratio}"
        );
        assert!(est.hidden_share < 0.02, "{est:?}");
        // The same scan seen from a point 20 degrees aside hides more of itself.
        let aside = centre + unit(truth + V::x()).unwrap() * truth.norm();
        let aside = DepthMap::new(&scan, aside.into(), 0.04, SENSOR_TOLERANCE_VOXELS * 0.04)
            .hidden_share(&scan);
        assert!(aside > est.hidden_share, "{aside} vs {est:?}");
    }
}

#[test]
fn the_estimate_is_deterministic_and_checks_its_input() {
    let scan = one_view([0.8, -1.2, 2.5]);
    let a = estimate_sensor(&scan, 0.04, [0.0, 0.0, 5.0]).unwrap();
    let b = estimate_sensor(&scan, 0.04, [0.0, 0.0, 5.0]).unwrap();
    assert_eq!(a, b);
    // A start at the centroid has no direction: straight up is taken.
    let stride = scan.len().div_ceil(SENSOR_SAMPLE).max(1);
    let sample: Vec<[f64; 3]> = scan.iter().step_by(stride).copied().collect();
    let centre = centroid(&sample);
    assert!(estimate_sensor(&scan, 0.04, centre.into()).is_ok());
    assert!(estimate_sensor(&scan[..2], 0.04, [0.0; 3]).is_err());
    assert!(estimate_sensor(&scan, 0.0, [0.0; 3]).is_err());
    assert!(estimate_sensor(&scan, 0.04, [f64::NAN, 0.0, 0.0]).is_err());
    let mut bad = scan.clone();
    bad[7][1] = f64::INFINITY;
    assert!(estimate_sensor(&bad, 0.04, [0.0; 3]).is_err());
}

#[test]
fn the_fused_hidden_share_is_the_depth_maps() {
    let mut scan = one_view([0.8, -1.2, 2.5]);
    scan.push([0.8, -1.2, 2.5]); // a point at the sensor has no ray
    scan.push([40.0, 3.0, -7.0]);
    for eye in [
        [0.8, -1.2, 2.5],
        [-2.0, 1.0, 1.0],
        [0.0, 0.0, 9.0],
        [0.3, 0.2, 0.1],
    ] {
        for (cell, tol) in [(0.04, 0.08), (0.02, 0.2), (0.1, 0.01)] {
            let map = DepthMap::new(&scan, eye, cell, tol).hidden_share(&scan);
            let fused = DepthMap::own_hidden_share(&scan, eye, cell, tol);
            assert_eq!(map.to_bits(), fused.to_bits(), "{eye:?} {cell} {tol}");
        }
    }
    assert_eq!(DepthMap::own_hidden_share(&[], [0.0; 3], 0.1, 0.1), 0.0);
}

#[test]
fn only_a_scan_reaching_past_one_model_spans_a_scene() {
    use crate::scene::sensor::spans_a_scene;
    use crate::scene::SceneRules;
    // One flattened object seen alone, then the same in front of a wide floor.
    let extent = SceneRules::default().scene_extent;
    let model: Vec<[f64; 3]> = (0..500)
        .map(|i| {
            let (th, z) = (i as f64 * 2.399_963, 1.0 - 2.0 * (i as f64 + 0.5) / 500.0);
            let r = (1.0 - z * z).sqrt();
            [r * th.cos(), r * th.sin(), z]
        })
        .collect();
    let alone: Vec<[f64; 3]> = model.iter().map(|p| [p[0], p[1], 0.2 * p[2]]).collect();
    assert!(!spans_a_scene(&alone, &model, extent));
    let mut scene = alone.clone();
    let side = 6.0 * extent;
    for i in 0..40 {
        for j in 0..40 {
            scene.push([
                side * (i as f64 / 39.0 - 0.5),
                side * (j as f64 / 39.0 - 0.5),
                -1.0,
            ]);
        }
    }
    assert!(spans_a_scene(&scene, &model, extent));
}
