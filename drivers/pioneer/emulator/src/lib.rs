//! An ARCOS robot controller (Pioneer 3-DX) for tests and bench work.
//!
//! It serves a real pseudo-terminal — reachable through a stable symlink, so a
//! driver can reopen it after a simulated unplug — or a TCP port like
//! MobileSim/AMRISim on 8101. The controller core ([`robot::ArcosRobot`]) is
//! pure: it integrates the commanded velocities with its own simple
//! kinematics unless the owner of the motion (a test, later the simulator)
//! takes over through the [`EmulatorHandle`].
//!
//! ```no_run
//! use smokenav_pioneer_emulator::{Emulator, RobotConfig};
//! let emu = Emulator::pty("/tmp/pioneer".as_ref(), RobotConfig::default()).unwrap();
//! // point the driver at /tmp/pioneer ...
//! let h = emu.handle();
//! let st = h.wait_for(std::time::Duration::from_secs(5), |s| s.robot.commanded.trans > 0.0);
//! ```

mod link;
pub mod robot;

pub use robot::{
    ArcosRobot, Motion, Phase, Pose, RobotConfig, RobotCounters, RobotStatus, SonarMode,
};

use smokenav_pioneer_codec::FramerStats;
use smokenav_shared_types::{Clock, MonotonicClock};
use std::io::Write;
use std::net::{SocketAddr, TcpListener};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use thiserror::Error;

#[derive(Debug, Error)]
pub enum EmulatorError {
    #[error("cannot create the pseudo-terminal behind {link}: {source}")]
    Pty {
        link: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot listen on {addr}: {source}")]
    Listen {
        addr: String,
        #[source]
        source: std::io::Error,
    },
    #[error("emulator setup: {0}")]
    Io(#[from] std::io::Error),
    #[error(transparent)]
    Subclass(smokenav_pioneer_codec::UnknownSubclass),
}

/// Transmit-side faults, applied by the I/O thread.
#[derive(Debug, Default)]
pub(crate) struct Faults {
    /// Corrupt the checksum of this many upcoming packets.
    corrupt_next: u32,
    /// Send nothing at all.
    silent: bool,
    /// Raw bytes to put on the wire once.
    noise: Vec<u8>,
    /// Pull the cable for this long (TCP: drop the client).
    unplug: Option<Duration>,
}

/// What the wire side has done.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LinkStatus {
    /// A PTY exists / a TCP client is connected.
    pub connected: bool,
    /// The current `/dev/pts/N` behind the symlink.
    pub device: Option<PathBuf>,
    pub clients: u64,
    pub unplugs: u64,
    pub rx_bytes: u64,
    /// Framing of what the host sent (bad checksums from the host show here).
    pub rx: FramerStats,
    pub tx_packets: u64,
    pub tx_bytes: u64,
    pub tx_corrupted: u64,
    /// Packets not sent because the emulator was told to be silent.
    pub tx_suppressed: u64,
    /// Bytes lost because nobody was reading (or the port was gone).
    pub tx_dropped_bytes: u64,
}

pub(crate) struct State {
    pub(crate) robot: ArcosRobot,
    pub(crate) faults: Faults,
    pub(crate) link: LinkStatus,
}

pub(crate) struct Shared {
    state: Mutex<State>,
    changed: Condvar,
    stop: AtomicBool,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic in the I/O thread must not hide the robot's state from a test.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// A snapshot of robot and link.
#[derive(Debug, Clone, PartialEq)]
pub struct EmulatorStatus {
    pub robot: RobotStatus,
    pub link: LinkStatus,
}

/// Shared access to a running emulator: read what the host commanded, move
/// the robot, set sonar ranges, inject faults. Cheap to clone.
#[derive(Clone)]
pub struct EmulatorHandle {
    shared: Arc<Shared>,
    wake: Arc<UnixStream>,
}

impl EmulatorHandle {
    fn with<R>(&self, f: impl FnOnce(&mut State) -> R) -> R {
        let r = f(&mut self.shared.lock());
        let _ = (&*self.wake).write(&[1]);
        r
    }

    pub fn status(&self) -> EmulatorStatus {
        let st = self.shared.lock();
        EmulatorStatus {
            robot: st.robot.status(),
            link: st.link.clone(),
        }
    }

    /// Velocities the host last commanded (VEL/RVEL/VEL2), mm/s and deg/s.
    pub fn commanded(&self) -> Motion {
        self.shared.lock().robot.status().commanded
    }

    /// Waits (on a condition variable, no polling) until `pred` holds or
    /// `timeout` passes. The I/O thread signals at least every 100 ms.
    pub fn wait_for(
        &self,
        timeout: Duration,
        mut pred: impl FnMut(&EmulatorStatus) -> bool,
    ) -> Option<EmulatorStatus> {
        let end = Instant::now() + timeout;
        let mut st = self.shared.lock();
        loop {
            let snap = EmulatorStatus {
                robot: st.robot.status(),
                link: st.link.clone(),
            };
            if pred(&snap) {
                return Some(snap);
            }
            let left = end.checked_duration_since(Instant::now())?;
            st = match self.shared.changed.wait_timeout(st, left) {
                Ok((g, _)) => g,
                Err(e) => e.into_inner().0,
            };
        }
    }

    /// Teleports the robot (true pose; odometry follows).
    pub fn set_pose(&self, pose: Pose) {
        self.with(|s| s.robot.set_pose(pose));
    }

    /// The owner integrates motion itself and calls [`EmulatorHandle::set_pose`].
    pub fn set_external_motion(&self, on: bool) {
        self.with(|s| s.robot.set_external_motion(on));
    }

    pub fn set_sonar_range(&self, index: usize, mm: u16) {
        self.with(|s| s.robot.set_sonar_range(index, mm));
    }

