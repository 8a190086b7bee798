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

use clap::Parser;
use smokenav_platform_bus::topics;
use smokenav_platform_runtime::{CommonArgs, Process};
use smokenav_shared_types::{Clock, MonotonicClock, SmokeReading};
use smokenav_smoke_driver::core::DriverCore;
use smokenav_smoke_driver::link::{Link, LinkEvent, policy_name};
use smokenav_smoke_driver::settings::Settings;
use std::process::ExitCode;
use std::time::{Duration, Instant};

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

/// Longest a link step blocks: keeps `tick` (watchdog, health) and the
/// 10 Hz idle publishing on time.
const MAX_WAIT: Duration = Duration::from_millis(50);

/// Malformed input is counted always but logged at most this often.
const ERROR_LOG_PERIOD: Duration = Duration::from_secs(1);

fn main() -> ExitCode {
    let args = Args::parse();
    smokenav_platform_runtime::main("smoke", &args.common, |p| run(p, args.warmup))
}

/// Logs recurring input errors at most once per [`ERROR_LOG_PERIOD`].
#[derive(Default)]
struct ErrorLog {
    last: Option<Instant>,
    suppressed: u64,
}

impl ErrorLog {
    fn report(&mut self, p: &mut Process, msg: &str) {
        let now = Instant::now();
        if self
            .last
            .is_some_and(|t| now.duration_since(t) < ERROR_LOG_PERIOD)
        {
            self.suppressed += 1;
            return;
        }
        if self.suppressed > 0 {
            p.health.error(&format!(
                "{msg} (and {} more since the last report)",
                self.suppressed
            ));
        } else {
            p.health.error(msg);
        }
        self.last = Some(now);
        self.suppressed = 0;
    }
}

fn run(p: &mut Process, warmup: Option<f64>) -> anyhow::Result<()> {
    let settings = Settings::new(&p.config.smoke, p.port_override.as_deref(), warmup)?;
    let clock = MonotonicClock;
    let mut publisher = p.bus.publisher::<SmokeReading>(topics::SMOKE_LEVEL)?;
    let mut core = DriverCore::new(&settings, clock.now_ns())?;
    let mut link = Link::new(&settings);
    let sample_rate = p.health.add_rate("sample_hz", None);
    let publish_rate = p.health.add_rate("publish_hz", Some(settings.rate_hz));
    tracing::info!(
        link = %link.describe(),
        warmup_s = settings.signal.warmup_s,
        checksum = policy_name(settings.checksum),
        "smoke driver starting"
    );

    let mut events: Vec<LinkEvent> = Vec::with_capacity(64);
    let mut readied = false;
    let mut errors = ErrorLog::default();
    let mut shown_state = None;
    while !p.shutdown_requested() {
        events.clear();
        link.step(MAX_WAIT, &clock, &mut events);
        for ev in &events {
            match ev {
                LinkEvent::Connected { device, .. } => {
                    if readied {
                        tracing::info!(device, "device back");
                    } else {
                        p.ready(&format!("reading {}", link.describe()));
                        readied = true;
                    }
                    p.health.clear_error();
                }
                LinkEvent::Sample { .. } => p.health.mark(sample_rate),
                LinkEvent::Malformed { error, .. } => errors.report(p, &error.to_string()),
                LinkEvent::OutOfRange { error, .. } => {
                    errors.report(p, &format!("value out of range: {error}"))
                }
                // Once per outage each: always worth a line.
                LinkEvent::Lost { reason, .. } | LinkEvent::OpenFailed { reason, .. } => {
                    p.health.error(reason)
                }
            }
            if let Some(msg) = core.on_event(ev) {
                publish(p, &mut publisher, &msg, &clock)?;
                p.health.mark(publish_rate);
            }
        }
        if let Some(msg) = core.on_idle(clock.now_ns()) {
            publish(p, &mut publisher, &msg, &clock)?;
            p.health.mark(publish_rate);
        }

        let now_ns = clock.now_ns();
        report_health(p, &core, &link, now_ns);
        let state = core.last_reading().map(|r| r.state);
        if state != shown_state {
            shown_state = state;
            if let Some(s) = state {
                tracing::info!(state = ?s, "sensor state");
                p.status(&format!("sensor {s:?}; {}", link.describe()));
            }
        }
        p.tick()?;
    }
    Ok(())
}

fn publish(
    p: &mut Process,
    publisher: &mut smokenav_platform_bus::Publisher<SmokeReading>,
    msg: &SmokeReading,
    clock: &MonotonicClock,
) -> anyhow::Result<()> {
    publisher.publish(msg)?;
    // Measurement (the read) to publication.
    p.health.record_latency(Duration::from_nanos(
        clock.now_ns().saturating_sub(msg.header.stamp_ns),
    ));
    Ok(())
}

fn report_health(p: &mut Process, core: &DriverCore, link: &Link, now_ns: u64) {
    let c = *core.counters();
    let h = &mut p.health;
    h.set_state(core.health_state(now_ns));
    h.set_metric("parse_errors", c.parse_errors as f64);
    h.set_metric("checksum_errors", c.checksum_errors as f64);
    h.set_metric("overlong_lines", c.overlong_lines as f64);
    h.set_metric("out_of_range", c.out_of_range as f64);
    h.set_metric("device_losses", c.losses as f64);
    h.set_metric("reconnects", c.connects.saturating_sub(1) as f64);
    h.set_metric("open_failures", c.open_failures as f64);
    h.set_metric("samples", c.samples as f64);
    h.set_metric("link_up", f64::from(u8::from(link.is_open())));
    h.set_metric(
        "baseline_known",
        f64::from(u8::from(core.baseline_mv().is_some())),
    );
    h.set_metric("baseline_mv", core.baseline_mv().unwrap_or(0.0));
    h.set_metric("warmup_left_s", core.warmup_left_s(now_ns));
    if let Some(r) = core.last_reading() {
        let msg = smokenav_smoke_driver::core::to_message(r);
        h.set_metric("sensor_state", f64::from(msg.state));
        h.set_metric("trend", f64::from(msg.trend));
        h.set_metric("level", r.level);
        h.set_metric("raw_mv", r.raw_mv);
    }
    if let Link::Serial(s) = link {
        let d = s.decoder_stats();
        h.set_metric("comment_lines", d.comments as f64);
        h.set_metric("skipped_bytes", d.skipped_bytes as f64);
    }
}
