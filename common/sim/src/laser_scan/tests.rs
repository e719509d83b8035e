use super::*;
use rand::{Rng, SeedableRng};

const META: BeamLayout = BeamLayout { beams: 540, fov: 1.5 * PI };

fn scan(angle_min: f64, angle_increment: f64, ranges: &[f32]) -> LaserScan<'_> {
    LaserScan { angle_min, angle_increment, range_min: 0.05, range_max: 8.0, ranges }
}

fn run(s: &LaserScan, setup: &SensorSetup, layout: BeamLayout) -> (Vec<f32>, usize) {
    let mut out = vec![f32::NAN; layout.beams];
    let filled = resample(s, setup, layout, &mut out).unwrap();
    (out, filled)
}

/// The same resampling computed the plain way: for every pair of meta beam and sensor reading,
/// do their intervals overlap? Two arcs of widths a and b overlap when their centres are less
/// than (a + b)/2 apart around the circle.
fn reference(s: &LaserScan, uncovered: f32, layout: BeamLayout) -> (Vec<f32>, usize) {
    let w = layout.fov / layout.beams as f64;
    let inc = s.angle_increment.abs();
    let mut out = Vec::with_capacity(layout.beams);
    let mut filled = 0;
    for i in 0..layout.beams {
        let centre = -layout.fov / 2.0 + (i as f64 + 0.5) * w;
        let mut best: Option<f64> = None;
        for (j, &r) in s.ranges.iter().enumerate() {
            let value = match r {
                r if r.is_nan() => continue,
                f32::INFINITY => s.range_max,
                0.0 => s.range_max,
                f32::NEG_INFINITY => s.range_min,
                r if f64::from(r) < s.range_min || f64::from(r) > s.range_max => continue,
                r => f64::from(r),
            };
            let theta = s.angle_min + j as f64 * s.angle_increment;
            let apart = (theta - centre).sin().atan2((theta - centre).cos()).abs();
            if apart < (w + inc) / 2.0 {
                best = Some(best.map_or(value, |b| b.min(value)));
            }
        }
        out.push(match best {
            Some(b) => b as f32,
            None => {
                filled += 1;
                uncovered
            }
        });
    }
    (out, filled)
}

#[test]
fn random_scans_match_the_plain_computation() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(117);
    let layouts = [META, BeamLayout::new(36, 360.0), BeamLayout::new(7, 90.0)];
    // (readings, field of view in degrees): a Hokuyo UTM-30LX, an RPLidar's varying counts, a
    // coarse 180° sensor, a depth camera's 87°, one reading.
    let sensors: [(usize, f64); 6] =
        [(1081, 270.0), (1947, 360.0), (360, 359.0), (181, 180.0), (58, 87.0), (1, 1.0)];
    for layout in layouts {
        for &(n, fov) in &sensors {
            for trial in 0..6 {
                let inc = fov.to_radians() / (n.max(2) - 1) as f64
                    * if trial % 2 == 0 { 1.0 } else { -1.0 };
                let centre: f64 = rng.random_range(-PI..PI);
                let angle_min = centre - inc * (n - 1) as f64 / 2.0;
                let ranges: Vec<f32> = (0..n)
                    .map(|_| match rng.random_range(0..10) {
                        0 => f32::INFINITY,
                        1 => f32::NEG_INFINITY,
                        2 => f32::NAN,
                        3 => rng.random_range(8.001..20.0),
                        4 => rng.random_range(0.0..0.049),
                        _ => rng.random_range(0.05..8.0),
                    })
                    .collect();
                let s = scan(angle_min, inc, &ranges);
                let setup =
                    SensorSetup { uncovered: Uncovered::Range(0.25), ..SensorSetup::default() };
                let got = run(&s, &setup, layout);
                let want = reference(&s, 0.25, layout);
                assert_eq!(got.1, want.1, "filled, {n} readings over {fov}°, trial {trial}");
                assert_eq!(got.0, want.0, "{n} readings over {fov}°, trial {trial}");
            }
        }
    }
}

