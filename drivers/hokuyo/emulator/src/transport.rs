//! The emulator's side of the link: a PTY (with a stable symlink to the
//! slave) or a TCP listener with one client.

use crate::Endpoint;
use smokenav_common_pty::{PtyOptions, PtyPair, PtyPort};
use std::io::{self, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::os::fd::{AsFd, AsRawFd, BorrowedFd};
use std::path::{Path, PathBuf};

pub enum Transport {
    /// Always plugged in: an unplugged PTY becomes [`Transport::Closed`].
    Pty(PtyPort),
    Tcp {
        listener: TcpListener,
        client: Option<TcpStream>,
    },
    Closed {
        tcp_port: Option<u16>,
    },
}

nix::ioctl_read_bad!(tcgets2, nix::libc::TCGETS2, nix::libc::termios2);

impl Transport {
    pub fn open(endpoint: &Endpoint, tcp_port: Option<u16>) -> io::Result<Transport> {
        match endpoint {
            Endpoint::Pty { link } => Ok(Transport::Pty(PtyPort::open(PtyOptions {
                link: link.clone(),
                // Held open so the master never sees EIO while the host has the
                // port closed, and so the termios (the host's baud) can be read.
                keep_slave_open: true,
            })?)),
            Endpoint::Tcp { addr } => {
                let mut addr = *addr;
                if let Some(p) = tcp_port {
                    addr.set_port(p);
                }
                let listener = TcpListener::bind(addr)?;
                listener.set_nonblocking(true)?;
                Ok(Transport::Tcp {
                    listener,
                    client: None,
                })
            }
        }
    }

    pub fn slave_path(&self) -> Option<PathBuf> {
        match self {
            Transport::Pty(port) => port.slave_path().map(Path::to_path_buf),
            _ => None,
        }
    }

    pub fn tcp_port(&self) -> Option<u16> {
        match self {
            Transport::Tcp { listener, .. } => listener.local_addr().ok().map(|a| a.port()),
            Transport::Closed { tcp_port } => *tcp_port,
            Transport::Pty(_) => None,
        }
    }

    pub fn close(&mut self) {
        if let Transport::Pty(port) = self {
            port.unplug();
        }
        let tcp_port = self.tcp_port();
        *self = Transport::Closed { tcp_port };
    }

    /// The fd to wait on: the PTY master, the TCP client, or the listener.
    pub fn poll_fd(&self) -> Option<BorrowedFd<'_>> {
        match self {
            Transport::Pty(port) => port.pair().map(PtyPair::master),
            Transport::Tcp {
                client: Some(c), ..
            } => Some(c.as_fd()),
            Transport::Tcp {
                listener,
                client: None,
            } => Some(listener.as_fd()),
            Transport::Closed { .. } => None,
        }
    }

    pub fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self {
            Transport::Pty(port) => port.pair().ok_or(io::ErrorKind::NotConnected)?.read(buf),
            Transport::Tcp { listener, client } => {
                let Some(c) = client else {
                    let (stream, peer) = listener.accept()?;
                    stream.set_nonblocking(true)?;
                    let _ = stream.set_nodelay(true);
                    tracing::info!(%peer, "emulator: TCP client connected");
                    *client = Some(stream);
                    return Ok(0);
                };
                match c.read(buf) {
                    Ok(0) => {
                        tracing::info!("emulator: TCP client closed");
                        *client = None;
                        Ok(0)
                    }
                    Err(e) if e.kind() == io::ErrorKind::WouldBlock => Err(e),
                    Err(e) => {
                        *client = None;
                        Err(e)
                    }
                    Ok(n) => Ok(n),
                }
            }
            Transport::Closed { .. } => Ok(0),
        }
    }

    pub fn write(&mut self, bytes: &[u8]) -> io::Result<usize> {
        match self {
            Transport::Pty(port) => port.pair().ok_or(io::ErrorKind::NotConnected)?.write(bytes),
            Transport::Tcp {
                client: Some(c), ..
            } => c.write(bytes),
            // Nobody connected: the bytes go nowhere, as from a device with no host.
            _ => Ok(bytes.len()),
        }
    }

    /// The bit rate the host set on its end of the PTY.
    pub fn host_baud(&self) -> Option<u32> {
        let Transport::Pty(port) = self else {
            return None;
        };
        let slave = port.pair()?.slave()?;
        let mut t = std::mem::MaybeUninit::<nix::libc::termios2>::zeroed();
        // SAFETY: `slave` is an open tty fd we own; TCGETS2 fills a plain C struct of
        // exactly this type, which zeroed memory already makes a valid value.
        let ok = unsafe { tcgets2(slave.as_raw_fd(), t.as_mut_ptr()) }.is_ok();
        // SAFETY: zero-initialised above and possibly filled by the kernel: valid either way.
        ok.then(|| unsafe { t.assume_init() }.c_ospeed)
    }
}
