//! `smokenav-pioneer`: the Pioneer driver process.
//!
//! Thin wiring: the profile to a [`PioneerCore`], the bus (`base/odom`,
//! `base/sonar` out, `base/cmd_vel` in) and health around
//! [`smokenav_pioneer_driver::Driver`], which owns the port (serial device or
//! `tcp://host:port` for MobileSim/AMRISim), the ARCOS session and reconnects.

use clap::Parser;
use smokenav_pioneer_driver::link::{PortSpec, parse_port};
use smokenav_pioneer_driver::session::SessionEvent;
use smokenav_pioneer_driver::{CoreCounters, Driver, DriverSink, Output, PioneerCore};
use smokenav_platform_bus::{Publisher, Subscriber, topics};
use smokenav_platform_runtime::{CommonArgs, Process, RateId, Reconnect, Report};
use smokenav_shared_types::clock::monotonic_now_ns;
use smokenav_shared_types::{HealthState, Odometry, SonarRing, VelocityCommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    version,
    about = "Pioneer (ARCOS) driver: odometry and sonar out, velocity commands in; serial or tcp://host:8101 (MobileSim)"
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    smokenav_platform_runtime::main("pioneer", &args.common, run)
}

struct BusSink<'a> {
    p: &'a mut Process,
    spec: PortSpec,
    odom_pub: Publisher<Odometry>,
    sonar_pub: Publisher<SonarRing>,
    cmd_sub: Subscriber<VelocityCommand>,
    sip_rate: RateId,
    ever_running: bool,
}

impl DriverSink for BusSink<'_> {
    fn commands(&mut self, core: &mut PioneerCore) -> anyhow::Result<()> {
        // All that queued up; the newest wins.
        while let Some(c) = self.cmd_sub.receive()? {
            core.on_velocity(c.linear, c.angular, monotonic_now_ns());
        }
        Ok(())
    }

    fn output(&mut self, out: Output) -> anyhow::Result<()> {
        let h = &mut self.p.health;
        let event = match out {
            Output::Odometry(o) => {
                h.mark(self.sip_rate);
                self.odom_pub.publish(&o)?;
                return Ok(());
            }
            Output::Sonar(ring) => {
                self.sonar_pub.publish(&ring)?;
                return Ok(());
            }
            Output::Event(e) => *e,
        };
        match event {
            SessionEvent::Connected { ident, params } => tracing::info!(
                "connected: {} ({} {}), DistConvFactor {}",
                ident.name,
                ident.class,
                ident.subclass,
                params.dist_conv
            ),
            SessionEvent::Running => {
                let msg = format!("streaming from {}", self.spec);
                if self.ever_running {
                    tracing::info!("{msg}");
                } else {
                    self.p.ready(&msg);
                }
                self.ever_running = true;
                self.p.health.set_state(HealthState::Ok);
                self.p.status(&msg);
            }
            SessionEvent::Config(c) => {
                tracing::info!(
                    "controller config: watchdog {} ms, SIP cycle {} ms, firmware {}",
                    c.watchdog,
                    c.sip_cycle,
                    c.firmware_version.as_deref().unwrap_or("not reported")
                );
                h.set_metric("robot_watchdog_ms", f64::from(c.watchdog));
            }
            SessionEvent::StaleSessionClosed => {
                h.error("a previous session was left open (SIPs during SYNC): sent CLOSE, retrying")
            }
            SessionEvent::LinkLost { reason } => {
                h.error(&format!("link to {}: {reason}; handshake again", self.spec));
                h.set_state(HealthState::Degraded);
                self.p.status("reconnecting");
            }
            SessionEvent::Undecodable { packet_type, error } => {
                tracing::debug!("packet type 0x{packet_type:02X} did not decode: {error}");
            }
            SessionEvent::Fatal(e) => {
                // Only a profile change fixes it: exit 78, which systemd does not restart.
                h.set_state(HealthState::Error);
                h.error(&e.to_string());
                return Err(anyhow::anyhow!(smokenav_platform_runtime::ConfigFailure(
                    e.to_string()
                )));
            }
            SessionEvent::Sip(_) => {}
        }
        Ok(())
    }

    fn lost(&mut self, _why: &str) {
        self.p.status("reconnecting");
    }

    fn idle(&mut self, counters: &CoreCounters, link: &Reconnect) -> bool {
        counters.report(&mut self.p.health);
        link.report(
            &mut self.p.health,
            &self.spec.to_string(),
            monotonic_now_ns(),
        );
        if let Err(e) = self.p.tick() {
            tracing::warn!("health: {e:#}");
        }
        self.p.shutdown_requested()
    }
}

fn run(p: &mut Process) -> anyhow::Result<()> {
    let cfg = &p.config;
    let spec = parse_port(p.port(&cfg.base.port), cfg.base.baud)?;
    let core = PioneerCore::from_profile(cfg);
    p.status(&format!("connecting to {spec}"));
    let mut sink = BusSink {
        odom_pub: p.bus.publisher(topics::BASE_ODOM)?,
        sonar_pub: p.bus.publisher(topics::BASE_SONAR)?,
        cmd_sub: p.bus.subscriber(topics::BASE_CMD_VEL)?,
        sip_rate: p.health.add_rate("sip_hz", Some(p.config.base.rate_hz)),
        spec: spec.clone(),
        ever_running: false,
        p,
    };
    Driver::new(spec, core).run(&mut sink)
}
