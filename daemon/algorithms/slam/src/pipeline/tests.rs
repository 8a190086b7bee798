//! The pipeline on the test room: the filter behind the front end and the
//! motion filter, and the odometry pairing policy (resets, stale and
//! missing odometry, superseded scans).

use super::*;
use crate::rbpf::Rbpf;
use crate::testkit::scan_at;
use smokenav_shared_types::{BeamReading, Header, SectionSource};

fn pipeline(c: &SlamSection, keep_trajectory: bool) -> SlamPipeline {
    SlamPipeline::from_config(
        c,
        &BackendOptions {
            keep_trajectory,
            ..BackendOptions::default()
        },
    )
}

fn rbpf(p: &SlamPipeline) -> &Rbpf {
    p.backend()
        .as_any()
        .downcast_ref()
        .expect("the default back-end is the particle filter")
}

fn cfg(particles: usize) -> SlamSection {
    SlamSection {
        particles,
        ..SlamSection::default()
    }
}

/// Drives an arc through the room; odometry over-reads distance by 5 % and
/// turns by 3 %, so it drifts while the filter should not.
fn drive(slam: &mut SlamPipeline, steps: usize) -> (Pose2, Pose2) {
    let start_truth = Pose2::new(-3.5, -1.5, 0.0);
    let mut truth = start_truth;
    let mut odom = Pose2::new(10.0, 20.0, 1.0);
    for k in 0..steps {
        slam.process(&scan_at(&truth, k as u64 * 100_000_000), &odom);
        let step = Pose2::new(0.1, 0.0, if k < 40 { 0.0 } else { 0.05 });
        truth = truth.compose(&step);
        odom = odom.compose(&Pose2::new(step.x * 1.05, 0.0, step.theta * 1.03));
    }
    // The map frame is the pose of the first scan: express the last scan's pose in it.
    let previous_truth = {
        // `truth` has advanced one step past the last scan; step back.
        let step = Pose2::new(0.1, 0.0, if steps - 1 < 40 { 0.0 } else { 0.05 });
        truth.compose(&step.inverse())
    };
    (start_truth.between(&previous_truth), slam.pose().unwrap())
}

#[test]
fn filter_tracks_a_robot_whose_odometry_drifts() {
    let mut slam = pipeline(&cfg(10), true);
    let (truth, est) = drive(&mut slam, 70);
    // 7 m driven with odometry 5 % long and turns 3 % wide (0.35 m, 0.1 rad of drift).
    assert!(
        (est.x - truth.x).abs() < 0.05 && (est.y - truth.y).abs() < 0.05,
        "{est:?} vs {truth:?}"
    );
    assert!(
        (est.theta - truth.theta).abs() < 0.02,
        "{est:?} vs {truth:?}"
    );
    assert_eq!(slam.trajectory().len(), 70);
    assert_eq!(rbpf(&slam).stats().updates, 70);
    let map = slam.map().unwrap();
    // The map shows the inner wall at x = 0 (3.5 m right of the start), y from 1 to 3.
    let (cx, cy) = map.world_to_cell(3.5, 3.5).unwrap();
    let near_wall = (cx.saturating_sub(2)..cx + 3).any(|x| map.get(x, cy).is_some_and(|v| v > 50));
    assert!(near_wall);
}

#[test]
fn scan_without_ranges_moves_the_particles_by_odometry() {
    let mut slam = pipeline(&cfg(5), false);
    let p = Pose2::new(-3.5, -1.5, 0.0);
    slam.process(&scan_at(&p, 0), &Pose2::default());
    let mut empty = scan_at(&p, 100_000_000);
    empty.beams.iter_mut().for_each(|b| b.range = None);
    let u = slam.process(&empty, &Pose2::new(0.2, 0.0, 0.0));
    assert!(u.pose.is_finite());
    assert!((u.pose.x - 0.2).abs() < 0.1, "{u:?}");
    assert_eq!(slam.stats().empty_scans, 1);
    // No beams at all, and a NaN odometry reading: still no panic, pose kept finite.
    let none = RangeScan {
        stamp_ns: 200_000_000,
        ..Default::default()
    };
    let u = slam.process(&none, &Pose2::new(f64::NAN, 0.0, 0.0));
    assert!(u.pose.is_finite());
}

