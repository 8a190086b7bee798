//! Velocity commands from the bus to a safe target for the robot.
//!
//! The robot is stopped when commands stop arriving for `timeout` (default
//! 0.2 s, two periods of the 10 Hz command stream): a crashed controller must never leave the robot driving (rosaria
//! PR #51 — ARIA's own resending defeats the firmware watchdog). Commands are
//! clamped to the profile's limits; non-finite ones stop the robot.

use crate::session::VelocityTarget;
use std::time::Duration;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionLimits {
    pub max_linear_mps: f64,
    pub max_angular_dps: f64,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MotionCounters {
    pub commands: u64,
    /// NaN or infinite commands (treated as stop).
    pub rejected: u64,
    /// Commands that exceeded a limit and were clamped.
    pub clamped: u64,
    /// Times the command stream went quiet while the target was not zero.
    pub timeouts: u64,
}

#[derive(Debug, Clone)]
pub struct MotionGuard {
    timeout_ns: u64,
    limits: MotionLimits,
    /// Last accepted target and when it was received.
    last: Option<(VelocityTarget, u64)>,
    timed_out: bool,
    /// The stream went quiet since [`MotionGuard::take_timeout`] last asked.
    timeout_event: bool,
    counters: MotionCounters,
}

impl MotionGuard {
    pub fn new(timeout: Duration, limits: MotionLimits) -> Self {
        Self {
            timeout_ns: u64::try_from(timeout.as_nanos()).unwrap_or(u64::MAX),
            limits,
            last: None,
            timed_out: false,
            timeout_event: false,
            counters: MotionCounters::default(),
        }
    }

    pub fn counters(&self) -> MotionCounters {
        self.counters
    }

    /// A command arrived at `now` (receive time: the only clock we trust to
    /// say the sender is still alive).
    pub fn command(&mut self, linear_mps: f64, angular_rps: f64, now: u64) {
        self.counters.commands += 1;
        self.timed_out = false;
        if !linear_mps.is_finite() || !angular_rps.is_finite() {
            self.counters.rejected += 1;
            self.last = Some((VelocityTarget::default(), now));
            return;
        }
        let max_l = self.limits.max_linear_mps;
        let max_a = self.limits.max_angular_dps;
        let l = linear_mps.clamp(-max_l, max_l);
        let a = angular_rps.to_degrees().clamp(-max_a, max_a);
        if l != linear_mps || a != angular_rps.to_degrees() {
            self.counters.clamped += 1;
        }
        let t = VelocityTarget {
            vel: (l * 1000.0).round() as i16,
            rvel: a.round() as i16,
        };
        self.last = Some((t, now));
    }

    /// What the robot should do at `now`.
    pub fn target(&mut self, now: u64) -> VelocityTarget {
        match self.last {
            Some((t, at)) if now.saturating_sub(at) < self.timeout_ns => t,
            Some((t, _)) => {
                if !self.timed_out && t != VelocityTarget::default() {
                    self.counters.timeouts += 1;
                    self.timeout_event = true;
                    tracing::warn!(
                        "no velocity command for {} ms: stopping",
                        self.timeout_ns / 1_000_000
                    );
                }
                self.timed_out = true;
                VelocityTarget::default()
            }
            None => VelocityTarget::default(),
        }
    }

    /// True once after the command stream went quiet with the robot moving
    /// (the caller may stop harder than a plain zero target).
    pub fn take_timeout(&mut self) -> bool {
        std::mem::take(&mut self.timeout_event)
    }

    /// When the current command expires (ns), if one is active.
    pub fn expires_at(&self) -> Option<u64> {
        match self.last {
            Some((t, at)) if !self.timed_out && t != VelocityTarget::default() => {
                Some(at + self.timeout_ns)
            }
            _ => None,
        }
    }

    /// Forget the last command (after a reconnect nothing old may drive the robot).
    pub fn clear(&mut self) {
        self.last = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn guard() -> MotionGuard {
        MotionGuard::new(
            Duration::from_millis(500),
            MotionLimits {
                max_linear_mps: 0.5,
                max_angular_dps: 60.0,
            },
        )
    }

    #[test]
    fn command_converts_to_mm_per_s_and_deg_per_s() {
        let mut g = guard();
        g.command(0.3, -20f64.to_radians(), 0);
        assert_eq!(
            g.target(10 * MS),
            VelocityTarget {
                vel: 300,
                rvel: -20
            }
        );
    }

    #[test]
    fn silence_for_0_5_s_stops_the_robot() {
        let mut g = guard();
        g.command(0.3, 0.0, 0);
        assert_eq!(g.target(499 * MS).vel, 300);
        assert_eq!(g.expires_at(), Some(500 * MS));
        assert_eq!(g.target(500 * MS), VelocityTarget::default());
        assert_eq!(g.target(900 * MS), VelocityTarget::default());
        assert_eq!(g.counters().timeouts, 1);
        assert_eq!(g.expires_at(), None);
        // A new command drives again.
        g.command(0.1, 0.0, 1000 * MS);
        assert_eq!(g.target(1000 * MS).vel, 100);
    }

    #[test]
    fn limits_clamp_and_non_finite_stops() {
        let mut g = guard();
        g.command(2.0, 3.0, 0);
        assert_eq!(g.target(0), VelocityTarget { vel: 500, rvel: 60 });
        assert_eq!(g.counters().clamped, 1);
        g.command(f64::NAN, 0.0, 0);
        assert_eq!(g.target(0), VelocityTarget::default());
        assert_eq!(g.counters().rejected, 1);
    }

    #[test]
    fn no_command_yet_means_stand_still() {
        let mut g = guard();
        assert_eq!(g.target(0), VelocityTarget::default());
    }
}
