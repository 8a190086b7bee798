//! A Nomad Scout on a pseudo-terminal.
//!
//! [`ScoutEmulator::start`] opens a real PTY, points a stable symlink at its
//! slave side (so a driver can reopen the same path after a simulated
//! unplug) and answers the Nomadic direct protocol the way the robot does:
//! every command gets one reply, a full state packet of the command's type;
//! `vm` drives the wheels, `st` stops them, `conf_tm` arms the robot-side
//! watchdog, `conf_sn` sets the sonar firing order and rate, `dp`/`da`/`zr`
//! redefine the odometry. Whoever drives it (a test, the simulator) feeds
//! sonar ranges and, optionally, the pose through an [`EmulatorHandle`], and
//! injects faults: corrupted checksums, truncated replies, garbage bytes,
//! NAKs, silence/stalls, disconnect and reconnect.

pub mod model;

pub use model::{Kinematics, Pose, RobotModel};
pub use smokenav_scout_codec::{Battery, DiffDrive, SonarOrder, WheelOrder, WheelSpeeds};

use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use smokenav_common_pty::{PtyError, PtyOptions, PtyPort};
use smokenav_scout_codec::frame::MAX_FRAME;
use smokenav_scout_codec::reply::SONARS;
use smokenav_scout_codec::units::sonar_byte;
use smokenav_scout_codec::{Command, Direction, FrameError, Reply, Splitter};
use smokenav_shared_types::clock::{Clock, MonotonicClock};
use std::collections::VecDeque;
use std::io::ErrorKind;
use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

#[derive(Debug, thiserror::Error)]
pub enum EmulatorError {
    #[error("cannot create the pseudo-terminal: {0}")]
    Pty(nix::Error),
    #[error("cannot link {link} to the pseudo-terminal: {source}")]
    Link {
        link: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot create the wake-up pipe: {0}")]
    Pipe(nix::Error),
    #[error("cannot start the emulator thread: {0}")]
    Thread(std::io::Error),
}

/// How to run the emulator.
#[derive(Clone)]
pub struct EmulatorConfig {
    /// The stable path the driver opens (a symlink to the current PTY).
    pub link_path: PathBuf,
    pub drive: DiffDrive,
    pub kinematics: Kinematics,
    /// Delay each reply by the time its bytes (and the request's) take on a
    /// serial line of this rate, 8N1; `None` answers at once.
    pub baud: Option<u32>,
    /// Seed of the fault randomness (same seed ⇒ same corrupted replies).
    pub seed: u64,
    pub clock: Arc<dyn Clock>,
}

impl EmulatorConfig {
    /// A Scout with Nomadic's geometry (0.345 m track, `vm(right, left, 0)`)
    /// paced like its 38400-baud line.
    pub fn new(link_path: impl Into<PathBuf>) -> Self {
        Self {
            link_path: link_path.into(),
            drive: DiffDrive::new(0.345, WheelOrder::RightLeft),
            kinematics: Kinematics::Internal,
            baud: Some(38400),
            seed: 1,
            clock: Arc::new(MonotonicClock),
        }
    }
}

/// What the emulator has seen and done.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EmulatorStats {
    pub bytes_in: u64,
    pub get_state: u64,
    pub velocity: u64,
    pub stop: u64,
    pub conf_sonar: u64,
    pub conf_timeout: u64,
    pub define: u64,
    pub zero: u64,
    pub limp: u64,
    pub replies: u64,
    pub naks: u64,
    pub corrupted: u64,
    pub truncated: u64,
    pub garbage_sent: u64,
    /// Commands swallowed while silent or stalled.
    pub ignored: u64,
    /// Damaged packets from the host (checksum, end byte, length, type).
    pub host_frame_errors: u64,
    pub unsupported: u64,
    /// Reply bytes dropped because nobody read the PTY.
    pub write_drops: u64,
    pub reconnects: u64,
}

impl EmulatorStats {
    pub fn commands(&self) -> u64 {
        self.get_state
            + self.velocity
            + self.stop
            + self.conf_sonar
            + self.conf_timeout
            + self.define
            + self.zero
            + self.limp
    }
}

/// A consistent view of the emulator.
#[derive(Debug, Clone, Copy)]
pub struct Snapshot {
    /// The pose the robot reports (odometry frame).
    pub pose: Pose,
    /// Wheel speeds the robot is running at (after watchdog and e-stop).
    pub wheels: WheelSpeeds,
    pub watchdog_s: u8,
    pub watchdog_trips: u64,
    pub sonar_rate: u8,
    pub sonar_order: SonarOrder,
    /// What the sonar bytes in a reply would hold now.
    pub sonar_reported: [u8; SONARS],
    pub stats: EmulatorStats,
    pub connected: bool,
}

