//! The emulator's side of the link: a PTY master (with a stable symlink to the
//! slave) or a TCP listener with one client.

use crate::Endpoint;
use nix::fcntl::{FcntlArg, FdFlag, OFlag, fcntl};
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
use std::io::{self, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::os::fd::{AsFd, AsRawFd, BorrowedFd, OwnedFd};
use std::path::{Path, PathBuf};

pub fn set_nonblocking(fd: &impl AsFd) -> io::Result<()> {
    let flags = OFlag::from_bits_truncate(fcntl(fd, FcntlArg::F_GETFL).map_err(io::Error::from)?);
    fcntl(fd, FcntlArg::F_SETFL(flags | OFlag::O_NONBLOCK)).map_err(io::Error::from)?;
    Ok(())
}

pub enum Transport {
    Pty {
        master: OwnedFd,
        /// Held open so the master never sees EIO while the host has the port closed,
        /// and so the termios (the host's baud) can be read.
        slave: OwnedFd,
        slave_path: PathBuf,
        link: Option<PathBuf>,
    },
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
            Endpoint::Pty { link } => {
                let pty = nix::pty::openpty(None, None).map_err(io::Error::from)?;
                // openpty(3) cannot set close-on-exec; without it every process
                // the test (or simulator) spawns inherits the master, and an
                // unplug never hangs up the driver's end.
                for fd in [&pty.master, &pty.slave] {
                    fcntl(fd, FcntlArg::F_SETFD(FdFlag::FD_CLOEXEC)).map_err(io::Error::from)?;
                }
                // Raw line discipline: no echo of the host's requests, no CR/LF mapping.
                let mut t = tcgetattr(&pty.slave).map_err(io::Error::from)?;
                cfmakeraw(&mut t);
                tcsetattr(&pty.slave, SetArg::TCSANOW, &t).map_err(io::Error::from)?;
                set_nonblocking(&pty.master)?;
                let slave_path =
                    std::fs::read_link(format!("/proc/self/fd/{}", pty.slave.as_raw_fd()))?;
                if let Some(link) = link {
                    replace_symlink(&slave_path, link)?;
                }
                Ok(Transport::Pty {
                    master: pty.master,
                    slave: pty.slave,
                    slave_path,
                    link: link.clone(),
                })
            }
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
            Transport::Pty { slave_path, .. } => Some(slave_path.clone()),
            _ => None,
        }
    }

    pub fn tcp_port(&self) -> Option<u16> {
        match self {
            Transport::Tcp { listener, .. } => listener.local_addr().ok().map(|a| a.port()),
            Transport::Closed { tcp_port } => *tcp_port,
            Transport::Pty { .. } => None,
        }
    }

    pub fn close(&mut self) {
        if let Transport::Pty {
            link: Some(link), ..
        } = self
        {
            let _ = std::fs::remove_file(link);
        }
        let tcp_port = self.tcp_port();
        *self = Transport::Closed { tcp_port };
    }

    /// The fd to wait on: the PTY master, the TCP client, or the listener.
    pub fn poll_fd(&self) -> Option<BorrowedFd<'_>> {
        match self {
            Transport::Pty { master, .. } => Some(master.as_fd()),
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
            Transport::Pty { master, .. } => {
                nix::unistd::read(&*master, buf).map_err(io::Error::from)
            }
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
            Transport::Pty { master, .. } => {
                nix::unistd::write(&*master, bytes).map_err(io::Error::from)
            }
            Transport::Tcp {
                client: Some(c), ..
            } => c.write(bytes),
            // Nobody connected: the bytes go nowhere, as from a device with no host.
            _ => Ok(bytes.len()),
        }
    }

    /// The bit rate the host set on its end of the PTY.
    pub fn host_baud(&self) -> Option<u32> {
        let Transport::Pty { slave, .. } = self else {
            return None;
        };
        let mut t = std::mem::MaybeUninit::<nix::libc::termios2>::zeroed();
        // SAFETY: `slave` is an open tty fd we own; TCGETS2 fills a plain C struct of
        // exactly this type, which zeroed memory already makes a valid value.
        let ok = unsafe { tcgets2(slave.as_raw_fd(), t.as_mut_ptr()) }.is_ok();
        // SAFETY: zero-initialised above and possibly filled by the kernel: valid either way.
        ok.then(|| unsafe { t.assume_init() }.c_ospeed)
    }
}

/// Points `link` at `target`, replacing any old link atomically.
fn replace_symlink(target: &Path, link: &Path) -> io::Result<()> {
    let tmp = link.with_extension("new-link");
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp)?;
    std::fs::rename(&tmp, link)
}
