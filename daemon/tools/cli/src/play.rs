//! `smokenav play run.mcap [TOPICS…] [--rate X | --fast]`: republish a recording.
//!
//! Messages go out in recorded order, at the recorded pace scaled by
//! `--rate` (receive times of the recorder, so jitter is replayed too), or
//! back to back with `--fast`. The bus never blocks a publisher: with
//! `--fast`, a subscriber slower than the player drops messages and sees the
//! gaps in its sequence numbers; use `--rate` for faithful re-runs.
//!
//! A replay must never move a robot or masquerade as its live sensors:
//! velocity commands are left out unless `--commands` asks for them, and
//! before publishing anything `play` looks for live processes publishing the
//! topics it would replay and refuses, naming them, unless `--force`. Play
//! onto a separate instance (`--instance replay`) to run beside a robot.

use crate::topic::BusArgs;
use anyhow::{Context, bail};
use clap::Args;
use smokenav_platform_bus::{Bus, MapPublisher, Publisher, topics};
use smokenav_platform_recording::bag::{Bag, BagMessages};
use smokenav_platform_recording::{AnyMessage, EndOfData, Playback, Played};
use smokenav_shared_types::catalog::{self, Cataloged, MessageVisitor};
use smokenav_shared_types::clock::monotonic_now_ns;
use std::collections::{BTreeMap, HashMap};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::{Duration, Instant};

#[derive(Debug, Args)]
pub struct PlayArgs {
    /// The recording (an MCAP file written by `smokenav record`; a file cut
    /// short is fine), or a ROS 2 bag (a rosbag2 folder, .mcap or .db3), whose
    /// LaserScan and Odometry topics are played as laser/scan and base/odom,
    /// and its sonar (Range or PointCloud2, mapped onto --config's [sonar]) as base/sonar.
    pub file: PathBuf,
    #[command(flatten)]
    pub roles: crate::bag::RoleArgs,
    /// Only these bus topics, as laser/scan or /laser/scan (default: every recorded one).
    #[arg(value_parser = crate::topic::bus_topic)]
    pub topics: Vec<String>,
    /// Speed factor on the recorded timing (2 = twice as fast).
    #[arg(long, default_value_t = 1.0)]
    pub rate: f64,
    /// Publish as fast as possible, ignoring the recorded timing.
    #[arg(long, conflicts_with = "rate")]
    pub fast: bool,
    /// Shift every stamp so the first message looks measured now (processes
    /// that drop stale data, like the fusion synchroniser, accept the replay).
    /// Without it, messages are republished bit for bit.
    #[arg(long)]
    pub restamp: bool,
    /// Do not publish the replay's time on `clock` (ROS 2 `/clock`, sim time).
    #[arg(long)]
    pub no_clock: bool,
    /// Seconds to wait after a topic's publisher appears, before its first
    /// message, so subscribers that start with the replay connect.
    #[arg(long, default_value_t = 0.0)]
    pub connect_delay: f64,
    /// Also replay velocity commands (`base/cmd_vel`): they drive a robot
    /// whose driver is listening.
    #[arg(long)]
    pub commands: bool,
    /// Publish even where live processes already publish the same topics.
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub bus: BusArgs,
}

/// Whether `topic` commands the robot: never replayed unless asked for.
fn is_command(topic: &str) -> bool {
    topic == topics::BASE_CMD_VEL.name()
}

/// Lists the live publishers of one topic, whatever catalog type it carries.
struct LivePublishers<'a> {
    bus: &'a Bus,
    topic: &'a str,
}

impl MessageVisitor for LivePublishers<'_> {
    type Output = anyhow::Result<Vec<String>>;

    fn fixed<M: Cataloged>(&mut self) -> Self::Output {
        match topics::lookup::<M>(self.topic) {
            Some(t) => Ok(self.bus.live_publishers(t)?),
            None => Ok(Vec::new()),
        }
    }

    fn map(&mut self) -> Self::Output {
        match topics::lookup_map(self.topic) {
            Some(t) => Ok(self.bus.live_map_publishers(t)?),
            None => Ok(Vec::new()),
        }
    }
}

/// The topics `play` may publish and, for each with live publishers on the
/// bus, who they are.
fn live_conflicts(bus: &Bus, playable: &[String]) -> anyhow::Result<Vec<(String, Vec<String>)>> {
    let mut out = Vec::new();
    for topic in playable {
        let Some(kind) = catalog::topic_kind(topic) else {
            continue;
        };
        let who = kind
            .visit(&mut LivePublishers { bus, topic })
            .with_context(|| format!("cannot look for publishers of {topic}"))?;
        if !who.is_empty() {
            out.push((topic.clone(), who));
        }
    }
    Ok(out)
}

