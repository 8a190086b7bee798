//! Approximate-time synchronisation with ROS message_filters semantics, plus a timeout.
//!
//! [`ApproxCore`] is a port of ROS message_filters' `ApproximateTime`
//! policy: per-topic bounded queues, a pivot, candidate sets of minimal span
//! (with ROS's age penalty), emission once a set is provably optimal,
//! inter-message lower bounds to prove it early. It works on
//! stamps only; the typed layer ([`Sync3`]) keeps the messages in FIFOs that
//! mirror the stamp queues, so no message is copied out or allocated per cycle.
//!
//! What it adds to ROS:
//! - **Timeout.** A topic whose newest stamp is older than `now − timeout`
//!   (or that has sent nothing for `timeout` since the first message of any
//!   topic arrived) becomes *inactive*: its queue is dropped and sets are formed from
//!   the other topics alone, so one silent sensor degrades the output instead
//!   of stalling it. The next message it sends makes it active again. `now`
//!   is injected by the caller (stamps in ns of the same clock), never read.
//! - **Drop counters** per topic and reason.
//! - **Out-of-order messages are dropped** (ROS only warns), which keeps the
//!   "sets never cross" guarantee unconditional.
//! - **`flush`** for the end of a recording: publishes what would be optimal
//!   if no message ever arrived again.
//!
//! Queue layout: a topic's queue holds ROS's `past` (messages passed over in
//! the current search) followed by its `deque`; `past[i]` is the length of
//! that prefix. While a pivot exists, each topic's candidate message is the
//! front of its queue: ROS only ever removes messages from the front.

use std::collections::VecDeque;

/// A message with a stamp (ns of the host monotonic clock).
pub trait Stamped {
    fn stamp_ns(&self) -> u64;
}

impl Stamped for smokenav_shared_types::LaserScan {
    fn stamp_ns(&self) -> u64 {
        self.header.stamp_ns
    }
}

impl Stamped for smokenav_shared_types::SonarRing {
    fn stamp_ns(&self) -> u64 {
        self.header.stamp_ns
    }
}

impl Stamped for smokenav_shared_types::SmokeReading {
    fn stamp_ns(&self) -> u64 {
        self.header.stamp_ns
    }
}

/// Why a message left a queue without being published.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DropReason {
    /// The topic's queue exceeded `queue_size`; its oldest message went.
    Overflow,
    /// The set it headed spanned more than `max_interval`.
    Interval,
    /// It headed a set whose pivot topic had just overflowed (ROS `has_dropped`).
    DroppedPivot,
    /// A better candidate set was found after it was passed over.
    Superseded,
    /// Its topic went silent for longer than the timeout.
    Timeout,
    /// Its stamp was older than the previous message of its topic.
    OutOfOrder,
}

pub const DROP_REASONS: [DropReason; 6] = [
    DropReason::Overflow,
    DropReason::Interval,
    DropReason::DroppedPivot,
    DropReason::Superseded,
    DropReason::Timeout,
    DropReason::OutOfOrder,
];

impl DropReason {
    pub fn as_str(self) -> &'static str {
        match self {
            DropReason::Overflow => "overflow",
            DropReason::Interval => "interval",
            DropReason::DroppedPivot => "dropped_pivot",
            DropReason::Superseded => "superseded",
            DropReason::Timeout => "timeout",
            DropReason::OutOfOrder => "out_of_order",
        }
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// Parameters of the synchroniser, in nanoseconds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SyncSettings<const N: usize> {
    /// Messages kept per topic (ROS `queue_size`, ≥ 1).
    pub queue_size: usize,
    /// Sets spanning more than this are never formed.
    pub max_interval_ns: u64,
    /// ROS `age_penalty`.
    pub age_penalty: f64,
    /// ROS inter-message lower bounds per topic; 0 = none.
    pub lower_bound_ns: [u64; N],
    /// Silence after which a topic stops holding up the output; `None` = never (pure ROS).
    pub timeout_ns: Option<u64>,
}

impl<const N: usize> SyncSettings<N> {
    /// Plain ROS behaviour: age penalty 0.1, no bounds, no timeout.
    pub fn ros(queue_size: usize, max_interval_ns: u64) -> Self {
        Self {
            queue_size,
            max_interval_ns,
            age_penalty: 0.1,
            lower_bound_ns: [0; N],
            timeout_ns: None,
        }
    }
}

