//! A fake Linux IIO ADC: a directory laid out like
//! `/sys/bus/iio/devices/iio:deviceN`, its `in_voltageN_raw` rewritten on
//! every tick.
//!
//! Real sysfs converts on each read; a regular file cannot, so a thread
//! refreshes it at `rate_hz` (write to a temporary name, then rename, so a
//! reader never sees half a number). A board unplug removes the whole
//! device directory, as the kernel does when the driver unbinds, and
//! recreates it afterwards.

use crate::board::{Board, BoardConfig, BoardStats, Command, Fault, Output};
use crate::model::Profile;
use smokenav_smoke_codec::iio::{SHARED_SCALE_ATTR, offset_attr, raw_attr, scale_attr, type_attr};
use std::collections::VecDeque;
use std::fs;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

#[derive(Debug, Clone)]
pub struct IioConfig {
    /// The board's ADC is the IIO device's: `scale = vref / 2^bits`.
    pub board: BoardConfig,
    /// How often `_raw` is refreshed, Hz.
    pub rate_hz: f64,
    pub channel: u8,
    /// Write `in_voltageN_offset` with this many counts.
    pub offset: Option<i32>,
    /// Write the scale as the shared `in_voltage_scale` instead of per channel.
    pub shared_scale: bool,
    /// Write `scan_elements/in_voltageN_type` (`le:uBITS/16>>0`), as an ADC
    /// with buffer support does; without it the device states only its scale.
    pub scan_type: bool,
    /// Device name written to `name`.
    pub name: String,
    pub schedule: Vec<(f64, Fault)>,
}

impl IioConfig {
    pub fn new(board: BoardConfig) -> Self {
        Self {
            board,
            rate_hz: 50.0,
            channel: 0,
            offset: None,
            shared_scale: false,
            scan_type: true,
            name: "smokenav-fake-adc".into(),
            schedule: Vec::new(),
        }
    }
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct IioStats {
    pub board: BoardStats,
    /// `_raw` updates written.
    pub updates: u64,
    /// Times the device directory was (re)created.
    pub appearances: u64,
    pub present: bool,
}

struct Shared {
    stop: AtomicBool,
    commands: Mutex<VecDeque<Command>>,
    stats: Mutex<IioStats>,
}

/// A running fake device. Dropping it stops the thread and removes the
/// directory (and the temporary root, if it made one).
pub struct FakeIio {
    device: PathBuf,
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
    _root: Option<tempfile::TempDir>,
}

/// Text a broken or misbehaving driver could leave in `_raw`, one per fault.
const GARBAGE: [&[u8]; 6] = [b"12a4\n", b"", b"\xFF\xFE\n", b"-\n", b"1.5e3\n", b"   \n"];

fn write_atomic(dir: &Path, name: &str, contents: &[u8]) -> io::Result<()> {
    let tmp = dir.join(format!(".{name}.tmp"));
    fs::write(&tmp, contents)?;
    fs::rename(&tmp, dir.join(name))
}

/// Builds the whole device under a temporary name, then renames it into
/// place: a reader sees either no device or a complete one with a real
/// first value.
fn create_device(dir: &Path, cfg: &IioConfig, raw: &[u8]) -> io::Result<()> {
    let staging = dir.with_extension("new");
    let _ = fs::remove_dir_all(&staging);
    fs::create_dir_all(&staging)?;
    write_atomic(&staging, "name", format!("{}\n", cfg.name).as_bytes())?;
    let scale = cfg.board.adc.lsb_mv();
    let scale_name = if cfg.shared_scale {
        SHARED_SCALE_ATTR.to_owned()
    } else {
        scale_attr(cfg.channel)
    };
    // Nine decimals, as the kernel prints IIO_VAL_INT_PLUS_NANO.
    write_atomic(&staging, &scale_name, format!("{scale:.9}\n").as_bytes())?;
    if let Some(off) = cfg.offset {
        write_atomic(
            &staging,
            &offset_attr(cfg.channel),
            format!("{off}\n").as_bytes(),
        )?;
    }
    if cfg.scan_type {
        let bits = cfg.board.adc.bits();
        let storage = if bits <= 16 { 16 } else { 32 };
        let attr = staging.join(type_attr(cfg.channel));
        if let (Some(folder), Some(name)) = (attr.parent(), attr.file_name()) {
            fs::create_dir_all(folder)?;
            write_atomic(
                folder,
                &name.to_string_lossy(),
                format!("le:u{bits}/{storage}>>0\n").as_bytes(),
            )?;
        }
    }
    write_atomic(&staging, &raw_attr(cfg.channel), raw)?;
    fs::rename(&staging, dir)
}

/// The `_raw` text for a board output; `None` when the board is offline.
fn raw_text(out: &Output, offset: i64) -> Option<Vec<u8>> {
    Some(match *out {
        Output::Sample { counts, .. } => format!("{}\n", i64::from(counts) - offset).into_bytes(),
        Output::OutOfRange { counts, .. } => format!("{counts}\n").into_bytes(),
        Output::Garbage { variant } => GARBAGE
            .get(variant as usize % GARBAGE.len())
            .map_or_else(Vec::new, |g| g.to_vec()),
        Output::Offline => return None,
    })
}

fn remove_device(dir: &Path) -> io::Result<()> {
    // Rename first so the device disappears in one step.
    let gone = dir.with_extension("removed");
    let _ = fs::remove_dir_all(&gone);
    fs::rename(dir, &gone)?;
    fs::remove_dir_all(&gone)
}

impl FakeIio {
    /// Creates `<tempdir>/iio:device0` and starts updating it.
    pub fn start(cfg: IioConfig) -> io::Result<Self> {
        let root = tempfile::Builder::new().prefix("fake-iio").tempdir()?;
        let device = root.path().join("iio:device0");
        let mut emu = Self::start_at(&device, cfg)?;
        emu._root = Some(root);
        Ok(emu)
    }