/// A publisher of one recorded topic, whatever its type.
trait Replay {
    /// Connects to subscribers that appeared since the last send.
    fn update_connections(&self) -> anyhow::Result<()>;
    /// Publishes `m`; returns the sequence number the bus gave it.
    fn publish(&mut self, m: &AnyMessage) -> anyhow::Result<u64>;
}

impl<T: Cataloged> Replay for Publisher<T> {
    fn update_connections(&self) -> anyhow::Result<()> {
        Ok(Publisher::update_connections(self)?)
    }

    fn publish(&mut self, m: &AnyMessage) -> anyhow::Result<u64> {
        let Some(msg) = T::from_any(m) else {
            bail!("the recording changes a topic's message type mid-file");
        };
        // Copied straight into shared memory (no temporary of a 10 kB scan).
        Ok(self.publish_with(|out| *out = *msg)?)
    }
}

impl Replay for MapPublisher {
    fn update_connections(&self) -> anyhow::Result<()> {
        // The map publisher connects on every send.
        Ok(())
    }

    fn publish(&mut self, m: &AnyMessage) -> anyhow::Result<u64> {
        let AnyMessage::Map(info, cells) = m else {
            bail!("the recording changes a topic's message type mid-file");
        };
        Ok(MapPublisher::publish(self, info, cells)?)
    }
}

/// Opens the publisher of a recorded topic for the type of its first message.
struct OpenReplay<'a> {
    bus: &'a Bus,
    topic: &'a str,
}

impl MessageVisitor for OpenReplay<'_> {
    type Output = anyhow::Result<Box<dyn Replay>>;

    fn fixed<M: Cataloged>(&mut self) -> Self::Output {
        let topic = topics::lookup::<M>(self.topic).with_context(|| {
            format!(
                "the recording has {} on `{}`, which carries another type",
                M::NAME,
                self.topic
            )
        })?;
        Ok(Box::new(self.bus.publisher(topic)?))
    }

    fn map(&mut self) -> Self::Output {
        let topic = topics::lookup_map(self.topic).with_context(|| {
            format!(
                "the recording has a map on `{}`, which carries another type",
                self.topic
            )
        })?;
        Ok(Box::new(self.bus.map_publisher(topic)?))
    }
}

#[derive(Default)]
struct TopicReport {
    published: u64,
    /// Messages whose recorded `header.seq` differs from the one the bus gave
    /// them (the recording started mid-stream, had gaps, or mixed publishers).
    renumbered: u64,
}

/// Sleeps until `deadline`, in slices, so SIGINT is noticed within 100 ms.
fn sleep_until(deadline: Instant, stop: &smokenav_platform_runtime::Shutdown) {
    loop {
        let now = Instant::now();
        if now >= deadline || stop.requested() {
            return;
        }
        std::thread::sleep((deadline - now).min(Duration::from_millis(100)));
    }
}

/// What `play` reads: a smokenav recording (every topic, bit for bit) or a
/// team's own bag (its standard topics, by role).
enum Source {
    Native(Box<Playback<std::io::BufReader<std::fs::File>>>),
    Bag(Box<BagMessages>),
}

