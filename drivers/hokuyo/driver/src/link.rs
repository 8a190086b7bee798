//! The byte pipe to the sensor: a serial device (RS-232 or USB CDC-ACM) or TCP.

use serialport::SerialPort;
use std::io::{self, Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::path::PathBuf;
use std::time::Duration;

/// Where the sensor is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PortSpec {
    Serial(PathBuf),
    /// `host:port` from `tcp://host:port`.
    Tcp(String),
}

impl PortSpec {
    pub fn parse(s: &str) -> PortSpec {
        match s.strip_prefix("tcp://") {
            Some(rest) => PortSpec::Tcp(rest.to_string()),
            None => PortSpec::Serial(PathBuf::from(s)),
        }
    }

    /// Whether the endpoint can be opened now (a serial device node exists).
    pub fn present(&self) -> bool {
        match self {
            PortSpec::Serial(p) => p.exists(),
            PortSpec::Tcp(_) => true,
        }
    }
}

impl std::fmt::Display for PortSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PortSpec::Serial(p) => write!(f, "{}", p.display()),
            PortSpec::Tcp(a) => write!(f, "tcp://{a}"),
        }
    }
}

pub enum Port {
    Serial(serialport::TTYPort),
    Tcp(TcpStream),
}

impl Port {
    pub fn open(spec: &PortSpec, baud: u32) -> io::Result<Port> {
        match spec {
            PortSpec::Serial(path) => {
                let port = serialport::new(path.to_string_lossy(), baud)
                    .timeout(Duration::from_millis(100))
                    .open_native()
                    .map_err(io::Error::from)?;
                Ok(Port::Serial(port))
            }
            PortSpec::Tcp(addr) => {
                let sock = addr.to_socket_addrs()?.next().ok_or_else(|| {
                    io::Error::new(io::ErrorKind::NotFound, format!("{addr}: no address"))
                })?;
                let s = TcpStream::connect_timeout(&sock, Duration::from_secs(2))?;
                s.set_nodelay(true)?;
                Ok(Port::Tcp(s))
            }
        }
    }

    pub fn is_serial(&self) -> bool {
        matches!(self, Port::Serial(_))
    }

    /// Reads what is there, waiting at most `timeout`. `Ok(0)` means nothing came;
    /// a vanished device (hang-up, peer closed) is an error.
    pub fn read_timeout(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        let timeout = timeout.max(Duration::from_millis(1));
        let r = match self {
            Port::Serial(p) => {
                p.set_timeout(timeout).map_err(io::Error::from)?;
                p.read(buf)
            }
            Port::Tcp(s) => {
                s.set_read_timeout(Some(timeout))?;
                s.read(buf)
            }
        };
        match r {
            Ok(0) if !buf.is_empty() => Err(io::Error::new(
                io::ErrorKind::UnexpectedEof,
                "device closed the link",
            )),
            Ok(n) => Ok(n),
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::TimedOut
                        | io::ErrorKind::WouldBlock
                        | io::ErrorKind::Interrupted
                ) =>
            {
                Ok(0)
            }
            Err(e) => Err(e),
        }
    }

    pub fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        match self {
            Port::Serial(p) => {
                p.set_timeout(Duration::from_millis(500))
                    .map_err(io::Error::from)?;
                p.write_all(bytes)?;
                p.flush()
            }
            Port::Tcp(s) => s.write_all(bytes),
        }
    }

    /// Changes the host side's bit rate (no-op over TCP).
    pub fn set_baud(&mut self, baud: u32) -> io::Result<()> {
        match self {
            Port::Serial(p) => p.set_baud_rate(baud).map_err(io::Error::from),
            Port::Tcp(_) => Ok(()),
        }
    }
}
