//! `smokenav-zenoh`: the robot's topics on Zenoh, as rmw_zenoh publishes
//! them (`<domain>/<namespace>/<topic>/<dds type>/<type hash>`, CDR, with
//! its liveliness tokens and attachments), so `ros2 topic echo` on a machine
//! running rmw_zenoh sees them, and `smokenav status --zenoh` shows several
//! robots at once. With `[zenoh] cmd_vel = true` it also takes
//! `<namespace>/cmd_vel` (geometry_msgs/Twist) onto `base/cmd_vel`, and with
//! `[zenoh] initial_pose = true` `<namespace>/initialpose`
//! (geometry_msgs/PoseWithCovarianceStamped, RViz's 2D Pose Estimate) onto
//! `slam/initial_pose`.
//! Health on `health/zenoh`.
//!
//! ```text
//! smokenav-zenoh --config robot.toml
//! ```

use anyhow::Context;
use clap::Parser;
use smokenav_nodes_zenoh::bridge::{self, unix_now_ns};
use smokenav_nodes_zenoh::{Bridge, command, keys, rihs};
use smokenav_platform_bus::tap::{self, Tap};
use smokenav_platform_bus::{
    Attachment, Bus, BusOptions, Message, Publisher, Topic, WaitOutcome, Waiter, topics,
};
use smokenav_platform_config::RobotConfig;
use smokenav_platform_recording::RobotGeometry;
use smokenav_platform_recording::{initial_pose, schema};
use smokenav_platform_runtime::{CommonArgs, Process, Shutdown};
use smokenav_shared_types::clock::monotonic_now_ns;
use smokenav_shared_types::{Header, VelocityCommand};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use zenoh::Wait;
use zenoh::handlers::{RingChannel, RingChannelHandler};

/// Its role: node name and health topic.
const ROLE: &str = "zenoh";

#[derive(Parser)]
#[command(
    version,
    about = "smokenav's topics on Zenoh, as rmw_zenoh carries them"
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    smokenav_platform_runtime::main(ROLE, &args.common, run)
}

#[derive(Default)]
struct PoseCounters {
    forwarded: AtomicU64,
    refused: AtomicU64,
}

#[derive(Default)]
struct CmdCounters {
    forwarded: AtomicU64,
    stale: AtomicU64,
    invalid: AtomicU64,
}

fn run(p: &mut Process) -> anyhow::Result<()> {
    let zc = p.config.zenoh.clone();
    let mut topics = if zc.topics.is_empty() {
        tap::default_topics()
    } else {
        zc.topics.clone()
    };
    let own = format!("{}{ROLE}", topics::HEALTH_PREFIX);
    if !topics.contains(&own) {
        topics.push(own);
    }
    let mut bridge = Bridge::open(&zc, Some(RobotGeometry::from_config(&p.config)))?;
    let taps: Vec<Box<dyn Tap>> = topics
        .iter()
        .map(|t| tap::open(&p.bus, t))
        .collect::<Result<_, _>>()?;
    bridge.static_transforms(monotonic_now_ns())?;

    let counters = Arc::new(CmdCounters::default());
    let _commands = if zc.cmd_vel {
        Some(spawn_commands(
            &p.config,
            &bridge,
            p.shutdown(),
            counters.clone(),
        )?)
    } else {
        None
    };
    let poses = Arc::new(PoseCounters::default());
    let _poses = if zc.initial_pose {
        Some(spawn_initial_poses(
            &p.config,
            &bridge,
            p.shutdown(),
            poses.clone(),
        )?)
    } else {
        None
    };

    let waiter = Waiter::new()?;
    let _attached: Vec<Attachment> = taps
        .iter()
        .map(|t| t.attach(&waiter))
        .collect::<Result<_, _>>()
        .context("cannot wait on the bus")?;
    let rate = p.health.add_rate("messages_hz", None);
    p.ready(&format!(
        "on Zenoh as {} (domain {}, namespace `{}`), {} topics{}",
        bridge.zid(),
        zc.domain_id,
        zc.namespace,
        taps.len(),
        match (zc.cmd_vel, zc.initial_pose) {
            (true, true) => ", cmd_vel and initialpose in",
            (true, false) => ", cmd_vel in",
            (false, true) => ", initialpose in",
            (false, false) => "",
        }
    ));
    while !p.shutdown_requested() {
        if waiter.wait(Some(Duration::from_millis(200)))? == WaitOutcome::Shutdown {
            break;
        }
        for t in &taps {
            t.drain(&mut |topic, msg| {
                bridge.push(topic, msg, monotonic_now_ns())?;
                p.health.mark(rate);
                Ok(())
            })?;
        }
        let h = &mut p.health;
        let s = bridge.stats;
        h.set_metric("sent_total", s.sent as f64);
        h.set_metric("bytes_total", s.bytes as f64);
        h.set_metric("put_errors", s.put_errors as f64);
        h.set_metric("publishers", s.publishers as f64);
        h.set_metric(
            "bus_lost",
            taps.iter().map(|t| t.stats().lost).sum::<u64>() as f64,
        );
        h.set_metric(
            "cmd_forwarded",
            counters.forwarded.load(Ordering::Relaxed) as f64,
        );
        h.set_metric("cmd_stale", counters.stale.load(Ordering::Relaxed) as f64);
        h.set_metric(
            "cmd_invalid",
            counters.invalid.load(Ordering::Relaxed) as f64,
        );
        h.set_metric(
            "initial_poses_forwarded",
            poses.forwarded.load(Ordering::Relaxed) as f64,
        );
        h.set_metric(
            "initial_poses_refused",
            poses.refused.load(Ordering::Relaxed) as f64,
        );
        p.tick()?;
    }
    Ok(())
}

