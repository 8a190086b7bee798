//! The wire side: a real pseudo-terminal (with a stable symlink) or a TCP
//! listener, and the thread that moves bytes between it and the robot core.

use crate::{Shared, State};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use smokenav_common_pty::{PtyOptions, PtyPair, PtyPort};
use smokenav_pioneer_codec::{Framer, PacketBuf};
use smokenav_shared_types::Clock;
use std::io::{self, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::os::fd::{AsFd, BorrowedFd};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::Ordering;

/// Outgoing bytes waiting for the reader; beyond this, packets are dropped
/// (and counted) as a serial line would lose them.
const TX_CAP: usize = 16 * 1024;
/// Longest wait without looking at the handle's requests.
const MAX_WAIT_MS: u64 = 100;

pub(crate) enum Port {
    Pty(PtyPort),
    Tcp {
        listener: TcpListener,
        client: Option<TcpStream>,
    },
}

impl Port {
    pub(crate) fn pty(link: &Path) -> io::Result<(Self, PathBuf)> {
        let port = PtyPort::open(PtyOptions::with_link(link))?;
        let path = port.slave_path().map(Path::to_path_buf).unwrap_or_default();
        Ok((Port::Pty(port), path))
    }

    pub(crate) fn tcp(listener: TcpListener) -> io::Result<Self> {
        listener.set_nonblocking(true)?;
        Ok(Port::Tcp {
            listener,
            client: None,
        })
    }

    fn data_fd(&self) -> Option<BorrowedFd<'_>> {
        match self {
            Port::Pty(p) => p.pair().map(PtyPair::master),
            Port::Tcp { client, .. } => client.as_ref().map(|c| c.as_fd()),
        }
    }

    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self {
            Port::Pty(p) => p.pair().ok_or(io::ErrorKind::NotConnected)?.read(buf),
            Port::Tcp {
                client: Some(c), ..
            } => c.read(buf),
            _ => Err(io::ErrorKind::NotConnected.into()),
        }
    }

    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        match self {
            Port::Pty(p) => p.pair().ok_or(io::ErrorKind::NotConnected)?.write(buf),
            Port::Tcp {
                client: Some(c), ..
            } => c.write(buf),
            _ => Err(io::ErrorKind::NotConnected.into()),
        }
    }

    fn connected(&self) -> bool {
        self.data_fd().is_some()
    }

    /// Pulls the cable: the device (and its link) or the client goes away.
    fn unplug(&mut self) {
        match self {
            // The link goes first: a driver woken by the hang-up must not find it.
            Port::Pty(p) => p.unplug(),
            Port::Tcp { client, .. } => *client = None,
        }
    }
}

/// The I/O thread's own state.
pub(crate) struct Io {
    pub(crate) port: Port,
    pub(crate) wake: UnixStream,
    pub(crate) clock: Arc<dyn Clock>,
    framer: Framer,
    tx: Vec<u8>,
    replug_at_ns: Option<u64>,
}

impl Io {
    pub(crate) fn new(port: Port, wake: UnixStream, clock: Arc<dyn Clock>) -> io::Result<Self> {
        wake.set_nonblocking(true)?;
        Ok(Self {
            port,
            wake,
            clock,
            framer: Framer::new(),
            tx: Vec::with_capacity(TX_CAP),
            replug_at_ns: None,
        })
    }

    pub(crate) fn run(mut self, shared: Arc<Shared>) {
        let mut buf = [0u8; 512];
        while !shared.stop.load(Ordering::SeqCst) {
            let now = self.clock.now_ns();
            let deadline = {
                let mut st = shared.lock();
                self.apply_requests(&mut st, now);
                st.link.connected = self.port.connected();
                st.robot.next_deadline_ns(now)
            };
            let wait_ms = (deadline.saturating_sub(now) / 1_000_000).min(MAX_WAIT_MS);
            let (data_ready, listener_ready) = self.wait(wait_ms);
            let now = self.clock.now_ns();
            if listener_ready {
                self.accept(&shared);
            }
            if data_ready {
                self.read_all(&shared, &mut buf, now);
            }
            {
                let mut guard = shared.lock();
                let State {
                    robot,
                    faults,
                    link,
                } = &mut *guard;
                let tx = &mut self.tx;
                robot.tick(now, &mut |p: &PacketBuf| queue(tx, p, faults, link));
                link.rx = self.framer.stats();
            }
            self.flush(&shared);
            shared.changed.notify_all();
        }
    }

    fn apply_requests(&mut self, st: &mut State, now: u64) {
        if let Some(d) = st.faults.unplug.take() {
            tracing::info!("emulator: unplugged for {d:?}");
            self.port.unplug();
            self.framer.clear();
            self.tx.clear();
            st.link.unplugs += 1;
            if matches!(self.port, Port::Tcp { .. }) {
                st.robot.end_session();
            } else {
                self.replug_at_ns = Some(now + d.as_nanos() as u64);
            }
        }
        if self.replug_at_ns.is_some_and(|t| now >= t) {
            self.replug_at_ns = None;
            if let Port::Pty(p) = &mut self.port {
                match p.replug() {
                    Ok(path) => {
                        tracing::info!("emulator: plugged back in at {}", path.display());
                        st.link.device = Some(path.to_owned());
                    }
                    Err(e) => tracing::warn!("emulator: cannot recreate the PTY: {e}"),
                }
            }
        }
        if !st.faults.noise.is_empty() {
            let noise = std::mem::take(&mut st.faults.noise);
            if self.port.connected() && self.tx.len() + noise.len() <= TX_CAP {
                self.tx.extend_from_slice(&noise);
            }
        }
    }

