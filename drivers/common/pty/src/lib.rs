//! The emulated serial cable every device emulator uses.
//!
//! A [`PtyPair`] is one pseudo-terminal, made the way an emulator needs it:
//!
//! - both ends close-on-exec from the start (`posix_openpt(O_CLOEXEC)`, then the
//!   slave opened with `O_CLOEXEC`). `openpty(3)` can only set `FD_CLOEXEC`
//!   afterwards, and a process spawned in between (the driver under test)
//!   would inherit the master; closing ours would then no longer hang up the
//!   driver's end and an unplug would go unnoticed;
//! - `O_NOCTTY` on both ends, so the emulator never acquires a controlling
//!   terminal;
//! - the slave in raw mode (`cfmakeraw`), so nothing is echoed back to the
//!   emulator and no CR/LF or control byte is translated before the driver
//!   sets its own termios;
//! - the master non-blocking, for an emulator thread that waits with `poll`;
//! - optionally the slave held open by the emulator, so the master never sees
//!   a hang-up (`EIO`, `POLLHUP`) while the driver closes and reopens the port,
//!   as a real UART does not vanish when its host closes it.
//!
//! A [`PtyPort`] is the cable: the current pair plus a stable symlink to its
//! slave (a udev-like name such as `/dev/serial/by-id/...`). The link is
//! replaced atomically (a temporary symlink renamed over it), so a driver
//! never finds it missing or half-made while it moves. [`PtyPort::unplug`]
//! removes the link and closes the pair (the driver's reads fail);
//! [`PtyPort::replug`] makes a new pair (usually a different `/dev/pts/N`) and
//! moves the link to it.

use nix::errno::Errno;
use nix::fcntl::{FcntlArg, OFlag, fcntl};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::pty::{PtyMaster, grantpt, posix_openpt, ptsname_r, unlockpt};
use nix::sys::stat::Mode;
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
use std::ffi::OsString;
use std::io;
use std::os::fd::{AsFd, BorrowedFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Why a pseudo-terminal or its link could not be made.
#[derive(Debug, thiserror::Error)]
pub enum PtyError {
    /// One of the system calls that make the pair failed.
    #[error("cannot create the pseudo-terminal: {step} failed: {source}")]
    Create {
        /// The call that failed (`posix_openpt`, `grantpt`, ...).
        step: &'static str,
        source: Errno,
    },
    /// The pair exists but the stable symlink could not be pointed at it.
    #[error("cannot point {link} at {target}: {source}")]
    Link {
        link: PathBuf,
        target: PathBuf,
        source: io::Error,
    },
}

impl From<PtyError> for io::Error {
    fn from(e: PtyError) -> io::Error {
        let kind = match &e {
            PtyError::Create { source, .. } => io::Error::from(*source).kind(),
            PtyError::Link { source, .. } => source.kind(),
        };
        io::Error::new(kind, e)
    }
}

/// Why [`PtyPair::write_all`] left bytes unwritten.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DropCause {
    /// The line stayed full until the timeout (nobody reading the slave).
    TimedOut,
    /// The write failed with this error.
    Failed(Errno),
}

/// What [`PtyPair::write_all`] did with the bytes it was given.
#[must_use]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WriteOutcome {
    /// Bytes the PTY took, a prefix of the input.
    pub written: usize,
    /// Bytes left over and dropped, as a serial line loses them.
    pub dropped: usize,
    /// Why bytes were dropped; `None` when all were written.
    pub cause: Option<DropCause>,
}

/// One pseudo-terminal pair, raw and close-on-exec, with a non-blocking master.
#[derive(Debug)]
pub struct PtyPair {
    master: PtyMaster,
    slave: Option<OwnedFd>,
    slave_path: PathBuf,
}

