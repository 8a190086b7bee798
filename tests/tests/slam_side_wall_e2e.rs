//! In smoke the real `smokenav-slam` holds its heading with the sonar that
//! faces a wall: a Pioneer 3-DX drives straight down a corridor (walls
//! 1.2 m left and 1.0 m right), the laser sees it for the first metre, then
//! the fusion withholds every beam for 6 m while the odometry turns 4° the
//! robot did not. The ring's transducers at ±90° (0 and 7) keep reading the
//! walls, and the published heading stays on the corridor's; without them
//! it would follow the odometry.

use smokenav_platform_bus::Waiter;
use smokenav_platform_config::{MountPose, SlamInput};
use smokenav_shared_types::{
    BeamReading, Clock, FusedScan, Header, MonotonicClock, Odometry, SectionSource,
};
use smokenav_tests::{
    FusedSlam, half_circle_fused, health_until, pose_for_scan, profile, unique_instance,
};

const LEFT_WALL_M: f64 = 1.2;
const RIGHT_WALL_M: f64 = 1.0;
/// Where the Pioneer's side transducers sit, left of the centre, m.
const SIDE_SONAR_Y_M: f64 = 0.136;
const STEP_M: f64 = 0.03;
const SEEN: usize = 35;
const BLIND: usize = 200;
/// The odometry's heading error at the end, rad.
const DRIFT_RAD: f64 = 0.07;
const BEAMS: usize = 361;

/// The corridor from (x, 0, 0): a laser scan over ±90° (or every beam
/// withheld), and the ring, the side transducers on the walls, the others
/// saturated.
fn fused(stamp: u64, blind: bool) -> FusedScan {
    let mut f = half_circle_fused(stamp, BEAMS);
    let s = &mut f.scan;
    for i in 0..BEAMS {
        let a = f64::from(s.angle_min) + i as f64 * f64::from(s.angle_increment);
        let r = if a > 0.0 {
            LEFT_WALL_M / a.sin()
        } else if a < 0.0 {
            RIGHT_WALL_M / -a.sin()
        } else {
            f64::INFINITY
        };
        let beam = if r < 5.6 {
            BeamReading::Range(r as f32)
        } else {
            BeamReading::BeyondMax
        };
        s.set_beam(i, beam);
    }
    let source = if blind {
        SectionSource::Neither
    } else {
        SectionSource::Laser
    };
    f.beam_source[..BEAMS].fill(source as u8);
    f.section_count = 8;
    for (k, d) in f.sections[..8].iter_mut().enumerate() {
        d.sonar_index = k as u8;
        d.first_beam = (k * BEAMS / 8) as u16;
        d.end_beam = ((k + 1) * BEAMS / 8) as u16;
        d.source = source as u8;
        d.sonar_range = match k {
            0 => (LEFT_WALL_M - SIDE_SONAR_Y_M) as f32,
            7 => (RIGHT_WALL_M - SIDE_SONAR_Y_M) as f32,
            _ => 5.0,
        };
    }
    f
}

#[test]
fn a_side_sonar_along_a_wall_holds_the_heading_through_smoke() {
    let instance = unique_instance("slam_side_wall_e2e");
    let dir = tempfile::tempdir().unwrap();
    let cfg_path = profile(dir.path(), "pioneer-3dx.toml", |c| {
        c.slam.input = SlamInput::Fused;
        c.laser.mount = MountPose::default();
        c.slam.max_blind_m = 0.0;
    });
    let mut slam = FusedSlam::spawn(&cfg_path, &instance);
    let waiter = Waiter::new().unwrap();
    let _g = [
        waiter.attach(&slam.poses).unwrap(),
        waiter.attach(&slam.health).unwrap(),
    ];

    let t0 = MonotonicClock.now_ns();
    // The odometry integrates a heading that turns while blind.
    let (mut ox, mut oy, mut oth) = (0.0_f64, 0.0_f64, 0.0_f64);
    let mut last = None;
    for k in 0..SEEN + BLIND {
        let blind = k >= SEEN;
        if k > 0 {
            if blind {
                oth += DRIFT_RAD / BLIND as f64;
            }
            ox += STEP_M * oth.cos();
            oy += STEP_M * oth.sin();
        }
        let stamp = t0 + k as u64 * 100_000_000;
        let odom = Odometry {
            header: Header::new(stamp, 0, "odom"),
            x: ox,
            y: oy,
            theta: oth,
            ..Default::default()
        };
        slam.odom.publish(&odom).unwrap();
        slam.scans.publish(&fused(stamp, blind)).unwrap();
        let p =
            pose_for_scan(&slam.poses, &waiter, stamp).unwrap_or_else(|e| panic!("scan {k}: {e}"));
        last = Some(p);
    }
    let end = last.unwrap();
    assert!(
        end.theta.abs() < DRIFT_RAD / 4.0,
        "heading {:.2}° at the end; the odometry's {:.2}°",
        end.theta.to_degrees(),
        oth.to_degrees()
    );
    // Sideways: the truth is y = 0; the odometry's path bent by ~0.2 m.
    assert!(oy.abs() > 0.15, "odometry y {oy}");
    assert!(
        end.y.abs() < oy.abs() / 2.0,
        "y {:.3} m, odometry {oy:.3} m",
        end.y
    );
    let h = health_until(&slam.health, &waiter, "counting the side wall", |h| {
        h.metric("heading_side_wall").is_some_and(|n| n > 0.0)
    });
    assert!(
        h.metric("heading_side_wall").unwrap() > BLIND as f64 / 2.0,
        "{:?}",
        h.metric("heading_side_wall")
    );
    drop(_g);
    slam.terminate();
}
