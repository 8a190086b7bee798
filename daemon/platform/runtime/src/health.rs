//! Health reporting: what `smokenav status` shows.

use smokenav_platform_bus::{Bus, BusError, Publisher, topics};
use smokenav_shared_types::{Health, HealthState, clock::monotonic_now_ns};
use std::time::{Duration, Instant};

/// Counts events and turns them into a rate per reporting window.
#[derive(Debug, Clone)]
pub struct RateMeter {
    count: u64,
    total: u64,
    window_start: Instant,
    last_rate: f64,
}

impl RateMeter {
    /// A meter that starts counting at `now`.
    pub fn new(now: Instant) -> Self {
        Self {
            count: 0,
            total: 0,
            window_start: now,
            last_rate: 0.0,
        }
    }

    /// Counts one event.
    pub fn mark(&mut self) {
        self.count += 1;
        self.total += 1;
    }

    /// Events counted since the start.
    pub fn total(&self) -> u64 {
        self.total
    }

    /// Closes the window and returns its rate in Hz.
    pub fn roll(&mut self, now: Instant) -> f64 {
        let dt = now.duration_since(self.window_start).as_secs_f64();
        if dt > 0.0 {
            self.last_rate = self.count as f64 / dt;
        }
        self.count = 0;
        self.window_start = now;
        self.last_rate
    }

    /// The rate over the last completed window, Hz.
    pub fn last_rate(&self) -> f64 {
        self.last_rate
    }
}

/// Latency percentiles over one reporting window (fixed memory, no allocation per record).
pub struct LatencyWindow {
    hist: hdrhistogram::Histogram<u64>,
}

impl LatencyWindow {
    /// An empty window.
    pub fn new() -> Self {
        Self {
            // 1 µs .. 100 s, 3 significant digits: allocated once.
            hist: hdrhistogram::Histogram::new_with_bounds(1, 100_000_000, 3)
                .unwrap_or_else(|_| hdrhistogram::Histogram::new(3).expect("3 sigfigs is valid")),
        }
    }

    /// Adds one processing time.
    pub fn record(&mut self, d: Duration) {
        let us = (d.as_micros() as u64).clamp(1, 100_000_000);
        let _ = self.hist.record(us);
    }

    /// Samples in the window.
    pub fn len(&self) -> u64 {
        self.hist.len()
    }

    /// Whether the window is empty.
    pub fn is_empty(&self) -> bool {
        self.hist.is_empty()
    }

    /// (p50, p99, max) in µs.
    pub fn percentiles(&self) -> (f64, f64, f64) {
        if self.hist.is_empty() {
            return (0.0, 0.0, 0.0);
        }
        (
            self.hist.value_at_quantile(0.5) as f64,
            self.hist.value_at_quantile(0.99) as f64,
            self.hist.max() as f64,
        )
    }

    /// Empties the window (after each report).
    pub fn reset(&mut self) {
        self.hist.reset();
    }
}

impl Default for LatencyWindow {
    fn default() -> Self {
        Self::new()
    }
}

/// Counters that show themselves in `smokenav status`: each struct writes
/// its own fields as metrics, so no process lists them by hand.
pub trait Report {
    /// Writes these counters into `health` as metrics.
    fn report(&self, health: &mut HealthReporter);
}

/// Index of a rate registered with [`HealthReporter::add_rate`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RateId(usize);

/// Keeps this process's `Health` and publishes it on `health/<role>` every period.
pub struct HealthReporter {
    health: Health,
    publisher: Publisher<Health>,
    period: Duration,
    started: Instant,
    last_publish: Option<Instant>,
    rates: Vec<(String, RateMeter, Option<f64>)>,
    latency: LatencyWindow,
    /// The state the process set; published as `Degraded` while a rate is low.
    state: HealthState,
    /// When the state last became `Ok`: rates are judged on whole windows after it.
    ok_since: Option<Instant>,
    rate_floor: f64,
    /// `last_error` holds this reporter's low-rate message (cleared on recovery).
    rate_error: bool,
    /// A metric did not fit the report (warned once).
    table_full_logged: bool,
}

/// Fraction of its expected rate below which a rate counts as low, unless configured.
pub const DEFAULT_RATE_FLOOR: f64 = 0.8;

impl HealthReporter {
    /// Publishes on `health/<role>` of `bus` every `period`.
    pub fn new(bus: &Bus, role: &str, period: Duration) -> Result<Self, BusError> {
        let publisher = bus.publisher(topics::health(role))?;
        let now = Instant::now();
        Ok(Self {
            health: Health::new(role, std::process::id()),
            publisher,
            period,
            started: now,
            last_publish: None,
            rates: Vec::new(),
            latency: LatencyWindow::new(),
            state: HealthState::Starting,
            ok_since: None,
            rate_floor: DEFAULT_RATE_FLOOR,
            rate_error: false,
            table_full_logged: false,
        })
    }

    /// The report as it stands.
    pub fn health(&self) -> &Health {
        &self.health
    }

    /// The reported state.
    pub fn state(&self) -> HealthState {
        self.health.state()
    }

    /// The state the process set ([`Self::set_state`]): an `Ok` one stays
    /// `Ok` here while a low rate has it published as `Degraded`. A process
    /// flagging a condition of its own tests this, or the rate's message
    /// would take the place of the condition's.
    pub fn own_state(&self) -> HealthState {
        self.state
    }

