//! `smokenav topic list|echo|hz`: how a user sees what flows on the bus.

use anyhow::{Context, bail};
use clap::{Args, Subcommand};
use smokenav_platform_bus::{
    Bus, BusOptions, MapSubscriber, Message as BusMessage, Subscriber, Waiter, topics,
};
use smokenav_platform_config::{INSTANCE_ENV, IOX2_ROOT_ENV, RobotConfig};
use smokenav_shared_types::record::{Message, TopicRecord};
use smokenav_shared_types::{
    FusedScan, Health, LaserScan, Odometry, PoseEstimate, SmokeReading, SonarRing, VelocityCommand,
};
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
        /// e.g. laser/scan, base/odom, health/hokuyo.
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
    /// Measure a topic's rate, jitter and sequence gaps.
    Hz {
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

fn echo(bus: &Bus, topic: &str, opts: &EchoOptions) -> anyhow::Result<()> {
    let Some(ty) = topics::type_of(topic) else {
        bail!("unknown topic `{topic}` (known: {})", known_topics());
    };
    match ty {
        "LaserScan" => echo_typed::<LaserScan>(bus, topic, opts, |m| Message::LaserScan(m.into())),
        "Odometry" => echo_typed::<Odometry>(bus, topic, opts, |m| Message::Odometry(m.into())),
        "SonarRing" => echo_typed::<SonarRing>(bus, topic, opts, |m| Message::SonarRing(m.into())),
        "VelocityCommand" => {
            echo_typed::<VelocityCommand>(bus, topic, opts, |m| Message::VelocityCommand(m.into()))
        }
        "SmokeReading" => {
            echo_typed::<SmokeReading>(bus, topic, opts, |m| Message::SmokeReading(m.into()))
        }
        "FusedScan" => echo_typed::<FusedScan>(bus, topic, opts, |m| Message::FusedScan(m.into())),
        "PoseEstimate" => {
            echo_typed::<PoseEstimate>(bus, topic, opts, |m| Message::PoseEstimate(m.into()))
        }
        "Health" => echo_typed::<Health>(bus, topic, opts, |m| Message::Health(m.into())),
        "MapInfo" => echo_map(bus, topic, opts),
        other => bail!("topic `{topic}` carries {other}, which echo cannot print"),
    }
}

fn known_topics() -> String {
    let mut v: Vec<&str> = topics::FIXED_TOPICS.iter().map(|(t, _)| *t).collect();
    v.push("health/<role>");
    v.join(", ")
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

fn echo_typed<T: BusMessage>(
    bus: &Bus,
    topic: &str,
    opts: &EchoOptions,
    to_record: impl Fn(&T) -> Message,
) -> anyhow::Result<()> {
    let sub: Subscriber<T> = bus.subscriber(topic)?;
    let waiter = Waiter::new()?;
    let _g = waiter.attach(&sub)?;
    let mut printed = 0u64;
    let mut out = std::io::stdout().lock();
    receive_loop(&waiter, opts.timeout, || {
        while let Some(s) = sub.receive()? {
            let record = TopicRecord {
                topic: topic.to_owned(),
                message: to_record(&s),
            };
            if opts.json {
                serde_json::to_writer(&mut out, &record)?;
                writeln!(out)?;
            } else {
                writeln!(out, "{}", summary(&record))?;
            }
            printed += 1;
            if opts.count.is_some_and(|c| printed >= c) {
                out.flush()?;
                return Ok(true);
            }
        }
        out.flush()?;
        Ok(false)
    })
}

fn echo_map(bus: &Bus, topic: &str, opts: &EchoOptions) -> anyhow::Result<()> {
    let sub = MapSubscriber::create(bus, topic)?;
    let waiter = Waiter::new()?;
    let _g = waiter.attach(&sub)?;
    let mut printed = 0u64;
    let mut out = std::io::stdout().lock();
    receive_loop(&waiter, opts.timeout, || {
        while let Some(s) = sub.receive()? {
            let mut rec = smokenav_shared_types::record::MapInfoRecord::from(s.user_header());
            if opts.with_data {
                rec.data = Some(s.payload().to_vec());
            }
            let record = TopicRecord {
                topic: topic.to_owned(),
                message: Message::MapInfo(rec),
            };
            if opts.json {
                serde_json::to_writer(&mut out, &record)?;
                writeln!(out)?;
            } else {
                writeln!(out, "{}", summary(&record))?;
            }
            printed += 1;
            if opts.count.is_some_and(|c| printed >= c) {
                return Ok(true);
            }
        }
        out.flush()?;
        Ok(false)
    })
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
    let Some(ty) = topics::type_of(topic) else {
        bail!("unknown topic `{topic}` (known: {})", known_topics());
    };
    let mut stats = RateStats::new(window);
    let start = Instant::now();
    let mut last_print = start;
    macro_rules! run_typed {
        ($t:ty) => {{
            let subscribed_ns = smokenav_shared_types::clock::monotonic_now_ns();
            let sub: Subscriber<$t> = bus.subscriber(topic)?;
            let waiter = Waiter::new()?;
            let _g = waiter.attach(&sub)?;
            let stop = smokenav_platform_runtime::Shutdown::install()?;
            loop {
                while let Some(s) = sub.receive()? {
                    let header = BusMessage::header(s.payload());
                    // The topic's history sample was published before we
                    // subscribed; counting it would fake a near-zero interval.
                    if header.stamp_ns != 0 && header.stamp_ns < subscribed_ns {
                        continue;
                    }
                    stats.arrive(Instant::now(), header.seq);
                }
                let now = Instant::now();
                if !json && now.duration_since(last_print) >= Duration::from_secs(1) {
                    last_print = now;
                    match stats.stats() {
                        Some((rate, min, max, sd)) => println!(
                            "average rate: {rate:.3} Hz\n  min: {min:.4}s max: {max:.4}s std dev: {sd:.5}s window: {}  gaps: {} ({} lost)",
                            stats.intervals.len() + 1,
                            stats.gaps,
                            stats.lost
                        ),
                        None => println!("no new messages"),
                    }
                }
                if stop.requested() || duration.is_some_and(|d| now.duration_since(start) >= d) {
                    break;
                }
                waiter.wait(Some(Duration::from_millis(200)))?;
            }
        }};
    }
    match ty {
        "LaserScan" => run_typed!(LaserScan),
        "Odometry" => run_typed!(Odometry),
        "SonarRing" => run_typed!(SonarRing),
        "VelocityCommand" => run_typed!(VelocityCommand),
        "SmokeReading" => run_typed!(SmokeReading),
        "FusedScan" => run_typed!(FusedScan),
        "PoseEstimate" => run_typed!(PoseEstimate),
        "Health" => run_typed!(Health),
        other => bail!("hz does not support {other} topics"),
    }
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