    /// Waits for input, a wake-up or the timeout; returns (data, listener).
    fn wait(&mut self, wait_ms: u64) -> (bool, bool) {
        let want_out = !self.tx.is_empty();
        let data = self.port.data_fd();
        let listener = match &self.port {
            Port::Tcp { listener, .. } => Some(listener.as_fd()),
            Port::Pty(_) => None,
        };
        let mut fds = vec![PollFd::new(self.wake.as_fd(), PollFlags::POLLIN)];
        let data_at = data.map(|fd| {
            let mut ev = PollFlags::POLLIN;
            if want_out {
                ev |= PollFlags::POLLOUT;
            }
            fds.push(PollFd::new(fd, ev));
            fds.len() - 1
        });
        let listener_at = listener.map(|fd| {
            fds.push(PollFd::new(fd, PollFlags::POLLIN));
            fds.len() - 1
        });
        let timeout = PollTimeout::try_from(wait_ms as i32).unwrap_or(PollTimeout::ZERO);
        if poll(&mut fds, timeout).is_err() {
            return (false, false);
        }
        let ready = |i: Option<usize>| {
            i.and_then(|i| fds.get(i))
                .and_then(|f| f.revents())
                .is_some_and(|r| !r.is_empty())
        };
        let woke = ready(Some(0));
        let d = ready(data_at);
        let l = ready(listener_at);
        drop(fds);
        if woke {
            let mut sink = [0u8; 64];
            while matches!(self.wake.read(&mut sink), Ok(n) if n > 0) {}
        }
        (d, l)
    }

    fn accept(&mut self, shared: &Shared) {
        let Port::Tcp { listener, client } = &mut self.port else {
            return;
        };
        while let Ok((stream, peer)) = listener.accept() {
            if client.is_some() {
                // One client per robot, as AMRISim; the newcomer is refused.
                tracing::warn!("emulator: refusing second client {peer}");
                continue;
            }
            if stream.set_nonblocking(true).is_err() {
                continue;
            }
            let _ = stream.set_nodelay(true);
            tracing::info!("emulator: client {peer} connected");
            *client = Some(stream);
            self.framer.clear();
            let mut st = shared.lock();
            st.link.clients += 1;
        }
    }

    fn read_all(&mut self, shared: &Shared, buf: &mut [u8], now: u64) {
        loop {
            match self.port.read(buf) {
                Ok(0) => {
                    // TCP client closed. A PTY read never returns 0 here since
                    // we hold the slave open.
                    if let Port::Tcp { client, .. } = &mut self.port {
                        tracing::info!("emulator: client disconnected");
                        *client = None;
                        self.framer.clear();
                        self.tx.clear();
                        shared.lock().robot.end_session();
                    }
                    return;
                }
                Ok(n) => {
                    let mut guard = shared.lock();
                    let State {
                        robot,
                        faults,
                        link,
                    } = &mut *guard;
                    let tx = &mut self.tx;
                    link.rx_bytes += n as u64;
                    self.framer.feed(buf.get(..n).unwrap_or(&[]), |r| match r {
                        Ok(payload) => robot.on_packet(payload, now, &mut |p: &PacketBuf| {
                            queue(tx, p, faults, link)
                        }),
                        Err(e) => tracing::debug!("emulator: dropped a packet: {e}"),
                    });
                    link.rx = self.framer.stats();
                }
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => return,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => {
                    tracing::debug!("emulator: read failed: {e}");
                    if let Port::Tcp { client, .. } = &mut self.port {
                        *client = None;
                        shared.lock().robot.end_session();
                    }
                    return;
                }
            }
        }
    }

    fn flush(&mut self, shared: &Shared) {
        while !self.tx.is_empty() {
            match self.port.write(&self.tx) {
                Ok(0) => break,
                Ok(n) => {
                    self.tx.drain(..n);
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => break,
                Err(e) => {
                    tracing::debug!("emulator: write failed: {e}");
                    let mut st = shared.lock();
                    st.link.tx_dropped_bytes += self.tx.len() as u64;
                    self.tx.clear();
                    break;
                }
            }
        }
    }
}

/// Queues one outgoing packet, applying the transmit faults.
fn queue(
    tx: &mut Vec<u8>,
    p: &PacketBuf,
    faults: &mut crate::Faults,
    link: &mut crate::LinkStatus,
) {
    if faults.silent {
        link.tx_suppressed += 1;
        return;
    }
    let bytes = p.as_bytes();
    if tx.len() + bytes.len() > TX_CAP {
        link.tx_dropped_bytes += bytes.len() as u64;
        return;
    }
    let start = tx.len();
    tx.extend_from_slice(bytes);
    if faults.corrupt_next > 0 {
        faults.corrupt_next -= 1;
        link.tx_corrupted += 1;
        // Flip the low checksum byte: the framing stays intact, the checksum fails.
        if let Some(last) = tx.last_mut() {
            *last ^= 0x5A;
        }
    }
    link.tx_packets += 1;
    link.tx_bytes += (tx.len() - start) as u64;
}
