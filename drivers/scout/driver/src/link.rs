//! The serial (or TCP) link to the robot and one request/reply exchange.

use smokenav_scout_codec::frame::MAX_FRAME;
use smokenav_scout_codec::{Command, Direction, Reply, Splitter, SplitterStats, StateReply};
use std::io::{ErrorKind, Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

/// Where the robot is: a serial device or `tcp://host:port` (Nserver-style
/// robot port, 65001 on a real Scout).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PortSpec {
    Serial(String),
    Tcp(String),
}

impl PortSpec {
    pub fn parse(s: &str) -> PortSpec {
        match s.strip_prefix("tcp://") {
            Some(addr) => PortSpec::Tcp(addr.to_string()),
            None => PortSpec::Serial(s.to_string()),
        }
    }
}

impl std::fmt::Display for PortSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PortSpec::Serial(p) => f.write_str(p),
            PortSpec::Tcp(a) => write!(f, "tcp://{a}"),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("cannot open {port}: {reason}")]
    Open { port: String, reason: String },
    #[error("no reply within {0:?}")]
    Timeout(Duration),
    #[error("the robot refused the command (NAK)")]
    Nak,
    #[error("link lost: {0}")]
    Io(#[from] std::io::Error),
    #[error("cannot encode the command: {0}")]
    Encode(#[from] smokenav_scout_codec::EncodeError),
}

impl LinkError {
    /// The port itself failed (unplugged, closed): reopen rather than retry.
    pub fn is_fatal(&self) -> bool {
        matches!(self, LinkError::Io(_) | LinkError::Open { .. })
    }
}

enum Port {
    Serial(serialport::TTYPort),
    Tcp(TcpStream),
}

/// Counters of the exchanges over this link (and earlier ones: they survive
/// reconnects because the driver keeps one `Exchanger`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkStats {
    pub requests: u64,
    pub replies: u64,
    pub timeouts: u64,
    pub naks: u64,
    /// State replies answering an earlier request (arrived late), dropped.
    pub stale_replies: u64,
    /// Replies that framed correctly but did not decode.
    pub bad_replies: u64,
    /// Bytes the splitter had no room for (should stay 0).
    pub dropped_bytes: u64,
}

impl std::ops::AddAssign for LinkStats {
    fn add_assign(&mut self, o: LinkStats) {
        self.requests += o.requests;
        self.replies += o.replies;
        self.timeouts += o.timeouts;
        self.naks += o.naks;
        self.stale_replies += o.stale_replies;
        self.bad_replies += o.bad_replies;
        self.dropped_bytes += o.dropped_bytes;
    }
}

/// An open link plus the bytes-to-replies machinery.
pub struct Link {
    port: Port,
    splitter: Splitter,
    stats: LinkStats,
    buf: [u8; 256],
}

impl Link {
    /// Opens the port: 8N1, no flow control, raw.
    pub fn open(spec: &PortSpec, baud: u32) -> Result<Link, LinkError> {
        let port = match spec {
            PortSpec::Serial(path) => {
                let p = serialport::new(path, baud)
                    .data_bits(serialport::DataBits::Eight)
                    .parity(serialport::Parity::None)
                    .stop_bits(serialport::StopBits::One)
                    .flow_control(serialport::FlowControl::None)
                    .timeout(Duration::from_millis(100))
                    .open_native()
                    .map_err(|e| LinkError::Open {
                        port: path.clone(),
                        reason: e.to_string(),
                    })?;
                Port::Serial(p)
            }
            PortSpec::Tcp(addr) => {
                let open_err = |e: std::io::Error| LinkError::Open {
                    port: format!("tcp://{addr}"),
                    reason: e.to_string(),
                };
                let sock = addr
                    .parse::<std::net::SocketAddr>()
                    .map_err(|e| LinkError::Open {
                        port: format!("tcp://{addr}"),
                        reason: e.to_string(),
                    })?;
                let s =
                    TcpStream::connect_timeout(&sock, Duration::from_secs(2)).map_err(open_err)?;
                s.set_nodelay(true).map_err(open_err)?;
                Port::Tcp(s)
            }
        };
        Ok(Link {
            port,
            splitter: Splitter::new(Direction::ScoutReplies),
            stats: LinkStats::default(),
            buf: [0; 256],
        })
    }

    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    pub fn frame_stats(&self) -> SplitterStats {
        self.splitter.stats()
    }