/// A subscription to ROS topic `ros_topic` (under the namespace) of type
/// `def` from outside, keeping only the newest sample, announced as
/// rmw_zenoh announces a subscriber (entity `entity`); with its key.
struct Inbound {
    sub: zenoh::pubsub::Subscriber<RingChannelHandler<zenoh::sample::Sample>>,
    token: zenoh::liveliness::LivelinessToken,
    key: String,
}

fn subscribe_inbound(
    cfg: &RobotConfig,
    bridge: &Bridge,
    ros_topic: &str,
    def: &schema::MsgDef,
    entity: u32,
) -> anyhow::Result<Inbound> {
    let zc = &cfg.zenoh;
    let topic = keys::qualified(&zc.namespace, ros_topic);
    let dds = rihs::dds_type_name(def.name);
    let hash = rihs::type_hash(def)?;
    let key = keys::topic_key(zc.domain_id, &topic, &dds, &hash);
    let session = bridge.session().clone();
    let sub = session
        .declare_subscriber(key.clone())
        .with(RingChannel::new(1))
        .wait()
        .map_err(|e| anyhow::anyhow!("cannot subscribe to `{key}`: {e}"))?;
    let token = bridge::declare_token(
        &session,
        &keys::entity_token(
            zc.domain_id,
            bridge.zid(),
            entity,
            keys::EntityKind::Subscription,
            &zc.namespace,
            &topic,
            &dds,
            &hash,
            keys::Qos {
                transient_local: false,
                depth: 1,
            },
        ),
    )?;
    Ok(Inbound { sub, token, key })
}

/// Forwards `inbound`'s samples onto bus topic `topic` on a thread of its
/// own (bus ports stay on the thread that made them), woken by Zenoh and
/// keeping only the newest sample (a backlog is never replayed):
/// `forward(payload, attachment, publisher)` decides what is published.
fn spawn_inbound<T: Message + 'static>(
    cfg: &RobotConfig,
    inbound: Inbound,
    node: &str,
    topic: Topic<T>,
    stop: Shutdown,
    mut forward: impl FnMut(&[u8], Option<&[u8]>, &mut Publisher<T>) + Send + 'static,
) -> anyhow::Result<std::thread::JoinHandle<()>> {
    let opts = BusOptions::new(&cfg.robot.instance, node).with_root_path(cfg.bus.root_path.clone());
    tracing::info!(key = %inbound.key, "taking it from Zenoh onto {}", topic.name());
    let bus =
        Bus::open(&opts).with_context(|| format!("cannot join the bus for {}", topic.name()))?;
    drop(bus); // checked here; the thread opens its own
    Ok(std::thread::spawn(move || {
        let Inbound {
            sub,
            token: _token,
            key,
        } = inbound;
        let bus = match Bus::open(&opts) {
            Ok(b) => b,
            Err(e) => return tracing::error!("{key}: cannot join the bus: {e}"),
        };
        let mut publisher = match bus.publisher(topic.clone()) {
            Ok(p) => p,
            Err(e) => return tracing::error!("{key}: cannot publish {}: {e}", topic.name()),
        };
        while !stop.requested() {
            let sample = match sub.recv_timeout(Duration::from_millis(200)) {
                Ok(Some(s)) => s,
                Ok(None) => continue,
                Err(e) => return tracing::error!("{key}: subscriber closed: {e}"),
            };
            let payload = sample.payload().to_bytes();
            let attachment = sample.attachment().map(|a| a.to_bytes());
            forward(&payload, attachment.as_deref(), &mut publisher);
        }
    }))
}