#[test]
fn sonar_only_scans_weigh_but_do_not_drag_the_particles() {
    // In dense smoke the fused scan is sonar arcs only. Here they show the
    // room as seen from the start while the wheels report 0.5 m of travel:
    // a matcher would pull the pose back; the filter must follow the odometry.
    let mut slam = pipeline(&cfg(10), false);
    let p = Pose2::new(-3.5, -1.5, 0.0);
    for k in 0..3 {
        slam.process(&scan_at(&p, k * 100_000_000), &Pose2::default());
    }
    let mut stale = scan_at(&p, 0);
    stale
        .beams
        .iter_mut()
        .for_each(|b| b.kind = BeamKind::Sonar);
    for k in 1..=5u64 {
        stale.stamp_ns = (3 + k) * 100_000_000;
        slam.process(&stale, &Pose2::new(0.1 * k as f64, 0.0, 0.0));
    }
    let est = slam.pose().unwrap();
    assert!((est.x - 0.5).abs() < 0.15, "{est:?}");
    assert!(
        rbpf(&slam).stats().unmatched_updates >= 1,
        "{:?}",
        rbpf(&slam).stats()
    );
    // Laser scans are matched again as soon as they return.
    let before = rbpf(&slam).stats().match_evaluations;
    slam.process(
        &scan_at(&Pose2::new(-3.0, -1.5, 0.0), 900_000_000),
        &Pose2::new(0.5, 0.0, 0.0),
    );
    assert!(rbpf(&slam).stats().match_evaluations > before);
}

#[test]
fn update_thresholds_skip_scans_until_the_robot_moved() {
    let mut c = cfg(3);
    c.linear_update_m = 0.5;
    c.angular_update_rad = 0.8;
    let mut slam = pipeline(&c, false);
    let mut processed = 0;
    for k in 0..12 {
        let truth = Pose2::new(-3.5 + 0.1 * k as f64, -1.5, 0.0);
        let u = slam.process(
            &scan_at(&truth, k * 100_000_000),
            &Pose2::new(0.1 * k as f64, 0.0, 0.0),
        );
        processed += usize::from(u.processed);
    }
    // The first scan, then every 0.5 m of the 1.1 m driven.
    assert_eq!(processed, 3);
}

const MS: u64 = 1_000_000;

/// The room scan at `truth` as a laser would publish it.
fn laser_at(truth: &Pose2, stamp_ns: u64) -> LaserScan {
    let s = scan_at(truth, stamp_ns);
    let mut l = LaserScan {
        header: Header::new(stamp_ns, 0, "laser"),
        angle_min: s.beams[0].angle,
        angle_increment: s.beams[1].angle - s.beams[0].angle,
        range_min: 0.02,
        range_max: 30.0,
        count: s.beams.len() as u32,
        ..Default::default()
    };
    for (i, b) in s.beams.iter().enumerate() {
        l.set_beam(i, b.range.map_or(BeamReading::NoReturn, BeamReading::Range));
    }
    l
}

fn odom(stamp_ns: u64, p: Pose2, flags: u32) -> Odometry {
    Odometry {
        header: Header::new(stamp_ns, 0, "odom"),
        x: p.x,
        y: p.y,
        theta: p.theta,
        flags,
        ..Default::default()
    }
}

#[test]
fn odometry_is_interpolated_at_the_scan_stamp() {
    let room = Pose2::new(-3.5, -1.5, 0.0);
    let mut slam = pipeline(&cfg(2), false);
    slam.push_odom(&odom(100 * MS, Pose2::new(0.0, 0.0, 0.0), 0));
    slam.push_odom(&odom(200 * MS, Pose2::new(0.1, 0.0, 0.2), 0));
    slam.push_laser(&laser_at(&room, 150 * MS));
    assert!(slam.poll(150 * MS).is_some(), "bracketed: no need to wait");
    let p = slam.last_odometry().unwrap();
    assert!((p.x - 0.05).abs() < 1e-12 && (p.theta - 0.1).abs() < 1e-12);
    // Before the oldest reading kept: that reading; after the newest: it is held.
    slam.push_laser(&laser_at(&room, 50 * MS));
    slam.poll(150 * MS).unwrap();
    assert_eq!(slam.last_odometry().unwrap().x, 0.0);
    slam.push_laser(&laser_at(&room, 290 * MS));
    slam.poll(490 * MS).unwrap();
    assert_eq!(slam.last_odometry().unwrap().x, 0.1);
    assert_eq!(slam.stats().no_odometry, 0);
    // No odometry yet: the scan waits for it as for a late reading (at
    // start-up the laser's first scan may come before the base's first
    // odometry), then is used on the origin, and counted.
    let mut none = pipeline(&cfg(2), false);
    none.push_laser(&laser_at(&room, 5));
    assert!(none.poll(5).is_none(), "waits for the first odometry");
    let wait = OdomPolicy::default().wait_ns;
    assert!(none.poll(5 + wait + 1).is_some());
    assert_eq!(none.stats().no_odometry, 1);
    assert_eq!(none.last_odometry(), Some(Pose2::default()));
    // The scans in a row without odometry, until one has it.
    none.push_laser(&laser_at(&room, 200 * MS));
    none.poll(200 * MS + wait + 1).unwrap();
    assert_eq!(none.stats().no_odometry_in_a_row, 2);
    none.push_odom(&odom(300 * MS, Pose2::default(), 0));
    none.push_laser(&laser_at(&room, 300 * MS));
    none.poll(300 * MS).unwrap();
    assert_eq!(
        (none.stats().no_odometry, none.stats().no_odometry_in_a_row),
        (2, 0)
    );
}

