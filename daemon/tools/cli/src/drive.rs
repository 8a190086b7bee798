//! `smokenav drive LINEAR ANGULAR --for SECONDS`: nudge the robot from a
//! terminal. Publishes `base/cmd_vel` at 10 Hz for that long, then stop
//! commands. Works for any base driver (Pioneer, Scout): they all read
//! `base/cmd_vel` and stop on their own if the commands stop.

use crate::topic::BusArgs;
use clap::Args;
use smokenav_platform_bus::topics;
use smokenav_shared_types::clock::monotonic_now_ns;
use smokenav_shared_types::{Header, VelocityCommand};
use std::time::{Duration, Instant};

#[derive(Debug, Args)]
pub struct DriveArgs {
    /// Forward velocity, m/s (negative: backwards).
    #[arg(allow_hyphen_values = true)]
    linear: f64,
    /// Turn rate, rad/s, counter-clockwise positive (with --deg: deg/s).
    #[arg(allow_hyphen_values = true)]
    angular: f64,
    /// How long to drive, s.
    #[arg(long = "for", value_name = "SECONDS")]
    duration: f64,
    /// ANGULAR is in degrees per second.
    #[arg(long)]
    deg: bool,
    /// Command rate, Hz.
    #[arg(long, default_value_t = 10.0)]
    rate: f64,
    #[command(flatten)]
    bus: BusArgs,
}

/// Stop commands sent at the end, so the base stops at once instead of
/// waiting for its command timeout.
const STOP_REPEATS: u32 = 3;

pub fn run(a: DriveArgs) -> anyhow::Result<()> {
    let angular = if a.deg {
        a.angular.to_radians()
    } else {
        a.angular
    };
    anyhow::ensure!(
        a.linear.is_finite() && angular.is_finite(),
        "velocities must be finite numbers"
    );
    anyhow::ensure!(
        a.duration.is_finite() && (0.0..=3600.0).contains(&a.duration),
        "--for must be 0–3600 s, got {}",
        a.duration
    );
    anyhow::ensure!(
        (1.0..=50.0).contains(&a.rate),
        "--rate must be 1–50 Hz, got {}",
        a.rate
    );
    let stop = smokenav_platform_runtime::Shutdown::install()?;
    let bus = a.bus.open("drive")?;
    let mut publisher = bus.publisher(topics::BASE_CMD_VEL)?;
    let period = Duration::from_secs_f64(1.0 / a.rate);
    let start = Instant::now();
    let end = start + Duration::from_secs_f64(a.duration);
    let mut next = start;
    let mut sent = 0u64;
    let command = |linear: f64, angular: f64| VelocityCommand {
        header: Header::new(monotonic_now_ns(), 0, "base_link"),
        linear,
        angular,
    };
    while Instant::now() < end && !stop.requested() {
        publisher.publish(&command(a.linear, angular))?;
        sent += 1;
        next += period;
        if let Some(d) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(d.min(end.saturating_duration_since(Instant::now())));
        }
    }
    let driven = start.elapsed();
    for i in 0..STOP_REPEATS {
        publisher.publish(&command(0.0, 0.0))?;
        if i + 1 < STOP_REPEATS {
            std::thread::sleep(period);
        }
    }
    eprintln!(
        "sent {sent} commands ({:.2} m/s, {:.3} rad/s) over {:.1} s, then stop",
        a.linear,
        angular,
        driven.as_secs_f64()
    );
    Ok(())
}
