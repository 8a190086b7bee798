//! `smokenav topic list|echo|hz` (and `info|bw`, in `topic_info`): how a user sees what flows on the bus.

use anyhow::{Context, bail};
use clap::{Args, Subcommand};
use smokenav_platform_bus::{Bus, BusOptions, Waiter, topics};
use smokenav_platform_config::{INSTANCE_ENV, IOX2_ROOT_ENV, RobotConfig};
use smokenav_shared_types::catalog::{self, Cataloged, MessageKind, MessageVisitor};
use smokenav_shared_types::record::{MapInfoRecord, Message, TopicRecord};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Where the systemd units put iceoryx2's files.
const SYSTEMD_IOX2_ROOT: &str = "/run/smokenav/iox2/";
use std::time::{Duration, Instant};

/// Which bus to look at.
#[derive(Debug, Clone, Args)]
pub struct BusArgs {
    /// Bus instance (default: $SMOKENAV_INSTANCE, else the profile's, else `smokenav`).
    #[arg(long, global = true)]
    pub instance: Option<String>,
    /// Robot profile to take the instance and iceoryx2 root path from.
    #[arg(long, short = 'c', global = true, env = "SMOKENAV_CONFIG")]
    pub config: Option<PathBuf>,
}

impl BusArgs {
    /// Opens the bus as a tool node named `name`.
    pub fn open(&self, name: &str) -> anyhow::Result<Bus> {
        let (mut instance, mut root) = (None, std::env::var(IOX2_ROOT_ENV).ok());
        if let Some(path) = &self.config {
            let cfg = RobotConfig::load(path)
                .with_context(|| format!("invalid robot profile {}", path.display()))?;
            instance = Some(cfg.robot.instance);
            root = cfg.bus.root_path;
        }
        if let Ok(env) = std::env::var(INSTANCE_ENV)
            && !env.is_empty()
        {
            instance = Some(env);
        }
        if let Some(i) = &self.instance {
            instance = Some(i.clone());
        }
        let instance = instance.unwrap_or_else(|| "smokenav".into());
        // On a robot running the systemd units, the processes share this
        // directory (systemd/smokenav-*.service); find them without extra flags.
        // Someone outside group smokenav cannot even look at it: still this bus,
        // so that they are told how to get in rather than shown an empty one.
        let systemd_bus = match std::fs::metadata(SYSTEMD_IOX2_ROOT) {
            Ok(m) => m.is_dir(),
            Err(e) => e.kind() == std::io::ErrorKind::PermissionDenied,
        };
        if root.is_none() && systemd_bus {
            root = Some(SYSTEMD_IOX2_ROOT.to_owned());
        }
        if let Some(root) = &root {
            crate::access::ensure_bus_access(Path::new(root), name)?;
        }
        let node = format!("{name}-{}", std::process::id());
        Bus::open(&BusOptions::new(&instance, &node).with_root_path(root))
            .with_context(|| format!("cannot open bus instance `{instance}`"))
    }
}

#[derive(Debug, Subcommand)]
pub enum TopicCommand {
    /// List the topics of the instance with their types.
    List {
        #[command(flatten)]
        bus: BusArgs,
    },
    /// Print the messages of a topic as they arrive.
    Echo {
        /// e.g. laser/scan, base/odom, health/hokuyo (or the ROS spelling, /laser/scan).
        #[arg(value_parser = bus_topic)]
        topic: String,
        /// Stop after this many messages.
        #[arg(long, short = 'n')]
        count: Option<u64>,
        /// One JSON object per line (the format `smokenav fuse` reads).
        #[arg(long)]
        json: bool,
        /// Include the cells of `slam/map` in JSON output.
        #[arg(long)]
        with_data: bool,
        /// Give up after this many seconds.
        #[arg(long)]
        timeout: Option<f64>,
        #[command(flatten)]
        bus: BusArgs,
    },
    /// Type, publishers, subscribers and QoS of a topic, as iceoryx2 reports them.
    Info {
        /// e.g. laser/scan (or /laser/scan).
        #[arg(value_parser = bus_topic)]
        topic: String,
        /// One JSON object instead of text.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        bus: BusArgs,
    },
    /// Publish a message given as JSON (`base/cmd_vel` only with --motion and --for, then stop).
    Pub(crate::topic_pub::PubArgs),
    /// Measure a topic's bandwidth on the bus (bytes per second, message sizes).
    Bw {
        /// e.g. laser/scan (or /laser/scan).
        #[arg(value_parser = bus_topic)]
        topic: String,
        /// Stop after this many seconds.
        #[arg(long)]
        duration: Option<f64>,
        /// Messages the figures are computed over.
        #[arg(long, default_value_t = 100)]
        window: usize,
        /// Print one JSON summary at the end instead of a line per second.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        bus: BusArgs,
    },
    /// Measure a topic's rate, jitter and sequence gaps.
    Hz {
        /// e.g. laser/scan (or /laser/scan).
        #[arg(value_parser = bus_topic)]
        topic: String,
        /// Stop after this many seconds.
        #[arg(long)]
        duration: Option<f64>,
        /// Intervals the statistics are computed over.
        #[arg(long, default_value_t = 100)]
        window: usize,
        /// Print one JSON summary at the end instead of a line per second.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        bus: BusArgs,
    },
}

