use crate::args::CommonArgs;
use crate::health::HealthReporter;
use crate::logging::init_logging;
use crate::shutdown::Shutdown;
use crate::systemd::SystemdNotifier;
use anyhow::Context;
use smokenav_platform_bus::{Bus, BusOptions};
use smokenav_platform_config::RobotConfig;
use smokenav_shared_types::HealthState;
use std::process::ExitCode;
use std::time::{Duration, Instant};

/// Exit status for a configuration error (sysexits EX_CONFIG). The units set
/// `RestartPreventExitStatus=78` so systemd does not restart-loop on a bad file.
pub const EXIT_CONFIG: u8 = 78;

/// A running smokenav process: its config, its bus connection and its health.
pub struct Process {
    /// The process role (`hokuyo`, `fusion`, …): its node and health topic name.
    pub role: String,
    /// The robot profile it was started with.
    pub config: RobotConfig,
    /// Its connection to the bus.
    pub bus: Bus,
    /// Its health report, published periodically.
    pub health: HealthReporter,
    /// `--port` if given.
    pub port_override: Option<String>,
    shutdown: Shutdown,
    systemd: SystemdNotifier,
}

impl Process {
    /// Loads the config and opens the bus. Logging must already be initialised.
    pub fn start(role: &str, args: &CommonArgs) -> anyhow::Result<Self> {
        let shutdown = Shutdown::install().context("cannot install signal handlers")?;
        let mut config = RobotConfig::load(&args.config)
            .map_err(|e| anyhow::anyhow!(ConfigFailure(e.to_string())))?;
        if let Some(inst) = &args.instance {
            config.robot.instance = inst.clone();
        }
        let opts = BusOptions::new(&config.robot.instance, role)
            .with_root_path(config.bus.root_path.clone());
        let bus = Bus::open(&opts).with_context(|| {
            format!(
                "cannot join the bus as `{role}` (instance `{}`)",
                config.robot.instance
            )
        })?;
        let period = Duration::from_secs_f64(config.bus.health_period_s);
        let mut health = HealthReporter::new(&bus, role, period)
            .with_context(|| format!("cannot publish health/{role}"))?;
        health.set_rate_floor(config.bus.health_rate_floor);
        health.set_state(HealthState::Starting);
        health.publish_now(Instant::now())?;
        tracing::info!(
            instance = %config.robot.instance,
            config = %args.config.display(),
            "{role} starting"
        );
        Ok(Self {
            role: role.to_owned(),
            config,
            bus,
            health,
            port_override: args.port.clone(),
            shutdown,
            systemd: SystemdNotifier::new(),
        })
    }

    /// The device to open: `--port` if given, else the configured one.
    pub fn port<'a>(&'a self, configured: &'a str) -> &'a str {
        self.port_override.as_deref().unwrap_or(configured)
    }

    /// Whether SIGTERM or SIGINT arrived.
    pub fn shutdown_requested(&self) -> bool {
        self.shutdown.requested()
    }

    /// A clonable handle, for threads that must notice shutdown.
    pub fn shutdown(&self) -> Shutdown {
        self.shutdown.clone()
    }

    /// Tells systemd we are up (after the device answered) and reports health `ok`.
    pub fn ready(&mut self, status: &str) {
        self.systemd.ready(status);
        if self.health.state() == HealthState::Starting {
            self.health.set_state(HealthState::Ok);
        }
        tracing::info!("{}: {status}", self.role);
    }

    /// Updates the one-line status `systemctl status` shows.
    pub fn status(&self, status: &str) {
        self.systemd.status(status);
    }

    /// Call from the main loop at least a few times per second: feeds the
    /// systemd watchdog and publishes health when due.
    pub fn tick(&mut self) -> anyhow::Result<()> {
        let now = Instant::now();
        self.systemd.tick(now);
        self.health.maybe_publish(now)?;
        Ok(())
    }

    fn stop(&mut self) {
        self.systemd.stopping();
        self.health.set_state(HealthState::Stopping);
        let _ = self.health.publish_now(Instant::now());
    }
}

/// An error that a configuration change must fix (bad profile, unknown robot
/// subclass): the process exits with [`EXIT_CONFIG`], which the units exclude
/// from automatic restarts. Return it (via `anyhow`) from the process body.
#[derive(Debug)]
pub struct ConfigFailure(pub String);

impl std::fmt::Display for ConfigFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ConfigFailure {}

/// Runs a process body with logging, config, bus, health and systemd set up;
/// turns errors into a logged message and an exit status.
pub fn main(
    role: &str,
    args: &CommonArgs,
    body: impl FnOnce(&mut Process) -> anyhow::Result<()>,
) -> ExitCode {
    init_logging(role);
    let mut process = match Process::start(role, args) {
        Ok(p) => p,
        Err(e) => {
            let is_config = e.downcast_ref::<ConfigFailure>().is_some();
            tracing::error!("{role}: {}", crate::error_line(&e));
            return ExitCode::from(if is_config { EXIT_CONFIG } else { 1 });
        }
    };
    let result = body(&mut process);
    process.stop();
    match result {
        Ok(()) => {
            tracing::info!("{role} stopped");
            ExitCode::SUCCESS
        }
        Err(e) => {
            tracing::error!("{role}: {}", crate::error_line(&e));
            if e.downcast_ref::<ConfigFailure>().is_some() {
                ExitCode::from(EXIT_CONFIG)
            } else {
                ExitCode::FAILURE
            }
        }
    }
}