    fn read_some(&mut self, timeout: Duration) -> Result<usize, LinkError> {
        let timeout = timeout.max(Duration::from_millis(1));
        let r = match &mut self.port {
            Port::Serial(p) => {
                serialport::SerialPort::set_timeout(p, timeout)
                    .map_err(|e| LinkError::Io(std::io::Error::other(e)))?;
                p.read(&mut self.buf)
            }
            Port::Tcp(s) => {
                s.set_read_timeout(Some(timeout))?;
                s.read(&mut self.buf)
            }
        };
        match r {
            Ok(0) => Err(LinkError::Io(ErrorKind::UnexpectedEof.into())),
            Ok(n) => Ok(n),
            Err(e) if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::WouldBlock) => Ok(0),
            Err(e) if e.kind() == ErrorKind::Interrupted => Ok(0),
            Err(e) => Err(LinkError::Io(e)),
        }
    }

    /// Drops whatever is waiting on the line, as Nomadic's host library does
    /// before each command, so a late reply is never taken for the next one.
    fn flush_input(&mut self) -> Result<(), LinkError> {
        self.splitter.clear();
        match &mut self.port {
            Port::Serial(p) => serialport::SerialPort::clear(p, serialport::ClearBuffer::Input)
                .map_err(|e| LinkError::Io(std::io::Error::other(e))),
            Port::Tcp(s) => {
                s.set_nonblocking(true)?;
                let mut sink = [0u8; 256];
                let r = loop {
                    match s.read(&mut sink) {
                        Ok(0) => break Err(LinkError::Io(ErrorKind::UnexpectedEof.into())),
                        Ok(_) => continue,
                        Err(e) if e.kind() == ErrorKind::WouldBlock => break Ok(()),
                        Err(e) => break Err(LinkError::Io(e)),
                    }
                };
                s.set_nonblocking(false)?;
                r
            }
        }
    }

    fn write_all(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        match &mut self.port {
            Port::Serial(p) => p.write_all(bytes)?,
            Port::Tcp(s) => s.write_all(bytes)?,
        }
        Ok(())
    }

    /// Sends `cmd` and waits up to `timeout` for its state reply.
    pub fn exchange(&mut self, cmd: Command, timeout: Duration) -> Result<StateReply, LinkError> {
        let mut out = [0u8; MAX_FRAME];
        let n = cmd.encode(&mut out)?;
        self.flush_input()?;
        self.write_all(&out[..n])?;
        self.stats.requests += 1;
        let deadline = Instant::now() + timeout;
        loop {
            while let Some(item) = self.splitter.next_frame() {
                // Framing errors are counted by the splitter; keep looking.
                let Ok(frame) = item else { continue };
                match Reply::decode(frame) {
                    Ok(Reply::State { to, state }) if to == cmd.packet_type() => {
                        self.stats.replies += 1;
                        return Ok(state);
                    }
                    Ok(Reply::State { .. }) => self.stats.stale_replies += 1,
                    Ok(Reply::Nak) => {
                        self.stats.naks += 1;
                        return Err(LinkError::Nak);
                    }
                    Err(_) => self.stats.bad_replies += 1,
                }
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                self.stats.timeouts += 1;
                return Err(LinkError::Timeout(timeout));
            }
            let got = self.read_some(left)?;
            // The splitter was drained above, so it has room for more than
            // the 256-byte read buffer (it holds two maximal packets).
            let taken = self.splitter.feed(&self.buf[..got]);
            self.stats.dropped_bytes += (got - taken) as u64;
        }
    }
}

/// How long to wait for one reply: a cycle period, but never less than three
/// times the request+reply wire time at this baud (a 4800-baud Scout needs
/// 113 ms per exchange), nor more than the link timeout.
pub fn reply_timeout(period: Duration, baud: u32, link_timeout: Duration) -> Duration {
    let wire = Duration::from_micros(54 * 10 * 1_000_000 / baud.max(1) as u64);
    period.max(wire * 3).min(link_timeout.max(wire * 2))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn port_spec_tells_tcp_from_serial() {
        assert_eq!(
            PortSpec::parse("tcp://127.0.0.1:65001"),
            PortSpec::Tcp("127.0.0.1:65001".into())
        );
        assert_eq!(
            PortSpec::parse("/dev/scout"),
            PortSpec::Serial("/dev/scout".into())
        );
        assert_eq!(PortSpec::parse("tcp://h:1").to_string(), "tcp://h:1");
    }

    #[test]
    fn reply_timeout_follows_the_baud() {
        let p = Duration::from_millis(100);
        let lt = Duration::from_secs(1);
        assert_eq!(reply_timeout(p, 38400, lt), p);
        // 4800 baud: 54 bytes × 10 bits = 112.5 ms on the wire.
        assert_eq!(reply_timeout(p, 4800, lt), Duration::from_micros(337_500));
    }
}
