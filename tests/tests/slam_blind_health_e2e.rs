//! The SLAM process says when its heading is dead reckoning: fused scans
//! whose every beam the fusion withheld from the laser (dense smoke) go
//! through the real `smokenav-slam` over iceoryx2 while the odometry moves
//! on; past `[slam] max_blind_m` its health turns degraded, names the
//! reason and reports the stretch (`heading_blind_m`), and once the laser
//! is back the reason goes and the longest stretch stays in the report.
//!
//! The scans and odometry are the first 200 of the MIT CSAIL log, the
//! middle ones blinded. The other tests: scans without odometry (a base
//! driver that never started); maps over `[slam] max_map_cells`;
//! odometry that jumps further than a robot drives.

use smokenav_algorithms_slam::carmen::LaserRecord;
use smokenav_platform_bus::{Publisher, Subscriber, Waiter};
use smokenav_platform_config::{MountPose, SlamInput};
use smokenav_shared_types::{
    Clock, FusedScan, Health, HealthState, MonotonicClock, Odometry, PoseEstimate, SectionSource,
};
use smokenav_tests::{
    FusedSlam, carmen_odometry, csail_prefix, fill_carmen_scan, health_until, pose_for_scan,
    profile, unique_instance,
};

/// Records whose scans the fusion withheld entirely.
const BLIND: std::ops::Range<usize> = 60..130;
const MAX_BLIND_M: f64 = 1.0;

fn fused(rec: &LaserRecord, stamp: u64, blind: bool) -> FusedScan {
    let mut f = FusedScan::default();
    fill_carmen_scan(&mut f.scan, rec, stamp);
    if blind {
        // A wall of smoke, no sonar echo in range: nothing is mapped.
        f.beam_source[..rec.ranges.len()].fill(SectionSource::Neither as u8);
    }
    f
}

/// The graph SLAM process on fused scans from a laser at the robot's
/// centre (as CARMEN's), its `[slam]` section as `slam` leaves it; the
/// folder holds its profile.
fn spawn_slam(
    instance: &str,
    slam: impl FnOnce(&mut smokenav_platform_config::SlamSection),
) -> (tempfile::TempDir, FusedSlam) {
    let dir = tempfile::tempdir().unwrap();
    let cfg_path = profile(dir.path(), "pioneer-3dx.toml", |c| {
        c.slam.input = SlamInput::Fused;
        c.laser.mount = MountPose::default();
        slam(&mut c.slam);
    });
    let slam = FusedSlam::spawn(&cfg_path, instance);
    (dir, slam)
}

/// Feeds the SLAM process the CSAIL prefix in lock step: `send(k,
/// odometry, blind)` publishes record `k`'s odometry (moved `odometry` m
/// along x and y; `None`: none at all) and its scan (withheld entirely
/// when `blind`), and returns that scan's pose before the next goes out.
fn lock_step<'a>(
    odom: &'a mut Publisher<Odometry>,
    scans: &'a mut Publisher<FusedScan>,
    poses: &'a Subscriber<PoseEstimate>,
    waiter: &'a Waiter,
) -> impl FnMut(usize, Option<f64>, bool) -> PoseEstimate + 'a {
    let records = csail_prefix();
    let t0 = MonotonicClock.now_ns();
    let ipc0 = records[0].ipc_timestamp_ns;
    move |k, odometry, blind| {
        let rec = &records[k];
        let stamp = t0 + (rec.ipc_timestamp_ns - ipc0);
        if let Some(moved) = odometry {
            let mut o = carmen_odometry(rec, stamp);
            (o.x, o.y) = (o.x + moved, o.y + moved);
            odom.publish(&o).unwrap();
        }
        scans.publish(&fused(rec, stamp, blind)).unwrap();
        pose_for_scan(poses, waiter, stamp).unwrap_or_else(|e| panic!("scan {k}: {e}"))
    }
}