/// The first odometry comes after scans were placed on the origin for want
/// of any: where the wheels say the robot is (MIT CSAIL's odometry starts
/// at x 576 m) is not taken as a drive there. Before, the pose jumped
/// hundreds of metres, and the map exported around it grew to 25 000 ×
/// 32 000 cells (the replay tests' SLAM process stalling for seconds on
/// each export: a scan that beat the first odometry by a moment).
#[test]
fn the_first_odometry_after_scans_without_any_is_no_motion() {
    let room = Pose2::new(-3.5, -1.5, 0.0);
    for frontend in [false, true] {
        let mut slam = pipeline(
            &SlamSection {
                frontend,
                ..cfg(10)
            },
            false,
        );
        let wait = OdomPolicy::default().wait_ns;
        slam.push_laser(&laser_at(&room, 0));
        slam.poll(wait + 1).unwrap();
        assert_eq!(slam.stats().no_odometry, 1);
        let wheels = Pose2::new(576.5, 0.1, -2.25);
        let mut last = None;
        for k in 1..=10u64 {
            let t = k * 100 * MS;
            let truth = Pose2::new(-3.5 + 0.02 * k as f64, -1.5, 0.0);
            let at = wheels.compose(&room.between(&truth));
            slam.push_odom(&odom(t, at, 0));
            slam.push_laser(&laser_at(&truth, t));
            last = slam.poll(t).or(last);
        }
        let est = last.unwrap().pose;
        assert!(
            (est.x - 0.2).hypot(est.y) < 0.1 && est.theta.abs() < 0.05,
            "front end {frontend}: {est:?}"
        );
        assert_eq!(slam.stats().odom_resets, 0, "no reset was flagged");
        assert_eq!(slam.stats().no_odometry, 1);
    }
}

#[test]
fn stale_odometry_is_waited_for_then_held_then_given_up() {
    let room = Pose2::new(-3.5, -1.5, 0.0);
    let mut slam = pipeline(&cfg(2), false);
    slam.push_odom(&odom(1000 * MS, Pose2::new(0.3, 0.0, 0.0), 0));
    slam.push_laser(&laser_at(&room, 1000 * MS));
    slam.poll(1000 * MS).unwrap();
    // The wheels go quiet. A scan 50 ms on waits up to 100 ms for odometry…
    slam.push_odom(&odom(1010 * MS, Pose2::new(0.31, 0.0, 0.0), 0));
    slam.push_laser(&laser_at(&room, 1060 * MS));
    assert!(slam.poll(1100 * MS).is_none());
    assert!(slam.pending());
    // … then holds the newest reading (50 ms old: within the 300 ms gap).
    let u = slam.poll(1161 * MS).unwrap();
    assert_eq!(u.stamp_ns, 1060 * MS);
    assert_eq!(slam.last_odometry(), Some(Pose2::new(0.31, 0.0, 0.0)));
    assert_eq!(slam.stats().no_odometry, 0);
    // 500 ms past the newest reading: no odometry, the last one used is held and counted.
    slam.push_laser(&laser_at(&room, 1510 * MS));
    slam.poll(2000 * MS).unwrap();
    assert_eq!(slam.stats().no_odometry, 1);
    assert_eq!(slam.last_odometry(), Some(Pose2::new(0.31, 0.0, 0.0)));
    // A reading older than the newest is dropped and counted.
    slam.push_odom(&odom(1005 * MS, Pose2::new(9.0, 9.0, 0.0), 0));
    assert_eq!(slam.stats().odom_out_of_order, 1);
    assert_eq!(slam.stats().scans, 3);
}

