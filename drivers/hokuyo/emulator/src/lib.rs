//! A URG-04LX (or UTM-30LX-EW) emulator answering on a real pseudo-terminal or a
//! TCP socket, as the device does: SCIP 1.1 at power-up, VV/PP/II with the real
//! strings, BM/QT/RS/TM/SS, GD/GS/MD/MS with correct checksums and the
//! remaining-scans countdown, scans at the model's rate, error statuses.
//!
//! Whoever drives it (a test, the simulator) feeds the ranges through
//! [`Emulator::set_scan`] or [`Emulator::set_scan_source`], and injects faults:
//! corrupted checksums, garbage, truncated lines, a stalled stream, disconnect and
//! reconnect (the PTY is closed and re-created behind the same symlink, as a udev
//! name survives a USB replug), a sensor left streaming or in SCIP 1.1.
//!
//! [`Device`] is the protocol state machine with no I/O; [`Emulator`] runs it on a
//! thread that waits on the port with `poll` until the next scan is due.
//! [`pattern`] is a test scan source with its checker.

pub mod device;
pub mod model;
pub mod pattern;
mod transport;

pub use device::{
    BootState, Device, DeviceConfig, DeviceState, DeviceStats, Faults, Link, ScanSource, SentScan,
    StaticScan,
};
pub use model::{Model, ModelSpec};

use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use smokenav_shared_types::{Clock, MonotonicClock};
use std::io;
use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use transport::Transport;

/// Where the emulator listens.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Endpoint {
    /// A pseudo-terminal; `link` is a stable symlink to its slave (a udev-like name)
    /// that survives disconnect/reconnect.
    Pty { link: Option<PathBuf> },
    /// TCP on this address (`127.0.0.1:0` picks a free port).
    Tcp { addr: std::net::SocketAddr },
}

pub struct EmulatorConfig {
    pub device: DeviceConfig,
    pub endpoint: Endpoint,
    /// Time base for scans and the sensor timer. The thread waits in real time, so a
    /// mock clock is only noticed every 20 ms.
    pub clock: Arc<dyn Clock>,
}

impl EmulatorConfig {
    pub fn pty(device: DeviceConfig, link: Option<PathBuf>) -> Self {
        EmulatorConfig {
            device,
            endpoint: Endpoint::Pty { link },
            clock: Arc::new(MonotonicClock),
        }
    }

    pub fn tcp(device: DeviceConfig) -> Self {
        EmulatorConfig {
            device: DeviceConfig {
                link: Link::Ethernet,
                ..device
            },
            endpoint: Endpoint::Tcp {
                addr: ([127, 0, 0, 1], 0).into(),
            },
            clock: Arc::new(MonotonicClock),
        }
    }
}

struct Shared {
    device: Device,
    faults: Faults,
    source: Box<dyn ScanSource>,
    /// Requested by the handle, carried out by the thread.
    disconnect: bool,
    reconnect: Option<bool>,
    shutdown: bool,
    connected: bool,
    slave_path: Option<PathBuf>,
    tcp_port: Option<u16>,
}

struct Inner {
    shared: Mutex<Shared>,
    wake_tx: OwnedFd,
}

impl Inner {
    fn lock(&self) -> MutexGuard<'_, Shared> {
        // A panic on the emulator thread poisons the lock; the state is still usable.
        self.shared.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn wake(&self) {
        let _ = nix::unistd::write(&self.wake_tx, &[1]);
    }
}

/// A running emulator. Dropping it stops the thread and removes the PTY and symlink.
pub struct Emulator {
    inner: Arc<Inner>,
    thread: Option<JoinHandle<()>>,
    link: Option<PathBuf>,
    clock: Arc<dyn Clock>,
}