    /// Sets the state; an `Ok` one is published as `Degraded` while a rate
    /// with an expected value runs below the rate floor.
    pub fn set_state(&mut self, s: HealthState) {
        if s != HealthState::Ok {
            self.ok_since = None;
        } else if self.ok_since.is_none() {
            self.ok_since = Some(Instant::now());
        }
        self.state = s;
        self.health.set_state(s);
    }

    /// Fraction of the expected rate below which a rate is low (published
    /// as the `rate_floor` metric when not the default, so `smokenav status`
    /// applies the same).
    pub fn set_rate_floor(&mut self, fraction: f64) {
        self.rate_floor = fraction;
    }

    /// Sets a named value (a counter, gauge, or setting worth showing).
    pub fn set_metric(&mut self, name: &str, value: f64) {
        if !self.health.set_metric(name, value, None) && !self.table_full_logged {
            // Once: the report goes out every period with the same names.
            self.table_full_logged = true;
            tracing::warn!(
                name,
                max = smokenav_shared_types::health::MAX_METRICS,
                "health metric table full: this metric and any later new one are not reported"
            );
        }
    }

    /// Registers a rate (e.g. `scan_hz`) with its nominal value.
    pub fn add_rate(&mut self, name: &str, expected_hz: Option<f64>) -> RateId {
        self.rates
            .push((name.to_owned(), RateMeter::new(Instant::now()), expected_hz));
        RateId(self.rates.len() - 1)
    }

    /// Sets (or clears) the expected value of a rate: a sensor's nominal rate
    /// is often known only once it is connected.
    pub fn set_expected_rate(&mut self, id: RateId, expected_hz: Option<f64>) {
        if let Some((_, _, e)) = self.rates.get_mut(id.0) {
            *e = expected_hz;
        }
    }

    /// Counts one event of a rate.
    pub fn mark(&mut self, id: RateId) {
        if let Some((_, m, _)) = self.rates.get_mut(id.0) {
            m.mark();
        }
    }

    /// Events counted by rate `id` since the start.
    pub fn rate_total(&self, id: RateId) -> u64 {
        self.rates.get(id.0).map(|(_, m, _)| m.total()).unwrap_or(0)
    }

    /// Adds one cycle's processing time to the latency window.
    pub fn record_latency(&mut self, d: Duration) {
        self.latency.record(d);
    }

    /// Counts a cycle that missed its deadline.
    pub fn deadline_missed(&mut self) {
        self.health.deadline_misses += 1;
    }

    /// Records an error for `status` and the log (logged once while it stays the last error).
    pub fn error(&mut self, msg: &str) {
        let last = self.health.last_error.as_str();
        if last.is_empty() || !msg.starts_with(last) {
            tracing::warn!("{msg}");
        }
        self.health.last_error.set(msg);
        // The message is no longer the low rate's: the rate coming back must not clear it.
        self.rate_error = false;
    }

    /// Clears the last error.
    pub fn clear_error(&mut self) {
        self.rate_error = false;
        self.health.last_error.set("");
    }

    /// Publishes if a period has passed since the last report (or none was sent yet).
    pub fn maybe_publish(&mut self, now: Instant) -> Result<bool, BusError> {
        if self
            .last_publish
            .is_some_and(|t| now.duration_since(t) < self.period)
        {
            return Ok(false);
        }
        self.publish_now(now)?;
        Ok(true)
    }

    /// Publishes the report now (the window restarts).
    pub fn publish_now(&mut self, now: Instant) -> Result<(), BusError> {
        // A window that began before the process was up says nothing.
        let judge = matches!((self.ok_since, self.last_publish), (Some(ok), Some(t)) if ok <= t);
        let mut low: Option<(&str, f64, f64)> = None;
        for (name, meter, expected) in &mut self.rates {
            let hz = meter.roll(now);
            self.health.set_metric(name, hz, *expected);
            if let Some(e) = *expected
                && judge
                && low.is_none()
                && hz < self.rate_floor * e
            {
                low = Some((name.as_str(), hz, e));
            }
        }
        // Only a configured floor takes a metric slot (the table is small);
        // `smokenav status` assumes the default without it.
        if self.rate_floor != DEFAULT_RATE_FLOOR {
            self.health.set_metric("rate_floor", self.rate_floor, None);
        }
        match low {
            Some((name, hz, e)) if self.state == HealthState::Ok => {
                self.health.set_state(HealthState::Degraded);
                let msg = format!(
                    "{name} {hz:.1} Hz, below {:.0} % of the expected {e:.1} Hz",
                    self.rate_floor * 100.0
                );
                if self.health.last_error.as_str() != msg {
                    tracing::warn!("{msg}");
                }
                self.health.last_error.set(&msg);
                self.rate_error = true;
            }
            _ => {
                self.health.set_state(self.state);
                if self.rate_error {
                    self.rate_error = false;
                    self.health.last_error.set("");
                }
            }
        }
        let (p50, p99, max) = self.latency.percentiles();
        self.health.latency_p50_us = p50 as f32;
        self.health.latency_p99_us = p99 as f32;
        self.health.latency_max_us = max as f32;
        self.latency.reset();
        self.health.uptime_s = now.duration_since(self.started).as_secs_f64();
        self.health.header.stamp_ns = monotonic_now_ns();
        let h = self.health;
        self.publisher.publish(&h)?;
        self.last_publish = Some(now);
        Ok(())
    }
}