impl PtyPair {
    /// Opens a new pair. With `keep_slave_open` the emulator holds the slave
    /// too, so the master never hangs up between driver opens (and the
    /// driver's termios can be read through [`PtyPair::slave`]).
    pub fn open(keep_slave_open: bool) -> Result<PtyPair, PtyError> {
        let step = |step: &'static str| move |source: Errno| PtyError::Create { step, source };
        let master = posix_openpt(OFlag::O_RDWR | OFlag::O_NOCTTY | OFlag::O_CLOEXEC)
            .map_err(step("posix_openpt"))?;
        grantpt(&master).map_err(step("grantpt"))?;
        unlockpt(&master).map_err(step("unlockpt"))?;
        let slave_path = PathBuf::from(ptsname_r(&master).map_err(step("ptsname_r"))?);
        let slave = nix::fcntl::open(
            &slave_path,
            OFlag::O_RDWR | OFlag::O_NOCTTY | OFlag::O_CLOEXEC,
            Mode::empty(),
        )
        .map_err(step("opening the slave"))?;
        // The termios lives with the pair, not with this slave fd: it stays
        // raw after we close the slave and until the driver changes it.
        let mut t = tcgetattr(&slave).map_err(step("tcgetattr"))?;
        cfmakeraw(&mut t);
        tcsetattr(&slave, SetArg::TCSANOW, &t).map_err(step("tcsetattr"))?;
        let flags = fcntl(&master, FcntlArg::F_GETFL).map_err(step("fcntl(F_GETFL)"))?;
        fcntl(
            &master,
            FcntlArg::F_SETFL(OFlag::from_bits_truncate(flags) | OFlag::O_NONBLOCK),
        )
        .map_err(step("fcntl(F_SETFL, O_NONBLOCK)"))?;
        Ok(PtyPair {
            master,
            slave: keep_slave_open.then_some(slave),
            slave_path,
        })
    }

    /// The master, to wait on with `poll`.
    pub fn master(&self) -> BorrowedFd<'_> {
        self.master.as_fd()
    }

    /// The slave the emulator holds open, if it does (e.g. to read the
    /// host's baud with `TCGETS2`).
    pub fn slave(&self) -> Option<BorrowedFd<'_>> {
        self.slave.as_ref().map(|s| s.as_fd())
    }

    /// The slave device, `/dev/pts/N`.
    pub fn slave_path(&self) -> &Path {
        &self.slave_path
    }

    /// Reads what the host wrote. Non-blocking: `WouldBlock` when there is
    /// nothing; `EIO` when no slave is open (only without `keep_slave_open`).
    pub fn read(&self, buf: &mut [u8]) -> io::Result<usize> {
        nix::unistd::read(&self.master, buf).map_err(io::Error::from)
    }

    /// One non-blocking write; `WouldBlock` when the line is full.
    pub fn write(&self, bytes: &[u8]) -> io::Result<usize> {
        nix::unistd::write(&self.master, bytes).map_err(io::Error::from)
    }

    /// Writes all of `bytes`, waiting (with `poll`, never spinning) while the
    /// line is full, for at most `timeout` in all. What is still unwritten
    /// then, or after a write error, is dropped and reported, as a serial
    /// line with no reader loses it.
    pub fn write_all(&self, bytes: &[u8], timeout: Duration) -> WriteOutcome {
        let mut rest = bytes;
        let mut deadline = None;
        let mut cause = None;
        while !rest.is_empty() {
            match nix::unistd::write(&self.master, rest) {
                Ok(n) => rest = rest.get(n..).unwrap_or_default(),
                Err(Errno::EINTR) => {}
                Err(Errno::EAGAIN) => {
                    let deadline = *deadline.get_or_insert_with(|| Instant::now() + timeout);
                    let left = deadline.saturating_duration_since(Instant::now());
                    if left.is_zero() || !self.wait_writable(left) {
                        cause = Some(DropCause::TimedOut);
                        break;
                    }
                }
                Err(e) => {
                    cause = Some(DropCause::Failed(e));
                    break;
                }
            }
        }
        WriteOutcome {
            written: bytes.len() - rest.len(),
            dropped: rest.len(),
            cause,
        }
    }

    /// Waits up to `left` for room on the line; false on timeout.
    fn wait_writable(&self, left: Duration) -> bool {
        // Round up: a 0 ms poll for a sub-millisecond remainder would spin.
        let ms = left.as_micros().div_ceil(1000);
        let timeout = PollTimeout::try_from(ms).unwrap_or(PollTimeout::MAX);
        let mut fds = [PollFd::new(self.master.as_fd(), PollFlags::POLLOUT)];
        match poll(&mut fds, timeout) {
            Ok(n) => n > 0,
            // A signal cut the wait short; the caller's deadline still holds.
            Err(Errno::EINTR) => true,
            Err(_) => false,
        }
    }
}

