use super::*;
use proptest::prelude::*;

const MS: u64 = 1_000_000;

/// A test message: which topic, which position in that topic's stream, when.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Msg {
    topic: usize,
    index: usize,
    stamp: u64,
}

impl Stamped for Msg {
    fn stamp_ns(&self) -> u64 {
        self.stamp
    }
}

type Set = [Option<usize>; 3];

fn set_of(m: Matched<'_, Msg, Msg, Msg>) -> Set {
    [
        m.a.map(|x| x.index),
        m.b.map(|x| x.index),
        m.c.map(|x| x.index),
    ]
}

fn push(s: &mut Sync3<Msg, Msg, Msg>, m: Msg, now: u64, out: &mut Vec<Set>) {
    let mut f = |x: Matched<'_, Msg, Msg, Msg>| out.push(set_of(x));
    match m.topic {
        0 => s.push_a(&m, now, &mut f),
        1 => s.push_b(&m, now, &mut f),
        _ => s.push_c(&m, now, &mut f),
    }
}

/// Feeds `streams` in the arrival order given by `order` (topic per step), `now` =
/// newest stamp seen, then flushes.
fn run(
    settings: SyncSettings<3>,
    streams: &[Vec<u64>; 3],
    order: &[usize],
) -> (Vec<Set>, SyncCounters<3>) {
    let mut s = Sync3::new(settings);
    let mut out = Vec::new();
    let mut next = [0usize; 3];
    let mut now = 0;
    for &t in order {
        if let Some(&stamp) = streams[t].get(next[t]) {
            now = now.max(stamp);
            push(
                &mut s,
                Msg {
                    topic: t,
                    index: next[t],
                    stamp,
                },
                now,
                &mut out,
            );
            next[t] += 1;
        }
    }
    s.flush(&mut |x| out.push(set_of(x)));
    (out, *s.counters())
}

/// The brute-force reference: what ApproximateTime must output when every
/// message is known in advance (unbounded queue, no future messages).
///
/// From the remaining messages: the pivot is the latest of the topics' first
/// messages; a head set spanning more than `max_interval` loses its earliest
/// message. Then every set `C(T)` = "each topic's first remaining message
/// stamped ≥ T" for T over the remaining stamps ≤ the pivot's stamp is a
/// candidate, scanned by increasing T, a later one replacing the best only if
/// its growth at the end, times 1 + age penalty, is less than its shrink at
/// the start. The best is emitted; it and all older messages are consumed.
fn reference(streams: &[Vec<u64>; 3], max_interval: u64, ap: f64) -> Vec<Set> {
    let mut pos = [0usize; 3];
    let mut out = Vec::new();
    loop {
        if (0..3).any(|i| pos[i] >= streams[i].len()) {
            return out;
        }
        let heads: [u64; 3] = std::array::from_fn(|i| streams[i][pos[i]]);
        // earliest: lowest index on ties; latest: highest index on ties
        let start_i = (0..3).min_by_key(|&i| (heads[i], i)).unwrap();
        let end_i = (0..3).max_by_key(|&i| (heads[i], i)).unwrap();
        if heads[end_i] - heads[start_i] > max_interval {
            pos[start_i] += 1;
            continue;
        }
        let pivot_t = heads[end_i];
        let mut ts: Vec<u64> = (0..3)
            .flat_map(|i| streams[i][pos[i]..].iter().copied())
            .filter(|&t| t <= pivot_t)
            .collect();
        ts.sort_unstable();
        ts.dedup();
        let mut best = pos;
        let (mut bs, mut be) = (heads[start_i], pivot_t);
        for t in ts {
            let cfg: Option<[usize; 3]> = (0..3)
                .map(|i| (pos[i]..streams[i].len()).find(|&k| streams[i][k] >= t))
                .collect::<Option<Vec<_>>>()
                .map(|v| [v[0], v[1], v[2]]);
            let Some(cfg) = cfg else { break };
            let st: Vec<u64> = (0..3).map(|i| streams[i][cfg[i]]).collect();
            let (s, e) = (*st.iter().min().unwrap(), *st.iter().max().unwrap());
            if ((e - be) as f64) * (1.0 + ap) < (s - bs) as f64 {
                best = cfg;
                bs = s;
                be = e;
            }
        }
        out.push([Some(best[0]), Some(best[1]), Some(best[2])]);
        pos = [best[0] + 1, best[1] + 1, best[2] + 1];
    }
}

