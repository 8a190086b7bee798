//! `smokenav-hokuyo-emulator`: a URG-04LX on a pseudo-terminal (or TCP) for demos
//! and manual testing. Prints the port to open, serves a synthetic room until
//! SIGINT/SIGTERM.

use anyhow::Context;
use clap::Parser;
use nix::sys::signal::{SigSet, Signal};
use smokenav_hokuyo_emulator::{BootState, DeviceConfig, Emulator, EmulatorConfig, Link, Model};
use std::path::PathBuf;

#[derive(Parser)]
#[command(about = "Emulated Hokuyo URG-04LX / UTM-30LX-EW on a PTY or TCP")]
struct Args {
    /// Stable symlink to the PTY slave (like a udev name), e.g. /tmp/hokuyo.
    #[arg(long)]
    link: Option<PathBuf>,
    /// Serve TCP on this address instead of a PTY, e.g. 127.0.0.1:10940.
    #[arg(long)]
    tcp: Option<std::net::SocketAddr>,
    /// Emulate a UTM-30LX-EW instead of a URG-04LX.
    #[arg(long)]
    utm: bool,
    /// RS-232 link: the host must match the device's bit rate (19200 at power-up).
    #[arg(long)]
    rs232: bool,
    /// Start as if a previous host left MD streaming.
    #[arg(long)]
    streaming: bool,
    /// Fraction of data lines sent with a wrong checksum.
    #[arg(long, default_value_t = 0.0)]
    corrupt: f64,
    /// Side of the square room the sensor sits in the middle of, m.
    #[arg(long, default_value_t = 4.0)]
    room_m: f64,
}

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stdout()))
        .init();
    let args = Args::parse();
    // Block the stop signals before the emulator thread starts so only sigwait sees them.
    let mut stop = SigSet::empty();
    stop.add(Signal::SIGINT);
    stop.add(Signal::SIGTERM);
    stop.thread_block().context("blocking SIGINT/SIGTERM")?;

    let model = if args.utm {
        Model::Utm30lxEw
    } else {
        Model::Urg04lx
    };
    let device = DeviceConfig {
        model,
        link: if args.rs232 { Link::Rs232 } else { Link::Usb },
        boot: BootState {
            streaming: args.streaming,
            ..Default::default()
        },
        ..Default::default()
    };
    let cfg = match args.tcp {
        Some(addr) => EmulatorConfig {
            endpoint: smokenav_hokuyo_emulator::Endpoint::Tcp { addr },
            ..EmulatorConfig::tcp(device)
        },
        None => EmulatorConfig::pty(device, args.link.clone()),
    };
    let emu = Emulator::spawn(cfg).context("starting the emulator")?;
    let g = emu.spec().geometry;
    let half = args.room_m / 2.0;
    let room: Vec<u16> = (g.amin..=g.amax)
        .map(|s| {
            let a = g.step_angle(s);
            // Distance to the walls of a square room centred on the sensor.
            let d = half / a.cos().abs().max(a.sin().abs());
            (d * 1000.0).round().clamp(0.0, f64::from(u16::MAX)) as u16
        })
        .collect();
    emu.set_scan(&room);
    emu.set_corrupt_line_fraction(args.corrupt);
    println!("{}", emu.port());
    if let Some(slave) = emu.slave_path() {
        println!("slave: {}", slave.display());
    }
    let sig = stop.wait().context("waiting for a signal")?;
    tracing::info!("{sig:?}: stopping");
    Ok(())
}