/// How to make a [`PtyPort`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PtyOptions {
    /// The stable symlink a driver opens; `None` serves the bare `/dev/pts/N`.
    pub link: Option<PathBuf>,
    /// Hold the slave open (see [`PtyPair::open`]).
    pub keep_slave_open: bool,
}

impl Default for PtyOptions {
    /// No link, slave kept open.
    fn default() -> Self {
        PtyOptions {
            link: None,
            keep_slave_open: true,
        }
    }
}

impl PtyOptions {
    /// A port behind `link`, slave kept open: what every emulator wants.
    pub fn with_link(link: impl Into<PathBuf>) -> Self {
        PtyOptions {
            link: Some(link.into()),
            ..PtyOptions::default()
        }
    }
}

/// The emulated cable: a [`PtyPair`] behind a stable symlink, which can be
/// unplugged and plugged back in. Dropping it unplugs it.
#[derive(Debug)]
pub struct PtyPort {
    link: Option<PathBuf>,
    keep_slave_open: bool,
    pair: Option<PtyPair>,
}

impl PtyPort {
    /// A new pair, plugged in, with the link (if any) pointing at its slave.
    pub fn open(options: PtyOptions) -> Result<PtyPort, PtyError> {
        let mut port = PtyPort {
            link: options.link,
            keep_slave_open: options.keep_slave_open,
            pair: None,
        };
        port.replug()?;
        Ok(port)
    }

    /// The current pair; `None` while unplugged.
    pub fn pair(&self) -> Option<&PtyPair> {
        self.pair.as_ref()
    }

    pub fn is_plugged(&self) -> bool {
        self.pair.is_some()
    }

    /// The current slave device; `None` while unplugged.
    pub fn slave_path(&self) -> Option<&Path> {
        self.pair.as_ref().map(PtyPair::slave_path)
    }

    /// The stable symlink, if the port has one.
    pub fn link(&self) -> Option<&Path> {
        self.link.as_deref()
    }

    /// Pulls the cable: the link goes, then the pair closes, so the driver's
    /// reads fail (`EIO`/hang-up) and it cannot reopen the path. Nothing
    /// happens if already unplugged.
    pub fn unplug(&mut self) {
        // Link first: a driver woken by the hang-up must not find it.
        self.remove_link_if_ours();
        self.pair = None;
    }

    /// Plugs a new cable in: a fresh pair, and the link moved to its slave.
    /// If a pair was plugged, it closes only after the link has moved, so the
    /// link never names a dead slave. Returns the new slave path; on error the
    /// port is left as it was.
    pub fn replug(&mut self) -> Result<&Path, PtyError> {
        let pair = PtyPair::open(self.keep_slave_open)?;
        if let Some(link) = &self.link {
            replace_symlink(pair.slave_path(), link).map_err(|source| PtyError::Link {
                link: link.clone(),
                target: pair.slave_path().to_owned(),
                source,
            })?;
        }
        Ok(self.pair.insert(pair).slave_path())
    }

    /// Removes the link only while it names our slave: another emulator may
    /// have taken the name over.
    fn remove_link_if_ours(&self) {
        let (Some(link), Some(pair)) = (&self.link, &self.pair) else {
            return;
        };
        if std::fs::read_link(link).is_ok_and(|target| target == pair.slave_path()) {
            let _ = std::fs::remove_file(link);
        }
    }
}

