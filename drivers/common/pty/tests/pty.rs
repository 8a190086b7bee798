//! The cable over real pseudo-terminals, seen from the driver's side: the
//! "driver" here opens the link like a serial port and reads/writes it.

use nix::errno::Errno;
use nix::fcntl::OFlag;
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::sys::stat::Mode;
use nix::sys::termios::{BaudRate, LocalFlags, SetArg, cfsetspeed, tcgetattr, tcsetattr};
use smokenav_common_pty::{DropCause, PtyOptions, PtyPair, PtyPort};
use std::os::fd::{AsFd, BorrowedFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// What a driver does: open the port path (following the link).
fn open_as_driver(path: &Path) -> nix::Result<OwnedFd> {
    nix::fcntl::open(
        path,
        OFlag::O_RDWR | OFlag::O_NOCTTY | OFlag::O_CLOEXEC,
        Mode::empty(),
    )
}

/// Waits up to `ms` for any of `events` (or a hang-up/error) on `fd`.
fn wait(fd: BorrowedFd<'_>, events: PollFlags, ms: u16) -> PollFlags {
    let mut fds = [PollFd::new(fd, events)];
    match poll(&mut fds, PollTimeout::from(ms)) {
        Ok(n) if n > 0 => fds[0].revents().unwrap_or(PollFlags::empty()),
        _ => PollFlags::empty(),
    }
}

/// Reads exactly `n` bytes from `fd`, waiting up to 2 s in all.
fn read_exactly(fd: BorrowedFd<'_>, n: usize) -> Vec<u8> {
    let deadline = Instant::now() + Duration::from_secs(2);
    let mut got = Vec::with_capacity(n);
    let mut buf = [0u8; 4096];
    while got.len() < n {
        assert!(Instant::now() < deadline, "only {} of {n} bytes", got.len());
        if wait(fd, PollFlags::POLLIN, 100).contains(PollFlags::POLLIN) {
            let k = nix::unistd::read(fd, &mut buf[..(n - got.len()).min(4096)]).unwrap();
            got.extend_from_slice(&buf[..k]);
        }
    }
    got
}

fn link_in(dir: &tempfile::TempDir) -> PathBuf {
    dir.path().join("ttyEMU")
}

#[test]
fn raw_slave_passes_control_bytes_unchanged_and_echoes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let port = PtyPort::open(PtyOptions::with_link(link_in(&dir))).unwrap();
    let pair = port.pair().unwrap();
    let driver = open_as_driver(&link_in(&dir)).unwrap();
    // CR (ICRNL would make it LF), ^C (ISIG), ^D (VEOF), a line without
    // newline (ICANON would hold it), DEL (VERASE).
    let to_host = b"\r\x03\x04AB\n\x7f";
    assert_eq!(pair.write(to_host).unwrap(), to_host.len());
    assert_eq!(read_exactly(driver.as_fd(), to_host.len()), to_host);
    // Nothing came back to the emulator (no ECHO).
    assert!(wait(pair.master(), PollFlags::POLLIN, 50).is_empty());
    // LF from the host arrives as LF (no ONLCR to CR LF).
    nix::unistd::write(&driver, b"QT\n").unwrap();
    assert_eq!(read_exactly(pair.master(), 3), b"QT\n");
    let t = tcgetattr(&driver).unwrap();
    assert!(!t.local_flags.contains(LocalFlags::ICANON));
    assert!(!t.local_flags.contains(LocalFlags::ECHO));
}