    /// Creates the device directory at `device` (which must not exist).
    pub fn start_at(device: &Path, cfg: IioConfig) -> io::Result<Self> {
        if !(cfg.rate_hz.is_finite() && cfg.rate_hz > 0.0 && cfg.rate_hz <= 10_000.0) {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("rate must be within (0, 10000] Hz, got {}", cfg.rate_hz),
            ));
        }
        if device.exists() {
            return Err(io::Error::new(
                io::ErrorKind::AlreadyExists,
                format!("{} already exists", device.display()),
            ));
        }
        let mut board = Board::new(cfg.board.clone());
        let start = Instant::now();
        let first = raw_text(&board.tick(0.0), i64::from(cfg.offset.unwrap_or(0)));
        create_device(device, &cfg, first.as_deref().unwrap_or(b"0\n"))?;
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            commands: Mutex::new(VecDeque::new()),
            stats: Mutex::new(IioStats {
                appearances: 1,
                present: true,
                ..IioStats::default()
            }),
        });
        let thread_shared = Arc::clone(&shared);
        let dir = device.to_owned();
        let thread = std::thread::Builder::new()
            .name("smoke-iio-emu".into())
            .spawn(move || run(&dir, &cfg, board, start, &thread_shared))?;
        Ok(Self {
            device: device.to_owned(),
            shared,
            thread: Some(thread),
            _root: None,
        })
    }

    /// The directory a driver takes as `--port`.
    pub fn device_path(&self) -> &Path {
        &self.device
    }

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

    pub fn stats(&self) -> IioStats {
        self.shared
            .stats
            .lock()
            .map(|s| s.clone())
            .unwrap_or_default()
    }

    pub fn stop(mut self) -> IioStats {
        self.halt();
        self.stats()
    }

    fn halt(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        if self.device.exists() {
            let _ = remove_device(&self.device);
        }
    }
}

impl Drop for FakeIio {
    fn drop(&mut self) {
        self.halt();
    }
}

fn run(dir: &Path, cfg: &IioConfig, mut board: Board, start: Instant, shared: &Shared) {
    let mut schedule = cfg.schedule.clone();
    schedule.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut schedule: VecDeque<(f64, Fault)> = schedule.into();
    let period = Duration::from_secs_f64(1.0 / cfg.rate_hz);
    let raw_name = raw_attr(cfg.channel);
    let offset = i64::from(cfg.offset.unwrap_or(0));
    let mut present = true;
    let mut tick: u32 = 1;

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
                board.inject(t_s, f);
            }
        }

        let mut appeared = false;
        let result = match raw_text(&board.tick(t_s), offset) {
            None if present => {
                present = false;
                tracing::info!(dir = %dir.display(), "IIO device removed");
                remove_device(dir)
            }
            None => Ok(()),
            Some(text) if !present => {
                present = true;
                appeared = true;
                tracing::info!(dir = %dir.display(), "IIO device back");
                create_device(dir, cfg, &text)
            }
            Some(text) => write_atomic(dir, &raw_name, &text),
        };
        if let Err(e) = result {
            tracing::warn!(error = %e, "fake IIO update failed");
        }
        if let Ok(mut st) = shared.stats.lock() {
            st.board = board.stats();
            st.present = present;
            if appeared {
                st.appearances += 1;
            }
            if present {
                st.updates += 1;
            }
        }
    }
}
