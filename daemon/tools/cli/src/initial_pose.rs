//! `smokenav initial-pose X Y HEADING`: tell SLAM where the robot is, as
//! RViz's "2D Pose Estimate" does on `/initialpose`. Publishes one pose on
//! `slam/initial_pose` (map frame, the σ given as its covariance); a SLAM
//! process localising on a saved map searches around it over its next 10
//! scans until one matches (and the next confirms it), and any SLAM process
//! starts there before its first scan. Then it reads `health/slam` to say whether the pose was taken.

use crate::topic::BusArgs;
use anyhow::Context;
use clap::Args;
use smokenav_platform_bus::topics;
use smokenav_platform_recording::initial_pose::PlanarPose;
use smokenav_shared_types::clock::monotonic_now_ns;
use smokenav_shared_types::{Health, PoseEstimate};
use std::time::{Duration, Instant};

#[derive(Debug, Args)]
pub struct InitialPoseArgs {
    /// Position in the map frame, m.
    #[arg(allow_hyphen_values = true)]
    x: f64,
    /// Position in the map frame, m.
    #[arg(allow_hyphen_values = true)]
    y: f64,
    /// Heading in the map frame, degrees counter-clockwise from the map's x axis (with --rad: radians).
    #[arg(allow_hyphen_values = true)]
    heading: f64,
    /// HEADING is in radians.
    #[arg(long)]
    rad: bool,
    /// How sure you are of the position (σ, m): SLAM searches ± 3σ, at least
    /// its loop-closure window (1.5 m), at most 3 m.
    #[arg(long, value_name = "M", default_value_t = 0.5)]
    sigma_m: f64,
    /// How sure you are of the heading (σ, degrees): searched ± 3σ, at least
    /// the closure window's 20°, at most 60°.
    #[arg(long, value_name = "DEG", default_value_t = 15.0)]
    sigma_deg: f64,
    /// How long to wait for SLAM's health to show the pose taken, s.
    #[arg(long, value_name = "SECONDS", default_value_t = 3.0)]
    wait: f64,
    #[command(flatten)]
    bus: BusArgs,
}

/// The health metric a localising SLAM counts given poses in.
const GIVEN_METRIC: &str = "localization_poses_given";

/// The message `slam/initial_pose` carries for these arguments.
pub fn pose_message(a: &InitialPoseArgs, stamp_ns: u64) -> anyhow::Result<PoseEstimate> {
    let heading = if a.rad {
        a.heading
    } else {
        a.heading.to_radians()
    };
    anyhow::ensure!(
        a.x.is_finite() && a.y.is_finite() && heading.is_finite(),
        "the pose must be finite numbers"
    );
    anyhow::ensure!(
        a.sigma_m.is_finite() && (0.0..=100.0).contains(&a.sigma_m),
        "--sigma-m must be 0–100 m, got {}",
        a.sigma_m
    );
    anyhow::ensure!(
        a.sigma_deg.is_finite() && (0.0..=180.0).contains(&a.sigma_deg),
        "--sigma-deg must be 0–180°, got {}",
        a.sigma_deg
    );
    let var = a.sigma_m * a.sigma_m;
    Ok(PlanarPose {
        x: a.x,
        y: a.y,
        yaw: heading,
        var_x: var,
        var_y: var,
        var_yaw: a.sigma_deg.to_radians().powi(2),
    }
    .to_estimate(stamp_ns))
}

pub fn run(a: InitialPoseArgs) -> anyhow::Result<()> {
    let msg = pose_message(&a, 0)?;
    anyhow::ensure!(
        a.wait.is_finite() && (0.0..=60.0).contains(&a.wait),
        "--wait must be 0–60 s, got {}",
        a.wait
    );
    let bus = a.bus.open("initial-pose")?;
    let health = bus.subscriber::<Health>(topics::health("slam"))?;
    let mut publisher = bus
        .publisher(topics::SLAM_INITIAL_POSE)
        .context("cannot publish slam/initial_pose")?;
    let sent_ns = monotonic_now_ns();
    publisher.publish_with(|m| {
        *m = msg;
        m.header.stamp_ns = sent_ns;
    })?;
    eprintln!(
        "published the pose x {:.2} m, y {:.2} m, heading {:.1}° (σ {} m, {}°) on slam/initial_pose",
        msg.x,
        msg.y,
        msg.theta.to_degrees(),
        a.sigma_m,
        a.sigma_deg
    );
    // Health is reported about once a second: wait for one that counts it.
    let end = Instant::now() + Duration::from_secs_f64(a.wait);
    let mut heard = false;
    // The count in reports made before the pose was sent.
    let mut before = 0.0;
    while Instant::now() < end {
        while let Some(h) = health.receive()? {
            heard = true;
            let Some(n) = h.metric(GIVEN_METRIC) else {
                continue;
            };
            if h.header.stamp_ns < sent_ns {
                before = n;
            } else if n > before {
                eprintln!(
                    "taken: SLAM is localising from there ({GIVEN_METRIC} {n}); `smokenav status` says when it matches the map again"
                );
                return Ok(());
            }
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    // Kept alive until here: a pose from a publisher that is gone cannot be taken.
    drop(publisher);
    if !heard {
        anyhow::bail!(
            "no SLAM process reported on health/slam within {} s: nothing took the pose",
            a.wait
        );
    }
    anyhow::bail!(
        "SLAM did not count the pose as a localisation within {} s: a SLAM that is mapping takes a pose only before its first scan (its log says why it refused)",
        a.wait
    )
}
