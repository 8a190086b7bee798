//! [`SimLink`]: the world stepped against the host clock, feeding the emulators.

use crate::base::{BaseEmulator, BaseError};
use crate::laser::{LaserFeed, LaserFeedStats};
use crate::smoke::TransparentAdc;
use crate::timebase::{TimeBase, align_start};
use crate::truth::TruthTrack;
use smokenav_hokuyo_emulator as hokuyo;
use smokenav_platform_config::{Platform, RobotConfig};
use smokenav_shared_types::Clock;
use smokenav_sim_world::{
    Pose2, Scenario, SimError, SmokeSample, SonarSample, StepOutput, TruthSample, World,
};
use smokenav_smoke_emulator::{
    AdcScale, BoardConfig, Eol, SerialConfig, SerialEmulator, ValueFormat,
};
use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How far the world runs ahead of the host clock: a scan is handed to the
/// emulator when its sweep ends (83 ms after the sensor's timestamp, while the
/// world's frame for it is complete 12.5 ms + 100 ms after it), plus margin
/// for a descheduled thread.
pub const LEAD: Duration = Duration::from_millis(150);
/// The world advances (and the emulators are fed) in steps of this much sim time.
pub const STEP: Duration = Duration::from_millis(5);
/// Odometry poses kept to pick the one for "now" from.
const HISTORY: usize = 400;

