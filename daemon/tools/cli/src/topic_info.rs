//! `smokenav topic info|bw`: who is on a topic, and how many bytes flow.

use anyhow::Context;
use smokenav_platform_bus::{Bus, PortInfo, TopicPorts, Waiter, topics};
use smokenav_shared_types::MapInfo;
use smokenav_shared_types::catalog::{Cataloged, MessageVisitor};
use std::collections::VecDeque;
use std::io::Write as _;
use std::time::{Duration, Instant};

/// The ports and QoS of one topic, whatever catalog type it carries.
struct Ports<'a> {
    bus: &'a Bus,
    topic: &'a str,
}

impl MessageVisitor for Ports<'_> {
    type Output = anyhow::Result<Option<TopicPorts>>;

    fn fixed<M: Cataloged>(&mut self) -> Self::Output {
        let t = topics::lookup::<M>(self.topic)
            .with_context(|| format!("topic `{}` does not carry {}", self.topic, M::NAME))?;
        Ok(self.bus.topic_ports(t)?)
    }

    fn map(&mut self) -> Self::Output {
        let t = topics::lookup_map(self.topic)
            .with_context(|| format!("topic `{}` does not carry the map", self.topic))?;
        Ok(self.bus.map_topic_ports(t)?)
    }
}

fn port_json(p: &PortInfo) -> serde_json::Value {
    serde_json::json!({ "node": p.node, "alive": p.alive })
}

/// `topic info TOPIC`: type, publishers, subscribers and QoS as iceoryx2 reports them.
pub fn info(bus: &Bus, topic: &str, json: bool) -> anyhow::Result<()> {
    let kind = crate::topic::kind_of(topic)?;
    let ports = kind.visit(&mut Ports { bus, topic })?;
    let ros2_topic = format!("/{topic}");
    if json {
        let v = serde_json::json!({
            "topic": topic,
            "ros2_topic": ros2_topic,
            "type": kind.name(),
            "ros2_type": kind.ros2_type(),
            "latched": kind.latched(),
            "exists": ports.is_some(),
            "bus_type": ports.as_ref().map(|p| p.type_name.clone()),
            "publishers": ports.as_ref().map(|p| p.publishers.iter().map(port_json).collect::<Vec<_>>()).unwrap_or_default(),
            "subscribers": ports.as_ref().map(|p| p.subscribers.iter().map(port_json).collect::<Vec<_>>()).unwrap_or_default(),
            "qos": ports.as_ref().map(|p| serde_json::json!({
                "history": p.qos.history,
                "queue": p.qos.buffer,
                "max_publishers": p.qos.max_publishers,
                "max_subscribers": p.qos.max_subscribers,
                "drop_oldest_when_full": p.safe_overflow,
            })),
        });
        println!("{v}");
        return Ok(());
    }
    let mut out = std::io::stdout().lock();
    writeln!(out, "Topic: {topic} (ROS 2: {ros2_topic})")?;
    writeln!(out, "Type: {} (ROS 2: {})", kind.name(), kind.ros2_type())?;
    let Some(p) = ports else {
        writeln!(
            out,
            "Not on instance `{}` yet: no process has opened it.",
            bus.instance()
        )?;
        writeln!(out, "Publisher count: 0\nSubscription count: 0")?;
        return Ok(());
    };
    writeln!(
        out,
        "QoS: history {} (late joiners get the last {}), queue {} per subscriber ({}), \
         at most {} publishers and {} subscribers{}",
        p.qos.history,
        p.qos.history,
        p.qos.buffer,
        if p.safe_overflow {
            "oldest dropped when full"
        } else {
            "publisher blocks when full"
        },
        p.qos.max_publishers,
        p.qos.max_subscribers,
        if kind.latched() {
            "; latched (ROS 2 transient local)"
        } else {
            ""
        }
    )?;
    for (label, list) in [
        ("Publisher count", &p.publishers),
        ("Subscription count", &p.subscribers),
    ] {
        writeln!(out, "{label}: {}", list.len())?;
        for port in list {
            writeln!(
                out,
                "  {}{}",
                port.node,
                if port.alive { "" } else { " (dead)" }
            )?;
        }
    }
    Ok(())
}

/// Bandwidth over a sliding window of arrivals: (time, bytes).
struct Bandwidth {
    window: usize,
    samples: VecDeque<(Instant, usize)>,
    total_bytes: u64,
    received: u64,
}

impl Bandwidth {
    fn new(window: usize) -> Self {
        Self {
            window,
            samples: VecDeque::with_capacity(window),
            total_bytes: 0,
            received: 0,
        }
    }

    fn arrive(&mut self, at: Instant, bytes: usize) {
        if self.samples.len() == self.window {
            self.samples.pop_front();
        }
        self.samples.push_back((at, bytes));
        self.total_bytes += bytes as u64;
        self.received += 1;
    }

    /// Bytes per second over the window (first to last arrival), mean, min and max message size.
    fn stats(&self) -> Option<(f64, f64, usize, usize)> {
        let (first, last) = (self.samples.front()?, self.samples.back()?);
        let span = last.0.duration_since(first.0).as_secs_f64();
        if self.samples.len() < 2 || span <= 0.0 {
            return None;
        }
        // The first arrival opens the window; the bytes after it arrived within `span`.
        let bytes: usize = self.samples.iter().skip(1).map(|s| s.1).sum();
        let all: usize = self.samples.iter().map(|s| s.1).sum();
        let min = self.samples.iter().map(|s| s.1).min()?;
        let max = self.samples.iter().map(|s| s.1).max()?;
        Some((
            bytes as f64 / span,
            all as f64 / self.samples.len() as f64,
            min,
            max,
        ))
    }
}

