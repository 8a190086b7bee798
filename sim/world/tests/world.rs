//! The world end to end: smoke physics as the sensors see it, device rates,
//! determinism, the bundled scenarios and the ground-truth files.

use smokenav_sim_world::laser::{URG_AFRT, URG_AMIN, URG_DMIN_MM, step_angle};
use smokenav_sim_world::{Scenario, StepOutput, World};
use std::path::Path;
use std::time::Duration;

/// A Pioneer parked in the corridor facing its end wall: laser at x = 13.16 m,
/// wall at 16 m (2.84 m ahead), as in the Fig. 4 trial of SmokeNav (Santos et al. 2015).
fn facing_wall(extra: &str) -> Scenario {
    let text = format!(
        "name = \"facing-wall\"\nseed = 11\nduration_s = 30\nrobot = \"pioneer-3dx\"\n\
         [arena]\nbuiltin = \"corridor\"\n[start]\nx = 13.0\ny = 1.0\nheading_deg = 0.0\n{extra}"
    );
    Scenario::parse(&text, Path::new("facing-wall.toml")).unwrap()
}

fn run(world: &mut World, secs: f64) -> StepOutput {
    world.step(Duration::from_secs_f64(secs))
}

fn mean_sd(v: &[f64]) -> (f64, f64) {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (
        m,
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt(),
    )
}

/// Valid ranges (m) of the beams within ±30° of straight ahead, over all scans.
fn front_sector(out: &StepOutput) -> Vec<f64> {
    let mut v = Vec::new();
    for scan in &out.laser {
        for (i, &mm) in scan.ranges_mm.iter().enumerate() {
            let a = step_angle(URG_AMIN + i as u32);
            if a.abs() <= 30f64.to_radians() && mm >= URG_DMIN_MM {
                v.push(mm as f64 / 1000.0);
            }
        }
    }
    v
}

/// Sonar ranges of the transducers facing the wall (Pioneer sonars 3 and 4, ±10°).
fn front_sonar(out: &StepOutput) -> Vec<f64> {
    out.sonar
        .iter()
        .filter(|s| s.index == 3 || s.index == 4)
        .map(|s| s.range_m)
        .collect()
}

#[test]
fn smoke_between_robot_and_wall_shortens_laser_and_drops_its_spread_but_not_the_sonars() {
    let mut clean = World::new(facing_wall("")).unwrap();
    // 0.6 g/m³ (extinction ≈ 5 /m) across the corridor between robot and wall.
    let mut smoky = World::new(facing_wall(
        "[smoke]\ndiffusion_m2ps = 0.01\n[[smoke.patch]]\ncenter = [14.5, 1.0]\nradius_m = 0.9\ndensity_gpm3 = 0.6\n",
    ))
    .unwrap();
    let (c, s) = (run(&mut clean, 3.0), run(&mut smoky, 3.0));

    let (lc, ls) = (front_sector(&c), front_sector(&s));
    let ((lc_mean, lc_sd), (ls_mean, ls_sd)) = (mean_sd(&lc), mean_sd(&ls));
    // Clean: the end wall at 2.84 m and the side walls beyond ±19°.
    assert!(lc_mean > 2.3, "clean front sector mean {lc_mean}");
    // Smoke front at 13.6 m, 0.44 m from the laser: readings just inside it.
    assert!(ls_mean < 0.8, "smoky front sector mean {ls_mean}");
    assert!(
        ls_sd < 0.5 * lc_sd,
        "spread drops: clean {lc_sd}, smoke {ls_sd}"
    );
    // The beam straight ahead, scan after scan: it reads the smoke front
    // (0.44 m), not the wall (2.84 m), within a few centimetres.
    let ahead = (URG_AFRT - URG_AMIN) as usize;
    let per_scan: Vec<f64> = s
        .laser
        .iter()
        .map(|f| f.ranges_mm[ahead] as f64 / 1000.0)
        .collect();
    let (a_mean, a_sd) = mean_sd(&per_scan);
    assert!(a_mean < 0.7 && a_sd < 0.1, "ahead beam {a_mean} ± {a_sd}");

    // The sonars do not care: same seed, same pings, same numbers.
    let (sc, ss) = (front_sonar(&c), front_sonar(&s));
    assert!(!sc.is_empty());
    assert_eq!(
        sc, ss,
        "sonar readings are identical with and without smoke"
    );
    let (sc_mean, sc_sd) = mean_sd(&sc);
    assert!(
        (sc_mean - 2.85).abs() < 0.1 && sc_sd < 0.05,
        "sonar sees the wall: {sc_mean} ± {sc_sd}"
    );
}

