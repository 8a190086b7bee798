//! The emulated cable: a PTY pair plus a stable symlink to its slave side.

use crate::EmulatorError;
use nix::fcntl::{FcntlArg, FdFlag, OFlag, fcntl};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};

pub(crate) struct Link {
    pub master: OwnedFd,
    /// Held open so the master never sees a hang-up when the driver closes
    /// and reopens the port (a real robot's UART does not vanish either).
    _slave: OwnedFd,
    pub device: PathBuf,
}

impl Link {
    pub fn open(link_path: &Path) -> Result<Link, EmulatorError> {
        let pty = nix::pty::openpty(None, None).map_err(EmulatorError::Pty)?;
        // openpty(3) cannot set close-on-exec; without it every process the
        // test (or simulator) spawns inherits the master, and an unplug never
        // hangs up the driver's end.
        for fd in [&pty.master, &pty.slave] {
            fcntl(fd, FcntlArg::F_SETFD(FdFlag::FD_CLOEXEC)).map_err(EmulatorError::Pty)?;
        }
        // Raw from the start so nothing is echoed or translated before the
        // driver sets its own termios.
        let mut t = tcgetattr(&pty.slave).map_err(EmulatorError::Pty)?;
        cfmakeraw(&mut t);
        tcsetattr(&pty.slave, SetArg::TCSANOW, &t).map_err(EmulatorError::Pty)?;
        let flags = fcntl(&pty.master, FcntlArg::F_GETFL).map_err(EmulatorError::Pty)?;
        fcntl(
            &pty.master,
            FcntlArg::F_SETFL(OFlag::from_bits_truncate(flags) | OFlag::O_NONBLOCK),
        )
        .map_err(EmulatorError::Pty)?;
        let device = nix::unistd::ttyname(&pty.slave).map_err(EmulatorError::Pty)?;
        relink(link_path, &device).map_err(|source| EmulatorError::Link {
            link: link_path.to_path_buf(),
            source,
        })?;
        Ok(Link {
            master: pty.master,
            _slave: pty.slave,
            device,
        })
    }

    /// Writes everything it can; returns the bytes dropped because the line
    /// stayed full for 100 ms (nobody reading the port).
    pub fn write_all(&self, mut bytes: &[u8]) -> usize {
        while !bytes.is_empty() {
            match nix::unistd::write(&self.master, bytes) {
                Ok(n) => bytes = &bytes[n..],
                Err(nix::errno::Errno::EINTR) => {}
                Err(nix::errno::Errno::EAGAIN) => {
                    let mut fds = [PollFd::new(self.master.as_fd(), PollFlags::POLLOUT)];
                    if !matches!(poll(&mut fds, PollTimeout::from(100u8)), Ok(n) if n > 0) {
                        return bytes.len();
                    }
                }
                Err(_) => return bytes.len(),
            }
        }
        0
    }
}

/// Points `link` at `target` atomically (a reader never sees it missing
/// during a replug).
fn relink(link: &Path, target: &Path) -> std::io::Result<()> {
    let mut tmp = link.as_os_str().to_owned();
    tmp.push(format!(".{}.tmp", std::process::id()));
    let tmp = PathBuf::from(tmp);
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp)?;
    std::fs::rename(&tmp, link)
}