/// Counters per topic, since creation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SyncCounters<const N: usize> {
    pub received: [u64; N],
    pub published: [u64; N],
    /// Indexed by `DropReason as usize` (see [`DROP_REASONS`]).
    pub dropped: [[u64; 6]; N],
    /// Sets published, and how many of them lacked at least one topic.
    pub sets: u64,
    pub degraded_sets: u64,
    /// Messages that arrived closer to their predecessor than the topic's lower bound.
    pub bound_violations: [u64; N],
}

impl<const N: usize> Default for SyncCounters<N> {
    fn default() -> Self {
        Self {
            received: [0; N],
            published: [0; N],
            dropped: [[0; 6]; N],
            sets: 0,
            degraded_sets: 0,
            bound_violations: [0; N],
        }
    }
}

impl<const N: usize> SyncCounters<N> {
    pub fn dropped(&self, topic: usize, reason: DropReason) -> u64 {
        self.dropped.get(topic).map_or(0, |d| d[reason.index()])
    }

    /// All drops of one topic.
    pub fn dropped_total(&self, topic: usize) -> u64 {
        self.dropped.get(topic).map_or(0, |d| d.iter().sum())
    }

    /// All drops of all topics.
    pub fn dropped_all(&self) -> u64 {
        (0..N).map(|i| self.dropped_total(i)).sum()
    }
}

/// Receives the core's queue operations, in order, so typed storage can mirror them.
pub trait SyncSink<const N: usize> {
    /// The front message of `topic` is dropped.
    fn drop_front(&mut self, topic: usize, reason: DropReason);
    /// The front message of every topic with `present[i]` forms a set; pop them after use.
    fn publish(&mut self, present: [bool; N]);
}

/// `a` (a later set's growth at the end) does not pay for `b` (its shrink at the start).
fn no_better(end_delta: u64, start_delta: u64, age_penalty: f64) -> bool {
    end_delta as f64 * (1.0 + age_penalty) >= start_delta as f64
}

/// The stamp-only ApproximateTime state machine over `N` topics.
#[derive(Debug, Clone)]
pub struct ApproxCore<const N: usize> {
    settings: SyncSettings<N>,
    queues: [VecDeque<u64>; N],
    past: [usize; N],
    active: [bool; N],
    has_dropped: [bool; N],
    pivot: Option<usize>,
    pivot_time: u64,
    cand_start: u64,
    cand_end: u64,
    last_stamp: [Option<u64>; N],
    first_now: Option<u64>,
    now: u64,
    end_of_stream: bool,
    counters: SyncCounters<N>,
}

impl<const N: usize> ApproxCore<N> {
    pub fn new(settings: SyncSettings<N>) -> Self {
        let settings = SyncSettings {
            queue_size: settings.queue_size.max(1),
            ..settings
        };
        let cap = settings.queue_size + 2;
        Self {
            settings,
            queues: std::array::from_fn(|_| VecDeque::with_capacity(cap)),
            past: [0; N],
            active: [true; N],
            has_dropped: [false; N],
            pivot: None,
            pivot_time: 0,
            cand_start: 0,
            cand_end: 0,
            last_stamp: [None; N],
            first_now: None,
            now: 0,
            end_of_stream: false,
            counters: SyncCounters::default(),
        }
    }

    pub fn settings(&self) -> &SyncSettings<N> {
        &self.settings
    }

    pub fn counters(&self) -> &SyncCounters<N> {
        &self.counters
    }

    /// Which topics currently take part in sets (not timed out).
    pub fn active(&self) -> [bool; N] {
        self.active
    }

    /// Messages held per topic (waiting or passed over in the current search).
    pub fn pending(&self) -> [usize; N] {
        std::array::from_fn(|i| self.queues[i].len())
    }

    /// Step 1 of adding a message: advances time, applies timeouts and decides
    /// whether the message is kept. When this returns true the caller stores
    /// the message at the back of its FIFO and then calls [`Self::enqueue`].
    pub fn admit<S: SyncSink<N>>(
        &mut self,
        topic: usize,
        stamp: u64,
        now: u64,
        sink: &mut S,
    ) -> bool {
        if topic >= N {
            return false;
        }
        self.counters.received[topic] += 1;
        if self.last_stamp[topic].is_some_and(|last| stamp < last) {
            self.counters.dropped[topic][DropReason::OutOfOrder.index()] += 1;
            return false;
        }
        if let Some(last) = self.last_stamp[topic] {
            let bound = self.settings.lower_bound_ns[topic];
            if bound > 0 && stamp - last < bound {
                self.counters.bound_violations[topic] += 1;
            }
        }
        self.last_stamp[topic] = Some(stamp);
        self.first_now.get_or_insert(now.max(self.now));
        self.advance(now, sink);
        if !self.active[topic] {
            // Already older than the timeout when it arrived.
            self.counters.dropped[topic][DropReason::Timeout.index()] += 1;
            return false;
        }
        true
    }

