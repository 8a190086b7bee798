//! Open → back off → reopen: the one reconnect policy every driver follows.
//!
//! A driver tells [`Reconnect`] what happened to its link — it came up, an
//! attempt to open it failed, it was lost — with the time; it answers when
//! the next attempt is due and shows the link in health. The wait before a
//! retry doubles after each failure up to a cap (a device that is gone for
//! good is not hammered; the cap keeps a replugged one back within a
//! second) and starts short again after a success.
//!
//! While the link is down the process is `degraded` when it was up before
//! and the outage is recent, `error` when it never came up or has been down
//! for [`ReconnectPolicy::error_after`]; the reason is the last error. While
//! it is up the driver owns the state (a sensor's own status, a session
//! still handshaking).
//!
//! Pure: time comes in as arguments (ns of the monotonic clock).

use crate::health::HealthReporter;
use smokenav_shared_types::HealthState;
use std::time::Duration;

/// How a driver retries its link.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReconnectPolicy {
    /// Wait after the first failure (and after a loss).
    pub first_retry: Duration,
    /// The wait doubles per failed attempt up to this.
    pub max_retry: Duration,
    /// Down this long (or never up): health `error` rather than `degraded`.
    pub error_after: Duration,
}

impl ReconnectPolicy {
    /// `first_retry` doubling to `max_retry`; `error` after 10 s down.
    pub fn new(first_retry: Duration, max_retry: Duration) -> Self {
        Self {
            first_retry,
            max_retry: max_retry.max(first_retry),
            error_after: Duration::from_secs(10),
        }
    }

    /// Reports `Error` (not just `Degraded`) once the link has been down this long.
    pub fn with_error_after(mut self, error_after: Duration) -> Self {
        self.error_after = error_after;
        self
    }
}

/// What happened to the link so far (health metrics of the same names).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkCounters {
    /// Times the link came up (`port_opens`).
    pub opens: u64,
    /// Attempts that did not bring it up (`connect_failures`).
    pub failures: u64,
    /// Times an open link was lost (`device_losses`).
    pub losses: u64,
}

impl LinkCounters {
    /// Successful opens after the first (`reconnects`).
    pub fn reconnects(&self) -> u64 {
        self.opens.saturating_sub(1)
    }
}

/// One driver's link: up or down, when to retry, and why it is down.
#[derive(Debug, Clone)]
pub struct Reconnect {
    policy: ReconnectPolicy,
    up: bool,
    /// Start of the current outage (or of the process, before the first open).
    down_since_ns: u64,
    retry_at_ns: u64,
    delay: Duration,
    /// Why the link is (or last was) down.
    reason: String,
    counters: LinkCounters,
}