#[derive(Debug, thiserror::Error)]
pub enum SimLinkError {
    #[error(transparent)]
    Sim(#[from] SimError),
    #[error("cannot create {}: {source}", path.display())]
    Dir {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("URG-04LX emulator: {0}")]
    Laser(std::io::Error),
    #[error(transparent)]
    Base(#[from] BaseError),
    #[error("smoke ADC emulator: {0}")]
    Smoke(std::io::Error),
    #[error("robot profile: [smoke] ADC: {0}")]
    Adc(String),
}

/// How to run.
#[derive(Clone)]
pub struct SimLinkConfig {
    pub scenario: Scenario,
    /// Where the devices' stable symlinks go (`hokuyo`, `pioneer`/`scout`, `smoke-adc`).
    pub dev_dir: PathBuf,
    /// Sim seconds per host second. The emulated devices keep their real
    /// rates, so at 2× each scan shows the world 200 ms after the last one.
    pub speed: f64,
    /// The host clock the drivers stamp with (and the emulators run on).
    pub clock: Arc<dyn Clock>,
}

impl SimLinkConfig {
    pub fn new(scenario: Scenario, dev_dir: impl Into<PathBuf>) -> Self {
        Self {
            scenario,
            dev_dir: dev_dir.into(),
            speed: 1.0,
            clock: Arc::new(smokenav_shared_types::MonotonicClock),
        }
    }
}

/// Where each emulated device is.
#[derive(Debug, Clone, PartialEq)]
pub struct Devices {
    pub platform: Platform,
    /// Stable paths a driver opens.
    pub laser: String,
    pub base: String,
    pub smoke: String,
    /// The pseudo-terminals behind them right now.
    pub laser_pty: Option<PathBuf>,
    pub base_pty: Option<PathBuf>,
    pub smoke_pty: Option<PathBuf>,
}

/// When a run ends.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Until {
    /// The scenario's `duration_s`.
    ScenarioEnd,
    /// The scripted route is complete (plus one second for the last data), or the scenario ends.
    RouteDone,
    /// This many sim seconds (or the scenario's end, if sooner).
    SimSeconds(f64),
}

/// A look at the run, once per step.
#[derive(Debug, Clone, Copy)]
pub struct Progress {
    pub timebase: TimeBase,
    /// Sim time the emulators are at, s.
    pub sim_s: f64,
    pub duration_s: f64,
    pub truth: Pose2,
    /// True smoke concentration at the robot, g/m³.
    pub smoke_gpm3: f64,
    /// The velocity the base runs at when driven by commands.
    pub commanded: Option<(f64, f64)>,
}

/// What a run did.
#[derive(Debug, Clone, Copy)]
pub struct RunSummary {
    pub timebase: TimeBase,
    /// Sim time reached, s.
    pub sim_s: f64,
    pub wall: Duration,
    pub stopped: bool,
    pub laser: LaserFeedStats,
    /// Times the loop was held up for longer than the lead (the devices may have been fed late).
    pub overruns: u64,
    pub truth_samples: usize,
}

/// The world and the emulators it feeds.
pub struct SimLink {
    world: World,
    laser_emu: hokuyo::Emulator,
    laser: LaserFeed,
    base: BaseEmulator,
    smoke_emu: SerialEmulator,
    smoke_adc: TransparentAdc,
    clock: Arc<dyn Clock>,
    speed: f64,
    by_commands: bool,
    truth: TruthTrack,
    dev_dir: PathBuf,
    timebase: Option<TimeBase>,
}

/// The world's MQ303A output in clean air, as counts of the profile's ADC
/// (the sim's own rounding: `round(mv / vref · (2^bits − 1))`).
fn clean_air_counts(s: &Scenario) -> u32 {
    let full = ((1u64 << s.adc_bits.min(31)) - 1) as f64;
    (s.smoke_sensor.sensor.clean_air_mv() / s.adc_vref_mv * full)
        .round()
        .clamp(0.0, full) as u32
}

impl SimLink {
    /// Creates the world and starts the emulators (idle: no echo, robot at the
    /// origin, clean air) so drivers can connect before the world runs.
    pub fn start(cfg: SimLinkConfig) -> Result<Self, SimLinkError> {
        std::fs::create_dir_all(&cfg.dev_dir).map_err(|source| SimLinkError::Dir {
            path: cfg.dev_dir.clone(),
            source,
        })?;
        let scenario = cfg.scenario;
        let profile = scenario.profile.clone();
        let seed = scenario.seed;
        let by_commands = scenario.route.is_none();

        let laser_emu = hokuyo::Emulator::spawn(hokuyo::EmulatorConfig {
            device: hokuyo::DeviceConfig {
                seed: seed | 1,
                ..hokuyo::DeviceConfig::default()
            },
            endpoint: hokuyo::Endpoint::Pty {
                link: Some(cfg.dev_dir.join("hokuyo")),
            },
            clock: cfg.clock.clone(),
        })
        .map_err(SimLinkError::Laser)?;
        let laser = LaserFeed::new(&laser_emu.spec().geometry, cfg.clock.clone());
        laser_emu.set_scan_source(laser.clone());

        let base_link = cfg.dev_dir.join(profile.robot.platform.driver_role());
        let mut base = BaseEmulator::start(&profile, &base_link, cfg.clock.clone(), seed)?;
        base.set_odometry(&Pose2::default());
        base.clear_sonar(profile.sonar.count);

        let adc = AdcScale::new(profile.smoke.vref_mv, profile.smoke.adc_bits)
            .map_err(|e| SimLinkError::Adc(e.to_string()))?;
        let smoke_adc = TransparentAdc::new(adc);
        let smoke_emu = SerialEmulator::start(
            cfg.dev_dir.join("smoke-adc"),
            SerialConfig {
                board: BoardConfig {
                    adc,
                    sensor: smoke_adc.sensor,
                    profile: smoke_adc.profile_for_counts(clean_air_counts(&scenario)),
                    // The world's sensor model adds the noise.
                    noise_mv: 0.0,
                    seed: seed | 1,
                    warm_start: true,
                },
                rate_hz: scenario.smoke_rate_hz,
                channel: profile.smoke.channel,
                format: ValueFormat::Counts,
                checksum: profile.smoke.require_checksum,
                eol: Eol::CrLf,
                banner: true,
                schedule: Vec::new(),
            },
        )
        .map_err(SimLinkError::Smoke)?;

        let world = World::new(scenario)?;
        Ok(Self {
            world,
            laser_emu,
            laser,
            base,
            smoke_emu,
            smoke_adc,
            clock: cfg.clock,
            speed: if cfg.speed.is_finite() && cfg.speed > 0.0 {
                cfg.speed
            } else {
                1.0
            },
            by_commands,
            truth: TruthTrack::default(),
            dev_dir: cfg.dev_dir,
            timebase: None,
        })
    }

    pub fn world(&self) -> &World {
        &self.world
    }

    pub fn scenario(&self) -> &Scenario {
        self.world.scenario()
    }