#[test]
fn smoke_reading_rises_fast_and_recovers_slowly_when_driving_through_a_cloud() {
    let text = "name = \"through-cloud\"\nseed = 5\nduration_s = 90\nrobot = \"pioneer-3dx\"\n\
                [arena]\nbuiltin = \"corridor\"\n[start]\nx = 1.0\ny = 1.0\n\
                [route]\nspeed_mps = 0.3\nwaypoints = [[15.0, 1.0]]\n\
                [smoke]\ndiffusion_m2ps = 0.002\ndecay_per_s = 0.0\n\
                [[smoke.patch]]\ncenter = [5.0, 1.0]\nradius_m = 1.0\ndensity_gpm3 = 0.3\n\
                [smoke_sensor]\nnoise_mv = 0.0\n";
    let mut world = World::new(Scenario::parse(text, Path::new("cloud.toml")).unwrap()).unwrap();
    let out = run(&mut world, 90.0);
    let samples = &out.smoke;
    let t = |i: usize| samples[i].t_ns as f64 * 1e-9;
    let clean_mv = samples[0].output_mv;
    let enter = samples
        .iter()
        .position(|s| s.true_density_gpm3 > 0.15)
        .unwrap();
    let exit = enter
        + samples[enter..]
            .iter()
            .position(|s| s.true_density_gpm3 < 0.15)
            .unwrap();
    let (lowest, i_low) = samples
        .iter()
        .enumerate()
        .map(|(i, s)| (s.output_mv, i))
        .fold((f64::INFINITY, 0), |a, b| if b.0 < a.0 { b } else { a });
    let swing = clean_mv - lowest;
    assert!(
        swing > 240.0,
        "dense cloud passes SMOKE_MAX_DOWN (240 mV): {swing} mV"
    );
    // Rise: from entering the cloud to 63 % of the swing.
    let rise_i = (enter..)
        .find(|&i| clean_mv - samples[i].output_mv >= 0.63 * swing)
        .unwrap();
    // Recovery: from the lowest point to 63 % of the way back.
    let rec_i = (i_low..samples.len()).find(|&i| clean_mv - samples[i].output_mv <= 0.37 * swing);
    let rise = t(rise_i) - t(enter);
    let recovery = t(rec_i.expect("recovers within the run")) - t(i_low);
    assert!(rise < 4.0, "rise {rise} s");
    assert!(
        recovery > 5.0 * rise,
        "recovery {recovery} s vs rise {rise} s"
    );
    // The output bottoms out as the robot leaves the cloud (within 1.5 s at 10 Hz).
    assert!(
        i_low.abs_diff(exit) <= 15,
        "lowest at {} s, exit at {} s",
        t(i_low),
        t(exit)
    );
    // ADC counts track the voltage: 10-bit, 5 V reference.
    let s = samples[i_low];
    assert_eq!(s.adc_counts, (s.output_mv / 5000.0 * 1023.0).round() as u32);
}

#[test]
fn sensors_fire_at_the_devices_rates() {
    let mut world = World::new(facing_wall("")).unwrap();
    let out = run(&mut world, 10.0);
    assert_eq!(out.laser.len(), 100, "URG-04LX: 600 rpm, 100 ms per scan");
    assert_eq!(out.odometry.len(), 100, "base.rate_hz = 10");
    assert_eq!(out.smoke.len(), 100, "smoke.rate_hz = 10");
    assert_eq!(out.truth.len(), 100);
    assert_eq!(out.sonar.len(), 250, "ARCOS: one disc every 40 ms");
    let order: Vec<u8> = out.sonar.iter().take(9).map(|s| s.index).collect();
    assert_eq!(order, [0, 1, 2, 3, 4, 5, 6, 7, 0]);
    assert!(
        out.laser
            .windows(2)
            .all(|w| w[1].t_ns - w[0].t_ns == 100_000_000 && w[1].seq == w[0].seq + 1)
    );

    let text = "name = \"s\"\nseed = 1\nduration_s = 10\nrobot = \"nomad-scout\"\n\
                [arena]\nbuiltin = \"corridor\"\n[start]\nx = 8.0\ny = 1.0\n";
    let mut world = World::new(Scenario::parse(text, Path::new("s.toml")).unwrap()).unwrap();
    let out = run(&mut world, 9.6);
    assert_eq!(
        out.sonar.len(),
        160,
        "conf_sn rate 15 × 4 ms = 60 ms per ping"
    );
    let order: Vec<u8> = out.sonar.iter().take(4).map(|s| s.index).collect();
    assert_eq!(order, [0, 2, 15, 1], "the profile's firing order");
}

