//! SmokeNav fusion layer (seed 000, §5.1–5.4): decides, per sonar section and
//! per scan, whether to trust the laser, the sonar, both or neither, and hands
//! an ordinary laser scan ([`smokenav_shared_types::FusedScan`]) to any 2D SLAM.
//!
//! A pure library: no bus, no clock (time comes from message stamps and an
//! injected `now`), no allocation per cycle.
//!
//! - [`sync`]: approximate-time synchroniser with ROS message_filters
//!   semantics, plus a timeout that degrades the output when a sensor goes
//!   silent, and drop counters.
//! - [`geometry`]: sonar poses in the laser frame, the sections τ, and
//!   Algorithm 1 (sonar readings painted into a laser-shaped scan).
//! - [`v1`]: Algorithm 2, the heuristic (smoke states, MAX_DIFF, zero crossings).
//! - [`v2`] and [`fuzzy`]: Algorithm 3 / Fig. 14, the fuzzy model.
//! - [`engine`]: `FusionEngine::step(laser, sonar, smoke, &mut FusedScan)`.
//! - [`pipeline`]: synchroniser + engine, as the process and `smokenav fuse` run them.
//! - [`offline`]: `fuse_jsonl`, the same over `topic echo --json` lines.
//! - [`testkit`]: constructed rooms, scans, rings and smoke readings for tests and benchmarks.
//!
//! Parameters (every threshold and membership breakpoint, with the paper's
//! values as defaults, and the paper's ambiguities) are documented in
//! `smokenav_platform_config::fusion`.

pub mod engine;
pub mod fuzzy;
pub mod geometry;
pub mod offline;
pub mod pipeline;
pub mod sync;
pub mod testkit;
pub mod v1;
pub mod v2;