/// Sorted stamps (ms grid, so ties happen) for three topics.
fn streams_strategy(max_len: usize) -> impl Strategy<Value = [Vec<u64>; 3]> {
    let one = prop::collection::vec(0u64..400, 0..max_len).prop_map(|mut v| {
        v.sort_unstable();
        v.into_iter().map(|t| t * MS).collect::<Vec<_>>()
    });
    (one.clone(), one.clone(), one).prop_map(|(a, b, c)| [a, b, c])
}

/// Streams whose successive stamps on one topic are at least `gap_ms` apart.
fn spaced_streams(max_len: usize, gap_ms: u64) -> impl Strategy<Value = [Vec<u64>; 3]> {
    let one =
        (0u64..50, prop::collection::vec(0u64..40, 0..max_len)).prop_map(move |(start, gaps)| {
            let mut t = start;
            gaps.into_iter()
                .map(|g| {
                    t += gap_ms + g;
                    t * MS
                })
                .collect::<Vec<_>>()
        });
    (one.clone(), one.clone(), one).prop_map(|(a, b, c)| [a, b, c])
}

fn order_strategy() -> impl Strategy<Value = Vec<usize>> {
    prop::collection::vec(0usize..3, 0..300)
}

/// Arrival order: the random topic sequence, then whatever is left, round robin.
fn full_order(streams: &[Vec<u64>; 3], order: &[usize]) -> Vec<usize> {
    let mut left = [streams[0].len(), streams[1].len(), streams[2].len()];
    let mut o = Vec::new();
    for &t in order {
        if left[t] > 0 {
            left[t] -= 1;
            o.push(t);
        }
    }
    while left.iter().any(|&l| l > 0) {
        for (t, l) in left.iter_mut().enumerate() {
            if *l > 0 {
                *l -= 1;
                o.push(t);
            }
        }
    }
    o
}