pub fn run(cmd: TopicCommand) -> anyhow::Result<()> {
    match cmd {
        TopicCommand::List { bus } => list(&bus.open("topic-list")?),
        TopicCommand::Echo {
            topic,
            count,
            json,
            with_data,
            timeout,
            bus,
        } => {
            let bus = bus.open("topic-echo")?;
            let opts = EchoOptions {
                count,
                json,
                with_data,
                timeout: timeout.map(Duration::from_secs_f64),
            };
            echo(&bus, &topic, &opts)
        }
        TopicCommand::Pub(args) => crate::topic_pub::run(args),
        TopicCommand::Info { topic, json, bus } => {
            crate::topic_info::info(&bus.open("topic-info")?, &topic, json)
        }
        TopicCommand::Bw {
            topic,
            duration,
            window,
            json,
            bus,
        } => crate::topic_info::bw(
            &bus.open("topic-bw")?,
            &topic,
            duration.map(Duration::from_secs_f64),
            window.max(2),
            json,
        ),
        TopicCommand::Hz {
            topic,
            duration,
            window,
            json,
            bus,
        } => hz(
            &bus.open("topic-hz")?,
            &topic,
            duration.map(Duration::from_secs_f64),
            window.max(2),
            json,
        ),
    }
}

fn list(bus: &Bus) -> anyhow::Result<()> {
    let services = bus.list()?;
    let mut out = std::io::stdout().lock();
    if services.is_empty() {
        writeln!(out, "no topics on instance `{}`", bus.instance())?;
        return Ok(());
    }
    let width = services.iter().map(|s| s.topic.len()).max().unwrap_or(0);
    for s in services {
        writeln!(
            out,
            "{:width$}  {}  ({} process{})",
            s.topic,
            s.type_name,
            s.nodes,
            if s.nodes == 1 { "" } else { "es" }
        )?;
    }
    Ok(())
}

struct EchoOptions {
    count: Option<u64>,
    json: bool,
    with_data: bool,
    timeout: Option<Duration>,
}

/// A topic named on the command line, the bus's way (`laser/scan`) or the
/// ROS way (`/laser/scan`): the bus name. Used as clap's `value_parser` for
/// every topic argument.
pub fn bus_topic(arg: &str) -> Result<String, String> {
    let name = catalog::bus_topic_name(arg);
    if name.is_empty() {
        return Err("a topic name is needed".into());
    }
    Ok(name.to_owned())
}

/// The catalog type `topic` carries, or an error listing the known topics.
pub(crate) fn kind_of(topic: &str) -> anyhow::Result<MessageKind> {
    catalog::topic_kind(topic)
        .with_context(|| format!("unknown topic `{topic}` (known: {})", known_topics()))
}

fn echo(bus: &Bus, topic: &str, opts: &EchoOptions) -> anyhow::Result<()> {
    kind_of(topic)?.visit(&mut Echo { bus, topic, opts })
}

