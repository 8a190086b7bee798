//! The systemd notify protocol as a `Type=notify` unit with `WatchdogSec=`
//! sees it: the service manager's side is a Unix datagram socket named by
//! `NOTIFY_SOCKET`, with `WATCHDOG_USEC` in the environment (what systemd
//! sets). The real fusion and SLAM processes must say `READY=1` with a
//! `STATUS=` once they serve, ping `WATCHDOG=1` at least every half interval
//! while they run, and say `STOPPING=1` on SIGTERM before exiting cleanly.
//! (PID 1 on the test machines is not systemd, so this is the closest to a
//! booted system the tests get; `systemd/check` verifies the units.)

use smokenav_tests::{Child, bin, profile, unique_instance};
use std::os::unix::net::UnixDatagram;
use std::time::{Duration, Instant};

/// Datagrams received until `until` or `stop` holds for one, with arrival times.
fn receive(
    sock: &UnixDatagram,
    until: Instant,
    mut stop: impl FnMut(&str) -> bool,
) -> Vec<(Instant, String)> {
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    while Instant::now() < until {
        sock.set_read_timeout(Some(
            until
                .saturating_duration_since(Instant::now())
                .max(Duration::from_millis(1)),
        ))
        .unwrap();
        match sock.recv(&mut buf) {
            Ok(n) => {
                let text = String::from_utf8_lossy(&buf[..n]).into_owned();
                let done = stop(&text);
                got.push((Instant::now(), text));
                if done {
                    break;
                }
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                break;
            }
            Err(e) => panic!("notify socket: {e}"),
        }
    }
    got
}

fn check_role(role: &str) {
    let dir = tempfile::tempdir().unwrap();
    let cfg = profile(dir.path(), "pioneer-3dx.toml", |_| {});
    let path = dir.path().join("notify.sock");
    let sock = UnixDatagram::bind(&path).unwrap();
    let instance = unique_instance(&format!("notify_{role}"));
    let socket = path.to_string_lossy().into_owned();
    let mut child = Child::spawn_env(
        &bin(&format!("smokenav-{role}")),
        &["--config", &cfg.to_string_lossy()],
        &instance,
        &[("NOTIFY_SOCKET", &socket), ("WATCHDOG_USEC", "1000000")],
    )
    .unwrap();

    let ready = receive(&sock, Instant::now() + Duration::from_secs(60), |m| {
        m.lines().any(|l| l == "READY=1")
    });
    let (_, msg) = ready
        .last()
        .unwrap_or_else(|| panic!("{role}: nothing on the notify socket\n{}", child.output()));
    assert!(
        msg.lines().any(|l| l == "READY=1"),
        "{role}: no READY=1 in {ready:?}\n{}",
        child.output()
    );
    assert!(
        msg.lines().any(|l| l.starts_with("STATUS=") && l.len() > 7),
        "{role}: READY=1 comes with a status: {msg:?}"
    );

    // Watchdog pings for 3 s: WatchdogSec=1 needs one at least every second.
    let from = Instant::now();
    let pings: Vec<Instant> = receive(&sock, from + Duration::from_secs(3), |_| false)
        .into_iter()
        .filter(|(_, m)| m.lines().any(|l| l == "WATCHDOG=1"))
        .map(|(t, _)| t)
        .collect();
    assert!(
        pings.len() >= 4,
        "{role}: {} watchdog pings in 3 s\n{}",
        pings.len(),
        child.output()
    );
    let mut prev = from;
    for t in &pings {
        assert!(
            t.duration_since(prev) < Duration::from_millis(900),
            "{role}: {:?} without a ping",
            t.duration_since(prev)
        );
        prev = *t;
    }

    child.signal(nix::sys::signal::Signal::SIGTERM);
    let stopping = receive(&sock, Instant::now() + Duration::from_secs(10), |m| {
        m.lines().any(|l| l == "STOPPING=1")
    });
    assert!(
        stopping
            .iter()
            .any(|(_, m)| m.lines().any(|l| l == "STOPPING=1")),
        "{role}: no STOPPING=1 after SIGTERM: {stopping:?}"
    );
    let status = child.wait_exit(Duration::from_secs(10)).unwrap();
    assert!(status.success(), "{role}: {status}\n{}", child.output());
}

#[test]
fn fusion_speaks_the_notify_protocol_with_watchdog() {
    check_role("fusion");
}

#[test]
fn slam_speaks_the_notify_protocol_with_watchdog() {
    check_role("slam");
}
