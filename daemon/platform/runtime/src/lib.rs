//! The scaffolding every `smokenav-<role>` process shares, so each binary is
//! thin wiring around its codec or algorithm:
//!
//! - [`CommonArgs`]: `--config FILE`, `--port DEVICE` (drivers), `--instance`;
//! - logging through `tracing` to the journal under systemd, to the console otherwise;
//! - SIGTERM/SIGINT as a [`Shutdown`] flag;
//! - systemd `READY=1`, `STATUS=` and `WATCHDOG=1` (sd-notify; no-ops outside systemd);
//! - [`HealthReporter`]: periodic `Health` on `health/<role>` with rates,
//!   counters ([`Report`]), the last error and latency percentiles;
//! - [`Reconnect`]: every driver's open → back off → reopen, shown in health;
//! - [`launch`]: starting and stopping a smokenav process from another
//!   program (the lab's supervisor, the end-to-end tests).
//!
//! A process looks like:
//!
//! ```no_run
//! use smokenav_platform_runtime::{CommonArgs, Process};
//! use clap::Parser;
//!
//! #[derive(Parser)]
//! struct Args {
//!     #[command(flatten)]
//!     common: CommonArgs,
//! }
//!
//! fn main() -> std::process::ExitCode {
//!     let args = Args::parse();
//!     smokenav_platform_runtime::main("example", &args.common, |p: &mut Process| {
//!         p.ready("streaming");
//!         while !p.shutdown_requested() {
//!             // wait for input with a timeout, process, publish ...
//!             p.tick()?;
//!         }
//!         Ok(())
//!     })
//! }
//! ```

#![warn(missing_docs)]

mod args;
mod error_line;
mod health;
pub mod launch;
mod logging;
mod process;
mod reconnect;
mod shutdown;
mod systemd;

pub use args::CommonArgs;
pub use error_line::error_line;
pub use health::{DEFAULT_RATE_FLOOR, HealthReporter, LatencyWindow, RateId, RateMeter, Report};
pub use logging::init_logging;
pub use process::{ConfigFailure, EXIT_CONFIG, Process, main};
pub use reconnect::{LinkCounters, Reconnect, ReconnectPolicy};
pub use shutdown::Shutdown;
pub use systemd::SystemdNotifier;