fn ns(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

impl Reconnect {
    /// Not connected yet; the first attempt is due at once.
    pub fn new(policy: ReconnectPolicy, now_ns: u64) -> Self {
        Self {
            policy,
            up: false,
            down_since_ns: now_ns,
            retry_at_ns: now_ns,
            delay: policy.first_retry,
            reason: "not connected yet".into(),
            counters: LinkCounters::default(),
        }
    }

    /// The back-off policy.
    pub fn policy(&self) -> &ReconnectPolicy {
        &self.policy
    }

    /// Whether the link is open.
    pub fn is_up(&self) -> bool {
        self.up
    }

    /// The link is down and an attempt to open it is due.
    pub fn due(&self, now_ns: u64) -> bool {
        !self.up && now_ns >= self.retry_at_ns
    }

    /// When the next attempt is due; `None` while the link is up.
    pub fn retry_at_ns(&self) -> Option<u64> {
        (!self.up).then_some(self.retry_at_ns)
    }

    /// How long until the next attempt (zero when it is due, or the link is up).
    pub fn wait(&self, now_ns: u64) -> Duration {
        match self.retry_at_ns() {
            Some(at) => Duration::from_nanos(at.saturating_sub(now_ns)),
            None => Duration::ZERO,
        }
    }

    /// Opens, failures and losses so far.
    pub fn counters(&self) -> LinkCounters {
        self.counters
    }

    /// Why the link is down (`None` while it is up).
    pub fn reason(&self) -> Option<&str> {
        (!self.up).then_some(self.reason.as_str())
    }

    /// The link came up at `now_ns`. Returns true for a reconnect (not the first open).
    pub fn opened(&mut self, _now_ns: u64) -> bool {
        self.up = true;
        self.delay = self.policy.first_retry;
        self.counters.opens += 1;
        self.counters.opens > 1
    }

    /// An attempt to open failed: retry after the current wait, then wait longer.
    pub fn open_failed(&mut self, now_ns: u64, reason: impl std::fmt::Display) {
        self.counters.failures += 1;
        self.reason = reason.to_string();
        self.retry_at_ns = now_ns.saturating_add(ns(self.delay));
        self.delay = (self.delay * 2).min(self.policy.max_retry);
    }

    /// The open link failed: down from `now_ns`, first retry after the short wait.
    /// Ignored while the link is already down.
    pub fn lost(&mut self, now_ns: u64, reason: impl std::fmt::Display) {
        if !self.up {
            return;
        }
        self.up = false;
        self.counters.losses += 1;
        self.down_since_ns = now_ns;
        self.reason = reason.to_string();
        self.delay = self.policy.first_retry;
        self.retry_at_ns = now_ns.saturating_add(ns(self.delay));
        self.delay = (self.delay * 2).min(self.policy.max_retry);
    }

    /// The health state the link calls for at `now_ns`: `None` while it is up
    /// (the driver decides), else `degraded` or `error`.
    pub fn state(&self, now_ns: u64) -> Option<HealthState> {
        if self.up {
            return None;
        }
        let long = now_ns.saturating_sub(self.down_since_ns) >= ns(self.policy.error_after);
        Some(if self.counters.opens == 0 || long {
            HealthState::Error
        } else {
            HealthState::Degraded
        })
    }

    /// Shows the link in health: the counters always; while down the state
    /// and `what: reason; reconnecting` as the last error; once back, clears
    /// that error unless the driver has set another since.
    pub fn report(&self, h: &mut HealthReporter, what: &str, now_ns: u64) {
        let c = self.counters;
        h.set_metric("link_up", f64::from(u8::from(self.up)));
        h.set_metric("port_opens", c.opens as f64);
        h.set_metric("reconnects", c.reconnects() as f64);
        h.set_metric("connect_failures", c.failures as f64);
        h.set_metric("device_losses", c.losses as f64);
        let msg = format!("{what}: {}; reconnecting", self.reason);
        match self.state(now_ns) {
            Some(state) => {
                h.set_state(state);
                h.error(&msg);
            }
            None => {
                // `last_error` is a fixed-size copy: ours may be cut short.
                let last = h.health().last_error.as_str();
                if !last.is_empty() && msg.starts_with(last) {
                    h.clear_error();
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn policy() -> ReconnectPolicy {
        ReconnectPolicy::new(Duration::from_millis(100), Duration::from_millis(400))
    }

    #[test]
    fn failed_opens_back_off_doubling_to_the_cap() {
        let mut r = Reconnect::new(policy(), 0);
        assert!(r.due(0));
        let mut at = Vec::new();
        let mut now = 0;
        for _ in 0..5 {
            r.open_failed(now, "no such device");
            now = r.retry_at_ns().unwrap();
            assert!(!r.due(now - 1) && r.due(now));
            at.push(now / MS);
        }
        // Waits of 100, 200, 400, 400, 400 ms.
        assert_eq!(at, [100, 300, 700, 1100, 1500]);
        assert_eq!(r.counters().failures, 5);
        assert_eq!(r.wait(1400 * MS), Duration::from_millis(100));
    }

    #[test]
    fn a_loss_retries_after_the_short_wait_and_counts_a_reconnect_once_back() {
        let mut r = Reconnect::new(policy(), 0);
        r.open_failed(0, "gone");
        r.open_failed(100 * MS, "gone");
        assert!(!r.opened(300 * MS), "the first open is not a reconnect");
        assert_eq!(r.retry_at_ns(), None);
        assert!(!r.due(10_000 * MS));
        r.lost(1000 * MS, "read: EOF");
        r.lost(1001 * MS, "ignored: already down");
        assert_eq!(r.reason(), Some("read: EOF"));
        assert_eq!(r.retry_at_ns(), Some(1100 * MS));
        r.open_failed(1100 * MS, "gone");
        assert_eq!(r.retry_at_ns(), Some(1300 * MS));
        assert!(r.opened(1300 * MS));
        let c = r.counters();
        assert_eq!(
            (c.opens, c.failures, c.losses, c.reconnects()),
            (2, 3, 1, 1)
        );
    }

    #[test]
    fn down_is_degraded_after_having_been_up_and_error_when_never_up_or_long() {
        let mut r = Reconnect::new(policy(), 0);
        assert_eq!(r.state(0), Some(HealthState::Error), "never up");
        r.opened(0);
        assert_eq!(r.state(5 * MS), None, "up: the driver decides");
        r.lost(1000 * MS, "unplugged");
        assert_eq!(r.state(1000 * MS), Some(HealthState::Degraded));
        assert_eq!(r.state(10_999 * MS), Some(HealthState::Degraded));
        assert_eq!(r.state(11_000 * MS), Some(HealthState::Error));
        let now_error = Reconnect::new(policy().with_error_after(Duration::ZERO), 0);
        assert_eq!(now_error.state(0), Some(HealthState::Error));
    }
}
