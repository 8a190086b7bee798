//! The `smokenav-smoke` driver: thin wiring around [`smokenav_smoke_codec`].
//!
//! * [`settings`]: the `[smoke]` section plus `--port` / `--warmup` turned
//!   into codec configuration, and the choice of back-end;
//! * [`link`]: the two ADC back-ends, a serial port and an IIO directory,
//!   each reopened after a loss (the runtime's reconnect policy), reporting
//!   samples and errors as [`link::LinkEvent`]s;
//! * [`core`]: samples to `SmokeReading`s at the publishing rate, with the
//!   counters health reports; no bus, no clock of its own;
//! * [`driver`]: the loop around them, talking to the process through a
//!   [`driver::DriverSink`].

pub mod core;
pub mod driver;
pub mod link;
pub mod settings;
