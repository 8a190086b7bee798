//! `smokenav-scout`: the Nomad Scout driver process.
//!
//! Thin wiring: the profile to a [`CoreConfig`], the bus (`base/odom`,
//! `base/sonar` out, `base/cmd_vel` in) and health around
//! [`smokenav_scout_driver::Driver`], which owns the port, the cycle and reconnects.

use clap::Parser;
use smokenav_platform_bus::{Publisher, Subscriber, WaitOutcome, Waiter, topics};
use smokenav_platform_runtime::{CommonArgs, Process, RateId, Report};
use smokenav_scout_codec::StateSi;
use smokenav_scout_driver::{
    CoreConfig, Driver, DriverConfig, DriverEvent, DriverSink, DriverStatus, PortSpec, ScoutCore,
};
use smokenav_shared_types::clock::monotonic_now_ns;
use smokenav_shared_types::{HealthState, Odometry, SonarRing, VelocityCommand};
use std::process::ExitCode;
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(
    version,
    about = "Nomad Scout driver: odometry and 16 sonars out, velocity commands in"
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    smokenav_platform_runtime::main("scout", &args.common, run)
}

struct BusSink<'a> {
    p: &'a mut Process,
    port: String,
    odom_pub: Publisher<Odometry>,
    sonar_pub: Publisher<SonarRing>,
    cmd_sub: &'a Subscriber<VelocityCommand>,
    /// Wakes on velocity commands (`cmd_sub` is attached to it).
    waiter: &'a Waiter,
    odom_rate: RateId,
    estop: bool,
}

impl DriverSink for BusSink<'_> {
    fn wait_until(&mut self, until: Instant, core: &mut ScoutCore) -> anyhow::Result<()> {
        loop {
            while let Some(c) = self.cmd_sub.receive()? {
                core.on_velocity(&c, monotonic_now_ns());
            }
            let left = until.saturating_duration_since(Instant::now());
            if left.is_zero() || self.p.shutdown_requested() {
                return Ok(());
            }
            if self.waiter.wait(Some(left))? == WaitOutcome::Shutdown {
                return Ok(());
            }
        }
    }

    fn publish(
        &mut self,
        odom: &Odometry,
        ring: &SonarRing,
        si: &StateSi,
        received: Instant,
    ) -> anyhow::Result<()> {
        self.odom_pub.publish(odom)?;
        self.sonar_pub.publish(ring)?;
        let h = &mut self.p.health;
        h.mark(self.odom_rate);
        h.record_latency(received.elapsed());
        h.set_metric("battery_v", si.motor_v);
        h.set_metric("cpu_v", si.cpu_v);
        h.set_metric("bumpers", si.bumpers as f64);
        if si.motor.estop() != self.estop {
            self.estop = si.motor.estop();
            if self.estop {
                h.set_state(HealthState::Degraded);
                h.error("e-stop pressed");
            } else {
                h.set_state(HealthState::Ok);
                h.clear_error();
            }
        }
        Ok(())
    }

    fn event(&mut self, event: DriverEvent<'_>) {
        let streaming = format!("streaming from {}", self.port);
        match event {
            DriverEvent::Connected { first: true } => self.p.ready(&streaming),
            DriverEvent::Connected { first: false } => {
                tracing::info!("link to {} restored", self.port);
                self.p.health.set_state(HealthState::Ok);
                self.p.status(&streaming);
            }
            DriverEvent::Lost(_) => self.p.status("reconnecting"),
            DriverEvent::DeadlineMissed => self.p.health.deadline_missed(),
        }
    }

    fn idle(&mut self, status: &DriverStatus<'_>) -> bool {
        status.report(&mut self.p.health);
        status
            .link
            .report(&mut self.p.health, &self.port, monotonic_now_ns());
        if let Err(e) = self.p.tick() {
            tracing::warn!("health: {e:#}");
        }
        self.p.shutdown_requested()
    }
}

fn run(p: &mut Process) -> anyhow::Result<()> {
    let core = ScoutCore::new(CoreConfig::from_profile(&p.config)?);
    let base = &p.config.base;
    let rate_hz = base.rate_hz;
    let cfg = DriverConfig {
        port: PortSpec::parse(p.port(&base.port)),
        baud: base.baud,
        period: Duration::from_secs_f64(1.0 / rate_hz),
        link_timeout: Duration::from_secs_f64(base.link_timeout_s),
    };
    p.health.set_metric("baud", f64::from(cfg.baud));
    let cmd_sub = p.bus.subscriber(topics::BASE_CMD_VEL)?;
    let waiter = Waiter::new()?;
    let _attached = waiter.attach(&cmd_sub)?;
    let mut sink = BusSink {
        port: cfg.port.to_string(),
        odom_pub: p.bus.publisher(topics::BASE_ODOM)?,
        sonar_pub: p.bus.publisher(topics::BASE_SONAR)?,
        cmd_sub: &cmd_sub,
        waiter: &waiter,
        odom_rate: p.health.add_rate("odom_hz", Some(rate_hz)),
        estop: false,
        p,
    };
    Driver::new(core, cfg).run(&mut sink)
}