#[test]
fn readings_follow_rep_117() {
    // Four readings 90° apart, each an interval of 90°: together the whole circle.
    let layout = BeamLayout::new(4, 360.0);
    let inc = PI / 2.0;
    // Sensor readings centred on −135°, −45°, 45°, 135° cover meta beams 0..4 one to one.
    let ranges = [f32::INFINITY, f32::NEG_INFINITY, f32::NAN, 3.5];
    let blocked = SensorSetup { uncovered: Uncovered::Range(0.0), ..SensorSetup::default() };
    let (out, filled) = run(&scan(-0.75 * PI, inc, &ranges), &blocked, layout);
    assert_eq!(out, [8.0, 0.05, 0.0, 3.5], "+inf = range_max, -inf = range_min, NaN unseen");
    assert_eq!(filled, 1);
    // By default the unseen beam takes the nearer of its neighbours' ranges.
    let (out, _) = run(&scan(-0.75 * PI, inc, &ranges), &SensorSetup::default(), layout);
    assert_eq!(out, [8.0, 0.05, 0.05, 3.5]);
    // 0.0 is a driver's "no return", like +inf; other finite readings outside [range_min,
    // range_max] are invalid.
    let ranges = [9.0, 0.01, 0.0, -1.0];
    let uncovered = SensorSetup { uncovered: Uncovered::Range(2.0), ..SensorSetup::default() };
    let (out, filled) = run(&scan(-0.75 * PI, inc, &ranges), &uncovered, layout);
    assert_eq!((out, filled), (vec![2.0, 2.0, 8.0, 2.0], 3));
    let (out, _) = run(&scan(-0.75 * PI, inc, &ranges), &SensorSetup::default(), layout);
    assert_eq!(out, [8.0; 4], "the one return fills the rest of the circle");
}

#[test]
fn each_meta_beam_keeps_the_nearest_reading_it_spans() {
    // A Hokuyo UTM-30LX: 1,081 readings 0.25° apart over 270°, all at 5 m but one thin pole at
    // 1.2 m straight ahead (reading 540): the meta beams whose intervals it touches read 1.2 m.
    let mut ranges = vec![5.0f32; 1081];
    ranges[540] = 1.2;
    let inc = 0.25f64.to_radians();
    let (out, filled) =
        run(&scan(-135f64.to_radians(), inc, &ranges), &SensorSetup::default(), META);
    assert_eq!(filled, 0, "the sensor covers the meta agent's 270°");
    let near: Vec<usize> = (0..540).filter(|&i| out[i] == 1.2).collect();
    // Reading 540 spans ±0.125° about 0°: it reaches into meta beams 269 ([−0.5°, 0°)) and 270.
    assert_eq!(near, [269, 270]);
    assert!(out.iter().enumerate().all(|(i, &r)| near.contains(&i) || r == 5.0));

    // The same scan turning clockwise (reversed readings, negative increment) reads the same.
    ranges.reverse();
    let (rev, _) = run(&scan(135f64.to_radians(), -inc, &ranges), &SensorSetup::default(), META);
    assert_eq!(rev, out);
}

#[test]
fn the_meta_layout_sent_as_a_scan_is_read_one_to_one() {
    let ranges: Vec<f32> = (0..540).map(|i| 0.5 + (i % 17) as f32 * 0.4).collect();
    let inc = 0.5f64.to_radians();
    let s = scan(-135f64.to_radians() + inc / 2.0, inc, &ranges);
    let (out, filled) = run(&LaserScan { range_max: 10.0, ..s }, &SensorSetup::default(), META);
    assert_eq!((out, filled), (ranges, 0));
}

#[test]
fn beams_outside_the_sensor_get_the_uncovered_value() {
    // A 180° sensor ahead: the meta agent's outer 45° each side are not seen.
    let ranges = vec![4.0f32; 721];
    let inc = 0.25f64.to_radians();
    let s = scan(-PI / 2.0, inc, &ranges);
    let (out, filled) = run(&s, &SensorSetup::default(), META);
    // 45° of 0.5° beams each side, less the one each side the edge reading's half-interval
    // reaches into.
    assert_eq!(filled, 2 * 89, "{filled}");
    assert_eq!(out[0], 4.0, "the nearest seen range by default");
    assert_eq!(out[270], 4.0);
    let range = |u: f64| SensorSetup { uncovered: Uncovered::Range(u), ..SensorSetup::default() };
    assert_eq!(run(&s, &range(0.0), META).0[0], 0.0);
    assert_eq!(run(&s, &range(10.0), META).0[0], 10.0);
    // Turned to look behind, it sees none of the meta agent's front.
    let back = SensorSetup { yaw: PI, ..range(0.0) };
    let (out, _) = run(&s, &back, META);
    assert_eq!(out[270], 0.0);
    assert_eq!(out[0], 4.0, "−135° is seen looking backwards");
}