#[test]
fn only_the_newest_scan_waits_older_ones_are_superseded() {
    let room = Pose2::new(-3.5, -1.5, 0.0);
    let mut slam = pipeline(&cfg(2), false);
    slam.push_odom(&odom(0, Pose2::default(), 0));
    for k in 1..=3 {
        slam.push_laser(&laser_at(&room, k * 100 * MS));
        assert!(slam.poll(k * 100 * MS).is_none(), "waiting for odometry");
    }
    slam.push_odom(&odom(400 * MS, Pose2::default(), 0));
    let u = slam.poll(400 * MS).unwrap();
    assert_eq!(u.stamp_ns, 300 * MS, "the newest scan");
    assert!(slam.poll(400 * MS).is_none(), "one update per scan");
    let s = slam.stats();
    assert_eq!((s.superseded, s.scans), (2, 1));
}

#[test]
fn held_back_scans_only_move_the_estimate() {
    let c = SlamSection {
        linear_update_m: 0.5,
        angular_update_rad: 0.8,
        ..cfg(3)
    };
    let mut slam = pipeline(&c, false);
    for k in 0..12 {
        let truth = Pose2::new(-3.5 + 0.1 * k as f64, -1.5, 0.0);
        let u = slam.process(
            &scan_at(&truth, k * 100 * MS),
            &Pose2::new(0.1 * k as f64, 0.0, 0.0),
        );
        // Every scan moves the estimate, used or not.
        assert!((u.pose.x - 0.1 * k as f64).abs() < 0.05, "{k}: {u:?}");
    }
    assert_eq!(slam.stats().held_back, 9);
    assert_eq!(rbpf(&slam).stats().updates, 3);
    assert_eq!(rbpf(&slam).stats().predictions, 9);
}

/// Drives 2 m along x through the room: odometry at 20 Hz, scans at 10 Hz
/// (stamped between readings). At 1 s the odometry frame jumps to
/// (50, -20, 2 rad), flagged as a reset when `flag_reset`. Returns the final
/// estimate's error against the truth (the map frame is the start pose).
fn drive_through_a_reset(frontend: bool, flag_reset: bool) -> (f64, PipelineStats) {
    let start = Pose2::new(-3.5, -1.5, 0.0);
    let jump = Pose2::new(50.0, -20.0, 2.0);
    let mut slam = pipeline(
        &SlamSection {
            frontend,
            ..cfg(10)
        },
        false,
    );
    let truth_at = |t_ms: u64| Pose2::new(-3.5 + 0.001 * t_ms as f64, -1.5, 0.0);
    // Odometry since the start, in the frame the wheels report it.
    let odom_at = |t_ms: u64| {
        if t_ms >= 1050 {
            jump.compose(&truth_at(1050).between(&truth_at(t_ms)))
        } else {
            start.between(&truth_at(t_ms))
        }
    };
    let mut last = None;
    for t in (0..=2000).step_by(50) {
        let flags = if t == 1050 && flag_reset {
            OdometryFlags::RESET
        } else {
            0
        };
        slam.push_odom(&odom(t * MS, odom_at(t), flags));
        // The scan 25 ms before this reading: bracketed by it and the one before.
        if t % 100 == 50 {
            slam.push_laser(&laser_at(&truth_at(t - 25), (t - 25) * MS));
            last = slam.poll(t * MS).or(last);
        }
    }
    let est = last.unwrap().pose;
    let truth = start.between(&truth_at(1925));
    ((est.x - truth.x).hypot(est.y - truth.y), slam.stats())
}

#[test]
fn odometry_reset_is_not_taken_as_motion() {
    for frontend in [false, true] {
        let (error, stats) = drive_through_a_reset(frontend, true);
        assert!(error < 0.1, "front end {frontend}: {error} m off");
        assert_eq!(stats.odom_resets, 1);
        assert_eq!(stats.scans, 20);
    }
    // The same jump unflagged, 54 m in 50 ms, is no motion any robot
    // makes: taken as a reset too, counted apart (it was driven as 54 m).
    for frontend in [false, true] {
        let (error, stats) = drive_through_a_reset(frontend, false);
        assert!(error < 0.1, "front end {frontend}: {error} m off");
        assert_eq!((stats.odom_resets, stats.odom_jumps), (0, 1));
    }
}

