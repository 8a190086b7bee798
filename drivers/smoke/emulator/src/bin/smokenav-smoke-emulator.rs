//! Runs an emulated MQ303A ADC board: on a PTY (serial) or as a fake IIO
//! directory.
//!
//! ```text
//! smokenav-smoke-emulator serial --link /tmp/smoke-adc --puff 10:12
//! smokenav-smoke-emulator iio --dir /tmp/iio/iio:device0 --bits 12
//! ```
//!
//! Prints `ready <path>` on stdout once the device exists. Reads fault
//! commands from stdin, one per line: `garbage N`, `out-of-range N`,
//! `sensor-off SECS`, `unplug SECS` (`vanish SECS` for IIO), `profile
//! t:ppm,…` (start a concentration profile now), `quit`.
//! Stops on `quit`, SIGINT, SIGTERM or after `--duration`, printing counters.

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand};
use nix::sys::signal::{SigSet, Signal};
use smokenav_smoke_codec::{AdcScale, Eol};
use smokenav_smoke_emulator::{
    BoardConfig, Command, FakeIio, Fault, IioConfig, Profile, SensorParams, SerialConfig,
    SerialEmulator, ValueFormat,
};
use std::io::BufRead;
use std::path::PathBuf;
use std::sync::mpsc;
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(version, about = "Emulated MQ303A smoke sensor ADC board")]
struct Cli {
    #[command(subcommand)]
    backend: Backend,
}

#[derive(Subcommand)]
enum Backend {
    /// An Arduino-class board printing sample lines on a pseudo-terminal.
    Serial {
        /// Symlink to create, pointing at the PTY slave.
        #[arg(long)]
        link: PathBuf,
        /// Print millivolts (`A0:2998.4mV`) instead of counts.
        #[arg(long)]
        millivolts: bool,
        /// Append a `*XX` checksum to each line.
        #[arg(long)]
        checksum: bool,
        /// End lines with LF only (default CR LF, like Arduino's println).
        #[arg(long)]
        lf: bool,
        /// No `#` banner at (re)connect.
        #[arg(long)]
        no_banner: bool,
        #[command(flatten)]
        common: Common,
    },
    /// A fake IIO device directory.
    Iio {
        /// Device directory to create (must not exist), e.g. /tmp/x/iio:device0.
        #[arg(long)]
        dir: PathBuf,
        /// Write the shared `in_voltage_scale` instead of the per-channel one.
        #[arg(long)]
        shared_scale: bool,
        /// Write `in_voltageN_offset` with this many counts.
        #[arg(long, allow_hyphen_values = true)]
        offset: Option<i32>,
        #[command(flatten)]
        common: Common,
    },
}

#[derive(Args)]
struct Common {
    /// Samples per second.
    #[arg(long, default_value_t = 10.0)]
    rate: f64,
    #[arg(long, default_value_t = 0)]
    channel: u8,
    /// ADC reference, mV.
    #[arg(long, default_value_t = 5000.0)]
    vref: f64,
    /// ADC resolution, bits.
    #[arg(long, default_value_t = 10)]
    bits: u8,
    /// Concentration profile `t:ppm,t:ppm,…` (ppm alcohol-equivalent).
    #[arg(long, conflicts_with = "puff")]
    profile: Option<Profile>,
    /// A smoke puff `START_S:PEAK_PPM` (1 s rise, 5 s hold, 1 s clear).
    #[arg(long)]
    puff: Option<String>,
    /// Sensor output noise, σ in mV.
    #[arg(long, default_value_t = 2.0)]
    noise: f64,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Heater warm-up of the emulated sensor, s (0: starts warm).
    #[arg(long, default_value_t = 0.0)]
    warmup: f64,
    /// Scheduled fault `T:KIND:ARG`, e.g. `5:garbage:3`, `8:unplug:2`.
    #[arg(long = "fault")]
    faults: Vec<String>,
    /// Stop after this many seconds.
    #[arg(long)]
    duration: Option<f64>,
}

impl Common {
    fn board(&self) -> Result<BoardConfig> {
        let adc = AdcScale::new(self.vref, self.bits).context("--vref/--bits")?;
        let profile = match (&self.profile, &self.puff) {
            (Some(p), _) => p.clone(),
            (None, Some(puff)) => {
                let (start, peak) = puff
                    .split_once(':')
                    .and_then(|(s, p)| Some((s.parse::<f64>().ok()?, p.parse::<f64>().ok()?)))
                    .with_context(|| format!("--puff expects START_S:PEAK_PPM, got {puff:?}"))?;
                Profile::puff(start, peak, 1.0, 5.0, 1.0)
            }
            (None, None) => Profile::clean(),
        };
        Ok(BoardConfig {
            adc,
            sensor: SensorParams {
                warmup_s: self.warmup,
                ..SensorParams::default()
            },
            profile,
            noise_mv: self.noise,
            seed: self.seed,
            warm_start: self.warmup <= 0.0,
        })
    }

