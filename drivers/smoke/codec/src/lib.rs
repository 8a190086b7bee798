//! Pure ADC sample-line codec and MQ303A signal processing (no I/O).
//!
//! SmokeNav (Santos et al. 2015) reads an MQ303A alcohol sensor (it smells the glycol-based
//! smoke) through an ADC at about 10 Hz; the sensor's output voltage falls
//! as the concentration rises, reacts fast to smoke and recovers slowly.
//! This crate is everything between the ADC and a `SmokeReading`, with no
//! port, clock or logger:
//!
//! * [`line`], [`splitter`], [`stream`]: the serial line format an
//!   Arduino-class board prints (`A0:512`, `A0:512*7D`, `A0:2480.5mV`),
//!   reassembled from arbitrary chunks in a fixed buffer, with typed errors
//!   and counters;
//! * [`iio`]: the text of Linux IIO sysfs attributes (`in_voltageN_raw`,
//!   `_scale`, `_offset`);
//! * [`adc`]: counts ↔ millivolts with range checks;
//! * [`signal`]: low-pass filter, clean-air baseline, smoke level on the
//!   paper's millivolt scale, [`trend`] with hysteresis, heater warm-up and
//!   disconnected / saturated / stale detection, all driven by stamps;
//! * [`decimate`]: thinning a fast board to the publishing rate;
//! * [`mq303a`]: the sensor's own physical model (concentration in, output
//!   voltage out), shared by the simulated world and the board emulator.

pub mod adc;
pub mod decimate;
pub mod iio;
pub mod line;
pub mod mq303a;
pub mod show;
pub mod signal;
pub mod splitter;
pub mod stream;
pub mod trend;

pub use adc::{AdcConfigError, AdcScale, Measurement, RangeError};
pub use decimate::RateDecimator;
pub use iio::{IioCalibration, IioError, IioRange};
pub use line::{
    ChecksumPolicy, Eol, Line, LineError, Sample, SampleValue, encode_sample, parse_line,
};
pub use show::{Found, Snippet};
pub use signal::{
    BaselineMode, Reading, SensorState, SignalConfig, SignalConfigError, SmokeProcessor,
};
pub use splitter::{LineSplitter, Split};
pub use stream::{DecoderStats, SerialDecoder, StreamError};
pub use trend::{Trend, TrendConfig, TrendDetector};