#[test]
fn spawned_child_inherits_neither_end_and_unplug_still_hangs_up() {
    let dir = tempfile::tempdir().unwrap();
    let link = link_in(&dir);
    let mut port = PtyPort::open(PtyOptions::with_link(&link)).unwrap();
    let slave = port.slave_path().unwrap().to_owned();
    let mut child = std::process::Command::new("sleep")
        .arg("30")
        .stdin(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let held: Vec<PathBuf> = std::fs::read_dir(format!("/proc/{}/fd", child.id()))
        .unwrap()
        .filter_map(|e| std::fs::read_link(e.ok()?.path()).ok())
        .collect();
    let driver = open_as_driver(&link).unwrap();
    port.unplug();
    // The only other holder of the master would be the child.
    let hup = wait(driver.as_fd(), PollFlags::POLLIN, 2000);
    let _ = child.kill();
    let _ = child.wait();
    for p in &held {
        assert_ne!(p, &slave, "child holds the slave: {held:?}");
        assert!(!p.ends_with("ptmx"), "child holds a PTY master: {held:?}");
    }
    assert!(hup.contains(PollFlags::POLLHUP), "{hup:?}");
}

#[test]
fn unplug_removes_the_link_and_a_reader_on_the_slave_sees_the_hang_up() {
    let dir = tempfile::tempdir().unwrap();
    let link = link_in(&dir);
    let mut port = PtyPort::open(PtyOptions::with_link(&link)).unwrap();
    let driver = open_as_driver(&link).unwrap();
    let reader = std::thread::spawn(move || {
        // A driver blocked in read(2) when the cable is pulled.
        let mut buf = [0u8; 16];
        nix::unistd::read(&driver, &mut buf)
    });
    std::thread::sleep(Duration::from_millis(50));
    port.unplug();
    let got = reader.join().unwrap();
    // Linux reports a hung-up PTY slave as EIO, other systems as end of file.
    assert!(matches!(got, Ok(0) | Err(Errno::EIO)), "{got:?}");
    assert!(!port.is_plugged());
    assert_eq!(port.slave_path(), None);
    assert!(std::fs::symlink_metadata(&link).is_err(), "link removed");
    assert!(open_as_driver(&link).is_err());
    port.unplug(); // twice is harmless
}

#[test]
fn replug_moves_the_link_to_a_fresh_slave_that_carries_data() {
    let dir = tempfile::tempdir().unwrap();
    let link = link_in(&dir);
    let mut port = PtyPort::open(PtyOptions::with_link(&link)).unwrap();
    // Keep the first slave open as a stale driver would, so the new pair
    // cannot reuse its number.
    let stale = open_as_driver(&link).unwrap();
    let first = port.slave_path().unwrap().to_owned();
    port.unplug();
    let second = port.replug().unwrap().to_owned();
    assert_ne!(first, second);
    assert_eq!(std::fs::read_link(&link).unwrap(), second);
    let driver = open_as_driver(&link).unwrap();
    nix::unistd::write(&driver, b"SYNC0").unwrap();
    assert_eq!(read_exactly(port.pair().unwrap().master(), 5), b"SYNC0");
    // The stale descriptor stays dead.
    let mut buf = [0u8; 4];
    assert!(matches!(
        nix::unistd::read(&stale, &mut buf),
        Ok(0) | Err(Errno::EIO)
    ));
}

#[test]
fn link_always_names_a_live_slave_while_replugging() {
    let dir = tempfile::tempdir().unwrap();
    let link = link_in(&dir);
    let port = Arc::new(Mutex::new(
        PtyPort::open(PtyOptions::with_link(&link)).unwrap(),
    ));
    // Replugs completed so far; 200 of them, 1 ms apart.
    let replugs = Arc::new(AtomicU64::new(0));
    let replugger = {
        let (port, replugs) = (port.clone(), replugs.clone());
        std::thread::spawn(move || {
            for _ in 0..200 {
                port.lock().unwrap().replug().unwrap();
                replugs.fetch_add(1, Ordering::SeqCst);
                std::thread::sleep(Duration::from_millis(1));
            }
        })
    };
    let mut targets = std::collections::HashSet::new();
    let mut checks = 0u32;
    while replugs.load(Ordering::SeqCst) < 200 {
        let before = replugs.load(Ordering::SeqCst);
        // Never missing: the link is replaced by rename, not remove + create.
        let target = std::fs::read_link(&link).expect("link missing during a replug");
        targets.insert(target.clone());
        if std::fs::metadata(&target).is_err() {
            // The slave it named is gone. With the old pair closed only after
            // the rename, the link has moved on by now, unless a later replug
            // (which must have completed in between) reused the number.
            let now = std::fs::read_link(&link).expect("link missing during a replug");
            let completed = replugs.load(Ordering::SeqCst) - before;
            assert!(now != target || completed > 0, "link names a dead slave");
        }
        checks += 1;
    }
    replugger.join().unwrap();
    assert!(checks > 100, "{checks} checks");
    assert!(targets.len() >= 2, "saw only {targets:?}");
    let port = port.lock().unwrap();
    assert_eq!(
        std::fs::read_link(&link).unwrap(),
        port.slave_path().unwrap()
    );
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names, ["ttyEMU"], "no temporary links left behind");
}

#[test]
fn kept_slave_means_the_master_never_hangs_up_between_driver_opens() {
    let dir = tempfile::tempdir().unwrap();
    let link = link_in(&dir);
    let port = PtyPort::open(PtyOptions::with_link(&link)).unwrap();
    let pair = port.pair().unwrap();
    for round in 0..3u8 {
        let driver = open_as_driver(&link).unwrap();
        nix::unistd::write(&driver, &[b'0' + round]).unwrap();
        drop(driver);
        assert_eq!(read_exactly(pair.master(), 1), [b'0' + round]);
        let ev = wait(pair.master(), PollFlags::POLLIN, 20);
        assert!(!ev.contains(PollFlags::POLLHUP), "round {round}: {ev:?}");
        let mut buf = [0u8; 4];
        let e = pair.read(&mut buf).unwrap_err();
        assert_eq!(e.kind(), std::io::ErrorKind::WouldBlock, "round {round}");
    }
}

#[test]
fn without_kept_slave_the_master_sees_the_driver_close_and_raw_mode_stays() {
    let dir = tempfile::tempdir().unwrap();
    let link = link_in(&dir);
    let port = PtyPort::open(PtyOptions {
        link: Some(link.clone()),
        keep_slave_open: false,
    })
    .unwrap();
    let pair = port.pair().unwrap();
    assert!(pair.slave().is_none());
    let driver = open_as_driver(&link).unwrap();
    let t = tcgetattr(&driver).unwrap();
    assert!(!t.local_flags.contains(LocalFlags::ICANON), "still raw");
    nix::unistd::write(&driver, b"x").unwrap();
    drop(driver);
    assert!(wait(pair.master(), PollFlags::POLLIN, 500).contains(PollFlags::POLLHUP));
    // Buffered input is still delivered, then the hang-up shows as EIO.
    assert_eq!(read_exactly(pair.master(), 1), b"x");
    let e = pair.read(&mut [0u8; 4]).unwrap_err();
    assert_eq!(e.raw_os_error(), Some(Errno::EIO as i32));
}