    /// Step 2 of adding a message (ROS `add`): queue it and search for sets.
    pub fn enqueue<S: SyncSink<N>>(&mut self, topic: usize, stamp: u64, sink: &mut S) {
        if topic >= N {
            return;
        }
        let was_empty = !self.deque_nonempty(topic);
        self.queues[topic].push_back(stamp);
        if was_empty && self.all_active_nonempty() {
            self.process(sink);
        }
        if self.queues[topic].len() > self.settings.queue_size {
            // Cancel the search, drop the oldest message of this topic.
            self.past = [0; N];
            self.delete_front(topic, DropReason::Overflow, sink);
            self.has_dropped[topic] = true;
            if self.pivot.take().is_some() {
                self.process(sink);
            }
        }
    }

    /// Advances time without a message: applies timeouts.
    pub fn poll<S: SyncSink<N>>(&mut self, now: u64, sink: &mut S) {
        self.advance(now, sink);
    }

    /// End of stream: publishes every set that would be optimal if no further
    /// message ever arrived. Messages that cannot form a set stay queued.
    pub fn flush<S: SyncSink<N>>(&mut self, sink: &mut S) {
        self.end_of_stream = true;
        if self.pivot.is_some() {
            self.publish(sink);
        }
        self.process(sink);
        self.end_of_stream = false;
    }

    fn advance<S: SyncSink<N>>(&mut self, now: u64, sink: &mut S) {
        self.now = self.now.max(now);
        // Before the first message nothing can be late: the clock for topics
        // that never spoke starts when data starts to flow.
        let (Some(timeout), Some(first)) = (self.settings.timeout_ns, self.first_now) else {
            return;
        };
        let now = self.now;
        let fresh: [bool; N] = std::array::from_fn(|i| match self.last_stamp[i] {
            Some(t) => now.saturating_sub(t) <= timeout,
            None => now.saturating_sub(first) <= timeout,
        });
        if fresh == self.active {
            return;
        }
        // The set of topics changed: cancel the search and start over.
        self.past = [0; N];
        self.pivot = None;
        for (i, &is_fresh) in fresh.iter().enumerate() {
            if self.active[i] && !is_fresh {
                while !self.queues[i].is_empty() {
                    self.delete_front(i, DropReason::Timeout, sink);
                }
            }
            self.has_dropped[i] = false;
        }
        self.active = fresh;
        if self.all_active_nonempty() {
            self.process(sink);
        }
    }

    fn deque_nonempty(&self, i: usize) -> bool {
        self.past[i] < self.queues[i].len()
    }

    fn head(&self, i: usize) -> Option<u64> {
        self.queues[i].get(self.past[i]).copied()
    }

    fn all_active_nonempty(&self) -> bool {
        let mut any = false;
        for i in 0..N {
            if self.active[i] {
                any = true;
                if !self.deque_nonempty(i) {
                    return false;
                }
            }
        }
        any
    }

    /// Earliest (`end == false`, lowest index on ties) or latest (`end == true`,
    /// highest index on ties) head among active topics, as ROS picks them.
    fn boundary(&self, end: bool, virtual_times: Option<&[u64; N]>) -> Option<(usize, u64)> {
        let mut best: Option<(usize, u64)> = None;
        for i in 0..N {
            if !self.active[i] {
                continue;
            }
            let t = match virtual_times {
                Some(v) => v[i],
                None => self.head(i)?,
            };
            best = match best {
                None => Some((i, t)),
                Some((_, bt)) if (t < bt) ^ end => Some((i, t)),
                keep => keep,
            };
        }
        best
    }

    fn delete_front<S: SyncSink<N>>(&mut self, i: usize, reason: DropReason, sink: &mut S) {
        if self.queues[i].pop_front().is_some() {
            self.past[i] = self.past[i].saturating_sub(1);
            self.counters.dropped[i][reason.index()] += 1;
            sink.drop_front(i, reason);
        }
    }

    fn move_to_past(&mut self, i: usize) -> bool {
        if self.deque_nonempty(i) {
            self.past[i] += 1;
            true
        } else {
            false
        }
    }