impl Emulator {
    pub fn spawn(cfg: EmulatorConfig) -> io::Result<Emulator> {
        let now = cfg.clock.now_ns();
        let device = Device::new(cfg.device.clone(), now);
        let steps = device.spec().geometry.step_count();
        let link = match &cfg.endpoint {
            Endpoint::Pty { link } => link.clone(),
            Endpoint::Tcp { .. } => None,
        };
        let transport = Transport::open(&cfg.endpoint, None)?;
        let (wake_rx, wake_tx) =
            nix::unistd::pipe2(nix::fcntl::OFlag::O_NONBLOCK | nix::fcntl::OFlag::O_CLOEXEC)
                .map_err(io::Error::from)?;
        let shared = Shared {
            device,
            faults: Faults::default(),
            // Until fed: every step at 1 m.
            source: Box::new(StaticScan(vec![1000; steps])),
            disconnect: false,
            reconnect: None,
            shutdown: false,
            connected: true,
            slave_path: transport.slave_path(),
            tcp_port: transport.tcp_port(),
        };
        let inner = Arc::new(Inner {
            shared: Mutex::new(shared),
            wake_tx,
        });
        let thread_inner = inner.clone();
        let clock = cfg.clock.clone();
        let endpoint = cfg.endpoint.clone();
        let thread = std::thread::Builder::new()
            .name("hokuyo-emulator".into())
            .spawn(move || run(thread_inner, transport, wake_rx, clock, endpoint))?;
        Ok(Emulator {
            inner,
            thread: Some(thread),
            link,
            clock: cfg.clock,
        })
    }

    /// What a driver opens: the stable symlink, else the PTY slave, else `tcp://127.0.0.1:port`.
    pub fn port(&self) -> String {
        if let Some(l) = &self.link {
            return l.display().to_string();
        }
        let s = self.inner.lock();
        match (&s.slave_path, s.tcp_port) {
            (Some(p), _) => p.display().to_string(),
            (None, Some(port)) => format!("tcp://127.0.0.1:{port}"),
            (None, None) => String::new(),
        }
    }

    /// The current PTY slave device (changes on reconnect), if serving a PTY.
    pub fn slave_path(&self) -> Option<PathBuf> {
        self.inner.lock().slave_path.clone()
    }

    pub fn link_path(&self) -> Option<&Path> {
        self.link.as_deref()
    }

    /// Ranges for every step AMIN..=AMAX, mm (below DMIN: error codes), sent from the next scan on.
    pub fn set_scan(&self, mm: &[u16]) {
        self.inner.lock().source = Box::new(StaticScan(mm.to_vec()));
    }

    /// A generator called with the scan number for each scan sent.
    pub fn set_scan_source(&self, source: impl ScanSource + 'static) {
        self.inner.lock().source = Box::new(source);
    }

    /// Changes the injected faults.
    pub fn with_faults<R>(&self, f: impl FnOnce(&mut Faults) -> R) -> R {
        let r = f(&mut self.inner.lock().faults);
        self.inner.wake();
        r
    }

    pub fn set_corrupt_line_fraction(&self, p: f64) {
        self.with_faults(|f| f.corrupt_line_fraction = p);
    }

    pub fn inject_garbage(&self, bytes: &[u8]) {
        self.with_faults(|f| f.garbage.extend_from_slice(bytes));
    }

    pub fn truncate_next_lines(&self, n: u32) {
        self.with_faults(|f| f.truncate_lines += n);
    }

    pub fn set_stalled(&self, stalled: bool) {
        self.with_faults(|f| f.stalled = stalled);
    }

    /// Unplug: the PTY (or TCP socket) closes and the symlink disappears.
    pub fn disconnect(&self) {
        self.inner.lock().disconnect = true;
        self.inner.wake();
    }

    /// Plug back in: a new PTY behind the same symlink (or the TCP port listening
    /// again). `power_cycle` resets the device to its boot state (SCIP 1.1 on a 04LX).
    pub fn reconnect(&self, power_cycle: bool) {
        self.inner.lock().reconnect = Some(power_cycle);
        self.inner.wake();
    }

    pub fn is_connected(&self) -> bool {
        self.inner.lock().connected
    }

    pub fn stats(&self) -> DeviceStats {
        self.inner.lock().device.stats()
    }

    pub fn state(&self) -> DeviceState {
        self.inner.lock().device.state()
    }

    /// Streamed scans sent so far (the last 4096), oldest first.
    pub fn sent_scans(&self) -> Vec<SentScan> {
        self.inner.lock().device.history().iter().copied().collect()
    }

    /// The last 256 request lines the device received.
    pub fn command_log(&self) -> Vec<String> {
        self.inner
            .lock()
            .device
            .command_log()
            .iter()
            .cloned()
            .collect()
    }

