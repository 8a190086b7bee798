//! An Arduino-class ADC board on a real pseudo-terminal.
//!
//! [`SerialEmulator`] opens a PTY pair (close-on-exec), puts the slave in raw mode and
//! points a stable symlink (e.g. `/tmp/x/smoke-adc`) at the slave, so a
//! driver opens the symlink exactly as it would `/dev/ttyACM0`. A thread
//! prints one line per tick in the [`smokenav_smoke_codec::line`] format. A board
//! unplug closes the PTY (the driver's reads fail) and removes the symlink;
//! the replug opens a fresh PTY (usually a different `/dev/pts/N`) and moves
//! the symlink to it, as udev does with a `/dev/serial/by-id` link.

use crate::board::{Board, BoardConfig, BoardStats, Command, Fault, Output};
use crate::model::Profile;
use smokenav_common_pty::{PtyOptions, PtyPair, PtyPort};
use smokenav_smoke_codec::line::xor_checksum;
use smokenav_smoke_codec::{Eol, Sample, SampleValue, encode_sample};
use std::collections::VecDeque;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How the board prints values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ValueFormat {
    /// `A0:614` raw counts.
    #[default]
    Counts,
    /// `A0:2998.4mV`, the board converting itself.
    Millivolts,
}

#[derive(Debug, Clone)]
pub struct SerialConfig {
    pub board: BoardConfig,
    /// Lines per second.
    pub rate_hz: f64,
    pub channel: u8,
    pub format: ValueFormat,
    pub checksum: bool,
    pub eol: Eol,
    /// Print a `#` banner line at every (re)connect, as a board does on reset.
    pub banner: bool,
    /// Faults to inject at given times (s since start).
    pub schedule: Vec<(f64, Fault)>,
}

impl SerialConfig {
    /// 10 Hz, channel 0, counts, CR LF (Arduino's `println`), with banner.
    pub fn new(board: BoardConfig) -> Self {
        Self {
            board,
            rate_hz: 10.0,
            channel: 0,
            format: ValueFormat::Counts,
            checksum: false,
            eol: Eol::CrLf,
            banner: true,
            schedule: Vec::new(),
        }
    }
}

/// The line(s) for one board output, or nothing.
pub fn render(out: &Output, cfg: &SerialConfig) -> Vec<u8> {
    let sample = |value| Sample {
        channel: cfg.channel,
        value,
    };
    let line = |value| {
        encode_sample(&sample(value), cfg.checksum, cfg.eol)
            .map(|l| l.as_bytes().to_vec())
            .unwrap_or_default()
    };
    match *out {
        Output::Offline => Vec::new(),
        Output::Sample { counts, mv } => match cfg.format {
            ValueFormat::Counts => line(SampleValue::Counts(counts)),
            ValueFormat::Millivolts => line(SampleValue::Millivolts(mv as f32)),
        },
        Output::OutOfRange { counts, mv } => match cfg.format {
            ValueFormat::Counts => line(SampleValue::Counts(counts.min(99_999_999) as u32)),
            ValueFormat::Millivolts => line(SampleValue::Millivolts(mv as f32)),
        },
        Output::Garbage { variant } => garbage(variant, cfg.channel),
    }
}

/// Kinds of corruption a real link shows, each exactly one bad line.
pub const GARBAGE_KINDS: u32 = 6;

fn garbage(variant: u32, channel: u8) -> Vec<u8> {
    match variant % GARBAGE_KINDS {
        // A byte hit by line noise in the middle of a sample.
        0 => format!("A{channel}:5\x1512\r\n").into_bytes(),
        // Reset noise: non-ASCII junk.
        1 => b"\xFF\xFE\x80junk\r\n".to_vec(),
        // A good-looking sample with a wrong checksum.
        2 => {
            let body = format!("A{channel}:512");
            let wrong = xor_checksum(body.as_bytes()) ^ 0xFF;
            format!("{body}*{wrong:02X}\r\n").into_bytes()
        }
        // Firmware chatter without the comment marker.
        3 => b"ERROR adc timeout\r\n".to_vec(),
        // A runaway line, longer than any line buffer.
        4 => {
            let mut v = format!("A{channel}:").into_bytes();
            v.resize(120, b'7');
            v.extend_from_slice(b"\r\n");
            v
        }
        // A line cut short.
        _ => format!("A{channel}:\r\n").into_bytes(),
    }
}

/// Counters, readable while the emulator runs.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SerialStats {
    pub board: BoardStats,
    /// Lines handed to the PTY.
    pub lines_written: u64,
    /// Lines dropped because the reader did not keep up.
    pub lines_dropped: u64,
    /// PTYs opened (1 + replugs).
    pub connects: u64,
    /// The slave device behind the link right now, if plugged.
    pub device: Option<PathBuf>,
}

struct Shared {
    stop: AtomicBool,
    commands: Mutex<VecDeque<Command>>,
    stats: Mutex<SerialStats>,
}

