//! `smokenav-fusion`: the SmokeNav fusion layer as a process.
//!
//! Subscribes to `laser/scan`, `base/sonar` and `smoke/level`, runs the
//! approximate-time synchroniser (with its timeout) and the configured method
//! (`[fusion] method` or `--method`: laser-only, v1, v2), and publishes one
//! `FusedScan` per synchronised set on `fusion/scan` — the laser's rate when
//! the sensors run at the same rate, as in the paper. Health on
//! `health/fusion`: method, smoke state, sonar usage, sync drops,
//! `speck_beams` (laser beams v2 dropped as specks of patchy smoke, total),
//! `vouched_beams` (laser beams v2 kept in sections it gave to the sonar,
//! which the sonar did not contradict, total),
//! `smoke_silent` (v2 fused the last set assuming smoke because the smoke
//! sensor sent nothing or flagged itself not ready; health degraded), and the
//! latency from the input that completed a set to its fused scan being
//! published (p50/p99/max per health period).
//!
//! ```text
//! smokenav-fusion --config robot.toml [--method v2]
//! ```

use anyhow::Context;
use clap::Parser;
use smokenav_algorithms_fusion::engine::StepReport;
use smokenav_algorithms_fusion::pipeline::{FusionPipeline, LASER, SMOKE, SONAR, TOPIC_NAMES};
use smokenav_algorithms_fusion::sync::DropReason;
use smokenav_platform_bus::{Publisher, WaitOutcome, Waiter, topics};
use smokenav_platform_runtime::{CommonArgs, HealthReporter, Process};
use smokenav_shared_types::{
    Clock, FusedScan, FusionMethod, HealthState, LaserScan, MonotonicClock, SmokeReading,
    SonarRing, SyncState,
};
use std::process::ExitCode;
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(
    version,
    about = "SmokeNav fusion: laser, sonar and smoke in, FusedScan on fusion/scan"
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// Fusion method, overriding `[fusion] method`.
    #[arg(long, value_enum)]
    method: Option<FusionMethod>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    smokenav_platform_runtime::main("fusion", &args.common, |p| run(p, args.method))
}

/// Where fused scans go, and what happened to them.
struct Output {
    publisher: Publisher<FusedScan>,
    publish_errors: u64,
}

impl Output {
    /// Publishes `f`; `trigger` is when the input that completed its set was
    /// received. Returns whether it went out.
    fn emit(&mut self, health: &mut HealthReporter, f: &FusedScan, trigger: Instant) -> bool {
        match self.publisher.publish(f) {
            Ok(_) => {
                health.record_latency(trigger.elapsed());
                true
            }
            Err(e) => {
                self.publish_errors += 1;
                health.error(&format!("cannot publish fusion/scan: {e}"));
                false
            }
        }
    }
}

fn run(p: &mut Process, method: Option<FusionMethod>) -> anyhow::Result<()> {
    let mut pipeline = FusionPipeline::from_config(&p.config, method)
        .context("the profile's sonar geometry is unusable")?;
    let method = pipeline.engine().method();
    let scans = p.bus.subscriber::<LaserScan>(topics::LASER_SCAN)?;
    let rings = p.bus.subscriber::<SonarRing>(topics::BASE_SONAR)?;
    let smoke = p.bus.subscriber::<SmokeReading>(topics::SMOKE_LEVEL)?;
    let mut out = Output {
        publisher: p.bus.publisher::<FusedScan>(topics::FUSION_SCAN)?,
        publish_errors: 0,
    };
    let rate = p.health.add_rate("fused_hz", Some(10.0));
    let waiter = Waiter::new()?;
    let _attached = [
        waiter.attach(&scans)?,
        waiter.attach(&rings)?,
        waiter.attach(&smoke)?,
    ];
    // Silent inputs are noticed by polling the synchroniser at least this often.
    let timeout = Duration::from_secs_f64(p.config.fusion.sync.timeout_s);
    let poll = (timeout / 5).clamp(Duration::from_millis(5), Duration::from_millis(100));
    let clock = MonotonicClock;
    p.ready(&format!(
        "fusing laser/scan, base/sonar, smoke/level with {}",
        method.as_str()
    ));
    let mut shown = String::new();
    while !p.shutdown_requested() {
        if waiter.wait(Some(poll))? == WaitOutcome::Shutdown {
            break;
        }
        let health = &mut p.health;
        while let Some(s) = scans.receive()? {
            let t0 = Instant::now();
            pipeline.push_laser(&s, clock.now_ns(), &mut |f: &FusedScan, _: &StepReport| {
                if out.emit(health, f, t0) {
                    health.mark(rate);
                }
            });
        }
        while let Some(s) = rings.receive()? {
            let t0 = Instant::now();
            pipeline.push_sonar(&s, clock.now_ns(), &mut |f: &FusedScan, _: &StepReport| {
                if out.emit(health, f, t0) {
                    health.mark(rate);
                }
            });
        }
        while let Some(s) = smoke.receive()? {
            let t0 = Instant::now();
            pipeline.push_smoke(&s, clock.now_ns(), &mut |f: &FusedScan, _: &StepReport| {
                if out.emit(health, f, t0) {
                    health.mark(rate);
                }
            });
        }
        let t0 = Instant::now();
        pipeline.poll(clock.now_ns(), &mut |f: &FusedScan, _: &StepReport| {
            if out.emit(health, f, t0) {
                health.mark(rate);
            }
        });
        let lost = scans.stats().lost + rings.stats().lost + smoke.stats().lost;
        let status = report(p, &pipeline, &out, lost);
        if status != shown {
            tracing::info!("{status}");
            p.status(&status);
            shown = status;
        }
        p.tick()?;
    }
    Ok(())
}