    /// Model geometry the device reports in PP.
    pub fn spec(&self) -> ModelSpec {
        self.inner.lock().device.spec().clone()
    }

    /// Sensor timer now, ms.
    pub fn sensor_ms(&self) -> u32 {
        let now = self.clock.now_ns();
        self.inner.lock().device.sensor_ms(now)
    }
}

impl Drop for Emulator {
    fn drop(&mut self) {
        self.inner.lock().shutdown = true;
        self.inner.wake();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Output kept while the host does not read; beyond it a real device's buffer overflows too.
const MAX_PENDING_OUTPUT: usize = 256 * 1024;

fn run(
    inner: Arc<Inner>,
    mut transport: Transport,
    wake_rx: OwnedFd,
    clock: Arc<dyn Clock>,
    endpoint: Endpoint,
) {
    let mut buf = [0u8; 4096];
    let mut pending: Vec<u8> = Vec::with_capacity(64 * 1024);
    loop {
        let now = clock.now_ns();
        let timeout_ms = {
            let mut s = inner.lock();
            if s.shutdown {
                break;
            }
            if std::mem::take(&mut s.disconnect) {
                transport.close();
                pending.clear();
                s.connected = false;
                tracing::info!("emulator: disconnected");
            }
            if let Some(power_cycle) = s.reconnect.take() {
                match Transport::open(&endpoint, transport.tcp_port()) {
                    Ok(t) => {
                        transport = t;
                        s.slave_path = transport.slave_path();
                        s.connected = true;
                        if power_cycle {
                            s.device.power_cycle(now);
                        }
                        tracing::info!(slave = ?s.slave_path, "emulator: reconnected");
                    }
                    Err(e) => tracing::warn!("emulator: reconnect failed: {e}"),
                }
            }
            let sh = &mut *s;
            sh.device.tick(now, &mut sh.faults, sh.source.as_mut());
            take_output(&mut sh.device, &mut pending, sh.connected);
            match sh.device.next_event_ns(&sh.faults) {
                Some(t) => (t.saturating_sub(now) / 1_000_000 + 1).min(20),
                None => 20,
            }
        };
        if !pending.is_empty() {
            match transport.write(&pending) {
                Ok(n) => {
                    pending.drain(..n);
                }
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {}
                Err(e) => {
                    tracing::debug!("emulator: write failed: {e}");
                    pending.clear();
                }
            }
        }
        let port_fd = transport.poll_fd();
        let mut fds = vec![PollFd::new(wake_rx.as_fd(), PollFlags::POLLIN)];
        if let Some(fd) = port_fd.as_ref() {
            let mut flags = PollFlags::POLLIN;
            if !pending.is_empty() {
                flags |= PollFlags::POLLOUT;
            }
            fds.push(PollFd::new(fd.as_fd(), flags));
        }
        let _ = poll(&mut fds, PollTimeout::from(timeout_ms as u16));
        let woke = fds[0]
            .revents()
            .is_some_and(|r| r.contains(PollFlags::POLLIN));
        let readable = fds
            .get(1)
            .and_then(|f| f.revents())
            .is_some_and(|r| !r.is_empty());
        drop(fds);
        if woke {
            while nix::unistd::read(&wake_rx, &mut buf).is_ok_and(|n| n > 0) {}
        }
        if readable {
            match transport.read(&mut buf) {
                Ok(0) => {}
                Ok(n) => {
                    let now = clock.now_ns();
                    let host_baud = transport.host_baud();
                    let mut s = inner.lock();
                    let sh = &mut *s;
                    sh.device.receive(
                        &buf[..n],
                        now,
                        host_baud,
                        &mut sh.faults,
                        sh.source.as_mut(),
                    );
                    take_output(&mut sh.device, &mut pending, sh.connected);
                }
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {}
                Err(e) => tracing::debug!("emulator: read failed: {e}"),
            }
        }
    }
    transport.close();
}

fn take_output(device: &mut Device, pending: &mut Vec<u8>, connected: bool) {
    let out = device.output();
    if connected && pending.len() + out.len() <= MAX_PENDING_OUTPUT {
        pending.extend_from_slice(out);
    }
    out.clear();
}