/// A running board emulator. Dropping it stops the thread and removes the
/// symlink.
pub struct SerialEmulator {
    link: PathBuf,
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

/// Cap on bytes waiting for a slow reader; a real board's UART does not
/// queue either.
const PENDING_CAP: usize = 4096;

/// Writes as much of `pending` as the PTY takes; the rest waits for the
/// next tick.
fn flush(pty: &PtyPair, pending: &mut Vec<u8>) -> io::Result<()> {
    while !pending.is_empty() {
        match pty.write(pending) {
            Ok(n) => {
                pending.drain(..n);
            }
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => return Ok(()),
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

impl SerialEmulator {
    /// Opens the PTY, creates `link` and starts printing.
    pub fn start(link: impl Into<PathBuf>, cfg: SerialConfig) -> io::Result<Self> {
        let link = link.into();
        if !(cfg.rate_hz.is_finite() && cfg.rate_hz > 0.0 && cfg.rate_hz <= 10_000.0) {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("rate must be within (0, 10000] Hz, got {}", cfg.rate_hz),
            ));
        }
        let port = PtyPort::open(PtyOptions::with_link(&link))?;
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            commands: Mutex::new(VecDeque::new()),
            stats: Mutex::new(SerialStats {
                connects: 1,
                device: port.slave_path().map(Path::to_path_buf),
                ..SerialStats::default()
            }),
        });
        let thread_shared = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("smoke-serial-emu".into())
            .spawn(move || run(port, cfg, &thread_shared))?;
        Ok(Self {
            link,
            shared,
            thread: Some(thread),
        })
    }

    /// The stable path to open.
    pub fn path(&self) -> &Path {
        &self.link
    }

    /// Injects a fault at the next tick.
    pub fn inject(&self, fault: Fault) {
        self.command(Command::Fault(fault));
    }

    /// Starts `profile` now (its t = 0 is the next tick).
    pub fn set_profile(&self, profile: Profile) {
        self.command(Command::Profile(profile));
    }

    pub fn command(&self, cmd: Command) {
        if let Ok(mut q) = self.shared.commands.lock() {
            q.push_back(cmd);
        }
    }

    pub fn stats(&self) -> SerialStats {
        self.shared
            .stats
            .lock()
            .map(|s| s.clone())
            .unwrap_or_default()
    }

    /// Stops the thread and removes the link.
    pub fn stop(mut self) -> SerialStats {
        self.halt();
        self.stats()
    }

    fn halt(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for SerialEmulator {
    fn drop(&mut self) {
        self.halt();
    }
}

/// The board's thread; dropping `port` at the end removes the link.
fn run(mut port: PtyPort, cfg: SerialConfig, shared: &Shared) {
    let mut board = Board::new(cfg.board.clone());
    let mut schedule = cfg.schedule.clone();
    schedule.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut schedule: VecDeque<(f64, Fault)> = schedule.into();
    let period = Duration::from_secs_f64(1.0 / cfg.rate_hz);
    let start = Instant::now();
    let mut pending = Vec::with_capacity(PENDING_CAP);
    let banner = format!(
        "# smokenav smoke-adc emulator, {} Hz, channel A{}\r\n",
        cfg.rate_hz, cfg.channel
    );
    if cfg.banner {
        pending.extend_from_slice(banner.as_bytes());
    }
    let mut tick: u32 = 0;

    while !shared.stop.load(Ordering::SeqCst) {
        let due = start + period * tick;
        let now = Instant::now();
        if due > now {
            std::thread::sleep(due - now);
        }
        tick = tick.saturating_add(1);
        let t_s = start.elapsed().as_secs_f64();

        if let Ok(mut q) = shared.commands.lock() {
            for c in q.drain(..) {
                tracing::info!(?c, t_s, "emulator command");
                board.apply(t_s, c);
            }
        }
        while schedule.front().is_some_and(|(at, _)| *at <= t_s) {
            if let Some((_, f)) = schedule.pop_front() {
                tracing::info!(?f, t_s, "scheduled fault");
                board.inject(t_s, f);
            }
        }

        let out = board.tick(t_s);
        let mut written = 0;
        let mut dropped = 0;
        if out == Output::Offline {
            if port.is_plugged() {
                port.unplug();
                tracing::info!("board unplugged: PTY closed, link removed");
                pending.clear();
            }
        } else {
            if !port.is_plugged() {
                match port.replug() {
                    Ok(device) => {
                        tracing::info!(device = %device.display(), "board replugged");
                        if let Ok(mut st) = shared.stats.lock() {
                            st.connects += 1;
                            st.device = Some(device.to_owned());
                        }
                        if cfg.banner {
                            pending.extend_from_slice(banner.as_bytes());
                        }
                    }
                    Err(e) => tracing::warn!(error = %e, "could not reopen the PTY"),
                }
            }
            let line = render(&out, &cfg);
            if pending.len() + line.len() <= PENDING_CAP {
                pending.extend_from_slice(&line);
                written = 1;
            } else {
                dropped = 1;
            }
            if let Some(p) = port.pair()
                && let Err(e) = flush(p, &mut pending)
            {
                tracing::warn!(error = %e, "PTY write failed");
            }
        }
        if let Ok(mut st) = shared.stats.lock() {
            st.board = board.stats();
            st.lines_written += written;
            st.lines_dropped += dropped;
            if !port.is_plugged() {
                st.device = None;
            }
        }
    }
}
