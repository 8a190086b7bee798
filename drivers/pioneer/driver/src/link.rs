//! The connection to the controller: a serial device, or TCP to MobileSim /
//! AMRISim (`tcp://127.0.0.1:8101`), the way ARIA connects to a simulator.

use serialport::{ClearBuffer, SerialPort, TTYPort};
use std::io::{self, Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::os::fd::{AsFd, AsRawFd, BorrowedFd};
use std::path::PathBuf;
use std::time::Duration;
use thiserror::Error;

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PortSpec {
    Serial { path: PathBuf, baud: u32 },
    Tcp { addr: String },
}

#[derive(Debug, Error)]
pub enum PortError {
    #[error("port {0:?}: empty")]
    Empty(String),
    #[error("port {spec:?}: expected tcp://HOST:PORT")]
    BadTcp { spec: String },
    #[error("cannot open serial port {path}: {source}")]
    Serial {
        path: String,
        #[source]
        source: serialport::Error,
    },
    #[error("cannot connect to {addr}: {source}")]
    Tcp {
        addr: String,
        #[source]
        source: io::Error,
    },
}

impl std::fmt::Display for PortSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PortSpec::Serial { path, baud } => write!(f, "{} at {baud} baud", path.display()),
            PortSpec::Tcp { addr } => write!(f, "tcp://{addr}"),
        }
    }
}

/// `tcp://host:port` or a device path.
pub fn parse_port(spec: &str, baud: u32) -> Result<PortSpec, PortError> {
    let s = spec.trim();
    if s.is_empty() {
        return Err(PortError::Empty(spec.into()));
    }
    match s.strip_prefix("tcp://") {
        Some(addr) => {
            let ok = addr
                .rsplit_once(':')
                .is_some_and(|(h, p)| !h.is_empty() && p.parse::<u16>().is_ok());
            if !ok {
                return Err(PortError::BadTcp { spec: spec.into() });
            }
            Ok(PortSpec::Tcp { addr: addr.into() })
        }
        None => Ok(PortSpec::Serial {
            path: PathBuf::from(s),
            baud,
        }),
    }
}

pub enum Link {
    Serial(TTYPort),
    Tcp(TcpStream),
}

impl Link {
    pub fn open(spec: &PortSpec) -> Result<Self, PortError> {
        match spec {
            PortSpec::Serial { path, baud } => {
                let p = path.to_string_lossy().into_owned();
                let port = serialport::new(p.clone(), *baud)
                    // Reads happen only after poll() says data is there.
                    .timeout(Duration::from_millis(100))
                    .open_native()
                    .map_err(|source| PortError::Serial {
                        path: p.clone(),
                        source,
                    })?;
                // Whatever piled up before we opened is stale.
                let _ = port.clear(ClearBuffer::Input);
                Ok(Link::Serial(port))
            }
            PortSpec::Tcp { addr } => {
                let err = |source| PortError::Tcp {
                    addr: addr.clone(),
                    source,
                };
                let sa = addr
                    .to_socket_addrs()
                    .map_err(err)?
                    .next()
                    .ok_or_else(|| err(io::ErrorKind::NotFound.into()))?;
                let s = TcpStream::connect_timeout(&sa, Duration::from_secs(2)).map_err(err)?;
                s.set_nodelay(true).map_err(err)?;
                s.set_read_timeout(Some(Duration::from_millis(100)))
                    .map_err(err)?;
                s.set_write_timeout(Some(Duration::from_millis(500)))
                    .map_err(err)?;
                Ok(Link::Tcp(s))
            }
        }
    }

    pub fn fd(&self) -> BorrowedFd<'_> {
        match self {
            // SAFETY: the descriptor is owned by `port`, which outlives the borrow.
            Link::Serial(p) => unsafe { BorrowedFd::borrow_raw(p.as_raw_fd()) },
            Link::Tcp(s) => s.as_fd(),
        }
    }

    /// Reads what is available. `Ok(0)` means the peer closed (TCP).
    pub fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self {
            Link::Serial(p) => p.read(buf),
            Link::Tcp(s) => s.read(buf),
        }
    }

    pub fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        match self {
            Link::Serial(p) => p.write_all(bytes),
            Link::Tcp(s) => s.write_all(bytes),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tcp_and_device_specs_parse() {
        assert_eq!(
            parse_port("tcp://127.0.0.1:8101", 9600).unwrap(),
            PortSpec::Tcp {
                addr: "127.0.0.1:8101".into()
            }
        );
        assert_eq!(
            parse_port("/dev/pioneer", 9600).unwrap(),
            PortSpec::Serial {
                path: "/dev/pioneer".into(),
                baud: 9600
            }
        );
        assert!(matches!(
            parse_port("tcp://nohost", 9600),
            Err(PortError::BadTcp { .. })
        ));
        assert!(matches!(
            parse_port("tcp://:8101", 9600),
            Err(PortError::BadTcp { .. })
        ));
        assert!(matches!(parse_port("  ", 9600), Err(PortError::Empty(_))));
    }
}