    /// The current heads become the candidate: everything passed over before them goes.
    fn make_candidate<S: SyncSink<N>>(&mut self, sink: &mut S) {
        for i in 0..N {
            while self.past[i] > 0 {
                self.delete_front(i, DropReason::Superseded, sink);
            }
        }
    }

    fn publish<S: SyncSink<N>>(&mut self, sink: &mut S) {
        self.pivot = None;
        self.past = [0; N];
        let present = self.active;
        let mut complete = true;
        for (i, &is_present) in present.iter().enumerate() {
            if is_present {
                self.queues[i].pop_front();
                self.counters.published[i] += 1;
            } else {
                complete = false;
            }
        }
        self.counters.sets += 1;
        if !complete {
            self.counters.degraded_sets += 1;
        }
        sink.publish(present);
    }

    /// Virtual head time of each active topic: its real head, or for an empty
    /// deque the earliest its next message can carry.
    fn virtual_times(&self) -> [u64; N] {
        std::array::from_fn(|i| match self.head(i) {
            Some(t) => t,
            None if self.end_of_stream => u64::MAX,
            None => {
                let last = self.past[i]
                    .checked_sub(1)
                    .and_then(|k| self.queues[i].get(k).copied())
                    .unwrap_or(self.pivot_time);
                last.saturating_add(self.settings.lower_bound_ns[i])
                    .max(self.pivot_time)
            }
        })
    }

    /// ROS `process()`.
    fn process<S: SyncSink<N>>(&mut self, sink: &mut S) {
        let ap = self.settings.age_penalty;
        while self.all_active_nonempty() {
            let (Some((start_i, start_t)), Some((end_i, end_t))) =
                (self.boundary(false, None), self.boundary(true, None))
            else {
                return;
            };
            for i in 0..N {
                if i != end_i {
                    self.has_dropped[i] = false;
                }
            }
            match self.pivot {
                None => {
                    if end_t - start_t > self.settings.max_interval_ns {
                        self.delete_front(start_i, DropReason::Interval, sink);
                        continue;
                    }
                    if self.has_dropped[end_i] {
                        self.delete_front(start_i, DropReason::DroppedPivot, sink);
                        continue;
                    }
                    self.make_candidate(sink);
                    self.cand_start = start_t;
                    self.cand_end = end_t;
                    self.pivot = Some(end_i);
                    self.pivot_time = end_t;
                    self.move_to_past(start_i);
                }
                Some(_) => {
                    if !no_better(
                        end_t.saturating_sub(self.cand_end),
                        start_t.saturating_sub(self.cand_start),
                        ap,
                    ) {
                        self.make_candidate(sink);
                        self.cand_start = start_t;
                        self.cand_end = end_t;
                    }
                    self.move_to_past(start_i);
                }
            }
            if self.pivot == Some(start_i) {
                // Every candidate for this pivot has been tried.
                self.publish(sink);
            } else if no_better(
                end_t.saturating_sub(self.cand_end),
                self.pivot_time.saturating_sub(self.cand_start),
                ap,
            ) {
                // Any later set must contain [pivot_time, end_t]: already worse.
                self.publish(sink);
            } else if !self.all_active_nonempty() {
                self.virtual_search(sink);
            }
        }
    }

    /// ROS's attempt to prove optimality from the lower bounds when a deque ran empty.
    fn virtual_search<S: SyncSink<N>>(&mut self, sink: &mut S) {
        let ap = self.settings.age_penalty;
        let mut moves = [0usize; N];
        loop {
            let times = self.virtual_times();
            let (Some((vs_i, vs_t)), Some((_, ve_t))) = (
                self.boundary(false, Some(&times)),
                self.boundary(true, Some(&times)),
            ) else {
                break;
            };
            if no_better(
                ve_t.saturating_sub(self.cand_end),
                self.pivot_time.saturating_sub(self.cand_start),
                ap,
            ) {
                self.publish(sink);
                return;
            }
            if !no_better(
                ve_t.saturating_sub(self.cand_end),
                vs_t.saturating_sub(self.cand_start),
                ap,
            ) {
                // An optimistic future set beats the candidate: wait for data.
                break;
            }
            if !self.move_to_past(vs_i) {
                break;
            }
            moves[vs_i] += 1;
        }
        for (p, m) in self.past.iter_mut().zip(moves) {
            *p -= m;
        }
    }
}