/// `cmd_vel` onto `base/cmd_vel`: each fresh, valid command once.
fn spawn_commands(
    cfg: &RobotConfig,
    bridge: &Bridge,
    stop: Shutdown,
    counters: Arc<CmdCounters>,
) -> anyhow::Result<std::thread::JoinHandle<()>> {
    let inbound = subscribe_inbound(cfg, bridge, "/cmd_vel", &schema::TWIST, 0x7fff_0000)?;
    let timeout_ns = (cfg.base.cmd_timeout_s * 1e9) as i64;
    spawn_inbound(
        cfg,
        inbound,
        "zenoh-cmd",
        topics::BASE_CMD_VEL,
        stop,
        move |payload, attachment, publisher| {
            let checked = command::decode_twist(payload).and_then(|t| {
                command::check_age(attachment, unix_now_ns(), timeout_ns)?;
                Ok(t)
            });
            match checked {
                Ok(t) => {
                    let cmd = VelocityCommand {
                        header: Header::new(monotonic_now_ns(), 0, "base_link"),
                        linear: t.linear,
                        angular: t.angular,
                    };
                    match publisher.publish(&cmd) {
                        Ok(_) => counters.forwarded.fetch_add(1, Ordering::Relaxed),
                        Err(e) => {
                            tracing::warn!("cmd_vel: {e}");
                            counters.invalid.fetch_add(1, Ordering::Relaxed)
                        }
                    };
                }
                Err(e @ command::CommandError::Stale { .. }) => {
                    tracing::debug!("cmd_vel dropped: {e}");
                    counters.stale.fetch_add(1, Ordering::Relaxed);
                }
                Err(e) => {
                    tracing::debug!("cmd_vel dropped: {e}");
                    counters.invalid.fetch_add(1, Ordering::Relaxed);
                }
            }
        },
    )
}

/// A pose older than this (its rmw_zenoh source time) was held by the
/// network while the robot moved on: dropped.
const POSE_MAX_AGE_NS: i64 = 5_000_000_000;

/// `initialpose` (RViz's 2D Pose Estimate) onto `slam/initial_pose`: each
/// fresh, valid pose once; a refused one is warned of (an operator's click,
/// not a stream of commands).
fn spawn_initial_poses(
    cfg: &RobotConfig,
    bridge: &Bridge,
    stop: Shutdown,
    counters: Arc<PoseCounters>,
) -> anyhow::Result<std::thread::JoinHandle<()>> {
    let inbound = subscribe_inbound(
        cfg,
        bridge,
        "/initialpose",
        &schema::POSE_WITH_COVARIANCE_STAMPED,
        0x7fff_0001,
    )?;
    spawn_inbound(
        cfg,
        inbound,
        "zenoh-pose",
        topics::SLAM_INITIAL_POSE,
        stop,
        move |payload, attachment, publisher| {
            let checked = command::check_age(attachment, unix_now_ns(), POSE_MAX_AGE_NS)
                .map_err(|e| e.to_string())
                .and_then(|()| initial_pose::decode(payload).map_err(|e| e.to_string()));
            let published = checked.and_then(|pose| {
                publisher
                    .publish(&pose.to_estimate(monotonic_now_ns()))
                    .map_err(|e| e.to_string())?;
                Ok(pose)
            });
            match published {
                Ok(pose) => {
                    tracing::info!(
                        "initialpose from Zenoh: x {:.2} m, y {:.2} m, heading {:.1}°",
                        pose.x,
                        pose.y,
                        pose.yaw.to_degrees()
                    );
                    counters.forwarded.fetch_add(1, Ordering::Relaxed);
                }
                Err(e) => {
                    tracing::warn!("initialpose refused: {e}");
                    counters.refused.fetch_add(1, Ordering::Relaxed);
                }
            }
        },
    )
}