fn human(bytes_per_s: f64) -> String {
    match bytes_per_s {
        b if b >= 1e6 => format!("{:.2} MB/s", b / 1e6),
        b if b >= 1e3 => format!("{:.2} KB/s", b / 1e3),
        b => format!("{b:.0} B/s"),
    }
}

struct Bw<'a> {
    bus: &'a Bus,
    topic: &'a str,
    duration: Option<Duration>,
    json: bool,
    stats: &'a mut Bandwidth,
}

impl Bw<'_> {
    /// Drains `receive` (bytes of each new sample) until the duration ends or Ctrl-C.
    fn run(
        &mut self,
        waiter: &Waiter,
        mut receive: impl FnMut() -> anyhow::Result<Option<usize>>,
    ) -> anyhow::Result<()> {
        let start = Instant::now();
        let mut last_print = start;
        let stop = smokenav_platform_runtime::Shutdown::install()?;
        loop {
            while let Some(bytes) = receive()? {
                self.stats.arrive(Instant::now(), bytes);
            }
            let now = Instant::now();
            if !self.json && now.duration_since(last_print) >= Duration::from_secs(1) {
                last_print = now;
                match self.stats.stats() {
                    Some((bw, mean, min, max)) => println!(
                        "average: {}\n  mean: {mean:.0} B min: {min} B max: {max} B window: {}",
                        human(bw),
                        self.stats.samples.len()
                    ),
                    None => println!("no new messages"),
                }
            }
            if stop.requested()
                || self
                    .duration
                    .is_some_and(|d| now.duration_since(start) >= d)
            {
                return Ok(());
            }
            waiter.wait(Some(Duration::from_millis(200)))?;
        }
    }
}

impl MessageVisitor for Bw<'_> {
    type Output = anyhow::Result<()>;

    fn fixed<M: Cataloged>(&mut self) -> Self::Output {
        let topic = topics::lookup::<M>(self.topic)
            .with_context(|| format!("topic `{}` does not carry {}", self.topic, M::NAME))?;
        let subscribed_ns = smokenav_shared_types::clock::monotonic_now_ns();
        let sub = self.bus.subscriber(topic)?;
        let waiter = Waiter::new()?;
        let _g = waiter.attach(&sub)?;
        // A fixed-size message is one shared-memory sample of its full size.
        let size = std::mem::size_of::<M>();
        self.run(&waiter, || {
            while let Some(s) = sub.receive()? {
                let h = s.payload().header();
                // The history sample predates us: it did not flow while we watched.
                if h.stamp_ns == 0 || h.stamp_ns >= subscribed_ns {
                    return Ok(Some(size));
                }
            }
            Ok(None)
        })
    }

    fn map(&mut self) -> Self::Output {
        let topic = topics::lookup_map(self.topic)
            .with_context(|| format!("topic `{}` does not carry the map", self.topic))?;
        let subscribed_ns = smokenav_shared_types::clock::monotonic_now_ns();
        let sub = self.bus.map_subscriber(topic)?;
        let waiter = Waiter::new()?;
        let _g = waiter.attach(&sub)?;
        self.run(&waiter, || {
            while let Some(s) = sub.receive()? {
                let h = s.user_header().header;
                if h.stamp_ns == 0 || h.stamp_ns >= subscribed_ns {
                    return Ok(Some(std::mem::size_of::<MapInfo>() + s.payload().len()));
                }
            }
            Ok(None)
        })
    }
}

/// `topic bw TOPIC`: bytes per second on the bus, and message sizes.
pub fn bw(
    bus: &Bus,
    topic: &str,
    duration: Option<Duration>,
    window: usize,
    json: bool,
) -> anyhow::Result<()> {
    let kind = crate::topic::kind_of(topic)?;
    let mut stats = Bandwidth::new(window);
    kind.visit(&mut Bw {
        bus,
        topic,
        duration,
        json,
        stats: &mut stats,
    })?;
    if json {
        let (bw, mean, min, max) = stats.stats().unwrap_or((0.0, 0.0, 0, 0));
        println!(
            "{}",
            serde_json::json!({
                "topic": topic,
                "received": stats.received,
                "total_bytes": stats.total_bytes,
                "bytes_per_s": bw,
                "mean_bytes": mean,
                "min_bytes": min,
                "max_bytes": max,
            })
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bandwidth_is_bytes_after_the_first_arrival_over_the_span() {
        let mut b = Bandwidth::new(10);
        let t0 = Instant::now();
        assert_eq!(b.stats(), None);
        for k in 0..5u64 {
            b.arrive(t0 + Duration::from_millis(100 * k), 1000);
        }
        let (bw, mean, min, max) = b.stats().unwrap();
        assert!((bw - 10_000.0).abs() < 1e-6, "{bw}");
        assert_eq!((mean, min, max), (1000.0, 1000, 1000));
        assert_eq!(b.total_bytes, 5000);
        // The window slides: the oldest arrivals leave it.
        for k in 5..20u64 {
            b.arrive(t0 + Duration::from_millis(100 * k), 2000);
        }
        assert_eq!(b.samples.len(), 10);
        assert!((b.stats().unwrap().0 - 20_000.0).abs() < 1e-6);
    }
}