#[test]
fn a_blind_stretch_past_the_limit_degrades_health_until_the_laser_is_back() {
    let instance = unique_instance("slam_blind_health_e2e");
    let (_dir, mut slam) = spawn_slam(&instance, |s| s.max_blind_m = MAX_BLIND_M);
    let waiter = Waiter::new().unwrap();
    let _g = [
        waiter.attach(&slam.poses).unwrap(),
        waiter.attach(&slam.health).unwrap(),
    ];
    let records = csail_prefix();
    // How far the odometry goes while blind: the limit must fall inside.
    let travel: f64 = records[BLIND.start - 1..BLIND.end]
        .windows(2)
        .map(|w| w[0].robot_pose.between(&w[1].robot_pose).translation_norm())
        .sum();
    assert!(travel > 2.0 * MAX_BLIND_M, "{travel} m");

    let mut send = lock_step(&mut slam.odom, &mut slam.scans, &slam.poses, &waiter);
    for k in 0..BLIND.end {
        send(k, Some(0.0), BLIND.contains(&k));
    }
    let blind = health_until(&slam.health, &waiter, "naming the blind stretch", |h| {
        h.last_error
            .as_str()
            .contains("heading from odometry alone")
    });
    assert_eq!(blind.state(), HealthState::Degraded);
    let metric = |h: &Health, name: &str| h.metric(name).unwrap_or(f64::NAN);
    assert!(
        (metric(&blind, "heading_blind_m") - travel).abs() < 0.05,
        "heading_blind_m {} against {travel:.2} m of odometry",
        metric(&blind, "heading_blind_m")
    );
    assert_eq!(
        metric(&blind, "frontend_withheld"),
        BLIND.len() as f64,
        "every blinded scan counted"
    );
    for k in BLIND.end..records.len() {
        send(k, Some(0.0), false);
    }
    let back = health_until(&slam.health, &waiter, "without the blind stretch", |h| {
        metric(h, "heading_blind_m") == 0.0
    });
    assert!(
        !back.last_error.as_str().contains("heading from odometry"),
        "{}",
        back.last_error.as_str()
    );
    // The first scan back has nothing near to match (the front end's last
    // scans are metres behind): the stretch ends at the one after it.
    let longest = metric(&back, "heading_blind_longest_m");
    assert!(
        longest > travel - 0.05 && longest < travel + 0.5,
        "longest {longest} against {travel:.2} m"
    );
    drop(send);
    drop(_g);
    slam.terminate();
}

/// A base driver that never started: the SLAM process places the scans
/// without odometry (each waits 100 ms for it first), and after ten in a
/// row its health turns degraded naming base/odom. When the odometry comes
/// (MIT CSAIL's reads x 576 m) it starts the odometry frame rather than
/// being taken as a drive there, and the reason goes.
#[test]
fn scans_without_odometry_degrade_health_until_the_base_speaks() {
    let instance = unique_instance("slam_no_odom_e2e");
    let (_dir, mut slam) = spawn_slam(&instance, |s| s.max_blind_m = 0.0);
    let waiter = Waiter::new().unwrap();
    let _g = [
        waiter.attach(&slam.poses).unwrap(),
        waiter.attach(&slam.health).unwrap(),
    ];
    let mut poses = Vec::new();
    let mut feed = lock_step(&mut slam.odom, &mut slam.scans, &slam.poses, &waiter);
    let mut send = |k: usize, with_odometry: bool| {
        let p = feed(k, with_odometry.then_some(0.0), false);
        poses.push((p.x, p.y));
    };
    for k in 0..15 {
        send(k, false);
    }
    let silent = health_until(&slam.health, &waiter, "naming the odometry", |h| {
        h.last_error.as_str().contains("no odometry on base/odom")
    });
    assert_eq!(silent.state(), HealthState::Degraded);
    assert!(silent.metric("scans_without_odometry").unwrap() >= 10.0);
    for k in 15..60 {
        send(k, true);
    }
    drop(feed);
    let back = health_until(&slam.health, &waiter, "without the odometry reason", |h| {
        !h.last_error.as_str().contains("no odometry")
    });
    assert_eq!(back.metric("scans_without_odometry"), Some(15.0));
    // The first 60 scans of the log lie within a few metres of the start.
    let far = poses.iter().map(|p| p.0.hypot(p.1)).fold(0.0, f64::max);
    assert!(far < 10.0, "a pose {far:.0} m from the start");
    drop(_g);
    slam.terminate();
}

