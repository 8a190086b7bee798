use sd_notify::NotifyState;
use std::time::{Duration, Instant};

/// Talks to systemd's notify socket. Every call is a no-op when the process
/// was not started by systemd with `Type=notify`.
#[derive(Debug)]
pub struct SystemdNotifier {
    watchdog: Option<Duration>,
    last_ping: Instant,
}

impl SystemdNotifier {
    /// Reads `NOTIFY_SOCKET` and `WATCHDOG_USEC` (no-ops when absent).
    pub fn new() -> Self {
        Self {
            watchdog: sd_notify::watchdog_enabled(),
            last_ping: Instant::now(),
        }
    }

    /// How often systemd wants a watchdog ping, when it watches this process.
    pub fn watchdog_interval(&self) -> Option<Duration> {
        self.watchdog
    }

    /// Sends `READY=1` with a status line.
    pub fn ready(&self, status: &str) {
        let _ = sd_notify::notify(&[NotifyState::Ready, NotifyState::Status(status)]);
    }

    /// Sends a status line.
    pub fn status(&self, status: &str) {
        let _ = sd_notify::notify(&[NotifyState::Status(status)]);
    }

    /// Sends `STOPPING=1`.
    pub fn stopping(&self) {
        let _ = sd_notify::notify(&[NotifyState::Stopping]);
    }

    /// Sends `WATCHDOG=1` if half the watchdog interval has passed. Called from
    /// the main loop, so a stuck loop stops the pings and systemd restarts us.
    pub fn tick(&mut self, now: Instant) {
        if let Some(interval) = self.watchdog
            && now.duration_since(self.last_ping) >= interval / 2
        {
            let _ = sd_notify::notify(&[NotifyState::Watchdog]);
            self.last_ping = now;
        }
    }
}

impl Default for SystemdNotifier {
    fn default() -> Self {
        Self::new()
    }
}