#[test]
fn a_sensor_ahead_of_the_axle_reads_ranges_from_the_axle() {
    // A wall across the robot's path at x = 2 m; the sensor sits 0.3 m ahead of the axle and
    // reads it at 1.7 m / cos θ. From the axle, beam angle a reads 2 m / cos a.
    let inc = 0.1f64.to_radians();
    let n = 1201; // ±60°
    let ranges: Vec<f32> = (0..n)
        .map(|j| {
            let theta = -PI / 3.0 + j as f64 * inc;
            (1.7 / theta.cos()) as f32
        })
        .collect();
    let s = LaserScan { range_max: 30.0, ..scan(-PI / 3.0, inc, &ranges) };
    let setup = SensorSetup { x: 0.3, ..SensorSetup::default() };
    let (out, filled) = run(&s, &setup, META);
    let (start, w) = META.grid();
    for (i, &r) in out.iter().enumerate() {
        let a = start + (i as f64 + 0.5) * w;
        if a.abs() < 50f64.to_radians() {
            let truth = 2.0 / a.cos();
            // Conservative: never beyond the wall, and within a beam's width of it.
            assert!(f64::from(r) <= truth + 1e-4, "beam {i}: {r} > {truth}");
            assert!(truth - f64::from(r) < truth * w * a.tan().abs() + 0.01, "beam {i}: {r}");
        }
    }
    // The far sides are unseen; each takes the range at the edge of what is seen on its side.
    assert!(filled > 0);
    let first_seen = (0..540).find(|&i| out[i] != out[0]).unwrap();
    assert!(first_seen > 100 && out[0] > 1.9 && out[539] > 1.9, "{first_seen} {}", out[0]);
    // The same sensor on the axle, turned 30° left: everything shifts by 60 meta beams.
    let turned = SensorSetup { yaw: PI / 6.0, ..SensorSetup::default() };
    let (t, _) = run(&s, &turned, META);
    let (c, _) = run(&s, &SensorSetup::default(), META);
    assert_eq!(t[300..400], c[240..340]);
}

#[test]
fn malformed_scans_name_the_field() {
    let ranges = [1.0f32; 10];
    let ok = scan(-1.0, 0.1, &ranges);
    ok.validate().unwrap();
    let field = |s: LaserScan| s.validate().unwrap_err().field;
    assert_eq!(field(LaserScan { ranges: &[], ..ok }), "ranges");
    assert_eq!(field(LaserScan { angle_min: f64::NAN, ..ok }), "angle_min");
    assert_eq!(field(LaserScan { angle_increment: 0.0, ..ok }), "angle_increment");
    assert_eq!(field(LaserScan { angle_increment: 2.0, ..ok }), "angle_increment");
    assert_eq!(field(LaserScan { range_min: -0.1, ..ok }), "range_min");
    assert_eq!(field(LaserScan { range_max: 0.01, range_min: 0.02, ..ok }), "range_max");
    assert_eq!(field(LaserScan { range_max: 1e39, ..ok }), "range_max");
    let many = vec![1.0f32; 800];
    let e = LaserScan { angle_increment: 0.01, ..scan(0.0, 0.01, &many) }.validate().unwrap_err();
    assert!(e.field == "angle_increment" && e.reason.contains("more than a turn"), "{e}");
    let bad = |s: SensorSetup| s.validate().unwrap_err().field;
    assert_eq!(bad(SensorSetup { x: f64::INFINITY, ..SensorSetup::default() }), "x");
    assert_eq!(bad(SensorSetup { yaw: 100.0, ..SensorSetup::default() }), "yaw");
    assert_eq!(
        bad(SensorSetup { uncovered: Uncovered::Range(-1.0), ..SensorSetup::default() }),
        "uncovered_range"
    );
}

#[test]
fn unseen_runs_take_the_nearer_range_at_their_ends() {
    let inf = f64::INFINITY;
    let fill = |v: &[f64], wraps: bool| {
        let mut v = v.to_vec();
        fill_from_neighbours(&mut v, wraps);
        v
    };
    // Runs at both edges, one between two ranges.
    let v = [inf, inf, 3.0, inf, inf, 1.0, 2.0, inf];
    assert_eq!(fill(&v, false), [3.0, 3.0, 3.0, 1.0, 1.0, 1.0, 2.0, 2.0]);
    // Around the circle the edge runs join: the last beam neighbours the first.
    assert_eq!(fill(&v, true), [2.0, 2.0, 3.0, 1.0, 1.0, 1.0, 2.0, 2.0]);
    assert_eq!(fill(&[inf, 5.0, inf], true), [5.0, 5.0, 5.0]);
    assert_eq!(fill(&[inf; 3], false), [0.0; 3], "nothing seen: blocked");
    assert_eq!(fill(&[1.0, 2.0], true), [1.0, 2.0]);
}