#[test]
fn kept_slave_shows_the_speed_the_driver_set() {
    let dir = tempfile::tempdir().unwrap();
    let link = link_in(&dir);
    let port = PtyPort::open(PtyOptions::with_link(&link)).unwrap();
    let driver = open_as_driver(&link).unwrap();
    let mut t = tcgetattr(&driver).unwrap();
    cfsetspeed(&mut t, BaudRate::B115200).unwrap();
    tcsetattr(&driver, SetArg::TCSANOW, &t).unwrap();
    let seen = tcgetattr(port.pair().unwrap().slave().unwrap()).unwrap();
    assert_eq!(
        nix::sys::termios::cfgetospeed(&seen),
        BaudRate::B115200,
        "the emulator's slave fd shares the driver's termios"
    );
}

fn pattern(n: usize) -> Vec<u8> {
    (0..n).map(|i| (i % 251) as u8).collect()
}

#[test]
fn write_all_with_nobody_reading_drops_the_rest_after_the_timeout() {
    let pair = PtyPair::open(true).unwrap();
    let bytes = pattern(1 << 20);
    let started = Instant::now();
    let out = pair.write_all(&bytes, Duration::from_millis(50));
    // A bound, not a performance figure: the call must not wait for a reader.
    assert!(started.elapsed() < Duration::from_secs(5));
    assert_eq!(out.cause, Some(DropCause::TimedOut));
    assert!(out.written > 0, "the line buffer takes some");
    assert!(out.dropped > 0, "1 MiB cannot fit in a PTY");
    assert_eq!(out.written + out.dropped, bytes.len());
    // What was taken is exactly the prefix, in order.
    let slave = pair.slave().unwrap();
    assert_eq!(read_exactly(slave, out.written), &bytes[..out.written]);
}

#[test]
fn write_all_with_a_reader_delivers_everything_in_order() {
    let dir = tempfile::tempdir().unwrap();
    let link = link_in(&dir);
    let port = PtyPort::open(PtyOptions::with_link(&link)).unwrap();
    let bytes = pattern(256 * 1024);
    let driver = open_as_driver(&link).unwrap();
    let n = bytes.len();
    let reader = std::thread::spawn(move || read_exactly_slowly(driver, n));
    let out = port
        .pair()
        .unwrap()
        .write_all(&bytes, Duration::from_secs(10));
    assert_eq!(out.cause, None);
    assert_eq!((out.written, out.dropped), (bytes.len(), 0));
    assert!(reader.join().unwrap() == bytes, "bytes differ");
}

/// Like [`read_exactly`] but with a longer deadline, for 256 KiB.
fn read_exactly_slowly(fd: OwnedFd, n: usize) -> Vec<u8> {
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut got = Vec::with_capacity(n);
    let mut buf = [0u8; 4096];
    while got.len() < n && Instant::now() < deadline {
        if wait(fd.as_fd(), PollFlags::POLLIN, 100).contains(PollFlags::POLLIN) {
            let k = nix::unistd::read(&fd, &mut buf).unwrap();
            got.extend_from_slice(&buf[..k]);
        }
    }
    got
}

#[test]
fn dropping_a_port_removes_only_its_own_link() {
    let dir = tempfile::tempdir().unwrap();
    let link = link_in(&dir);
    let a = PtyPort::open(PtyOptions::with_link(&link)).unwrap();
    let b = PtyPort::open(PtyOptions::with_link(&link)).unwrap();
    assert_eq!(std::fs::read_link(&link).unwrap(), b.slave_path().unwrap());
    drop(a);
    assert_eq!(
        std::fs::read_link(&link).unwrap(),
        b.slave_path().unwrap(),
        "a newer port's link survives the older port"
    );
    drop(b);
    assert!(std::fs::symlink_metadata(&link).is_err());
}

#[test]
fn port_without_link_serves_the_bare_slave_across_replugs() {
    let mut port = PtyPort::open(PtyOptions::default()).unwrap();
    assert_eq!(port.link(), None);
    let first = port.slave_path().unwrap().to_owned();
    let driver = open_as_driver(&first).unwrap();
    nix::unistd::write(&driver, b"VV\n").unwrap();
    assert_eq!(read_exactly(port.pair().unwrap().master(), 3), b"VV\n");
    port.unplug();
    assert!(port.pair().is_none());
    let second = port.replug().unwrap().to_owned();
    assert!(second.starts_with("/dev/pts/"));
    let driver = open_as_driver(&second).unwrap();
    nix::unistd::write(&driver, b"II\n").unwrap();
    assert_eq!(read_exactly(port.pair().unwrap().master(), 3), b"II\n");
}
