//! A minimal SCIP host for the tests: opens the PTY slave like a driver would,
//! sets raw mode and a baud rate, and reads frames with the codec's splitter.

#![allow(dead_code)]

use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::sys::termios::{BaudRate, SetArg, cfmakeraw, cfsetspeed, tcgetattr, tcsetattr};
use smokenav_hokuyo_codec::FrameSplitter;
use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::os::fd::AsFd;
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;
use std::time::{Duration, Instant};

pub struct Host {
    port: Box<dyn ReadWrite>,
    splitter: FrameSplitter,
}

pub trait ReadWrite: Read + Write + AsFd + Send {}
impl<T: Read + Write + AsFd + Send> ReadWrite for T {}

impl Host {
    pub fn open_pty(path: &Path, baud: BaudRate) -> Host {
        let file: File = OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(nix::libc::O_NOCTTY | nix::libc::O_NONBLOCK)
            .open(path)
            .unwrap_or_else(|e| panic!("open {}: {e}", path.display()));
        let mut t = tcgetattr(&file).unwrap();
        cfmakeraw(&mut t);
        cfsetspeed(&mut t, baud).unwrap();
        tcsetattr(&file, SetArg::TCSANOW, &t).unwrap();
        Host {
            port: Box::new(file),
            splitter: FrameSplitter::default(),
        }
    }

    pub fn open_tcp(addr: &str) -> Host {
        let s = std::net::TcpStream::connect(addr).unwrap();
        s.set_nonblocking(true).unwrap();
        Host {
            port: Box::new(s),
            splitter: FrameSplitter::default(),
        }
    }

    pub fn set_baud(&mut self, baud: BaudRate) {
        let mut t = tcgetattr(self.port.as_fd()).unwrap();
        cfsetspeed(&mut t, baud).unwrap();
        tcsetattr(self.port.as_fd(), SetArg::TCSANOW, &t).unwrap();
    }

    pub fn send(&mut self, line: &str) {
        self.port.write_all(line.as_bytes()).unwrap();
        self.port.write_all(b"\n").unwrap();
    }

    /// The next complete frame, or `None` after `timeout`.
    pub fn frame(&mut self, timeout: Duration) -> Option<Vec<u8>> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(f) = self.splitter.next_frame() {
                return Some(f.to_vec());
            }
            let left = deadline.checked_duration_since(Instant::now())?;
            let mut fds = [PollFd::new(self.port.as_fd(), PollFlags::POLLIN)];
            let ms = left.as_millis().clamp(1, 60_000) as u16;
            poll(&mut fds, PollTimeout::from(ms)).ok()?;
            let spare = self.splitter.spare();
            match self.port.read(spare) {
                Ok(0) => return None,
                Ok(n) => self.splitter.commit(n),
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
                Err(_) => return None,
            }
        }
    }

    /// Sends `line` and returns the next frame (panics after 1 s).
    pub fn ask(&mut self, line: &str) -> Vec<u8> {
        self.send(line);
        self.frame(Duration::from_secs(1))
            .unwrap_or_else(|| panic!("no reply to {line:?}"))
    }
}