#[test]
fn same_scenario_and_seed_give_identical_sensor_data_however_time_is_sliced() {
    let scenario = Scenario::builtin("r32-dense-crossing").unwrap();
    let mut a = World::new(scenario.clone()).unwrap();
    let mut b = World::new(scenario.clone()).unwrap();
    // One 12 s step against 12 s in uneven slices (including sub-tick ones).
    let whole = run(&mut a, 12.0);
    let mut sliced = StepOutput::default();
    let mut t = 0u64;
    let mut k = 0u64;
    while t < 12_000_000_000 {
        let dt = [333_333u64, 7_000_000, 49_999_999, 1_500_000, 100_000_001][(k % 5) as usize]
            .min(12_000_000_000 - t);
        let mut part = b.step(Duration::from_nanos(dt));
        sliced.append(&mut part);
        t += dt;
        k += 1;
    }
    assert_eq!(a.time_ns(), b.time_ns());
    assert!(!whole.laser.is_empty() && !whole.sonar.is_empty());
    assert_eq!(whole, sliced, "identical sensor data");
    assert_eq!(a.truth_pose(), b.truth_pose());

    let mut other_seed = scenario;
    other_seed.seed += 1;
    let mut c = World::new(other_seed).unwrap();
    let other = run(&mut c, 12.0);
    assert_ne!(
        whole.laser, other.laser,
        "a different seed gives different noise"
    );
}

#[test]
fn dense_crossing_blinds_the_laser_while_sonars_keep_seeing_walls() {
    let mut world = World::new(Scenario::builtin("r32-dense-crossing").unwrap()).unwrap();
    let mut before = Vec::new();
    let mut inside = Vec::new();
    let mut sonar_inside = (0, 0);
    let mut min_mv = f64::INFINITY;
    let mut clean_mv = None;
    while world.time_ns() < 90_000_000_000 {
        let out = run(&mut world, 1.0);
        let dens = out.truth.last().unwrap().smoke_gpm3;
        for scan in &out.laser {
            let v: Vec<f64> = scan
                .ranges_mm
                .iter()
                .filter(|&&r| r >= URG_DMIN_MM)
                .map(|&r| r as f64 / 1000.0)
                .collect();
            let sd = mean_sd(&v).1;
            if dens == 0.0 {
                before.push(sd);
            } else if dens > 0.3 {
                inside.push(sd);
            }
        }
        if dens > 0.3 {
            sonar_inside.0 += out.sonar.iter().filter(|s| !s.saturated).count();
            sonar_inside.1 += out.sonar.len();
        }
        min_mv = out.smoke.iter().fold(min_mv, |m, s| m.min(s.output_mv));
        clean_mv = clean_mv.or(out.smoke.first().map(|s| s.output_mv));
    }
    let (b, i) = (mean_sd(&before).0, mean_sd(&inside).0);
    assert!(!inside.is_empty(), "the route crosses dense smoke");
    // SmokeNav's fuzzy rule trusts the laser while σ(lR) is above 0.8.
    assert!(b > 0.8 && i < 0.3, "scan sd before {b}, in smoke {i}");
    assert!(
        sonar_inside.0 * 2 > sonar_inside.1,
        "most sonar pings still echo: {sonar_inside:?}"
    );
    let drop = clean_mv.unwrap() - min_mv;
    assert!(
        drop > 240.0,
        "smoke sensor passes SMOKE_MAX_DOWN: {drop} mV"
    );
}

#[test]
fn bundled_routes_complete_without_touching_walls() {
    for name in ["mrl-clean", "corridor", "r32-light-puff"] {
        let mut world = World::new(Scenario::builtin(name).unwrap()).unwrap();
        world.set_laser_enabled(false); // motion only: spare the ray casting
        let mut stalls = 0;
        while !world.is_finished() && !world.route_done() {
            let out = run(&mut world, 1.0);
            stalls += out.odometry.iter().filter(|o| o.stalled).count();
        }
        assert!(
            world.route_done(),
            "{name}: route unfinished at {:?}",
            world.truth_pose()
        );
        assert_eq!(stalls, 0, "{name}: the robot touched a wall");
    }
}