#[test]
fn odometry_is_taken_as_motion_up_to_what_a_robot_can_drive() {
    let at = |ms: u64, x: f64| (ms * MS, Pose2::new(576.5 + x, 0.1, -2.2));
    // 0.5 m whatever the time, then 5 m/s.
    assert!(!odometry_jumped(at(0, 0.0), at(50, 0.74)));
    assert!(odometry_jumped(at(0, 0.0), at(50, 0.76)));
    assert!(!odometry_jumped(at(0, 0.0), at(1, 0.5)));
    assert!(
        !odometry_jumped(at(0, 0.0), at(10_000, 50.0)),
        "10 s silent"
    );
    assert!(odometry_jumped(at(0, 0.0), at(100, -600.0)));
    // Not newer, or not a pose: the buffer drops it; no jump.
    assert!(!odometry_jumped(at(100, 0.0), at(100, 600.0)));
    assert!(!odometry_jumped(at(100, 0.0), at(50, 600.0)));
    assert!(!odometry_jumped(
        at(0, 0.0),
        (MS, Pose2::new(f64::NAN, 0.0, 0.0))
    ));
    // Turning on the spot is never a jump (headings wrap).
    assert!(!odometry_jumped(
        at(0, 0.0),
        (MS, Pose2::new(576.5, 0.1, 3.1))
    ));
}

#[test]
fn the_smoke_return_check_takes_the_fusions_contradiction_margin() {
    // One section over the whole scan of the room, its sonar hearing 4 m:
    // every laser return nearer than 3.7 m is one the sonar contradicts at
    // v2's default margin, none at a margin of 5 m.
    let mut f = FusedScan {
        scan: laser_at(&Pose2::new(-3.5, -1.5, 0.0), 0),
        ..Default::default()
    };
    f.section_count = 1;
    f.sections[0].first_beam = 0;
    f.sections[0].end_beam = f.scan.count as u16;
    f.sections[0].sonar_range = 4.0;
    let measured = |slam: &SlamPipeline| {
        slam.scan()
            .laser_roughness
            .iter()
            .filter(|r| !r.is_nan())
            .count()
    };
    let mut slam = pipeline(&cfg(2), false);
    slam.push_fused(&f);
    assert!(measured(&slam) > 100, "{}", measured(&slam));
    let mut slam = pipeline(&cfg(2), false).with_contradiction_margin(5.0);
    slam.push_fused(&f);
    assert_eq!(measured(&slam), 0);
}

#[test]
fn fused_scans_carry_the_smoke_noise_and_the_beam_sources() {
    let mut slam = pipeline(&cfg(2), false);
    let mut f = FusedScan {
        scan: laser_at(&Pose2::new(-3.5, -1.5, 0.0), 0),
        smoke_level: 300.0,
        ..Default::default()
    };
    f.beam_source[1] = SectionSource::Sonar as u8;
    f.beam_source[2] = SectionSource::Neither as u8;
    slam.push_fused(&f);
    let s = slam.scan();
    let fog = slam.noise_model().factor(300.0);
    assert!((fog - (13.75f64 / 5.0).sqrt()).abs() < 1e-9);
    assert_eq!(s.laser_noise_factor, fog);
    assert_eq!(s.beams[1].kind, BeamKind::Sonar);
    assert_eq!(s.beams[2].range, None);
    assert_eq!(s.beams[0].kind, BeamKind::Laser);
}

/// Scans down the room with odometry 10 % long and turning 0.01 rad a step
/// the robot does not turn, from scan `from` on marked as mostly withheld
/// from the laser (smoke) with share `withheld`: returns the front end's motion
/// over those ten scans, its heading error at the end and the stats.
fn front_end_through_withheld_scans(withheld: f64, from: u64) -> (f64, f64, PipelineStats) {
    let mut slam = pipeline(&cfg(2), false);
    let mut truth = Pose2::new(-3.5, -1.5, 0.0);
    let mut odom = Pose2::new(10.0, 20.0, 1.0);
    let mut before = Pose2::default();
    let mut first = None;
    for k in 0..20u64 {
        let mut scan = scan_at(&truth, k * 100_000_000);
        if k >= from {
            scan.withheld_share = withheld;
        }
        slam.process(&scan, &odom);
        first.get_or_insert(slam.frontend_pose().unwrap());
        if k == 9 {
            before = slam.frontend_pose().unwrap();
        }
        truth = truth.compose(&Pose2::new(0.1, 0.0, 0.0));
        odom = odom.compose(&Pose2::new(0.11, 0.0, 0.01));
    }
    let after = slam.frontend_pose().unwrap();
    // The robot never turned: the heading should stay the first scan's.
    let heading_error =
        smokenav_shared_types::odom::normalize_angle(after.theta - first.unwrap().theta);
    (
        before.between(&after).translation_norm(),
        heading_error.abs(),
        slam.stats(),
    )
}