#[derive(Debug, Default)]
struct Faults {
    corrupt_next: u32,
    corrupt_ppm: u32,
    truncate_next: u32,
    nak_next: u32,
    silent: bool,
    stall_until: u64,
    garbage: Vec<u8>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Control {
    Disconnect,
    Reconnect,
    Shutdown,
}

struct Shared {
    model: RobotModel,
    faults: Faults,
    stats: EmulatorStats,
    controls: VecDeque<Control>,
    connected: bool,
    device: Option<PathBuf>,
    link_generation: u64,
    rng: u64,
}

impl Shared {
    fn next_random(&mut self) -> u64 {
        // xorshift64*: deterministic fault placement from the seed.
        let mut x = self.rng;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.rng = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
}

struct Inner {
    shared: Mutex<Shared>,
    changed: Condvar,
    wake_tx: OwnedFd,
    clock: Arc<dyn Clock>,
    link_path: PathBuf,
    baud: Option<u32>,
}

impl Inner {
    fn lock(&self) -> MutexGuard<'_, Shared> {
        // A panic while holding the lock leaves plain data; keep serving.
        self.shared.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn wake(&self) {
        // A full pipe already means "wake up"; nothing else can go wrong here.
        let _ = nix::unistd::write(&self.wake_tx, &[1]);
    }
}

/// A running emulator. Dropping it stops the thread and removes the link.
pub struct ScoutEmulator {
    handle: EmulatorHandle,
    thread: Option<JoinHandle<()>>,
}

impl ScoutEmulator {
    pub fn start(cfg: EmulatorConfig) -> Result<Self, EmulatorError> {
        let port = PtyPort::open(PtyOptions::with_link(&cfg.link_path)).map_err(pty_error)?;
        let (wake_rx, wake_tx) =
            nix::unistd::pipe2(nix::fcntl::OFlag::O_NONBLOCK | nix::fcntl::OFlag::O_CLOEXEC)
                .map_err(EmulatorError::Pipe)?;
        let now = cfg.clock.now_ns();
        let seed = if cfg.seed == 0 { 0x9E37_79B9 } else { cfg.seed };
        let inner = Arc::new(Inner {
            shared: Mutex::new(Shared {
                model: RobotModel::new(cfg.drive, cfg.kinematics, now),
                faults: Faults::default(),
                stats: EmulatorStats::default(),
                controls: VecDeque::new(),
                connected: true,
                device: port.slave_path().map(Path::to_path_buf),
                link_generation: 0,
                rng: seed,
            }),
            changed: Condvar::new(),
            wake_tx,
            clock: cfg.clock,
            link_path: cfg.link_path,
            baud: cfg.baud,
        });
        let thread_inner = inner.clone();
        let thread = std::thread::Builder::new()
            .name("scout-emulator".into())
            .spawn(move || serve(thread_inner, wake_rx, port))
            .map_err(EmulatorError::Thread)?;
        Ok(Self {
            handle: EmulatorHandle { inner },
            thread: Some(thread),
        })
    }

    pub fn handle(&self) -> EmulatorHandle {
        self.handle.clone()
    }