/// The catalog's topics, families as `health/<role>`.
pub fn known_topics() -> String {
    catalog::TOPICS
        .iter()
        .map(|t| {
            if t.family {
                format!("{}<role>", t.name)
            } else {
                t.name.to_owned()
            }
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// Echoes one topic, whatever catalog type it carries.
struct Echo<'a> {
    bus: &'a Bus,
    topic: &'a str,
    opts: &'a EchoOptions,
}

impl MessageVisitor for Echo<'_> {
    type Output = anyhow::Result<()>;

    fn fixed<M: Cataloged>(&mut self) -> Self::Output {
        let topic = topics::lookup::<M>(self.topic)
            .with_context(|| format!("topic `{}` does not carry {}", self.topic, M::NAME))?;
        let sub = self.bus.subscriber(topic)?;
        let waiter = Waiter::new()?;
        let _g = waiter.attach(&sub)?;
        let mut printer = Printer::new(self.topic, self.opts);
        receive_loop(&waiter, self.opts.timeout, || {
            while let Some(s) = sub.receive()? {
                if printer.print(M::to_json(&s))? {
                    return Ok(true);
                }
            }
            printer.flush()?;
            Ok(false)
        })
    }

    fn map(&mut self) -> Self::Output {
        let topic = topics::lookup_map(self.topic)
            .with_context(|| format!("topic `{}` does not carry the map", self.topic))?;
        let sub = self.bus.map_subscriber(topic)?;
        let waiter = Waiter::new()?;
        let _g = waiter.attach(&sub)?;
        let with_data = self.opts.with_data;
        let mut printer = Printer::new(self.topic, self.opts);
        receive_loop(&waiter, self.opts.timeout, || {
            while let Some(s) = sub.receive()? {
                let cells = with_data.then(|| s.payload());
                let record = MapInfoRecord::from_map(s.user_header(), cells);
                if printer.print(Message::MapInfo(record))? {
                    return Ok(true);
                }
            }
            printer.flush()?;
            Ok(false)
        })
    }
}

/// Prints records of one topic, as JSON lines or one summary line each.
struct Printer<'a> {
    topic: &'a str,
    opts: &'a EchoOptions,
    out: std::io::StdoutLock<'static>,
    printed: u64,
}

impl<'a> Printer<'a> {
    fn new(topic: &'a str, opts: &'a EchoOptions) -> Self {
        Self {
            topic,
            opts,
            out: std::io::stdout().lock(),
            printed: 0,
        }
    }

    /// Prints `message`; true once `--count` messages are out.
    fn print(&mut self, message: Message) -> anyhow::Result<bool> {
        let record = TopicRecord {
            topic: self.topic.to_owned(),
            message,
        };
        if self.opts.json {
            serde_json::to_writer(&mut self.out, &record)?;
            writeln!(self.out)?;
        } else {
            writeln!(self.out, "{}", summary(&record))?;
        }
        self.printed += 1;
        let done = self.opts.count.is_some_and(|c| self.printed >= c);
        if done {
            self.flush()?;
        }
        Ok(done)
    }

    fn flush(&mut self) -> anyhow::Result<()> {
        Ok(self.out.flush()?)
    }
}

/// Runs `body` on each arrival until the count, the timeout or Ctrl-C.
fn receive_loop(
    waiter: &Waiter,
    timeout: Option<Duration>,
    mut body: impl FnMut() -> anyhow::Result<bool>,
) -> anyhow::Result<()> {
    let end = timeout.map(|t| Instant::now() + t);
    let stop = smokenav_platform_runtime::Shutdown::install()?;
    loop {
        if body()? {
            return Ok(());
        }
        if stop.requested() {
            return Ok(());
        }
        let wait = match end {
            Some(end) => {
                let left = end.saturating_duration_since(Instant::now());
                if left.is_zero() {
                    bail!("timed out after {:?}", timeout.unwrap_or_default());
                }
                left.min(Duration::from_millis(500))
            }
            None => Duration::from_millis(500),
        };
        waiter.wait(Some(wait))?;
    }
}