#[test]
fn scans_mostly_withheld_from_the_laser_keep_the_heading_and_follow_odometry_in_position() {
    // Matched, the front end follows the room: 1 m over the last ten steps, heading held.
    let (matched, heading, stats) = front_end_through_withheld_scans(MAX_WITHHELD_TO_MATCH, 10);
    assert!((matched - 1.0).abs() < 0.03, "{matched} m");
    assert!(heading < 0.02, "{heading} rad");
    assert_eq!(stats.frontend_withheld, 0);
    // Withheld, the position follows the odometry's 1.1 m, but the match
    // still holds the heading the odometry turned by 0.1 rad.
    let (odometry, heading, stats) = front_end_through_withheld_scans(0.5, 10);
    assert!((odometry - 1.1).abs() < 0.02, "{odometry} m");
    assert!(heading < 0.02, "{heading} rad");
    assert_eq!(stats.frontend_withheld, 10);
}

#[test]
fn a_robot_whose_scans_are_withheld_from_the_start_still_holds_its_heading() {
    // The smoke sensor warming up: v2 assumes smoke from the first scan. The
    // first withheld scan becomes the local map the others hold the heading against.
    let (odometry, heading, stats) = front_end_through_withheld_scans(0.5, 0);
    assert!((odometry - 1.1).abs() < 0.02, "{odometry} m");
    assert!(heading < 0.02, "{heading} rad");
    assert_eq!(stats.frontend_withheld, 20);
}

/// Turns the robot round on the spot, 32 steps of 0.1 rad, with odometry
/// that turns 5 % too far; `mark` makes each scan what the fusion sent,
/// given the three of its eight 46-beam sections that still see (other
/// ones from scan to scan). Returns the front end's heading error at the
/// end, rad (odometry alone: 0.155 rad), and the pipeline's stats.
fn turning_on_the_spot(mut mark: impl FnMut(&mut RangeScan, [usize; 3])) -> (f64, PipelineStats) {
    let mut slam = pipeline(&cfg(2), false);
    let mut truth = Pose2::new(-3.5, -1.5, 0.0);
    let mut odom = Pose2::new(10.0, 20.0, 1.0);
    let step = 0.1;
    let steps = 32u64;
    let mut first = None;
    for k in 0..steps {
        let mut scan = scan_at(&truth, k * 100_000_000);
        mark(
            &mut scan,
            [
                (k % 8) as usize,
                ((k + 3) % 8) as usize,
                ((k + 5) % 8) as usize,
            ],
        );
        slam.process(&scan, &odom);
        first.get_or_insert(slam.frontend_pose().unwrap());
        if k + 1 < steps {
            truth = truth.compose(&Pose2::new(0.0, 0.0, step));
            odom = odom.compose(&Pose2::new(0.0, 0.0, step * 1.05));
        }
    }
    let turned = slam.frontend_pose().unwrap().theta - first.unwrap().theta;
    let error =
        smokenav_shared_types::odom::normalize_angle(turned - step * (steps - 1) as f64).abs();
    (error, slam.stats())
}

#[test]
fn a_robot_turning_on_the_spot_while_its_scans_are_withheld_holds_its_heading() {
    // The smoke sensor warming up (v2 assumes smoke, every scan mostly
    // withheld) while the robot turns round on the spot. v2 keeps the
    // laser in a few sections of each scan, other ones from scan to scan,
    // and the 180° scan at the end shares nothing with the first: holding
    // the heading needs the scans between.
    let (error, stats) = turning_on_the_spot(|scan, kept| {
        for (i, b) in scan.beams.iter_mut().enumerate() {
            if !kept.contains(&(i / 46)) {
                b.kind = BeamKind::Sonar;
                b.range = None;
            }
        }
        scan.withheld_share = 0.6;
    });
    assert!(
        error < 0.03,
        "heading {error} rad off after turning on the spot"
    );
    assert_eq!(stats.frontend_withheld, 32);
}

/// Dense smoke: v2 gives every section to the sonar, but in the three that
/// still see the sonar's echo did not contradict the laser and the fused
/// scan keeps the laser's ranges there (`Both`); the rest have no range.
/// With `painted`, those three sections are painted from the sonar instead
/// (their ranges are the sonar's arcs, here the same numbers). The front
/// end's heading error after turning on the spot, rad.
fn turning_blind_with_uncontradicted_laser(painted: bool) -> f64 {
    turning_on_the_spot(|scan, kept| {
        scan.sonar_of = vec![crate::scan::NO_SONAR; scan.beams.len()];
        for (i, b) in scan.beams.iter_mut().enumerate() {
            b.kind = BeamKind::Sonar;
            if !kept.contains(&(i / 46)) {
                b.range = None;
            } else if painted {
                scan.sonar_of[i] = (i / 46) as u8;
            }
        }
        scan.withheld_share = 1.0;
    })
    .0
}