/// A synchronised set: one message per topic, `None` for topics that timed out.
#[derive(Debug, Clone, Copy)]
pub struct Matched<'m, A, B, C> {
    pub a: Option<&'m A>,
    pub b: Option<&'m B>,
    pub c: Option<&'m C>,
}

/// ApproximateTime over three typed topics (0 = `A`, 1 = `B`, 2 = `C`).
#[derive(Debug, Clone)]
pub struct Sync3<A, B, C> {
    core: ApproxCore<3>,
    a: VecDeque<A>,
    b: VecDeque<B>,
    c: VecDeque<C>,
}

struct Sink3<'s, A, B, C, F> {
    a: &'s mut VecDeque<A>,
    b: &'s mut VecDeque<B>,
    c: &'s mut VecDeque<C>,
    out: &'s mut F,
}

impl<A, B, C, F: FnMut(Matched<'_, A, B, C>)> SyncSink<3> for Sink3<'_, A, B, C, F> {
    fn drop_front(&mut self, topic: usize, _reason: DropReason) {
        match topic {
            0 => drop(self.a.pop_front()),
            1 => drop(self.b.pop_front()),
            _ => drop(self.c.pop_front()),
        }
    }

    fn publish(&mut self, present: [bool; 3]) {
        (self.out)(Matched {
            a: if present[0] { self.a.front() } else { None },
            b: if present[1] { self.b.front() } else { None },
            c: if present[2] { self.c.front() } else { None },
        });
        if present[0] {
            self.a.pop_front();
        }
        if present[1] {
            self.b.pop_front();
        }
        if present[2] {
            self.c.pop_front();
        }
    }
}

impl<A: Stamped + Clone, B: Stamped + Clone, C: Stamped + Clone> Sync3<A, B, C> {
    pub fn new(settings: SyncSettings<3>) -> Self {
        let core = ApproxCore::new(settings);
        let cap = core.settings().queue_size + 2;
        Self {
            core,
            a: VecDeque::with_capacity(cap),
            b: VecDeque::with_capacity(cap),
            c: VecDeque::with_capacity(cap),
        }
    }

    pub fn core(&self) -> &ApproxCore<3> {
        &self.core
    }

    pub fn counters(&self) -> &SyncCounters<3> {
        self.core.counters()
    }

    pub fn push_a<F: FnMut(Matched<'_, A, B, C>)>(&mut self, msg: &A, now: u64, out: &mut F) {
        let stamp = msg.stamp_ns();
        let mut sink = Sink3 {
            a: &mut self.a,
            b: &mut self.b,
            c: &mut self.c,
            out,
        };
        if self.core.admit(0, stamp, now, &mut sink) {
            sink.a.push_back(msg.clone());
            self.core.enqueue(0, stamp, &mut sink);
        }
    }

    pub fn push_b<F: FnMut(Matched<'_, A, B, C>)>(&mut self, msg: &B, now: u64, out: &mut F) {
        let stamp = msg.stamp_ns();
        let mut sink = Sink3 {
            a: &mut self.a,
            b: &mut self.b,
            c: &mut self.c,
            out,
        };
        if self.core.admit(1, stamp, now, &mut sink) {
            sink.b.push_back(msg.clone());
            self.core.enqueue(1, stamp, &mut sink);
        }
    }

    pub fn push_c<F: FnMut(Matched<'_, A, B, C>)>(&mut self, msg: &C, now: u64, out: &mut F) {
        let stamp = msg.stamp_ns();
        let mut sink = Sink3 {
            a: &mut self.a,
            b: &mut self.b,
            c: &mut self.c,
            out,
        };
        if self.core.admit(2, stamp, now, &mut sink) {
            sink.c.push_back(msg.clone());
            self.core.enqueue(2, stamp, &mut sink);
        }
    }

    /// Applies timeouts at time `now` (call periodically while inputs may be silent).
    pub fn poll<F: FnMut(Matched<'_, A, B, C>)>(&mut self, now: u64, out: &mut F) {
        let mut sink = Sink3 {
            a: &mut self.a,
            b: &mut self.b,
            c: &mut self.c,
            out,
        };
        self.core.poll(now, &mut sink);
    }

    /// End of stream (see [`ApproxCore::flush`]).
    pub fn flush<F: FnMut(Matched<'_, A, B, C>)>(&mut self, out: &mut F) {
        let mut sink = Sink3 {
            a: &mut self.a,
            b: &mut self.b,
            c: &mut self.c,
            out,
        };
        self.core.flush(&mut sink);
    }
}

#[cfg(test)]
mod tests;