    /// True when the base's velocity commands move the robot (the scenario has no route).
    pub fn driven_by_commands(&self) -> bool {
        self.by_commands
    }

    pub fn dev_dir(&self) -> &Path {
        &self.dev_dir
    }

    pub fn devices(&self) -> Devices {
        let smoke_stats = self.smoke_emu.stats();
        Devices {
            platform: self.base.platform(),
            laser: self.laser_emu.port(),
            base: self.base.port(),
            smoke: self.smoke_emu.path().display().to_string(),
            laser_pty: self.laser_emu.slave_path(),
            base_pty: self.base.device(),
            smoke_pty: smoke_stats.device,
        }
    }

    /// The scenario's robot profile with the drivers pointed at the emulated
    /// devices. The world's MQ303A starts warm, so the smoke driver's warm-up
    /// is off unless the scenario asks for a cold sensor.
    pub fn driver_profile(&self, instance: Option<&str>) -> RobotConfig {
        let mut p = self.scenario().profile.clone();
        let d = self.devices();
        p.laser.port = d.laser;
        p.base.port = d.base;
        p.smoke.port = d.smoke;
        p.smoke.backend = Some(smokenav_platform_config::AdcBackend::Serial);
        if !self.scenario().smoke_sensor.cold_start {
            p.smoke.warmup_s = 0.0;
        }
        if let Some(i) = instance {
            p.robot.instance = i.to_owned();
        }
        // Sped up, the emulated URG sweeps `speed` times faster in host time
        // than the period it reports, from which the driver derives each
        // beam's time: deskewed by it, every sweep would be corrected `speed`
        // times over, bending the walls the other way.
        if (self.speed - 1.0).abs() > 1e-9 {
            p.slam.deskew = false;
        }
        p
    }

    /// Writes [`SimLink::driver_profile`] to `path`.
    pub fn write_profile(&self, path: &Path, instance: Option<&str>) -> std::io::Result<()> {
        std::fs::write(path, self.driver_profile(instance).to_toml())
    }

    /// The ground truth so far: poses stamped in host time.
    pub fn truth(&self) -> &TruthTrack {
        &self.truth
    }

    /// The mapping between sim and host time, once the run started.
    pub fn timebase(&self) -> Option<TimeBase> {
        self.timebase
    }

    pub fn laser_stats(&self) -> LaserFeedStats {
        self.laser.stats()
    }