/// One human-readable line per message.
fn summary(r: &TopicRecord) -> String {
    let h = r.message.header();
    let head = format!("[{:>6}] t={:.3}s", h.seq, h.stamp_ns as f64 * 1e-9);
    match &r.message {
        Message::LaserScan(s) => {
            let valid: Vec<f32> = s.ranges.iter().flatten().copied().collect();
            let (mn, mx) = valid
                .iter()
                .fold((f32::INFINITY, 0f32), |(a, b), &v| (a.min(v), b.max(v)));
            format!(
                "{head} LaserScan {} beams ({} valid) {:.1}°..{:.1}° range {:.3}..{:.3} m",
                s.ranges.len(),
                valid.len(),
                s.angle_min.to_degrees(),
                (s.angle_min + s.angle_increment * s.ranges.len().saturating_sub(1) as f32)
                    .to_degrees(),
                if valid.is_empty() { 0.0 } else { mn },
                mx
            )
        }
        Message::SonarRing(s) => format!(
            "{head} SonarRing [{}]",
            s.readings
                .iter()
                .map(|r| if r.status == "valid" {
                    format!("{}:{:.2}", r.index, r.range)
                } else {
                    format!("{}:{}", r.index, &r.status[..3])
                })
                .collect::<Vec<_>>()
                .join(" ")
        ),
        Message::SimClock(_) => format!("{head} Clock (simulated time)"),
        Message::Odometry(o) => format!(
            "{head} Odometry x={:.3} y={:.3} θ={:.1}° v={:.3} ω={:.1}°/s battery={:.1}V",
            o.x,
            o.y,
            o.theta.to_degrees(),
            o.linear,
            o.angular.to_degrees(),
            o.battery_v
        ),
        Message::VelocityCommand(c) => format!(
            "{head} VelocityCommand v={:.3} ω={:.1}°/s",
            c.linear,
            c.angular.to_degrees()
        ),
        Message::SmokeReading(s) => format!(
            "{head} Smoke level={:.1} raw={:.0}mV baseline={:.0}mV {} {}",
            s.level, s.raw_mv, s.baseline_mv, s.trend, s.state
        ),
        Message::FusedScan(f) => format!(
            "{head} FusedScan {} sync={} smoke={:.1} spread={:.3}m sonar usage {:.0}% [{}]",
            f.method,
            f.sync_state,
            f.smoke_level,
            f.laser_spread,
            f.sonar_usage * 100.0,
            f.sections
                .iter()
                .map(|s| &s.source[..1])
                .collect::<Vec<_>>()
                .join("")
        ),
        Message::PoseEstimate(p) => format!(
            "{head} Pose x={:.3} y={:.3} θ={:.1}° n_eff={:.1}/{} skipped={} {}µs",
            p.x,
            p.y,
            p.theta.to_degrees(),
            p.n_eff,
            p.particles,
            p.scans_skipped,
            p.processing_us
        ),
        Message::VoxelCloud(v) => {
            let n = v.xyz.len() / 3;
            let (lo, hi) = v
                .xyz
                .iter()
                .skip(2)
                .step_by(3)
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &z| {
                    (a.min(z), b.max(z))
                });
            format!(
                "{head} VoxelCloud {n} voxels @ {:.3} m ({} truncated) z {:.2}..{:.2} m",
                v.resolution,
                v.truncated,
                if n == 0 { 0.0 } else { lo },
                if n == 0 { 0.0 } else { hi }
            )
        }
        Message::MapInfo(m) => format!(
            "{head} Map {}×{} @ {:.3} m origin ({:.2}, {:.2})",
            m.width, m.height, m.resolution, m.origin_x, m.origin_y
        ),
        Message::Health(h) => format!(
            "{head} Health {} pid {} {} up {:.0}s p99 {:.0}µs {}{}",
            h.role,
            h.pid,
            h.state,
            h.uptime_s,
            h.latency_p99_us,
            h.metrics
                .iter()
                .map(|m| format!("{}={:.3}", m.name, m.value))
                .collect::<Vec<_>>()
                .join(" "),
            if h.last_error.is_empty() {
                String::new()
            } else {
                format!(" last error: {}", h.last_error)
            }
        ),
    }
}

/// Rate statistics over a sliding window of arrival intervals.
struct RateStats {
    intervals: std::collections::VecDeque<f64>,
    window: usize,
    last_arrival: Option<Instant>,
    last_seq: Option<u64>,
    received: u64,
    gaps: u64,
    lost: u64,
}

impl RateStats {
    fn new(window: usize) -> Self {
        Self {
            intervals: std::collections::VecDeque::with_capacity(window),
            window,
            last_arrival: None,
            last_seq: None,
            received: 0,
            gaps: 0,
            lost: 0,
        }
    }

