//! `smokenav topic pub TOPIC JSON`: publish a message typed on the command
//! line, in the JSON form `topic echo --json` prints (fields left out keep
//! their defaults; the stamp is always now).
//!
//! A motion command is guarded as `smokenav drive` is: `base/cmd_vel` is
//! refused without `--motion`, needs `--for SECONDS` (at most an hour), and
//! ends — on time, on Ctrl-C or on SIGTERM — with stop commands, so the
//! base stops at once instead of waiting for its command timeout.

use crate::topic::{BusArgs, bus_topic};
use anyhow::{Context, bail};
use clap::Args;
use smokenav_platform_bus::{Bus, topics};
use smokenav_shared_types::catalog::{self, Cataloged, MessageVisitor};
use smokenav_shared_types::clock::monotonic_now_ns;
use std::time::{Duration, Instant};

#[derive(Debug, Args)]
pub struct PubArgs {
    /// e.g. smoke/level (or /smoke/level).
    #[arg(value_parser = bus_topic)]
    topic: String,
    /// The message as JSON, e.g. '{"linear": 0.2, "angular": 0.0}' (the
    /// fields of `topic echo --json`; the ones left out keep their defaults).
    json: String,
    /// Publish this often, Hz (default: once, or 10 Hz for a motion command).
    #[arg(long)]
    rate: Option<f64>,
    /// Publish for this long, s (a motion command must give it).
    #[arg(long = "for", value_name = "SECONDS")]
    duration: Option<f64>,
    /// Publish this many messages (default 1 without --for).
    #[arg(long)]
    times: Option<u64>,
    /// Keep the publisher this long after the last message, s: samples of a
    /// publisher that is gone can no longer be taken by a slow subscriber.
    #[arg(long, value_name = "SECONDS", default_value_t = 0.5)]
    linger: f64,
    /// Allow a motion command (`base/cmd_vel`): the robot moves.
    #[arg(long)]
    motion: bool,
    #[command(flatten)]
    bus: BusArgs,
}

/// Stop commands at the end of a motion command, as `drive` sends.
const STOP_REPEATS: u32 = 3;

/// Overwrites `base`'s fields with `patch`'s, object by object.
fn merge(base: &mut serde_json::Value, patch: serde_json::Value) {
    match (base, patch) {
        (serde_json::Value::Object(b), serde_json::Value::Object(p)) => {
            for (k, v) in p {
                match b.get_mut(&k) {
                    Some(slot) => merge(slot, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (slot, v) => *slot = v,
    }
}

/// The message `json` describes, over the type's defaults.
pub fn message_from_json<M: Cataloged + Default>(json: &str) -> anyhow::Result<M> {
    let patch: serde_json::Value =
        serde_json::from_str(json).context("the message is not valid JSON")?;
    anyhow::ensure!(
        patch.is_object(),
        "the message must be a JSON object of {} fields",
        M::NAME
    );
    let mut value = serde_json::to_value(M::default().to_record())?;
    merge(&mut value, patch);
    let record: M::Record = serde_path_to_error::deserialize(value)
        .map_err(|e| anyhow::anyhow!("key {}: {}", e.path(), e.inner()))
        .with_context(|| format!("not a {} message", M::NAME))?;
    let mut out = M::default();
    M::write_record(&record, &mut out).with_context(|| format!("not a {} message", M::NAME))?;
    Ok(out)
}

struct Publish<'a> {
    bus: &'a Bus,
    args: &'a PubArgs,
}

impl MessageVisitor for Publish<'_> {
    type Output = anyhow::Result<()>;

    fn fixed<M: Cataloged>(&mut self) -> Self::Output {
        let a = self.args;
        let topic = topics::lookup::<M>(&a.topic)
            .with_context(|| format!("topic `{}` does not carry {}", a.topic, M::NAME))?;
        let motion = a.topic == topics::BASE_CMD_VEL.name();
        if motion && !a.motion {
            bail!(
                "{} moves the robot: pass --motion (and --for SECONDS) to publish it, or use `smokenav drive`",
                a.topic
            );
        }
        let msg: M = message_from_json(&a.json)?;
        if motion {
            anyhow::ensure!(
                a.duration
                    .is_some_and(|d| d.is_finite() && (0.0..=3600.0).contains(&d)),
                "a motion command needs --for SECONDS (0–3600): it stops when that ends"
            );
            anyhow::ensure!(
                a.times.is_none(),
                "a motion command is bounded by --for, not --times"
            );
        }
        let rate = a.rate.unwrap_or(if motion { 10.0 } else { 1.0 });
        anyhow::ensure!(
            rate.is_finite() && (0.01..=1000.0).contains(&rate),
            "--rate must be 0.01–1000 Hz, got {rate}"
        );
        if let Some(d) = a.duration {
            anyhow::ensure!(
                d.is_finite() && d >= 0.0,
                "--for must be a non-negative number of seconds"
            );
        }
        let times = match (a.times, a.duration) {
            (Some(n), _) => n,
            (None, Some(_)) => u64::MAX,
            (None, None) => 1,
        };
        let end = a
            .duration
            .map(|d| Instant::now() + Duration::from_secs_f64(d));
        let header = {
            let mut m = msg;
            *m.header_mut()
        };
        let stop = smokenav_platform_runtime::Shutdown::install()?;
        let mut publisher = self.bus.publisher(topic)?;
        let period = Duration::from_secs_f64(1.0 / rate);
        let mut next = Instant::now();
        let mut sent = 0u64;
        while sent < times && !stop.requested() && end.is_none_or(|e| Instant::now() < e) {
            publisher.publish_with(|out| {
                *out = msg;
                out.header_mut().stamp_ns = monotonic_now_ns();
            })?;
            sent += 1;
            if sent == times {
                break;
            }
            next += period;
            let until = end.map_or(next, |e| next.min(e));
            while !stop.requested() {
                let Some(left) = until.checked_duration_since(Instant::now()) else {
                    break;
                };
                std::thread::sleep(left.min(Duration::from_millis(100)));
            }
        }
        if motion {
            for i in 0..STOP_REPEATS {
                publisher.publish_with(|out| {
                    *out = M::default();
                    *out.header_mut() = header;
                    out.header_mut().stamp_ns = monotonic_now_ns();
                })?;
                if i + 1 < STOP_REPEATS {
                    std::thread::sleep(Duration::from_millis(100));
                }
            }
        }
        if a.linger.is_finite() && a.linger > 0.0 && !stop.requested() {
            std::thread::sleep(Duration::from_secs_f64(a.linger.min(10.0)));
        }
        eprintln!(
            "published {sent} {} on {}{}",
            M::NAME,
            a.topic,
            if motion { ", then stop" } else { "" }
        );
        Ok(())
    }

    fn map(&mut self) -> Self::Output {
        bail!("topic pub does not publish maps")
    }
}

pub fn run(args: PubArgs) -> anyhow::Result<()> {
    let kind = catalog::topic_kind(&args.topic).with_context(|| {
        format!(
            "unknown topic `{}` (smokenav topic list shows them)",
            args.topic
        )
    })?;
    let bus = args.bus.open("topic-pub")?;
    kind.visit(&mut Publish {
        bus: &bus,
        args: &args,
    })
}