    /// Runs the world against the host clock until `until`, or `stop()` says
    /// so. Each true pose goes to `on_truth` with its host stamp when its time
    /// comes (publish it on the bus); `on_progress` sees every step.
    pub fn run(
        &mut self,
        until: Until,
        stop: &dyn Fn() -> bool,
        on_truth: &mut dyn FnMut(&TruthSample, u64),
        on_progress: &mut dyn FnMut(&Progress),
    ) -> RunSummary {
        let wall = Instant::now();
        let period = self.laser.period_ns();
        // Sim time 0 on the sensor's scan grid, so each scan's stamp is when the world measured it.
        if let Some(last) = self.laser_emu.sent_scans().last() {
            self.laser.set_epoch(last.scan_no, last.start_host_ns);
        }
        let not_before = self.clock.now_ns() + 20_000_000;
        let t0 = match self.laser.epoch() {
            Some(epoch) if (self.speed - 1.0).abs() < 1e-9 => {
                align_start(not_before, epoch, self.laser.rear_to_step0_ns(), period)
            }
            _ => not_before,
        };
        let tb = TimeBase::new(t0, self.speed);
        self.timebase = Some(tb);
        self.laser.set_timebase(tb);

        let duration_ns = (self.scenario().duration_s * 1e9) as u64;
        let end_ns = match until {
            Until::SimSeconds(s) if s.is_finite() && s > 0.0 => ((s * 1e9) as u64).min(duration_ns),
            _ => duration_ns,
        };
        let lead_ns = (LEAD.as_nanos() as f64 * self.speed) as u64;
        let step_ns = STEP.as_nanos() as u64;
        let mut route_done_at: Option<u64> = None;
        let mut sonar: VecDeque<SonarSample> = VecDeque::new();
        let mut smoke: VecDeque<SmokeSample> = VecDeque::new();
        let mut truth: VecDeque<TruthSample> = VecDeque::new();
        let mut history: VecDeque<(u64, Pose2)> = VecDeque::with_capacity(HISTORY);
        history.push_back((0, self.world.odometry_pose()));
        let mut out = StepOutput::default();
        let mut overruns = 0u64;
        let mut stopped = false;
        let mut sim_now = 0u64;
        loop {
            if stop() {
                stopped = true;
                break;
            }
            let now = self.clock.now_ns();
            let signed = tb.host_to_sim_signed(now);
            if signed < 0 {
                std::thread::sleep(Duration::from_nanos((-signed) as u64).min(STEP));
                continue;
            }
            sim_now = signed as u64;
            let end = match (until, route_done_at) {
                (Until::RouteDone, Some(t)) => (t + 1_000_000_000).min(end_ns),
                _ => end_ns,
            };
            if sim_now >= end {
                sim_now = end;
                break;
            }
            // The world ahead of the clock by the lead.
            let target = (sim_now + lead_ns).min(end);
            if target > self.world.time_ns() + lead_ns + step_ns {
                overruns += 1;
            }
            while self.world.time_ns() < target {
                out.clear();
                self.world.step_into(STEP, &mut out);
                for f in out.laser.drain(..) {
                    self.laser.push(f);
                }
                sonar.extend(out.sonar.drain(..));
                smoke.extend(out.smoke.drain(..));
                truth.extend(out.truth.drain(..));
                if history.len() == HISTORY {
                    history.pop_front();
                }
                history.push_back((self.world.time_ns(), self.world.odometry_pose()));
                if route_done_at.is_none() && self.world.route_done() {
                    route_done_at = Some(self.world.time_ns());
                }
            }
            // What the devices measure now.
            while let Some(s) = sonar.front().filter(|s| s.t_ns <= sim_now).copied() {
                sonar.pop_front();
                self.base.set_sonar(s.index, s.range_m, s.saturated);
            }
            while let Some(s) = smoke.front().filter(|s| s.t_ns <= sim_now).copied() {
                smoke.pop_front();
                self.smoke_emu
                    .set_profile(self.smoke_adc.profile_for_counts(s.adc_counts));
            }
            let mut latest_truth = None;
            while let Some(t) = truth.front().filter(|t| t.t_ns <= sim_now).copied() {
                truth.pop_front();
                let host = tb.sim_to_host(t.t_ns);
                self.truth.push(host, t.pose, t.smoke_gpm3);
                on_truth(&t, host);
                latest_truth = Some(t);
            }
            if let Some(&(_, pose)) = history.iter().rev().find(|(t, _)| *t <= sim_now) {
                self.base.set_odometry(&pose);
            }
            let commanded = if self.by_commands {
                let (v, w) = self.base.commanded();
                self.world.set_velocity_command(v, w);
                Some((v, w))
            } else {
                None
            };
            let t = latest_truth.or_else(|| self.truth.last_sample());
            on_progress(&Progress {
                timebase: tb,
                sim_s: sim_now as f64 * 1e-9,
                duration_s: self.scenario().duration_s,
                truth: t.map_or(self.scenario().start, |t| t.pose),
                smoke_gpm3: t.map_or(0.0, |t| t.smoke_gpm3),
                commanded,
            });
            // Sleep to the next step of the host clock.
            let next = tb.sim_to_host(sim_now + step_ns);
            let now = self.clock.now_ns();
            if next > now {
                std::thread::sleep(Duration::from_nanos(next - now).min(STEP));
            }
        }
        RunSummary {
            timebase: tb,
            sim_s: sim_now as f64 * 1e-9,
            wall: wall.elapsed(),
            stopped,
            laser: self.laser.stats(),
            overruns,
            truth_samples: self.truth.len(),
        }
    }

    /// Writes the true map (`truth.yaml` + `truth.pgm`) and the true
    /// trajectory (`truth.txt`, host-time stamps) to `dir`; returns their paths.
    pub fn write_truth(&self, dir: &Path) -> Result<(PathBuf, PathBuf), SimError> {
        let map = smokenav_sim_world::truth::write_map(&self.world.truth_map(), dir, "truth")?;
        let traj = dir.join("truth.txt");
        self.truth.write(&traj)?;
        Ok((map, traj))
    }
}