impl Source {
    fn open(args: &PlayArgs) -> anyhow::Result<Self> {
        let cannot = || format!("cannot open {}", args.file.display());
        let bag = Bag::open(&args.file).with_context(cannot)?;
        if bag.is_smokenav() && !args.roles.given() {
            return Ok(Self::Native(Box::new(
                Playback::open(&args.file).with_context(cannot)?,
            )));
        }
        let roles = bag.roles(&args.roles.request())?;
        if roles.laser.is_none() && roles.odom.is_none() && roles.sonar.is_empty() {
            bail!(
                "{}: no sensor_msgs/msg/LaserScan or nav_msgs/msg/Odometry topic to play (nor a sonar); topics: {}",
                args.file.display(),
                bag.topics()
                    .iter()
                    .map(|t| format!("{} ({})", t.name, t.type_name))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        for (role, bus) in [
            (&roles.laser, topics::LASER_SCAN.name()),
            (&roles.odom, topics::BASE_ODOM.name()),
        ] {
            if let Some(t) = role {
                tracing::info!("{}: {t} → {bus}", args.file.display());
            }
        }
        if let Some(what) = crate::bag::sonar_summary(&roles) {
            tracing::info!(
                "{}: {what} → {}",
                args.file.display(),
                topics::BASE_SONAR.name()
            );
        }
        // The sonar is mapped onto the transducers of the robot profile (--config).
        let cfg = match &args.bus.config {
            Some(path) => smokenav_platform_config::RobotConfig::load(path)
                .with_context(|| format!("invalid robot profile {}", path.display()))?,
            None => smokenav_platform_config::RobotConfig::builtin("pioneer-3dx")
                .context("the built-in profile is invalid")?,
        };
        Ok(Self::Bag(Box::new(
            bag.messages_with_sonar(&roles, &cfg.sonar)?,
        )))
    }

    fn read_next(&mut self) -> anyhow::Result<Option<Played>> {
        Ok(match self {
            Self::Native(p) => p.read_next()?,
            Self::Bag(b) => b.read_next()?,
        })
    }

    /// What was added to the stamps' clock to make the log times (a bag's are on it already).
    fn unix_offset(&self) -> i64 {
        match self {
            Self::Native(p) => smokenav_platform_recording::unix_offset(p.source().metadata()),
            Self::Bag(_) => 0,
        }
    }

    fn position(&self) -> u64 {
        match self {
            Self::Native(p) => p.source().bytes_read(),
            Self::Bag(_) => 0,
        }
    }

    fn end(&self) -> Option<&EndOfData> {
        match self {
            Self::Native(p) => p.source().end(),
            Self::Bag(b) => b.end(),
        }
    }
}

pub fn run(args: PlayArgs) -> anyhow::Result<()> {
    smokenav_platform_runtime::init_logging("play");
    if !args.fast && (args.rate <= 0.0 || !args.rate.is_finite()) {
        bail!("--rate must be a positive number");
    }
    let size = std::fs::metadata(&args.file)
        .with_context(|| format!("cannot open {}", args.file.display()))?
        .len();
    let mut source = Source::open(&args)?;
    let bus = args.bus.open("play")?;
    let wanted = |topic: &str| {
        (args.topics.is_empty() || args.topics.iter().any(|t| t == topic))
            && (args.commands || !is_command(topic))
    };
    // Every topic the recording could hold: checked before the first message,
    // so a refusal publishes nothing at all.
    let playable: Vec<String> = if args.topics.is_empty() {
        smokenav_platform_bus::tap::default_topics()
    } else {
        args.topics.clone()
    };
    let playable: Vec<String> = playable.into_iter().filter(|t| wanted(t)).collect();
    let mut playable = playable;
    if !args.no_clock {
        playable.push(topics::CLOCK.name().to_owned());
    }
    let conflicts = live_conflicts(&bus, &playable)?;
    if !conflicts.is_empty() {
        let list = conflicts
            .iter()
            .map(|(t, who)| format!("  {t} <- {}", who.join(", ")))
            .collect::<Vec<_>>()
            .join("\n");
        if args.force {
            tracing::warn!(
                "--force: publishing beside live publishers on instance `{}`:\n{list}",
                bus.instance()
            );
        } else {
            bail!(
                "refusing to play onto instance `{}`: live processes publish the same topics\n{list}\n\
                 stop them, play onto another instance (--instance replay), or pass --force",
                bus.instance()
            );
        }
    }
    let stop = smokenav_platform_runtime::Shutdown::install()?;

    let bar = if std::io::stderr().is_terminal() {
        indicatif::ProgressBar::new(size)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:40} {percent:>3}% {msg} [{elapsed_precise} < {eta_precise}]",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );

    let mut publishers: HashMap<String, Box<dyn Replay>> = HashMap::new();
    let mut report: BTreeMap<String, TopicReport> = BTreeMap::new();
    let mut clock: Option<(u64, Instant)> = None;
    // Restamping: (first receive time on the stamps' clock, bus time it maps to).
    let mut restamp_base: Option<(u64, u64)> = None;
    // Read with the first message: the file's metadata precedes it.
    let mut unix_offset: Option<i64> = None;
    let mut clock_pub = if args.no_clock {
        None
    } else {
        Some(bus.publisher(topics::CLOCK)?)
    };
    let mut last_clock: Option<u64> = None;
    let mut clocks = 0u64;
    let started = Instant::now();
    let mut published = 0u64;
    let mut commands_skipped = 0u64;
    while !stop.requested() {
        let Some(mut played) = source
            .read_next()
            .with_context(|| format!("reading {} failed", args.file.display()))?
        else {
            break;
        };
        if !wanted(&played.topic) {
            commands_skipped += u64::from(is_command(&played.topic));
            continue;
        }
        if !args.fast {
            let (t0, w0) = *clock.get_or_insert((played.log_time, Instant::now()));
            let offset = played.log_time.saturating_sub(t0) as f64 / args.rate;
            sleep_until(w0 + Duration::from_secs_f64(offset * 1e-9), &stop);
            if stop.requested() {
                break;
            }
        }
        // When the recorder received it, on the clock of the stamps.
        let unix_offset = *unix_offset.get_or_insert_with(|| source.unix_offset());
        let received =
            smokenav_platform_recording::shift_ns(played.log_time, unix_offset.saturating_neg());
        let mut data_time = received;
        if args.restamp {
            // Recorder receive time → the bus clock, at the replay's pace, so
            // at any --rate a stamp keeps its lag behind its message's
            // arrival (a constant shift would run ahead by the time saved).
            let (r0, m0) = *restamp_base.get_or_insert_with(|| (received, monotonic_now_ns()));
            let elapsed = received.saturating_sub(r0) as f64;
            let scaled = if args.fast {
                elapsed
            } else {
                elapsed / args.rate
            };
            let target = i128::from(m0) + scaled as i128;
            let offset = (target - i128::from(received))
                .clamp(i128::from(i64::MIN), i128::from(i64::MAX)) as i64;
            played.message.shift_stamps(offset);
            data_time = smokenav_platform_recording::shift_ns(received, offset);
        }
        // Sim time at most every 10 ms of data, just before the data it dates.
        if let Some(c) = &mut clock_pub
            && last_clock.is_none_or(|t| data_time >= t + 10_000_000)
        {
            c.publish_with(|m| m.header.stamp_ns = data_time)?;
            last_clock = Some(data_time);
            clocks += 1;
        }
        if !publishers.contains_key(&played.topic) {
            let p = played
                .message
                .kind()
                .visit(&mut OpenReplay {
                    bus: &bus,
                    topic: &played.topic,
                })
                .with_context(|| format!("cannot publish on {}", played.topic))?;
            p.update_connections()?;
            if args.connect_delay > 0.0 {
                std::thread::sleep(Duration::from_secs_f64(args.connect_delay));
                p.update_connections()?;
                // Keep the recorded pace after the pause.
                if let Some((_, w0)) = &mut clock {
                    *w0 += Duration::from_secs_f64(args.connect_delay);
                }
            }
            publishers.insert(played.topic.clone(), p);
        }
        let Some(p) = publishers.get_mut(&played.topic) else {
            continue;
        };
        let seq = p.publish(&played.message)?;
        let r = report.entry(played.topic.clone()).or_default();
        r.published += 1;
        r.renumbered += u64::from(seq != played.message.header().seq);
        published += 1;
        if published.is_multiple_of(64) {
            bar.set_position(source.position());
            bar.set_message(format!("{published} messages"));
        }
    }
    bar.finish_and_clear();

    println!(
        "played {published} messages in {:.1} s from {}{}",
        started.elapsed().as_secs_f64(),
        args.file.display(),
        match source.end() {
            Some(EndOfData::Truncated) => " (the file was cut short; played every complete chunk)",
            None => " (interrupted)",
            Some(EndOfData::Complete) => "",
        }
    );
    for (topic, r) in &report {
        println!(
            "  {topic:<16} published {:>8}{}",
            r.published,
            if r.renumbered > 0 {
                format!("  ({} with a new sequence number)", r.renumbered)
            } else {
                String::new()
            }
        );
    }
    if clocks > 0 {
        println!(
            "  {:<16} published {clocks:>8}  (simulated time)",
            topics::CLOCK.name()
        );
    }
    if commands_skipped > 0 {
        println!(
            "  left out {commands_skipped} velocity commands (base/cmd_vel); --commands replays them"
        );
    }
    let Source::Native(playback) = &source else {
        anyhow::ensure!(
            published > 0 || stop.requested(),
            "{}: nothing to play",
            args.file.display()
        );
        return Ok(());
    };
    let stats = playback.stats().clone();
    println!(
        "skipped: {} views (/tf, sonar points), {} foreign, {} orphaned, {} undecodable",
        stats.views, stats.foreign, stats.orphans, stats.decode_errors
    );
    if let Some(e) = &stats.last_error {
        println!("last decode error: {e}");
    }
    if stats.decode_errors > 0 {
        bail!("{} messages could not be decoded", stats.decode_errors);
    }
    if published == 0 && !stop.requested() && stats.foreign > 0 {
        bail!(
            "{}: none of its {} messages is a smokenav message",
            args.file.display(),
            stats.foreign
        );
    }
    Ok(())
}
