//! MQ303A smoke sensor emulation for tests, bench work and the simulator.
//!
//! * [`model`]: a pure, documented model of the MQ303A on the paper's
//!   divider (output falls as concentration rises; fast rise, slow
//!   recovery; cold-heater warm-up) and concentration-over-time
//!   [`Profile`]s. The simulator can reuse it directly: it has no I/O and
//!   takes time steps from its caller.
//! * [`board`]: sensor + ADC + noise + injected [`Fault`]s, pure.
//! * [`serial`]: the board printing sample lines on a real PTY behind a
//!   stable symlink, with unplug/replug.
//! * [`iio`]: the board as a fake IIO sysfs directory that can vanish.
//!
//! The `smokenav-smoke-emulator` binary runs either emulator from the
//! command line and takes fault commands on stdin.

pub mod board;
pub mod iio;
pub mod model;
pub mod noise;
pub mod serial;

pub use board::{Board, BoardConfig, BoardStats, Command, Fault, Output};
pub use iio::{FakeIio, IioConfig, IioStats};
pub use model::{Mq303a, Profile, ProfileError, SensorParams};
pub use noise::Noise;
pub use serial::{SerialConfig, SerialEmulator, SerialStats, ValueFormat};
/// Codec types this crate's API takes.
pub use smokenav_smoke_codec::{AdcScale, Eol};