    fn arrive(&mut self, now: Instant, seq: u64) {
        if let Some(prev) = self.last_arrival {
            if self.intervals.len() == self.window {
                self.intervals.pop_front();
            }
            self.intervals
                .push_back(now.duration_since(prev).as_secs_f64());
        }
        if let Some(last) = self.last_seq
            && seq > last + 1
        {
            self.gaps += 1;
            self.lost += seq - last - 1;
        }
        self.last_arrival = Some(now);
        self.last_seq = Some(seq);
        self.received += 1;
    }

    /// (rate Hz, min s, max s, std dev s)
    fn stats(&self) -> Option<(f64, f64, f64, f64)> {
        if self.intervals.is_empty() {
            return None;
        }
        let n = self.intervals.len() as f64;
        let mean = self.intervals.iter().sum::<f64>() / n;
        let var = self
            .intervals
            .iter()
            .map(|d| (d - mean).powi(2))
            .sum::<f64>()
            / n;
        let min = self.intervals.iter().copied().fold(f64::INFINITY, f64::min);
        let max = self.intervals.iter().copied().fold(0.0, f64::max);
        Some((1.0 / mean, min, max, var.sqrt()))
    }
}

fn hz(
    bus: &Bus,
    topic: &str,
    duration: Option<Duration>,
    window: usize,
    json: bool,
) -> anyhow::Result<()> {
    let kind = kind_of(topic)?;
    let mut stats = RateStats::new(window);
    kind.visit(&mut Hz {
        bus,
        topic,
        duration,
        json,
        stats: &mut stats,
    })?;
    if json {
        let (rate, min, max, sd) = stats.stats().unwrap_or((0.0, 0.0, 0.0, 0.0));
        println!(
            "{}",
            serde_json::json!({
                "topic": topic,
                "received": stats.received,
                "rate_hz": rate,
                "min_interval_s": min,
                "max_interval_s": max,
                "std_dev_s": sd,
                "gaps": stats.gaps,
                "lost": stats.lost,
            })
        );
    }
    Ok(())
}

/// Measures one topic's rate, whatever catalog type it carries.
struct Hz<'a> {
    bus: &'a Bus,
    topic: &'a str,
    duration: Option<Duration>,
    json: bool,
    stats: &'a mut RateStats,
}

impl MessageVisitor for Hz<'_> {
    type Output = anyhow::Result<()>;

    fn fixed<M: Cataloged>(&mut self) -> Self::Output {
        let topic = topics::lookup::<M>(self.topic)
            .with_context(|| format!("topic `{}` does not carry {}", self.topic, M::NAME))?;
        let start = Instant::now();
        let mut last_print = start;
        let sub = self.bus.subscriber(topic)?;
        let waiter = Waiter::new()?;
        let _g = waiter.attach(&sub)?;
        let stop = smokenav_platform_runtime::Shutdown::install()?;
        // Rates are measured on receive time, never on stamps (a replay
        // keeps its recorded ones). The topic's history arrives in the first
        // batch together with the newest message: only that newest one
        // anchors the intervals, or the history would fake near-zero ones.
        let mut anchored = false;
        loop {
            let mut first_batch: Option<u64> = None;
            while let Some(s) = sub.receive()? {
                let seq = s.payload().header().seq;
                if anchored {
                    self.stats.arrive(Instant::now(), seq);
                } else {
                    first_batch = Some(first_batch.map_or(seq, |m: u64| m.max(seq)));
                }
            }
            if let Some(seq) = first_batch {
                anchored = true;
                self.stats.arrive(Instant::now(), seq);
            }
            let now = Instant::now();
            if !self.json && now.duration_since(last_print) >= Duration::from_secs(1) {
                last_print = now;
                match self.stats.stats() {
                    Some((rate, min, max, sd)) => println!(
                        "average rate: {rate:.3} Hz\n  min: {min:.4}s max: {max:.4}s std dev: {sd:.5}s window: {}  gaps: {} ({} lost)",
                        self.stats.intervals.len() + 1,
                        self.stats.gaps,
                        self.stats.lost
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

    fn map(&mut self) -> Self::Output {
        bail!("hz does not support {} topics", MessageKind::Map.name())
    }
}