#[test]
fn laser_ranges_the_sonar_did_not_contradict_hold_the_heading_through_smoke() {
    let held = turning_blind_with_uncontradicted_laser(false);
    assert!(held < 0.03, "heading {held} rad off");
    // Ranges painted from the sonar are not matched: the odometry's 0.155 rad.
    let odometry = turning_blind_with_uncontradicted_laser(true);
    assert!((odometry - 0.155).abs() < 0.01, "{odometry} rad off");
}

#[test]
fn the_blind_stretch_counts_odometry_until_the_laser_gives_the_heading_again() {
    let mut slam = pipeline(&cfg(2), false);
    let mut truth = Pose2::new(-3.5, -1.5, 0.0);
    let mut odom = Pose2::new(10.0, 20.0, 1.0);
    let mut at = |k: u64, blind: bool, slam: &mut SlamPipeline| {
        let mut scan = scan_at(&truth, k * 100_000_000);
        if blind {
            // Dense smoke: v2 withholds every beam from the laser.
            for b in &mut scan.beams {
                b.kind = BeamKind::Sonar;
                b.range = None;
            }
            scan.withheld_share = 1.0;
        }
        slam.process(&scan, &odom);
        truth = truth.compose(&Pose2::new(0.1, 0.0, 0.0));
        odom = odom.compose(&Pose2::new(0.1, 0.0, 0.02));
        slam.stats()
    };
    for k in 0..5 {
        let st = at(k, false, &mut slam);
        assert_eq!((st.blind_m, st.longest_blind_m), (0.0, 0.0), "scan {k}");
    }
    // Ten blind scans: 1 m and 0.2 rad of odometry since the last matched one.
    let mut st = PipelineStats::default();
    for k in 5..15 {
        st = at(k, true, &mut slam);
    }
    assert!((st.blind_m - 1.0).abs() < 1e-6, "{}", st.blind_m);
    assert!((st.blind_rad - 0.2).abs() < 1e-6, "{}", st.blind_rad);
    // The laser back: the stretch ends, the longest is kept.
    let st = at(15, false, &mut slam);
    assert_eq!((st.blind_m, st.blind_rad), (0.0, 0.0));
    assert!((st.longest_blind_m - 1.0).abs() < 1e-6);
}

/// A robot turning through the room at 0.3 m/s and 0.8 rad/s, its laser
/// sweeping each 180° scan in 67 ms as it goes (stamped at the first beam,
/// with the time between beams when `time_increment`), exact odometry every
/// 50 ms from before the first scan. Returns the front end's worst pose
/// error (m, rad) against the truth, both relative to the first scan.
fn turning_sweeps(time_increment: bool) -> (f64, f64) {
    turning_sweeps_with(time_increment, &cfg(2))
}

fn turning_sweeps_with(time_increment: bool, c: &SlamSection) -> (f64, f64) {
    let dt = 67e-3 / 360.0;
    let (v, w) = (0.3, 0.8);
    let start = Pose2::new(-3.0, -1.5, 0.0);
    // On the arc: a constant velocity in the robot's own frame.
    let at = |t: f64| {
        start.compose(&Pose2::new(
            v / w * (w * t).sin(),
            v / w * (1.0 - (w * t).cos()),
            w * t,
        ))
    };
    let mut slam = pipeline(c, false);
    let (mut worst_t, mut worst_r) = (0.0f64, 0.0f64);
    let mut first = None;
    for k in 0..60u64 {
        let stamp = k * 50 * MS;
        let truth = at(k as f64 * 0.05);
        slam.push_odom(&odom(stamp, truth, 0));
        // A scan every 100 ms from 0.2 s on.
        if k < 4 || k % 2 == 1 {
            continue;
        }
        let mut l = laser_at(&truth, stamp);
        for i in 0..l.count as usize {
            let a = f64::from(l.angle_min) + i as f64 * f64::from(l.angle_increment);
            let p = at(k as f64 * 0.05 + i as f64 * dt);
            let r = crate::testkit::cast(p.x, p.y, p.theta + a);
            l.set_beam(
                i,
                r.map_or(BeamReading::NoReturn, |r| BeamReading::Range(r as f32)),
            );
        }
        if time_increment {
            l.time_increment = dt as f32;
        }
        slam.push_laser(&l);
        slam.poll(stamp).expect("odometry at the stamp");
        let pose = slam.frontend_pose().unwrap();
        let (f_truth, f_pose) = *first.get_or_insert((truth, pose));
        let err = f_truth.between(&truth).between(&f_pose.between(&pose));
        worst_t = worst_t.max(err.translation_norm());
        worst_r = worst_r.max(err.theta.abs());
    }
    // With the time increment every scan is deskewed, the first too (the
    // odometry runs from before it); without it, none.
    let deskewed = if time_increment && c.deskew { 28 } else { 0 };
    assert_eq!(slam.stats().deskewed, deskewed);
    (worst_t, worst_r)
}

