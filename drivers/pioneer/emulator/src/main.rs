//! `smokenav-pioneer-emulator`: a P3-DX controller on a PTY or a TCP port,
//! for bench work without a robot or MobileSim. It drives itself from the
//! velocity commands it receives; Ctrl-C stops it and removes the symlink.

use clap::Parser;
use nix::sys::signal::{SigSet, Signal};
use smokenav_pioneer_emulator::{Emulator, RobotConfig, SonarMode};
use std::path::PathBuf;
use std::time::Duration;

#[derive(Parser)]
#[command(name = "smokenav-pioneer-emulator", version, about)]
struct Args {
    /// Serve a pseudo-terminal reachable through this symlink (e.g. /tmp/pioneer).
    #[arg(long, conflicts_with = "tcp")]
    pty: Option<PathBuf>,
    /// Serve TCP on this address, like MobileSim (e.g. 127.0.0.1:8101).
    #[arg(long)]
    tcp: Option<String>,
    /// Subclass reported in SYNC2 (selects DistConvFactor on the host).
    #[arg(long, default_value = "p3dx")]
    subclass: String,
    /// Conversion factors to emulate when --subclass is not a known one
    /// (e.g. --subclass box --factors-from p3dx, like MobileSim's box model).
    #[arg(long)]
    factors_from: Option<String>,
    /// 8 (front array) or 16 sonars.
    #[arg(long, default_value_t = 16)]
    sonars: u8,
    /// Send only this many sonars per SIP, round-robin (0: all, like AMRISim).
    #[arg(long, default_value_t = 0)]
    sonars_per_sip: u8,
    /// Firmware watchdog, ms (0: off).
    #[arg(long, default_value_t = 2000)]
    watchdog_ms: u16,
    /// Start with a session left open (SIPs before any SYNC).
    #[arg(long)]
    stale_session: bool,
    /// SIPs without the optional trailing fields (older firmware).
    #[arg(long)]
    legacy_sip: bool,
    /// Range every sonar reports, mm (5000 = no echo).
    #[arg(long, default_value_t = 5000)]
    sonar_range_mm: u16,
}

fn main() -> anyhow_like::Result {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let args = Args::parse();
    let cfg = RobotConfig {
        subclass: args.subclass,
        factors_from: args.factors_from,
        sonar_count: args.sonars,
        sonar_mode: if args.sonars_per_sip == 0 {
            SonarMode::All
        } else {
            SonarMode::Cycle {
                per_sip: args.sonars_per_sip,
            }
        },
        watchdog_ms: args.watchdog_ms,
        start_open: args.stale_session,
        legacy_sip: args.legacy_sip,
        ..RobotConfig::default()
    };
    // Block the stop signals before any thread starts so only sigwait sees them.
    let mut signals = SigSet::empty();
    signals.add(Signal::SIGINT);
    signals.add(Signal::SIGTERM);
    signals
        .thread_block()
        .map_err(|e| format!("cannot block signals: {e}"))?;
    let emu = match (&args.pty, &args.tcp) {
        (Some(link), _) => Emulator::pty(link, cfg),
        (None, Some(addr)) => Emulator::tcp(addr, cfg),
        (None, None) => return Err("give --pty PATH or --tcp ADDR".into()),
    }
    .map_err(|e| e.to_string())?;
    emu.handle().set_sonar_ranges(&[args.sonar_range_mm; 32]);
    // The port for a driver's --port, on stdout for scripts.
    println!("{}", emu.port_arg());
    let sig = signals.wait().map_err(|e| format!("sigwait: {e}"))?;
    tracing::info!("{sig:?}: stopping");
    drop(emu);
    std::thread::sleep(Duration::from_millis(10));
    Ok(())
}

/// A string error is all this small binary needs.
mod anyhow_like {
    pub type Result = std::result::Result<(), String>;
}
