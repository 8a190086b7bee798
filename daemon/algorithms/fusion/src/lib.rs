//! The SmokeNav fusion layer (SmokeNav (Santos et al. 2015), §5.1–5.4):
//! decides, per sonar section and per scan, whether to trust the laser, the
//! sonar, both or neither, and hands an ordinary laser scan
//! ([`smokenav_shared_types::FusedScan`]) to any 2D SLAM.
//!
//! The laser fails in smoke — its beam scatters and the scan turns into a
//! phantom wall close to the robot — while the sonar is immune but coarse
//! (wide cones, one echo per cone). The paper's two answers are here with
//! their design: [`v1`], a heuristic driven by the smoke sensor's level and
//! trend and the noisiness of each laser section; and [`v2`], a fuzzy model
//! of smoke level, laser spread and sonar range, to which this
//! implementation adds the sonar as a witness against phantom walls. Each
//! module's documentation gives the paper's numbers, the keys they became,
//! and what was decided where the paper is ambiguous.
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
//! - `testkit` (feature `testkit`, for tests and benchmarks): constructed rooms,
//!   scans, rings and smoke readings.
//!
//! Parameters (every threshold and membership breakpoint, with the paper's
//! values as defaults) are the `[fusion]` table of the robot profile; its
//! keys, defaults and ranges are listed in `smokenav_platform_config::fusion`.
//! The papers are listed in `REFERENCES.md` at the top of the repository.

pub mod engine;
pub mod fuzzy;
pub mod geometry;
pub mod offline;
pub mod pipeline;
pub mod sync;
#[cfg(any(test, feature = "testkit"))]
pub mod testkit;
pub mod v1;
pub mod v2;
