//! `smokenav-smoke`: the MQ303A smoke sensor driver.
//!
//! Reads the ADC (an Arduino-class board on a serial port, or a Linux IIO
//! device directory), runs the `smokenav-adc` signal chain and publishes
//! `SmokeReading` on `smoke/level` at `[smoke] rate_hz` (10 Hz, as in the
//! paper), with health on `health/smoke`.
//!
//! ```text
//! smokenav-smoke --config robot.toml [--port /dev/ttyACM0 | /sys/bus/iio/devices/iio:device0] [--warmup 0]
//! ```
//!
//! Thin wiring around [`smokenav_smoke_driver::driver::Driver`].

use clap::Parser;
use smokenav_platform_bus::{Publisher, topics};
use smokenav_platform_runtime::{CommonArgs, Process, RateId};
use smokenav_shared_types::{Clock, MonotonicClock, SmokeReading};
use smokenav_smoke_codec::SensorState;
use smokenav_smoke_driver::core::DriverCore;
use smokenav_smoke_driver::driver::{Driver, DriverSink, ErrorLog};
use smokenav_smoke_driver::link::{Link, LinkEvent, policy_name};
use smokenav_smoke_driver::settings::Settings;
use std::process::ExitCode;
use std::time::Duration;

#[derive(Parser)]
#[command(
    version,
    about = "MQ303A smoke sensor driver: serial or IIO ADC in, SmokeReading on smoke/level"
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// Heater warm-up in seconds, overriding `[smoke] warmup_s` (0 for bench tests).
    #[arg(long, value_name = "SECONDS")]
    warmup: Option<f64>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    smokenav_platform_runtime::main("smoke", &args.common, |p| run(p, args.warmup))
}

struct BusSink<'a> {
    p: &'a mut Process,
    publisher: Publisher<SmokeReading>,
    sample_rate: RateId,
    publish_rate: RateId,
    readied: bool,
    errors: ErrorLog,
    shown_state: Option<SensorState>,
}

impl DriverSink for BusSink<'_> {
    fn publish(&mut self, msg: &SmokeReading) -> anyhow::Result<()> {
        self.publisher.publish(msg)?;
        self.p.health.mark(self.publish_rate);
        // Measurement (the read) to publication.
        self.p.health.record_latency(Duration::from_nanos(
            MonotonicClock.now_ns().saturating_sub(msg.header.stamp_ns),
        ));
        Ok(())
    }

    fn event(&mut self, ev: &LinkEvent, link: &Link) {
        let error = match ev {
            LinkEvent::Connected { device, .. } => {
                if self.readied {
                    tracing::info!(device, "device back");
                } else {
                    self.p.ready(&format!("reading {}", link.describe()));
                    self.readied = true;
                }
                self.p.health.clear_error();
                return;
            }
            LinkEvent::Sample { .. } => {
                self.p.health.mark(self.sample_rate);
                return;
            }
            LinkEvent::Malformed { error, .. } => error.to_string(),
            LinkEvent::OutOfRange { error, .. } => format!("value out of range: {error}"),
            // Once per outage each: always worth a line.
            LinkEvent::Lost { reason, .. } | LinkEvent::OpenFailed { reason, .. } => {
                self.p.health.error(reason);
                return;
            }
        };
        if let Some(msg) = self.errors.admit(&error) {
            self.p.health.error(&msg);
        }
    }

    fn idle(&mut self, core: &DriverCore, link: &Link, now_ns: u64) -> bool {
        let h = &mut self.p.health;
        link.reconnect().report(h, &link.describe(), now_ns);
        core.report(h, now_ns);
        if let Link::Serial(s) = link {
            let d = s.decoder_stats();
            h.set_metric("comment_lines", d.comments as f64);
            h.set_metric("skipped_bytes", d.skipped_bytes as f64);
        }
        let state = core.last_reading().map(|r| r.state);
        if state != self.shown_state {
            self.shown_state = state;
            if let Some(s) = state {
                tracing::info!(state = ?s, "sensor state");
                self.p.status(&format!("sensor {s:?}; {}", link.describe()));
            }
        }
        if let Err(e) = self.p.tick() {
            tracing::warn!("health: {e:#}");
        }
        self.p.shutdown_requested()
    }
}

fn run(p: &mut Process, warmup: Option<f64>) -> anyhow::Result<()> {
    let settings = Settings::new(&p.config.smoke, p.port_override.as_deref(), warmup)?;
    let clock = MonotonicClock;
    let core = DriverCore::new(&settings, clock.now_ns())?;
    let link = Link::new(&settings);
    tracing::info!(
        link = %link.describe(),
        warmup_s = settings.signal.warmup_s,
        checksum = policy_name(settings.checksum),
        "smoke driver starting"
    );
    let mut sink = BusSink {
        publisher: p.bus.publisher::<SmokeReading>(topics::SMOKE_LEVEL)?,
        sample_rate: p.health.add_rate("sample_hz", None),
        publish_rate: p.health.add_rate("publish_hz", Some(settings.rate_hz)),
        readied: false,
        errors: ErrorLog::default(),
        shown_state: None,
        p,
    };
    Driver::new(core, link).run(&clock, &mut sink)
}