#[test]
fn a_laser_sweeping_while_the_robot_turns_is_deskewed_by_the_odometry() {
    // Matched as if taken at once, the bent sweeps turn the tracked heading
    // 0.04 rad off exact odometry in 2.8 s; deskewed, 0.002 rad. (The
    // position error, 3–4 cm either way, is the front end's own on this
    // turning route: the same without any sweep.)
    let (_, skewed) = turning_sweeps(false);
    let (_, deskewed) = turning_sweeps(true);
    assert!(deskewed < 0.005, "deskewed: {deskewed} rad off");
    assert!(skewed > 5.0 * deskewed, "skewed: {skewed} rad off");
}

#[test]
fn deskewing_can_be_turned_off() {
    let off = SlamSection {
        deskew: false,
        ..cfg(2)
    };
    assert_eq!(turning_sweeps_with(true, &off), turning_sweeps(false));
}

/// The map's largest value within 0.1 m of `(x, y)` (map frame).
fn max_near(map: &OccupancyGrid, x: f64, y: f64) -> i8 {
    let mut max = -1;
    for dy in -2..=2 {
        for dx in -2..=2 {
            let p = (x + 0.05 * f64::from(dx), y + 0.05 * f64::from(dy));
            if let Some((cx, cy)) = map.world_to_cell(p.0, p.1) {
                max = max.max(map.get(cx, cy).unwrap_or(-1));
            }
        }
    }
    max
}

/// A smoke cloud on the robot's path: the laser sees it as a short wall
/// 1.5 m ahead (a phantom), is blind inside it, and clear past it, the
/// phantom then behind the robot where no beam looks. Only the footprint
/// can tell the map that the robot drove through that "wall".
#[test]
fn the_exported_map_is_free_where_the_robot_drove_through_a_phantom() {
    use crate::testkit::{WALLS, scan_in};
    use smokenav_platform_config::SlamBackendKind;
    for backend in [SlamBackendKind::Graph, SlamBackendKind::Rbpf] {
        let mut phantom_value = Vec::new();
        for footprint in [0.0, 0.185] {
            let c = SlamSection {
                backend,
                particles: 5,
                ..SlamSection::default()
            };
            let mut slam = pipeline(&c, true).with_footprint(footprint);
            let start = Pose2::new(-3.5, -1.5, 0.0);
            let mut truth = start;
            let mut with_phantom = WALLS.to_vec();
            with_phantom.push((-2.0, -1.7, -2.0, -1.3));
            for k in 0..32u64 {
                let stamp = k * 100_000_000;
                let scan = if truth.x < -2.65 {
                    scan_in(&with_phantom, f64::INFINITY, &truth, stamp)
                } else if truth.x < -1.55 {
                    let mut s = scan_at(&truth, stamp);
                    s.beams.iter_mut().for_each(|b| b.range = None);
                    s
                } else {
                    scan_at(&truth, stamp)
                };
                slam.process(&scan, &truth);
                truth = truth.compose(&Pose2::new(0.1, 0.0, 0.0));
            }
            let (map, cleared) = slam.map_and_footprint().unwrap();
            // The map frame is the first scan's pose: the phantom lies 1.5 m ahead of it.
            phantom_value.push((max_near(&map, 1.5, 0.0), cleared));
            // The room's real walls stay: the inner wall's end 3.5 m right, 2.5 m up.
            assert!(
                max_near(&map, 3.5, 2.6) >= 65,
                "{backend:?}: a real wall went"
            );
        }
        let [(without, none), (with, cleared)] = phantom_value[..] else {
            unreachable!()
        };
        assert!(
            without >= 65,
            "{backend:?}: the phantom is mapped ({without})"
        );
        assert_eq!(none, 0);
        assert!(
            with <= 19,
            "{backend:?}: the robot drove through it ({with})"
        );
        assert!(cleared >= 3, "{backend:?}: {cleared} wall cells cleared");
    }
}