    /// Sets ranges for transducers `0..ranges.len()`.
    pub fn set_sonar_ranges(&self, ranges: &[u16]) {
        self.with(|s| {
            for (i, mm) in ranges.iter().enumerate() {
                s.robot.set_sonar_range(i, *mm);
            }
        });
    }

    /// Raw STALL/BUMPERS word (see `smokenav_pioneer_codec::Sip::stall_bumpers`).
    pub fn set_stall_bumpers(&self, v: u16) {
        self.with(|s| s.robot.set_stall_bumpers(v));
    }

    pub fn set_battery_dv(&self, dv: u8) {
        self.with(|s| s.robot.set_battery_dv(dv));
    }

    pub fn set_estop(&self, on: bool) {
        self.with(|s| s.robot.set_estop(on));
    }

    /// Fault: the next `n` packets go out with a bad checksum.
    pub fn corrupt_next_packets(&self, n: u32) {
        self.with(|s| s.faults.corrupt_next += n);
    }

    /// Fault: put these bytes on the wire (line noise).
    pub fn inject_noise(&self, bytes: &[u8]) {
        self.with(|s| s.faults.noise.extend_from_slice(bytes));
    }

    /// Fault: stop (or resume) sending anything; commands are still received.
    pub fn set_silent(&self, on: bool) {
        self.with(|s| s.faults.silent = on);
    }

    /// Fault: a previous client left the session open (SIPs stream, no SYNC needed).
    pub fn open_stale_session(&self) {
        self.with(|s| s.robot.open_stale_session());
    }

    /// Fault: pull the cable. A PTY and its symlink vanish for `for_` and come
    /// back as a new `/dev/pts/N` (the controller keeps its session, as a real
    /// one does when a USB adapter is unplugged); a TCP client is dropped.
    pub fn unplug(&self, for_: Duration) {
        self.with(|s| s.faults.unplug = Some(for_));
    }
}

/// A running emulator; dropping it stops the thread and removes the symlink.
pub struct Emulator {
    handle: EmulatorHandle,
    thread: Option<JoinHandle<()>>,
    endpoint: Endpoint,
}

#[derive(Debug, Clone)]
enum Endpoint {
    Pty(PathBuf),
    Tcp(SocketAddr),
}

impl Emulator {
    /// Serves a new PTY reachable at `link` (a symlink to `/dev/pts/N`).
    pub fn pty(link: &Path, cfg: RobotConfig) -> Result<Self, EmulatorError> {
        Self::pty_with_clock(link, cfg, Arc::new(MonotonicClock))
    }

    pub fn pty_with_clock(
        link: &Path,
        cfg: RobotConfig,
        clock: Arc<dyn Clock>,
    ) -> Result<Self, EmulatorError> {
        let robot = ArcosRobot::new(cfg).map_err(EmulatorError::Subclass)?;
        let (port, device) = link::Port::pty(link).map_err(|source| EmulatorError::Pty {
            link: link.to_owned(),
            source,
        })?;
        let link_status = LinkStatus {
            connected: true,
            device: Some(device),
            ..Default::default()
        };
        Self::start(
            port,
            robot,
            link_status,
            clock,
            Endpoint::Pty(link.to_owned()),
        )
    }

    /// Serves ARCOS on a TCP address (`127.0.0.1:0` picks a free port).
    pub fn tcp(addr: &str, cfg: RobotConfig) -> Result<Self, EmulatorError> {
        let robot = ArcosRobot::new(cfg).map_err(EmulatorError::Subclass)?;
        let listener = TcpListener::bind(addr).map_err(|source| EmulatorError::Listen {
            addr: addr.to_owned(),
            source,
        })?;
        let local = listener.local_addr()?;
        let port = link::Port::tcp(listener)?;
        Self::start(
            port,
            robot,
            LinkStatus::default(),
            Arc::new(MonotonicClock),
            Endpoint::Tcp(local),
        )
    }

    fn start(
        port: link::Port,
        robot: ArcosRobot,
        link_status: LinkStatus,
        clock: Arc<dyn Clock>,
        endpoint: Endpoint,
    ) -> Result<Self, EmulatorError> {
        let (wake_tx, wake_rx) = UnixStream::pair()?;
        wake_tx.set_nonblocking(true)?;
        let shared = Arc::new(Shared {
            state: Mutex::new(State {
                robot,
                faults: Faults::default(),
                link: link_status,
            }),
            changed: Condvar::new(),
            stop: AtomicBool::new(false),
        });
        let io = link::Io::new(port, wake_rx, clock)?;
        let s = shared.clone();
        let thread = std::thread::Builder::new()
            .name("arcos-emulator".into())
            .spawn(move || io.run(s))?;
        Ok(Self {
            handle: EmulatorHandle {
                shared,
                wake: Arc::new(wake_tx),
            },
            thread: Some(thread),
            endpoint,
        })
    }

    pub fn handle(&self) -> EmulatorHandle {
        self.handle.clone()
    }

    /// What to pass to a driver's `--port`: the symlink path or `tcp://host:port`.
    pub fn port_arg(&self) -> String {
        match &self.endpoint {
            Endpoint::Pty(p) => p.display().to_string(),
            Endpoint::Tcp(a) => format!("tcp://{a}"),
        }
    }

    pub fn tcp_addr(&self) -> Option<SocketAddr> {
        match self.endpoint {
            Endpoint::Tcp(a) => Some(a),
            Endpoint::Pty(_) => None,
        }
    }
}

impl Drop for Emulator {
    fn drop(&mut self) {
        self.handle
            .shared
            .stop
            .store(true, std::sync::atomic::Ordering::SeqCst);
        let _ = (&*self.handle.wake).write(&[1]);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