fn big_queue(max_interval_ms: u64, ap: f64) -> SyncSettings<3> {
    SyncSettings {
        queue_size: 10_000,
        max_interval_ns: max_interval_ms * MS,
        age_penalty: ap,
        lower_bound_ns: [0; 3],
        timeout_ns: None,
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

    #[test]
    fn output_equals_brute_force_reference(
        streams in streams_strategy(25),
        order in order_strategy(),
        max_interval_ms in 1u64..500,
        penalise in any::<bool>(),
    ) {
        let ap = if penalise { 0.1 } else { 0.0 };
        let (got, _) = run(big_queue(max_interval_ms, ap), &streams, &full_order(&streams, &order));
        prop_assert_eq!(got, reference(&streams, max_interval_ms * MS, ap));
    }

    #[test]
    fn output_depends_only_on_stamps_not_arrival_order(
        streams in streams_strategy(25),
        order1 in order_strategy(),
        order2 in order_strategy(),
    ) {
        let s = big_queue(100, 0.1);
        let (a, _) = run(s, &streams, &full_order(&streams, &order1));
        let (b, _) = run(s, &streams, &full_order(&streams, &order2));
        prop_assert_eq!(a, b);
    }

    #[test]
    fn valid_lower_bounds_keep_the_reference_output(
        streams in spaced_streams(25, 30),
        order in order_strategy(),
    ) {
        // Every topic's messages are >= 30 ms apart, so a 30 ms bound is true.
        let s = SyncSettings { lower_bound_ns: [30 * MS; 3], ..big_queue(150, 0.1) };
        let (got, c) = run(s, &streams, &full_order(&streams, &order));
        prop_assert_eq!(got, reference(&streams, 150 * MS, 0.1));
        prop_assert_eq!(c.bound_violations, [0; 3]);
    }

    #[test]
    fn bounded_queues_use_each_message_once_never_cross_and_count_every_drop(
        streams in streams_strategy(40),
        order in order_strategy(),
        queue_size in 1usize..6,
        max_interval_ms in 1u64..200,
        bound_ms in 0u64..20,
    ) {
        let settings = SyncSettings {
            queue_size,
            max_interval_ns: max_interval_ms * MS,
            age_penalty: 0.1,
            lower_bound_ns: [bound_ms * MS; 3],
            timeout_ns: None,
        };
        let mut s = Sync3::new(settings);
        let mut out = Vec::new();
        let mut next = [0usize; 3];
        for t in full_order(&streams, &order) {
            let stamp = streams[t][next[t]];
            push(&mut s, Msg { topic: t, index: next[t], stamp }, stamp, &mut out);
            next[t] += 1;
            prop_assert!(s.core().pending().iter().all(|&p| p <= queue_size));
        }
        let mut last: [Option<usize>; 3] = [None; 3];
        for set in &out {
            let st: Vec<u64> = (0..3).map(|i| streams[i][set[i].unwrap()]).collect();
            let span = st.iter().max().unwrap() - st.iter().min().unwrap();
            prop_assert!(span <= max_interval_ms * MS, "set {set:?} spans {span}");
            for i in 0..3 {
                let k = set[i].unwrap();
                prop_assert!(last[i].is_none_or(|l| k > l), "topic {i} reused or crossed: {out:?}");
                last[i] = Some(k);
            }
        }
        let c = s.counters();
        let pending = s.core().pending();
        for i in 0..3 {
            prop_assert_eq!(c.received[i], streams[i].len() as u64);
            prop_assert_eq!(c.received[i], c.published[i] + c.dropped_total(i) + pending[i] as u64);
        }
        prop_assert_eq!(c.sets, out.len() as u64);
    }

    #[test]
    fn arbitrary_pushes_and_polls_never_panic_and_stay_bounded(
        ops in prop::collection::vec((0usize..4, 0u64..2_000), 0..400),
        queue_size in 1usize..5,
    ) {
        let settings = SyncSettings {
            queue_size,
            max_interval_ns: 50 * MS,
            age_penalty: 0.1,
            lower_bound_ns: [20 * MS; 3],
            timeout_ns: Some(100 * MS),
        };
        let mut s = Sync3::new(settings);
        let mut out = Vec::new();
        let mut now = 0;
        for (i, (t, stamp)) in ops.into_iter().enumerate() {
            now = now.max(stamp * MS / 2);
            if t == 3 {
                s.poll(now, &mut |x| out.push(set_of(x)));
            } else {
                push(&mut s, Msg { topic: t, index: i, stamp: stamp * MS }, now, &mut out);
            }
            prop_assert!(s.core().pending().iter().all(|&p| p <= queue_size));
        }
    }
}

fn msg(topic: usize, index: usize, stamp_ms: u64) -> Msg {
    Msg {
        topic,
        index,
        stamp: stamp_ms * MS,
    }
}

fn tight(timeout_ms: Option<u64>, bound_ms: u64) -> SyncSettings<3> {
    SyncSettings {
        queue_size: 8,
        max_interval_ns: 150 * MS,
        age_penalty: 0.1,
        lower_bound_ns: [bound_ms * MS; 3],
        timeout_ns: timeout_ms.map(|t| t * MS),
    }
}

#[test]
fn without_bounds_a_set_waits_for_the_next_message_like_ros() {
    let mut s = Sync3::new(tight(None, 0));
    let mut out = Vec::new();
    push(&mut s, msg(0, 0, 100), 100 * MS, &mut out);
    push(&mut s, msg(1, 0, 101), 101 * MS, &mut out);
    push(&mut s, msg(2, 0, 102), 102 * MS, &mut out);
    assert!(out.is_empty(), "ROS cannot prove optimality yet: {out:?}");
    push(&mut s, msg(0, 1, 200), 200 * MS, &mut out);
    assert_eq!(out, vec![[Some(0), Some(0), Some(0)]]);
}

#[test]
fn lower_bounds_emit_the_set_when_its_last_member_arrives() {
    // 10 Hz sensors, 50 ms bounds: stamps 100/101/102 ms form a provably best
    // set as soon as the 102 ms smoke reading is in.
    let mut s = Sync3::new(tight(None, 50));
    let mut out = Vec::new();
    push(&mut s, msg(0, 0, 100), 100 * MS, &mut out);
    push(&mut s, msg(1, 0, 101), 101 * MS, &mut out);
    assert!(out.is_empty());
    push(&mut s, msg(2, 0, 102), 102 * MS, &mut out);
    assert_eq!(out, vec![[Some(0), Some(0), Some(0)]]);
}

#[test]
fn silent_topic_degrades_output_within_the_timeout() {
    // Sonar (topic 1) stops after 300 ms; timeout 500 ms.
    let mut s = Sync3::new(tight(Some(500), 50));
    let mut out = Vec::new();
    for k in 0..4u64 {
        let t = 100 * k;
        push(&mut s, msg(0, k as usize, t), t * MS, &mut out);
        push(&mut s, msg(1, k as usize, t), t * MS, &mut out);
        push(&mut s, msg(2, k as usize, t), t * MS, &mut out);
    }
    assert_eq!(out.len(), 4);
    assert!(out.iter().all(|x| x.iter().all(Option::is_some)));
    out.clear();
    for k in 4..10u64 {
        let t = 100 * k;
        push(&mut s, msg(0, k as usize, t), t * MS, &mut out);
        push(&mut s, msg(2, k as usize, t), t * MS, &mut out);
    }
    // Last sonar at 300 ms: inactive once now > 800 ms. Laser+smoke sets from
    // 400 ms on come out the moment the sonar is declared silent, then live.
    assert_eq!(s.core().active(), [true, false, true]);
    let idx: Vec<Set> = out.clone();
    assert_eq!(idx.first(), Some(&[Some(4), None, Some(4)]));
    assert_eq!(idx.last(), Some(&[Some(9), None, Some(9)]));
    assert_eq!(idx.len(), 6, "{idx:?}");
    assert_eq!(s.counters().degraded_sets, 6);
}

#[test]
fn poll_alone_releases_queued_messages_of_a_silent_partner() {
    let mut s = Sync3::new(tight(Some(500), 50));
    let mut out = Vec::new();
    // Only the laser ever speaks.
    push(&mut s, msg(0, 0, 0), 0, &mut out);
    push(&mut s, msg(0, 1, 100), 100 * MS, &mut out);
    assert!(out.is_empty());
    s.poll(499 * MS, &mut |x| out.push(set_of(x)));
    assert!(out.is_empty(), "not yet silent for 500 ms");
    s.poll(501 * MS, &mut |x| out.push(set_of(x)));
    assert_eq!(out, vec![[Some(0), None, None], [Some(1), None, None]]);
}

#[test]
fn a_topic_that_speaks_again_rejoins_the_sets() {
    let mut s = Sync3::new(tight(Some(500), 50));
    let mut out = Vec::new();
    for k in 0..8u64 {
        let t = 100 * k;
        push(&mut s, msg(0, k as usize, t), t * MS, &mut out);
        push(&mut s, msg(2, k as usize, t), t * MS, &mut out);
    }
    assert_eq!(s.core().active(), [true, false, true]);
    out.clear();
    push(&mut s, msg(0, 8, 800), 800 * MS, &mut out);
    push(&mut s, msg(1, 0, 801), 801 * MS, &mut out);
    push(&mut s, msg(2, 8, 802), 802 * MS, &mut out);
    assert_eq!(s.core().active(), [true, true, true]);
    assert_eq!(out, vec![[Some(8), Some(0), Some(8)]]);
}

#[test]
fn polling_before_any_message_starts_no_timeout() {
    // The process polls from start-up; sensors come up later, a few ms apart.
    let mut s = Sync3::new(tight(Some(500), 50));
    let mut out = Vec::new();
    s.poll(0, &mut |x| out.push(set_of(x)));
    s.poll(2_000 * MS, &mut |x| out.push(set_of(x)));
    push(&mut s, msg(0, 0, 2_100), 2_100 * MS, &mut out);
    push(&mut s, msg(1, 0, 2_101), 2_101 * MS, &mut out);
    push(&mut s, msg(2, 0, 2_102), 2_102 * MS, &mut out);
    assert_eq!(out, vec![[Some(0), Some(0), Some(0)]]);
    assert_eq!(s.core().active(), [true; 3]);
}

#[test]
fn out_of_order_message_is_dropped_and_counted() {
    let mut s = Sync3::new(tight(None, 0));
    let mut out = Vec::new();
    push(&mut s, msg(0, 0, 100), 100 * MS, &mut out);
    push(&mut s, msg(0, 1, 90), 100 * MS, &mut out);
    assert_eq!(s.counters().dropped(0, DropReason::OutOfOrder), 1);
    assert_eq!(s.core().pending()[0], 1);
}

#[test]
fn stale_message_of_a_silent_topic_is_dropped_on_arrival() {
    let mut s = Sync3::new(tight(Some(500), 50));
    let mut out = Vec::new();
    push(&mut s, msg(0, 0, 1000), 1000 * MS, &mut out);
    // A sonar reading stamped 600 ms before "now" is already beyond the timeout.
    push(&mut s, msg(1, 0, 400), 1000 * MS, &mut out);
    assert_eq!(s.counters().dropped(1, DropReason::Timeout), 1);
}

#[test]
fn overflow_drops_the_oldest_and_counts_it() {
    let mut s = Sync3::new(SyncSettings {
        queue_size: 3,
        ..tight(None, 0)
    });
    let mut out = Vec::new();
    for k in 0..5 {
        push(&mut s, msg(0, k, 100 * k as u64), 0, &mut out);
    }
    assert_eq!(s.counters().dropped(0, DropReason::Overflow), 2);
    assert_eq!(s.core().pending()[0], 3);
}
