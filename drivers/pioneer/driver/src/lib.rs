//! The Pioneer driver's logic, kept apart from the process wiring so it can be
//! tested without a port or a bus:
//!
//! - [`session`]: the ARCOS session state machine (handshake, stale-session
//!   recovery, link loss, velocity refresh and keep-alive);
//! - [`motion`]: bus velocity commands to a safe target (limits, stop on timeout);
//! - [`messages`]: SIPs to `Odometry` and `SonarRing`;
//! - [`port`]: serial device or `tcp://host:port`.

pub mod messages;
pub mod motion;
pub mod port;
pub mod session;