/// Refreshes the health metrics; returns a one-line status.
fn report(p: &mut Process, pipeline: &FusionPipeline, out: &Output, bus_lost: u64) -> String {
    let h = &mut p.health;
    let engine = pipeline.engine();
    let stats = pipeline.stats();
    let sync = pipeline.sync_counters();
    let active = pipeline.active();
    let last = pipeline.last_report();
    h.set_metric("method", f64::from(engine.method() as u8));
    h.set_metric("smoke_state", f64::from(engine.smoke_state().code()));
    h.set_metric("smoke_rising", f64::from(u8::from(engine.smoke_rising())));
    h.set_metric("sonar_usage", stats.sonar_usage());
    let last_usage = last.map_or(0.0, |r| {
        if r.sections == 0 {
            0.0
        } else {
            r.sonar_sections as f64 / r.sections as f64
        }
    });
    h.set_metric("sonar_usage_last", last_usage);
    h.set_metric(
        "rho_laser_last",
        last.map_or(0.0, |r| f64::from(r.rho_laser)),
    );
    let sync_state = last.map_or(SyncState::Complete, |r| r.sync_state);
    h.set_metric("sync_state", f64::from(sync_state as u8));
    h.set_metric("sync_drops", sync.dropped_all() as f64);
    for (topic, name) in [
        (LASER, "drops_laser"),
        (SONAR, "drops_sonar"),
        (SMOKE, "drops_smoke"),
    ] {
        h.set_metric(name, sync.dropped_total(topic) as f64);
    }
    let timeouts: u64 = (0..3).map(|t| sync.dropped(t, DropReason::Timeout)).sum();
    h.set_metric("sync_timeout_drops", timeouts as f64);
    h.set_metric("degraded_sets", sync.degraded_sets as f64);
    h.set_metric(
        "active_topics",
        active
            .iter()
            .rev()
            .fold(0.0, |m, &a| m * 2.0 + f64::from(u8::from(a))),
    );
    h.set_metric("fused_total", stats.outputs as f64);
    h.set_metric("skipped_sets", stats.skipped as f64);
    h.set_metric("bad_laser_layouts", stats.bad_layouts as f64);
    h.set_metric("speck_beams", stats.speck_beams as f64);
    h.set_metric("vouched_beams", stats.vouched_beams as f64);
    h.set_metric("bus_lost", bus_lost as f64);
    h.set_metric("publish_errors", out.publish_errors as f64);

    let silent: Vec<&str> = (0..3)
        .filter(|&t| !active[t])
        .map(|t| TOPIC_NAMES[t])
        .collect();
    let method = engine.method().as_str();
    // v2 fused the last set without a usable smoke reading (none arrived, or
    // the sensor is not ready): it assumed smoke; say so.
    let smoke_silent = last.is_some_and(|r| r.smoke_silent);
    h.set_metric("smoke_silent", f64::from(u8::from(smoke_silent)));
    if smoke_silent {
        let why = if active[SMOKE] {
            "smoke sensor not ready"
        } else {
            "smoke silent"
        };
        let text = format!("{why}: assuming smoke, sonar witness on in every section ({method})");
        h.error(&text);
        h.set_state(HealthState::Degraded);
        text
    } else if engine.method() != FusionMethod::LaserOnly && !silent.is_empty() {
        if h.state() == HealthState::Ok {
            h.error(&format!(
                "{} silent: output degraded to {}",
                silent.join(", "),
                sync_state.as_str()
            ));
            h.set_state(HealthState::Degraded);
        }
        format!(
            "{method}: {} silent, {}",
            silent.join(", "),
            sync_state.as_str()
        )
    } else {
        if h.state() == HealthState::Degraded {
            h.clear_error();
            h.set_state(HealthState::Ok);
        }
        format!(
            "{method}: {}, smoke {}",
            sync_state.as_str(),
            engine.smoke_state().as_str()
        )
    }
}