    /// The stable path a driver opens.
    pub fn path(&self) -> &Path {
        &self.handle.inner.link_path
    }
}

impl std::ops::Deref for ScoutEmulator {
    type Target = EmulatorHandle;
    fn deref(&self) -> &EmulatorHandle {
        &self.handle
    }
}

impl Drop for ScoutEmulator {
    fn drop(&mut self) {
        self.handle.control(Control::Shutdown);
        // The thread's port removes the link as it goes.
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Feeds and inspects a running emulator; cheap to clone, usable from any thread.
#[derive(Clone)]
pub struct EmulatorHandle {
    inner: Arc<Inner>,
}

impl EmulatorHandle {
    fn now(&self) -> u64 {
        self.inner.clock.now_ns()
    }

    fn control(&self, c: Control) {
        self.inner.lock().controls.push_back(c);
        self.inner.wake();
    }

    /// Sonar ranges in inches as the robot reports them (255 = no echo).
    /// Each sonar picks its value up when it next fires.
    pub fn set_sonar_inches(&self, inches: [u8; SONARS]) {
        let now = self.now();
        self.inner.lock().model.set_sonar_inches(now, inches);
    }

    /// Sonar ranges in metres (≥ 6.477 m or NaN ⇒ no echo).
    pub fn set_sonar_m(&self, ranges: &[f64; SONARS]) {
        self.set_sonar_inches(ranges.map(sonar_byte));
    }

    /// Feeds the robot's pose (see [`Kinematics`]).
    pub fn set_pose(&self, pose: Pose) {
        let now = self.now();
        self.inner.lock().model.set_pose(now, pose);
    }

    pub fn set_bumpers(&self, bits: u32) {
        self.inner.lock().model.bumpers = bits;
    }

    /// The e-stop also stops the wheels.
    pub fn set_estop(&self, on: bool) {
        let now = self.now();
        let mut sh = self.inner.lock();
        sh.model.estop = on;
        if on {
            sh.model.execute(now, &Command::Stop);
        }
    }

    pub fn set_power(&self, battery: Battery, plugged_in: bool, charging: bool) {
        let mut sh = self.inner.lock();
        sh.model.battery = battery;
        sh.model.plugged_in = plugged_in;
        sh.model.charging = charging;
    }

    pub fn set_voltages(&self, cpu_v: f64, motor_v: f64) {
        let mut sh = self.inner.lock();
        sh.model.cpu_v = cpu_v;
        sh.model.motor_v = motor_v;
    }

    pub fn snapshot(&self) -> Snapshot {
        let now = self.now();
        let mut sh = self.inner.lock();
        sh.model.advance(now);
        snapshot_of(&sh)
    }

    pub fn stats(&self) -> EmulatorStats {
        self.inner.lock().stats
    }

    /// The current PTY slave (e.g. `/dev/pts/7`), None while unplugged.
    pub fn device_path(&self) -> Option<PathBuf> {
        self.inner.lock().device.clone()
    }

    pub fn link_path(&self) -> &Path {
        &self.inner.link_path
    }

    /// Waits until `pred` holds (checked after every reply and control), or
    /// the timeout passes; returns the last snapshot and whether it held.
    pub fn wait_for(
        &self,
        timeout: Duration,
        mut pred: impl FnMut(&Snapshot) -> bool,
    ) -> (Snapshot, bool) {
        let deadline = Instant::now() + timeout;
        let mut sh = self.inner.lock();
        loop {
            let now = self.now();
            sh.model.advance(now);
            let snap = snapshot_of(&sh);
            if pred(&snap) {
                return (snap, true);
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return (snap, false);
            }
            // Time-based state (watchdog, sonar firing) changes without a
            // notification, so re-check at least every 20 ms.
            let (g, _) = self
                .inner
                .changed
                .wait_timeout(sh, left.min(Duration::from_millis(20)))
                .unwrap_or_else(|e| e.into_inner());
            sh = g;
        }
    }

    // ---- fault hooks ----

    /// The next `n` replies go out with a wrong checksum.
    pub fn corrupt_next_replies(&self, n: u32) {
        self.inner.lock().faults.corrupt_next += n;
    }

    /// Corrupts this fraction of replies (0.01 = 1 %), placed by the seed.
    pub fn set_corrupt_rate(&self, fraction: f64) {
        self.inner.lock().faults.corrupt_ppm = (fraction.clamp(0.0, 1.0) * 1e6) as u32;
    }

    /// The next `n` replies are cut off after half their bytes.
    pub fn truncate_next_replies(&self, n: u32) {
        self.inner.lock().faults.truncate_next += n;
    }

    /// The next `n` commands are refused with NAK (and not executed).
    pub fn nak_next_commands(&self, n: u32) {
        self.inner.lock().faults.nak_next += n;
    }

    /// Writes these bytes to the line now (line noise).
    pub fn send_garbage(&self, bytes: &[u8]) {
        self.inner.lock().faults.garbage.extend_from_slice(bytes);
        self.inner.wake();
    }

    /// While silent the robot neither executes nor answers commands (a dead
    /// link that stays plugged in); its watchdog keeps running.
    pub fn set_silent(&self, silent: bool) {
        self.inner.lock().faults.silent = silent;
    }

    /// Silent for `d` from now.
    pub fn stall_for(&self, d: Duration) {
        let until = self.now().saturating_add(d.as_nanos() as u64);
        self.inner.lock().faults.stall_until = until;
    }

    /// Unplugs the cable: the PTY closes (the driver's reads fail) and the
    /// link path disappears. The robot keeps running (and its watchdog).
    /// Returns once done.
    pub fn disconnect(&self) {
        self.control_and_wait(Control::Disconnect);
    }

    /// Plugs back in: a new PTY behind the same link path.
    pub fn reconnect(&self) {
        self.control_and_wait(Control::Reconnect);
    }

    fn control_and_wait(&self, c: Control) {
        let gen0 = self.inner.lock().link_generation;
        self.control(c);
        let deadline = Instant::now() + Duration::from_secs(5);
        let mut sh = self.inner.lock();
        while sh.link_generation == gen0 && Instant::now() < deadline {
            sh = self
                .inner
                .changed
                .wait_timeout(sh, Duration::from_millis(50))
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }
}

fn snapshot_of(sh: &Shared) -> Snapshot {
    let (sonar_rate, sonar_order) = sh.model.sonar_config();
    Snapshot {
        pose: sh.model.odometry_pose(),
        wheels: sh.model.wheels(),
        watchdog_s: sh.model.watchdog_s(),
        watchdog_trips: sh.model.watchdog_trips(),
        sonar_rate,
        sonar_order,
        sonar_reported: sh.model.sonar_reported(),
        stats: sh.stats,
        connected: sh.connected,
    }
}

/// Longest a reply may wait for the host to make room on the line before the
/// rest of it is dropped (and counted).
const WRITE_TIMEOUT: Duration = Duration::from_millis(100);

/// Maps the cable's errors onto this crate's (public) error type.
fn pty_error(e: PtyError) -> EmulatorError {
    match e {
        PtyError::Create { source, .. } => EmulatorError::Pty(source),
        PtyError::Link { link, source, .. } => EmulatorError::Link { link, source },
    }
}

/// The emulator thread: waits on the PTY and the wake pipe, never on a timer.
fn serve(inner: Arc<Inner>, wake_rx: OwnedFd, mut port: PtyPort) {
    let mut splitter = Splitter::new(Direction::Commands);
    let mut buf = [0u8; 512];
    loop {
        let (controls, garbage) = {
            let mut sh = inner.lock();
            let c: Vec<Control> = sh.controls.drain(..).collect();
            (c, std::mem::take(&mut sh.faults.garbage))
        };
        for c in controls {
            match c {
                Control::Shutdown => return,
                Control::Disconnect => {
                    port.unplug();
                    splitter.clear();
                    let mut sh = inner.lock();
                    sh.connected = false;
                    sh.device = None;
                    sh.link_generation += 1;
                    inner.changed.notify_all();
                    tracing::info!("scout emulator unplugged");
                }
                Control::Reconnect => {
                    let opened = if port.is_plugged() {
                        None
                    } else {
                        match port.replug() {
                            Ok(device) => Some(device.to_owned()),
                            Err(e) => {
                                tracing::warn!("scout emulator cannot replug: {e}");
                                None
                            }
                        }
                    };
                    let mut sh = inner.lock();
                    if let Some(device) = opened {
                        sh.device = Some(device);
                        sh.connected = true;
                        sh.stats.reconnects += 1;
                        tracing::info!("scout emulator plugged in again");
                    }
                    sh.link_generation += 1;
                    inner.changed.notify_all();
                }
            }
        }
        if let Some(pair) = port.pair()
            && !garbage.is_empty()
        {
            let dropped = pair.write_all(&garbage, WRITE_TIMEOUT).dropped;
            let mut sh = inner.lock();
            sh.stats.garbage_sent += garbage.len() as u64;
            sh.stats.write_drops += dropped as u64;
        }

        let mut fds = vec![PollFd::new(wake_rx.as_fd(), PollFlags::POLLIN)];
        if let Some(pair) = port.pair() {
            fds.push(PollFd::new(pair.master(), PollFlags::POLLIN));
        }
        match poll(&mut fds, PollTimeout::NONE) {
            Ok(_) | Err(nix::errno::Errno::EINTR) => {}
            Err(e) => {
                tracing::error!("scout emulator poll failed: {e}");
                return;
            }
        }
        let readable = |f: &PollFd| {
            f.revents()
                .is_some_and(|r| r.intersects(PollFlags::POLLIN | PollFlags::POLLHUP))
        };
        if fds.first().is_some_and(readable) {
            let mut sink = [0u8; 64];
            while matches!(nix::unistd::read(&wake_rx, &mut sink), Ok(n) if n > 0) {}
        }
        let master_ready = fds.get(1).is_some_and(readable);
        drop(fds);
        let Some(pair) = port.pair() else { continue };
        if !master_ready {
            continue;
        }
        let n = match pair.read(&mut buf) {
            Ok(n) => n,
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::Interrupted) => {
                continue;
            }
            Err(e) => {
                // EIO: no slave open; cannot happen while we hold the slave.
                tracing::warn!("scout emulator read failed: {e}");
                std::thread::sleep(Duration::from_millis(10));
                continue;
            }
        };
        inner.lock().stats.bytes_in += n as u64;
        let mut rest = &buf[..n];
        while !rest.is_empty() {
            let k = splitter.feed(rest);
            rest = &rest[k..];
            while let Some(item) = splitter.next_frame() {
                let request_len = match &item {
                    Ok(f) => f.data.len() + 6,
                    Err(_) => 0,
                };
                let mut out = [0u8; MAX_FRAME];
                let len = respond(&inner, item, &mut out);
                if len == 0 {
                    continue;
                }
                if let Some(baud) = inner.baud.filter(|&b| b > 0) {
                    // 10 bits per byte on an 8N1 line.
                    let bits = (request_len + len) as u64 * 10;
                    std::thread::sleep(Duration::from_micros(bits * 1_000_000 / baud as u64));
                }
                let dropped = pair.write_all(&out[..len], WRITE_TIMEOUT).dropped;
                let mut sh = inner.lock();
                sh.stats.write_drops += dropped as u64;
                inner.changed.notify_all();
            }
        }
    }
}

/// Runs one packet (or framing error) from the host; writes the reply into
/// `out` and returns its length (0 = no reply).
fn respond(
    inner: &Inner,
    item: Result<smokenav_scout_codec::Frame<'_>, FrameError>,
    out: &mut [u8],
) -> usize {
    let now = inner.clock.now_ns();
    let mut sh = inner.lock();
    sh.model.advance(now);
    if sh.faults.silent || now < sh.faults.stall_until {
        if item.is_ok() {
            sh.stats.ignored += 1;
        }
        return 0;
    }
    let reply = match item {
        Err(FrameError::Garbage { .. }) => return 0,
        Err(FrameError::BadChecksum { .. } | FrameError::BadEnd { .. }) => {
            // A packet arrived damaged: refuse it.
            sh.stats.host_frame_errors += 1;
            Reply::Nak
        }
        Err(_) => {
            sh.stats.host_frame_errors += 1;
            return 0;
        }
        Ok(frame) if sh.faults.nak_next > 0 => {
            let _ = frame;
            sh.faults.nak_next -= 1;
            Reply::Nak
        }
        Ok(frame) => match Command::decode(frame) {
            Ok(cmd) => {
                let st = &mut sh.stats;
                match cmd {
                    Command::GetState => st.get_state += 1,
                    Command::Velocity(_) => st.velocity += 1,
                    Command::Stop => st.stop += 1,
                    Command::ConfSonar { .. } => st.conf_sonar += 1,
                    Command::ConfTimeout(_) => st.conf_timeout += 1,
                    Command::DefinePosition { .. } | Command::DefineAngles { .. } => st.define += 1,
                    Command::Zero => st.zero += 1,
                    Command::Limp => st.limp += 1,
                }
                let state = sh.model.execute(now, &cmd);
                Reply::State {
                    to: cmd.packet_type(),
                    state,
                }
            }
            Err(e) => {
                tracing::debug!("scout emulator refuses a command: {e}");
                sh.stats.unsupported += 1;
                Reply::Nak
            }
        },
    };
    let Ok(mut len) = reply.encode(out) else {
        return 0;
    };
    if reply == Reply::Nak {
        sh.stats.naks += 1;
    }
    sh.stats.replies += 1;
    let mut corrupt = false;
    if sh.faults.corrupt_next > 0 {
        sh.faults.corrupt_next -= 1;
        corrupt = true;
    } else if sh.faults.corrupt_ppm > 0 {
        corrupt = sh.next_random() % 1_000_000 < sh.faults.corrupt_ppm as u64;
    }
    if corrupt && len >= 2 {
        out[len - 2] ^= 0x5A;
        sh.stats.corrupted += 1;
    }
    if sh.faults.truncate_next > 0 {
        sh.faults.truncate_next -= 1;
        len /= 2;
        sh.stats.truncated += 1;
    }
    len
}