impl Drop for PtyPort {
    fn drop(&mut self) {
        self.unplug();
    }
}

/// Points `link` at `target`, replacing whatever `link` was in one `rename`,
/// so a reader sees the old target or the new one, never nothing.
fn replace_symlink(target: &Path, link: &Path) -> io::Result<()> {
    let tmp = temp_link_name(link);
    std::os::unix::fs::symlink(target, &tmp)?;
    std::fs::rename(&tmp, link).inspect_err(|_| {
        let _ = std::fs::remove_file(&tmp);
    })
}

/// A name beside `link` that no other port, thread or process is using:
/// `<link>.<pid>-<n>.tmp`.
fn temp_link_name(link: &Path) -> PathBuf {
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    let mut name: OsString = link
        .file_name()
        .map_or_else(|| "pty-link".into(), ToOwned::to_owned);
    name.push(format!(".{}-{n}.tmp", std::process::id()));
    link.with_file_name(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names_in(dir: &Path) -> Vec<OsString> {
        let entries = std::fs::read_dir(dir).unwrap();
        entries.map(|e| e.unwrap().file_name()).collect()
    }

    #[test]
    fn temp_link_names_are_beside_the_link_and_never_repeat() {
        let link = Path::new("/run/smokenav/hokuyo");
        let a = temp_link_name(link);
        let b = temp_link_name(link);
        assert_ne!(a, b);
        assert_eq!(a.parent(), link.parent());
        let name = a.file_name().and_then(|n| n.to_str()).unwrap_or_default();
        assert!(name.starts_with("hokuyo."), "{name}");
        assert!(name.ends_with(".tmp"), "{name}");
        // A dotted link name keeps its whole name (no extension swapped).
        let dotted = temp_link_name(Path::new("/tmp/laser.dev"));
        assert!(
            dotted
                .to_str()
                .is_some_and(|s| s.starts_with("/tmp/laser.dev.")),
            "{dotted:?}"
        );
    }

    #[test]
    fn replace_symlink_swaps_the_target_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("port");
        replace_symlink(Path::new("/dev/pts/1"), &link).unwrap();
        replace_symlink(Path::new("/dev/pts/2"), &link).unwrap();
        assert_eq!(std::fs::read_link(&link).unwrap(), Path::new("/dev/pts/2"));
        let names = names_in(dir.path());
        assert_eq!(names, ["port"]);
    }

    #[test]
    fn replace_symlink_over_a_regular_file_replaces_it() {
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("port");
        std::fs::write(&link, b"stale").unwrap();
        replace_symlink(Path::new("/dev/pts/7"), &link).unwrap();
        assert_eq!(std::fs::read_link(&link).unwrap(), Path::new("/dev/pts/7"));
    }

    #[test]
    fn failed_link_reports_the_paths_and_cleans_up() {
        let dir = tempfile::tempdir().unwrap();
        // A directory at the link path: rename(2) cannot replace it with a symlink.
        let link = dir.path().join("port");
        std::fs::create_dir(&link).unwrap();
        let err = PtyPort::open(PtyOptions::with_link(&link)).unwrap_err();
        let PtyError::Link {
            link: l, target, ..
        } = &err
        else {
            panic!("{err:?}")
        };
        assert_eq!(l, &link);
        assert!(target.starts_with("/dev/pts/"), "{target:?}");
        assert!(err.to_string().contains("port"), "{err}");
        let names = names_in(dir.path());
        assert_eq!(names, ["port"], "the temporary link is removed");
        assert_eq!(io::Error::from(err).kind(), io::ErrorKind::IsADirectory);
    }

    #[test]
    fn pair_slave_path_is_a_pts_device_and_master_starts_empty() {
        let pair = PtyPair::open(true).unwrap();
        assert!(pair.slave_path().starts_with("/dev/pts/"));
        assert!(pair.slave().is_some());
        let mut buf = [0u8; 8];
        // Non-blocking: nothing written yet, so no wait and no data.
        let err = pair.read(&mut buf).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::WouldBlock);
    }
}