    fn schedule(&self) -> Result<Vec<(f64, Fault)>> {
        self.faults
            .iter()
            .map(|f| {
                let (t, rest) = f
                    .split_once(':')
                    .with_context(|| format!("--fault expects T:KIND:ARG, got {f:?}"))?;
                let t: f64 = t
                    .parse()
                    .with_context(|| format!("--fault time in {f:?}"))?;
                Ok((t, rest.parse::<Fault>()?))
            })
            .collect()
    }
}

enum Event {
    Command(Command),
    Quit(&'static str),
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let cli = Cli::parse();

    // Block the stop signals in every thread and take them with sigwait in
    // one, so shutdown removes the link instead of leaving it dangling.
    let mut stop_signals = SigSet::empty();
    stop_signals.add(Signal::SIGINT);
    stop_signals.add(Signal::SIGTERM);
    stop_signals.thread_block()?;

    let (tx, rx) = mpsc::channel();
    let sig_tx = tx.clone();
    std::thread::spawn(move || {
        if stop_signals.wait().is_ok() {
            let _ = sig_tx.send(Event::Quit("signal"));
        }
    });

    let (common, running): (&Common, Box<dyn Running>) = match &cli.backend {
        Backend::Serial {
            link,
            millivolts,
            checksum,
            lf,
            no_banner,
            common,
        } => {
            let cfg = SerialConfig {
                rate_hz: common.rate,
                channel: common.channel,
                format: if *millivolts {
                    ValueFormat::Millivolts
                } else {
                    ValueFormat::Counts
                },
                checksum: *checksum,
                eol: if *lf { Eol::Lf } else { Eol::CrLf },
                banner: !no_banner,
                schedule: common.schedule()?,
                ..SerialConfig::new(common.board()?)
            };
            let emu = SerialEmulator::start(link.clone(), cfg)
                .with_context(|| format!("creating the PTY at {}", link.display()))?;
            (common, Box::new(emu))
        }
        Backend::Iio {
            dir,
            shared_scale,
            offset,
            common,
        } => {
            let cfg = IioConfig {
                rate_hz: common.rate,
                channel: common.channel,
                offset: *offset,
                shared_scale: *shared_scale,
                schedule: common.schedule()?,
                ..IioConfig::new(common.board()?)
            };
            let emu = FakeIio::start_at(dir, cfg)
                .with_context(|| format!("creating the IIO directory {}", dir.display()))?;
            (common, Box::new(emu))
        }
    };
    println!("ready {}", running.path().display());

    std::thread::spawn(move || {
        for line in std::io::stdin().lock().lines() {
            let Ok(line) = line else { break };
            let cmd = line.trim();
            if cmd.is_empty() {
                continue;
            }
            let parsed = if cmd == "quit" {
                Ok(Event::Quit("quit command"))
            } else if let Some(spec) = cmd.strip_prefix("profile ") {
                spec.parse::<Profile>()
                    .map(|p| Event::Command(Command::Profile(p)))
                    .map_err(|e| e.to_string())
            } else {
                cmd.parse::<Fault>()
                    .map(|f| Event::Command(Command::Fault(f)))
                    .map_err(|e| e.to_string())
            };
            let event = match parsed {
                Ok(e) => e,
                Err(e) => {
                    eprintln!("{e}");
                    continue;
                }
            };
            if tx.send(event).is_err() {
                break;
            }
        }
    });

    let deadline = common
        .duration
        .map(|d| Instant::now() + Duration::from_secs_f64(d.max(0.0)));
    let why = loop {
        let wait = deadline.map_or(Duration::from_secs(3600), |d| {
            d.saturating_duration_since(Instant::now())
        });
        match rx.recv_timeout(wait) {
            Ok(Event::Command(c)) => running.command(c),
            Ok(Event::Quit(why)) => break why,
            Err(mpsc::RecvTimeoutError::Timeout) if deadline.is_some() => break "duration",
            Err(mpsc::RecvTimeoutError::Timeout) => continue,
            Err(mpsc::RecvTimeoutError::Disconnected) => bail!("control channels closed"),
        }
    };
    println!("stopping ({why}): {}", running.finish());
    Ok(())
}

/// What main needs from either emulator.
trait Running {
    fn path(&self) -> &std::path::Path;
    fn command(&self, c: Command);
    fn finish(self: Box<Self>) -> String;
}

impl Running for SerialEmulator {
    fn path(&self) -> &std::path::Path {
        SerialEmulator::path(self)
    }
    fn command(&self, c: Command) {
        SerialEmulator::command(self, c)
    }
    fn finish(self: Box<Self>) -> String {
        format!("{:?}", self.stop())
    }
}

impl Running for FakeIio {
    fn path(&self) -> &std::path::Path {
        self.device_path()
    }
    fn command(&self, c: Command) {
        FakeIio::command(self, c)
    }
    fn finish(self: Box<Self>) -> String {
        format!("{:?}", self.stop())
    }
}