/// A map larger than `[slam] max_map_cells` (here 2000 cells, 5 m² at
/// 5 cm; CSAIL's first scans map some 30 m × 30 m) is neither published
/// nor kept: health turns degraded naming the key and counts it, and no
/// map reaches `slam/map`; the poses go on.
#[test]
fn a_map_over_the_limit_is_not_published_and_health_says_why() {
    let instance = unique_instance("slam_map_limit_e2e");
    let (_dir, mut slam) = spawn_slam(&instance, |s| {
        s.max_blind_m = 0.0;
        s.max_map_cells = 2000;
    });
    let bus = smokenav_tests::open_bus(&instance);
    let maps = bus
        .map_subscriber(smokenav_platform_bus::topics::SLAM_MAP)
        .unwrap();
    let waiter = Waiter::new().unwrap();
    let _g = [
        waiter.attach(&slam.poses).unwrap(),
        waiter.attach(&slam.health).unwrap(),
    ];
    let mut send = lock_step(&mut slam.odom, &mut slam.scans, &slam.poses, &waiter);
    for k in 0..30 {
        send(k, Some(0.0), false);
    }
    // Maps are due once a second, from the process's own timer.
    let refused = health_until(&slam.health, &waiter, "refusing the map", |h| {
        h.metric("maps_refused").unwrap_or(0.0) >= 1.0
    });
    assert_eq!(refused.state(), HealthState::Degraded);
    let why = refused.last_error.as_str();
    assert!(
        why.contains("slam/map not published") && why.contains("[slam] max_map_cells 2000"),
        "{why}"
    );
    assert_eq!(refused.metric("maps_published"), Some(0.0));
    assert!(
        maps.receive().unwrap().is_none(),
        "a refused map on slam/map"
    );
    drop(send);
    drop(_g);
    slam.terminate();
}

/// A trajectory that alone spans more than `[slam] max_map_cells` (here
/// 5000 cells; CSAIL's 200 scans drive some 6.9 m × 8.1 m, 22 000 cells
/// at 5 cm) is refused its map before it is drawn ("at least"): drawing a
/// map that size would take the memory publishing it does.
#[test]
fn a_trajectory_over_the_limit_is_refused_a_map_before_it_is_drawn() {
    let instance = unique_instance("slam_map_span_e2e");
    let (_dir, mut slam) = spawn_slam(&instance, |s| {
        s.max_blind_m = 0.0;
        s.max_map_cells = 5000;
    });
    let waiter = Waiter::new().unwrap();
    let _g = [
        waiter.attach(&slam.poses).unwrap(),
        waiter.attach(&slam.health).unwrap(),
    ];
    let mut send = lock_step(&mut slam.odom, &mut slam.scans, &slam.poses, &waiter);
    for k in 0..csail_prefix().len() {
        send(k, Some(0.0), false);
    }
    let refused = health_until(&slam.health, &waiter, "refusing before drawing", |h| {
        h.last_error.as_str().contains("the map is at least ")
    });
    assert!(
        refused
            .last_error
            .as_str()
            .contains("over [slam] max_map_cells 5000"),
        "{}",
        refused.last_error.as_str()
    );
    assert_eq!(refused.state(), HealthState::Degraded);
    assert_eq!(refused.metric("maps_published"), Some(0.0));
    drop(send);
    drop(_g);
    slam.terminate();
}

/// Odometry gone astray: a jump of 600 m each way between two readings
/// 200 ms apart, no reset flagged (a corrupt reading, a driver's fault).
/// No robot drives that: it is taken as a reset of the odometry frame,
/// counted as `odom_jumps`, and the poses go on where the scans match
/// (before, they followed it 850 m off and the map with them).
#[test]
fn odometry_gone_astray_is_taken_as_a_reset_not_a_drive() {
    let instance = unique_instance("slam_odom_jump_e2e");
    let (_dir, mut slam) = spawn_slam(&instance, |s| s.max_blind_m = 0.0);
    let waiter = Waiter::new().unwrap();
    let _g = [
        waiter.attach(&slam.poses).unwrap(),
        waiter.attach(&slam.health).unwrap(),
    ];
    let mut send = lock_step(&mut slam.odom, &mut slam.scans, &slam.poses, &waiter);
    let before: Vec<_> = (0..30).map(|k| send(k, Some(0.0), false)).collect();
    let after: Vec<_> = (30..60).map(|k| send(k, Some(600.0), false)).collect();
    // The first 60 scans of the log lie within a few metres of the start.
    let far = before
        .iter()
        .chain(&after)
        .map(|p| p.x.hypot(p.y))
        .fold(0.0, f64::max);
    assert!(far < 10.0, "a pose {far:.0} m from the start");
    let jumped = health_until(&slam.health, &waiter, "counting the jump", |h| {
        h.metric("odom_jumps").unwrap_or(0.0) >= 1.0
    });
    assert_eq!(jumped.metric("odom_jumps"), Some(1.0));
    assert_eq!(jumped.metric("odom_resets"), Some(0.0), "none was flagged");
    drop(send);
    drop(_g);
    slam.terminate();
}
