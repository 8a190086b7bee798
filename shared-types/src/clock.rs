//! The one clock abstraction.
//!
//! Algorithms never read the time themselves: they take stamps from messages,
//! and processes hand them a [`Clock`]. In production that is
//! [`MonotonicClock`] (the host's `CLOCK_MONOTONIC`, shared by every process on
//! the machine, so stamps from different processes compare directly). Tests and
//! replay use [`MockClock`], whose clones all follow the same mock time.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// Nanoseconds of the host monotonic clock.
pub type Stamp = u64;

/// A source of monotonic time stamps (ns), injected into whatever needs the time.
pub trait Clock: Send + Sync {
    /// Current time in nanoseconds of the monotonic time base.
    fn now_ns(&self) -> Stamp;

    /// Time elapsed since `earlier` (zero if `earlier` is in the future).
    fn elapsed_since(&self, earlier: Stamp) -> Duration {
        Duration::from_nanos(self.now_ns().saturating_sub(earlier))
    }
}

/// The host's `CLOCK_MONOTONIC`: never jumps with NTP, shared by all processes.
#[derive(Debug, Clone, Copy, Default)]
pub struct MonotonicClock;

impl Clock for MonotonicClock {
    fn now_ns(&self) -> Stamp {
        monotonic_now_ns()
    }
}

/// Reads `CLOCK_MONOTONIC` directly. Use a [`Clock`] in library code; this is
/// for process edges (drivers stamping data on arrival).
pub fn monotonic_now_ns() -> Stamp {
    match nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC) {
        Ok(ts) => (ts.tv_sec() as u64)
            .saturating_mul(1_000_000_000)
            .saturating_add(ts.tv_nsec() as u64),
        // CLOCK_MONOTONIC cannot fail on Linux; if it ever did, 0 is an
        // obviously-wrong stamp rather than a crash on the hot path.
        Err(_) => 0,
    }
}

/// A clock that only moves when told to. Clones share the same time.
#[derive(Debug, Clone, Default)]
pub struct MockClock {
    now: Arc<AtomicU64>,
}

impl MockClock {
    /// A mock clock that reads `start_ns` until moved.
    pub fn new(start_ns: Stamp) -> Self {
        Self {
            now: Arc::new(AtomicU64::new(start_ns)),
        }
    }

    /// Sets the time (every clone sees it).
    pub fn set_ns(&self, ns: Stamp) {
        self.now.store(ns, Ordering::SeqCst);
    }

    /// Moves the time forward by `d` (every clone sees it).
    pub fn advance(&self, d: Duration) {
        self.now.fetch_add(d.as_nanos() as u64, Ordering::SeqCst);
    }
}

impl Clock for MockClock {
    fn now_ns(&self) -> Stamp {
        self.now.load(Ordering::SeqCst)
    }
}

impl<C: Clock + ?Sized> Clock for Arc<C> {
    fn now_ns(&self) -> Stamp {
        (**self).now_ns()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mock_clones_follow_the_mock() {
        let clock = MockClock::new(5);
        let clone = clock.clone();
        clock.advance(Duration::from_millis(1));
        assert_eq!(clone.now_ns(), 1_000_005);
        assert_eq!(clone.elapsed_since(5), Duration::from_millis(1));
    }

    #[test]
    fn monotonic_clock_does_not_go_back() {
        let c = MonotonicClock;
        let a = c.now_ns();
        let b = c.now_ns();
        assert!(a > 0 && b >= a);
    }
}
