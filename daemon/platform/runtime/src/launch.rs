//! Starting and stopping a smokenav process from another program — the lab's
//! supervisor (`smokenav-lab demo`) and the end-to-end tests — with the
//! environment systemd would not add: the bus instance, the log filter, and
//! no inherited `NOTIFY_SOCKET` (a child must not report readiness for its
//! parent's unit).

use smokenav_platform_config::INSTANCE_ENV;
use std::path::Path;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

/// Log filter a launched process gets when the launcher's own `RUST_LOG` is unset.
pub const DEFAULT_LOG_FILTER: &str = "info";

/// A command for `program` on bus `instance`: `SMOKENAV_INSTANCE=instance`,
/// the launcher's `RUST_LOG` (else [`DEFAULT_LOG_FILTER`]), no
/// `NOTIFY_SOCKET`, stdin from `/dev/null`. The caller adds arguments and
/// decides where output goes.
pub fn command(program: &Path, instance: &str) -> Command {
    let mut cmd = Command::new(program);
    cmd.env(INSTANCE_ENV, instance)
        .env(
            "RUST_LOG",
            std::env::var("RUST_LOG").unwrap_or_else(|_| DEFAULT_LOG_FILTER.into()),
        )
        .env_remove("NOTIFY_SOCKET")
        .stdin(Stdio::null());
    cmd
}

/// Stops `child` as systemd does: SIGTERM, then SIGKILL if it has not exited
/// after `grace`. Returns its exit status.
pub fn stop(child: &mut Child, grace: Duration) -> std::io::Result<ExitStatus> {
    if let Some(status) = child.try_wait()? {
        return Ok(status);
    }
    let pid = nix::unistd::Pid::from_raw(child.id() as i32);
    // It may have exited since try_wait; then there is nothing to signal.
    let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM);
    let end = Instant::now() + grace;
    while Instant::now() < end {
        if let Some(status) = child.try_wait()? {
            return Ok(status);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill()?;
    child.wait()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::ffi::OsStr;
    use std::os::unix::process::ExitStatusExt;

    #[test]
    fn command_sets_the_instance_and_log_filter_and_drops_the_notify_socket() {
        let cmd = command(Path::new("/bin/sh"), "lab_1");
        let envs: Vec<(&OsStr, Option<&OsStr>)> = cmd.get_envs().collect();
        assert!(envs.contains(&(OsStr::new(INSTANCE_ENV), Some(OsStr::new("lab_1")))));
        assert!(envs.contains(&(OsStr::new("NOTIFY_SOCKET"), None)));
        assert!(envs.iter().any(|(k, v)| *k == "RUST_LOG" && v.is_some()));
    }

    #[test]
    fn the_launched_process_sees_that_environment() {
        let out = command(Path::new("/bin/sh"), "lab_2")
            .args([
                "-c",
                "echo \"$SMOKENAV_INSTANCE ${NOTIFY_SOCKET-unset} ${RUST_LOG:+log}\"",
            ])
            .output()
            .unwrap();
        assert_eq!(
            String::from_utf8_lossy(&out.stdout).trim(),
            "lab_2 unset log"
        );
    }

    #[test]
    fn stop_terminates_and_kills_what_ignores_sigterm() {
        let mut polite = command(Path::new("/bin/sleep"), "t")
            .arg("30")
            .spawn()
            .unwrap();
        let status = stop(&mut polite, Duration::from_secs(5)).unwrap();
        assert_eq!(status.signal(), Some(libc_sigterm()));

        // The shell says when its trap is set: a fixed sleep raced it on a
        // loaded machine (SIGTERM arrived before `trap` ran).
        let mut stubborn = command(Path::new("/bin/sh"), "t")
            .args(["-c", "trap '' TERM; echo ready; sleep 30 & wait; sleep 30"])
            .stdout(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let mut line = String::new();
        std::io::BufRead::read_line(
            &mut std::io::BufReader::new(stubborn.stdout.take().unwrap()),
            &mut line,
        )
        .unwrap();
        assert_eq!(line.trim(), "ready");
        let started = Instant::now();
        let status = stop(&mut stubborn, Duration::from_millis(300)).unwrap();
        assert_eq!(status.signal(), Some(9), "SIGKILL after the grace time");
        assert!(started.elapsed() < Duration::from_secs(5));
    }

    fn libc_sigterm() -> i32 {
        nix::sys::signal::Signal::SIGTERM as i32
    }
}
