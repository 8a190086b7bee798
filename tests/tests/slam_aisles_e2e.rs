//! Degenerate scan matching: the `aisles` scenario (two 20 m aisles, walls
//! longer than the URG-04LX's 5.6 m range, features only at the ends) in clean
//! air, through the simulator's fast path (the messages the real drivers would
//! publish) and the SLAM pipeline with each back-end. Mid-aisle the laser only
//! says where the walls are, not how far the robot went; a matcher that slides
//! along the aisle there shrinks it. Both back-ends must keep the length each
//! aisle was driven within 2 % of the truth.

use smokenav_algorithms_slam::{BackendOptions, Pose2, SlamPipeline, StampedPose};
use smokenav_platform_config::SlamBackendKind;
use smokenav_sim_link::{DirectDrivers, DirectMessage};
use smokenav_sim_world::{Scenario, StepOutput, World};
use std::time::Duration;

const T0_NS: u64 = 1_000_000_000;

/// Runs the scenario to the end of its route: the back-end's trajectory and the truth (stamp, pose).
fn run(backend: SlamBackendKind, particles: usize) -> (Vec<StampedPose>, Vec<(u64, Pose2)>) {
    let scenario = Scenario::builtin("aisles").unwrap();
    let mut profile = scenario.profile.clone();
    profile.slam.backend = backend;
    profile.slam.particles = particles;
    let mount = profile.laser.mount;
    let mut drivers = DirectDrivers::new(&profile, T0_NS).unwrap();
    let mut slam = SlamPipeline::from_config(
        &profile.slam,
        &BackendOptions {
            keep_trajectory: true,
            ..BackendOptions::default()
        },
    )
    .with_sensor_pose(Pose2::new(mount.x, mount.y, mount.yaw_rad()));
    let mut world = World::new(scenario).unwrap();
    let mut truth = Vec::new();
    let mut out = StepOutput::default();
    let mut done_at = None;
    while !world.is_finished() && done_at.is_none_or(|t| world.time_ns() < t + 1_000_000_000) {
        out.clear();
        world.step_into(Duration::from_millis(100), &mut out);
        if done_at.is_none() && world.route_done() {
            done_at = Some(world.time_ns());
        }
        truth.extend(out.truth.iter().map(|t| (T0_NS + t.t_ns, t.pose)));
        drivers.convert(&out, |now, msg| {
            match &msg {
                DirectMessage::Laser(s) => slam.push_laser(s),
                DirectMessage::Odometry(o) => slam.push_odom(o),
                _ => return,
            }
            slam.poll(now);
        });
    }
    slam.flush();
    assert!(done_at.is_some(), "the route did not finish");
    (slam.trajectory(), truth)
}

/// The first sample at or after `t` (both sorted by stamp).
fn at<T: Copy>(track: &[(u64, T)], t: u64) -> T {
    let i = track.partition_point(|(s, _)| *s < t);
    track[i.min(track.len() - 1)].1
}

/// (true, estimated) length between where the robot crossed x = 4 and x = 22
/// in the aisle whose centre line is below (`lower`) or above the rack.
fn aisle(est: &[StampedPose], truth: &[(u64, Pose2)], lower: bool) -> (f64, f64) {
    let inside = |p: &Pose2| if lower { p.y < 2.75 } else { p.y > 4.75 };
    let crossing = |x: f64| {
        truth
            .windows(2)
            .find(|w| inside(&w[0].1) && (w[0].1.x - x) * (w[1].1.x - x) <= 0.0)
            .map(|w| w[1].0)
            .unwrap_or_else(|| panic!("the robot never crossed x = {x} (lower {lower})"))
    };
    let (a, b) = (crossing(4.0), crossing(22.0));
    let est: Vec<(u64, Pose2)> = est.iter().map(|p| (p.stamp_ns, p.pose)).collect();
    let dist = |p: Pose2, q: Pose2| (p.x - q.x).hypot(p.y - q.y);
    (
        dist(at(truth, a), at(truth, b)),
        dist(at(&est, a), at(&est, b)),
    )
}

fn check(backend: SlamBackendKind, particles: usize) {
    let (est, truth) = run(backend, particles);
    assert!(est.len() > 1000, "{} poses", est.len());
    for lower in [true, false] {
        let (t, e) = aisle(&est, &truth, lower);
        let err = (e - t) / t;
        eprintln!(
            "{backend:?}, aisle {}: true {t:.3} m, estimated {e:.3} m ({:+.2} %)",
            if lower { "1" } else { "2" },
            100.0 * err
        );
        assert!(
            err.abs() <= 0.02,
            "{backend:?}: aisle {t:.2} m long mapped as {e:.2} m"
        );
    }
}

#[test]
fn graph_keeps_the_length_of_long_featureless_aisles() {
    check(SlamBackendKind::Graph, 1);
}

#[test]
fn rbpf_keeps_the_length_of_long_featureless_aisles() {
    check(SlamBackendKind::Rbpf, 10);
}