#[test]
fn truth_map_and_trajectory_files_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let mut world = World::new(Scenario::builtin("mrl-clean").unwrap()).unwrap();
    let out = run(&mut world, 5.0);
    let map = world.truth_map();
    let yaml = smokenav_sim_world::truth::write_map(&map, dir.path(), "truth").unwrap();
    assert_eq!(smokenav_platform_map::load_map_server(&yaml).unwrap(), map);
    // MRL arena walls: 4.57 × 4.04 m at 5 cm cells.
    let occupied = map.occupied_points(65);
    let (xs, ys): (Vec<f64>, Vec<f64>) = occupied.iter().copied().unzip();
    let span_x = xs.iter().fold(f64::NEG_INFINITY, |a, &b| a.max(b))
        - xs.iter().fold(f64::INFINITY, |a, &b| a.min(b));
    let span_y = ys.iter().fold(f64::NEG_INFINITY, |a, &b| a.max(b))
        - ys.iter().fold(f64::INFINITY, |a, &b| a.min(b));
    assert!(
        (span_x - 4.57).abs() < 0.06 && (span_y - 4.04).abs() < 0.06,
        "{span_x} × {span_y}"
    );

    let path = dir.path().join("truth.txt");
    smokenav_sim_world::truth::write_trajectory(&path, out.truth.iter().map(|s| (s.t_ns, &s.pose)))
        .unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    let lines: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
    assert_eq!(lines.len(), 50);
    let f: Vec<f64> = lines[49]
        .split_whitespace()
        .map(|x| x.parse().unwrap())
        .collect();
    assert_eq!(f.len(), 4);
    assert!((f[0] - 5.0).abs() < 1e-9);
    assert!(
        (f[1] - out.truth[49].pose.x).abs() < 1e-6 && (f[2] - out.truth[49].pose.y).abs() < 1e-6
    );
}

#[test]
fn external_commands_take_over_from_the_route() {
    let mut world = World::new(Scenario::builtin("corridor").unwrap()).unwrap();
    run(&mut world, 2.0);
    let x0 = world.truth_pose().x;
    assert!(x0 > 1.1, "the route drives it forward: {x0}");
    // A driver's cmd_vel: turn left on the spot at 0.5 rad/s.
    world.set_velocity_command(0.0, 0.5);
    let out = run(&mut world, 2.0);
    let p = world.truth_pose();
    assert!(p.theta > 0.6, "turned left: {p:?}");
    assert!(out.odometry.last().unwrap().angular_rps > 0.4);
    // Wheel speeds (Scout vm / Pioneer VEL2): equal and opposite spin it back right.
    world.set_wheel_command(0.08, -0.08);
    run(&mut world, 2.0);
    assert!(
        world.truth_pose().theta < p.theta - 0.5,
        "{:?}",
        world.truth_pose()
    );
    // Stop: it stays put, the route does not resume.
    world.set_velocity_command(0.0, 0.0);
    run(&mut world, 2.0);
    let still = world.truth_pose();
    run(&mut world, 2.0);
    assert_eq!(world.truth_pose(), still);
}

#[test]
fn the_truth_map_leaves_out_the_cables_the_base_drives_over_and_keeps_the_low_box() {
    let world = World::new(Scenario::builtin("cables").unwrap()).unwrap();
    let map = world.truth_map();
    let at = |x: f64, y: f64| {
        let (cx, cy) = map.world_to_cell(x, y).unwrap();
        map.get(cx, cy).unwrap()
    };
    // The 3 cm cable at x = 1.5 and the 6 cm tray at x = 8.5 (climb 8 cm): floor.
    assert_eq!(at(1.5, 2.0), smokenav_platform_map::FREE, "cable");
    assert_eq!(at(8.5, 2.0), smokenav_platform_map::FREE, "tray");
    // The 25 cm box (3.8, 1.2; 0.6 × 0.4 m): its south edge at y = 1.0.
    assert_eq!(at(3.8, 1.0), smokenav_platform_map::OCCUPIED, "low box");
    assert_eq!(at(5.0, 1.0), smokenav_platform_map::OCCUPIED, "partition");
}
