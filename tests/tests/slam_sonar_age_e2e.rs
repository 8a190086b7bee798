//! The real `smokenav-slam` draws a wall heard by a stale sonar reading
//! where it is: a Nomad Scout drives at 0.3 m/s straight at a wall 4.5 m
//! ahead, blind (the fusion paints the front section from sonar 0 and
//! withholds the rest). The ring reports every transducer every 100 ms but
//! fires each once per 0.96 s (`conf_sn` rate 15, sixteen transducers), so
//! the reading the fusion paints is up to 0.29 m old: drawn as if heard
//! now, the wall lands 0.15 m too far on average. With
//! `[slam] sonar_age_compensation` (the default) the echoes are moved by
//! the odometry since the firing, dated by when the reading changed.

use smokenav_platform_bus::{Waiter, topics};
use smokenav_platform_config::{MountPose, SlamInput};
use smokenav_shared_types::{
    BeamReading, Clock, FusedScan, Header, MapInfo, MonotonicClock, Odometry, SectionSource,
};
use smokenav_tests::{
    FusedSlam, half_circle_fused, open_bus, pose_for_scan, profile, unique_instance,
};
use std::time::{Duration, Instant};

const WALL_X_M: f64 = 4.5;
/// The front transducer's distance ahead of the robot's centre (the profile's ring).
const RING_M: f64 = 0.19;
const STEP_M: f64 = 0.03;
const SCANS: u64 = 100;
const BEAMS: usize = 361;
/// Sonar 0 fires at 20 ms into every 960 ms cycle.
const PHASE_NS: u64 = 20_000_000;
const CYCLE_NS: u64 = 960_000_000;
const PERIOD_NS: u64 = 100_000_000;

/// Scan `k`: sonar 0's last reading (taken at its last firing, in whole
/// inches as the Scout reports) painted across the front section from the
/// robot's centre (the laser's mount), everything else withheld.
fn fused(k: u64, t0: u64) -> FusedScan {
    let now = k * PERIOD_NS;
    let fired = now.saturating_sub(PHASE_NS) / CYCLE_NS * CYCLE_NS + PHASE_NS;
    let fired = fired.min(now.max(PHASE_NS));
    let x_fired = STEP_M * (fired as f64 / PERIOD_NS as f64);
    let inches = ((WALL_X_M - x_fired - RING_M) / 0.0254).round();
    let reading = inches * 0.0254;
    let mut f = half_circle_fused(t0 + now, BEAMS);
    let s = &mut f.scan;
    f.beam_source[..BEAMS].fill(SectionSource::Neither as u8);
    // ±11.25°: the beams 158..=202 of 361 over 180°.
    let (first, last) = (158usize, 202usize);
    for i in 0..BEAMS {
        let painted = (first..=last).contains(&i);
        s.set_beam(
            i,
            if painted {
                BeamReading::Range((reading + RING_M) as f32)
            } else {
                BeamReading::BeyondMax
            },
        );
        if painted {
            f.beam_source[i] = SectionSource::Sonar as u8;
        }
    }
    f.section_count = 1;
    let d = &mut f.sections[0];
    d.sonar_index = 0;
    d.first_beam = first as u16;
    d.end_beam = last as u16 + 1;
    d.source = SectionSource::Sonar as u8;
    d.sonar_range = reading as f32;
    f.sonar_stamp_ns = t0 + now;
    f
}

/// Drives the run with `compensate` and returns where the map's wall ahead
/// is: the mean x of the occupied cells within 0.1 m of the path, beyond 3.5 m.
fn wall_x(compensate: bool) -> f64 {
    let instance = unique_instance("slam_sonar_age_e2e");
    let dir = tempfile::tempdir().unwrap();
    let cfg_path = profile(dir.path(), "nomad-scout.toml", |c| {
        c.slam.input = SlamInput::Fused;
        c.laser.mount = MountPose::default();
        c.slam.max_blind_m = 0.0;
        c.slam.sonar_age_compensation = compensate;
    });
    let mut slam = FusedSlam::spawn(&cfg_path, &instance);
    let bus = open_bus(&instance);
    let maps = bus.map_subscriber(topics::SLAM_MAP).unwrap();
    let waiter = Waiter::new().unwrap();
    let _g = [waiter.attach(&slam.poses).unwrap()];
    let t0 = MonotonicClock.now_ns();
    let mut last = 0;
    for k in 0..SCANS {
        let stamp = t0 + k * PERIOD_NS;
        let odom = Odometry {
            header: Header::new(stamp, 0, "odom"),
            x: STEP_M * k as f64,
            ..Default::default()
        };
        slam.odom.publish(&odom).unwrap();
        slam.scans.publish(&fused(k, t0)).unwrap();
        pose_for_scan(&slam.poses, &waiter, stamp).unwrap_or_else(|e| panic!("scan {k}: {e}"));
        last = stamp;
    }
    // The first map published after the last scan.
    let map_waiter = Waiter::new().unwrap();
    let _m = map_waiter.attach(&maps).unwrap();
    let end = Instant::now() + Duration::from_secs(30);
    let (info, cells): (MapInfo, Vec<i8>) = loop {
        let mut newest = None;
        while let Some(m) = maps.receive().unwrap() {
            if m.user_header().header.stamp_ns >= last {
                newest = Some((*m.user_header(), m.payload().to_vec()));
            }
        }
        if let Some(n) = newest {
            break n;
        }
        assert!(
            Instant::now() < end,
            "no map after the last scan\n{}",
            slam.process.output()
        );
        map_waiter.wait(Some(Duration::from_millis(200))).unwrap();
    };
    let res = f64::from(info.resolution);
    let (mut sum, mut weight) = (0.0, 0.0);
    for row in 0..info.height as usize {
        for col in 0..info.width as usize {
            let v = cells[row * info.width as usize + col];
            let (x, y) = (
                info.origin_x + (col as f64 + 0.5) * res,
                info.origin_y + (row as f64 + 0.5) * res,
            );
            if v > 50 && y.abs() < 0.1 && x > 3.5 {
                sum += x * f64::from(v - 50);
                weight += f64::from(v - 50);
            }
        }
    }
    drop(_g);
    drop(_m);
    slam.terminate();
    assert!(weight > 0.0, "no wall ahead in the map");
    sum / weight
}

#[test]
fn a_wall_heard_by_a_stale_sonar_reading_is_drawn_where_it_stands() {
    let compensated = wall_x(true);
    let stale = wall_x(false);
    assert!(
        (compensated - WALL_X_M).abs() < 0.06,
        "wall drawn at {compensated:.3} m, stands at {WALL_X_M} m (uncompensated {stale:.3} m)"
    );
    // The scenario does show the lag: painted as if heard now, it is far off.
    assert!(
        stale - WALL_X_M > 0.08,
        "uncompensated wall at {stale:.3} m"
    );
}
