//! `smokenav-view`: the robot's topics, live, for Foxglove or Lichtblick.
//!
//! A bus subscriber of every catalog topic (and every process's health)
//! serving them on a Foxglove WebSocket as the recordings carry them:
//! ROS 2 topic names (`/laser/scan`), `ros2msg` schemas, CDR, plus `/tf`
//! (map → odom → base_link), `/tf_static` (base_link → laser) and the sonar
//! ring's points. Bound to 127.0.0.1:8765 unless `--listen` opens it.
//! Health on `health/view`: clients, and what each was sent and lost.
//! With `--initial-pose` a client may publish a "2D Pose Estimate"
//! (`/initialpose`, geometry_msgs/PoseWithCovarianceStamped in CDR: Foxglove's
//! 3D panel publish tool) and it goes onto `slam/initial_pose`; nothing
//! else is ever taken from a client.
//!
//! ```text
//! smokenav-view --config robot.toml [--listen 0.0.0.0:8765] [--initial-pose]
//! ```

use anyhow::Context;
use clap::Parser;
use smokenav_nodes_view::{Limits, Pump, ViewServer, channel_table};
use smokenav_platform_bus::tap::{self, Tap};
use smokenav_platform_bus::{Attachment, WaitOutcome, Waiter};
use smokenav_platform_recording::RobotGeometry;
use smokenav_platform_runtime::{CommonArgs, Process};
use smokenav_shared_types::clock::monotonic_now_ns;
use std::process::ExitCode;
use std::time::Duration;

/// Its role: node name and health topic.
const ROLE: &str = "view";
/// Clients whose counters appear one by one in health (the metric table is small).
const CLIENTS_IN_HEALTH: usize = 4;

#[derive(Parser)]
#[command(version, about = "Every smokenav topic, live, on a Foxglove WebSocket")]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// Address and port to listen on; anything but loopback opens the robot's
    /// topics to that network.
    #[arg(long, default_value = "127.0.0.1:8765")]
    listen: String,
    /// Stream messages queued per client before the oldest is dropped.
    #[arg(long, default_value_t = Limits::default().stream_queue)]
    queue: usize,
    /// Kernel send buffer per client, bytes (0: the kernel's default).
    #[arg(long, default_value_t = 64 * 1024)]
    send_buffer: usize,
    /// Let clients publish a "2D Pose Estimate" on /initialpose, handed to
    /// SLAM on slam/initial_pose (a localising SLAM searches there). Off:
    /// clients only watch.
    #[arg(long)]
    initial_pose: bool,
}

fn main() -> ExitCode {
    let args = Args::parse();
    smokenav_platform_runtime::main(ROLE, &args.common, |p| run(p, &args))
}

fn run(p: &mut Process, args: &Args) -> anyhow::Result<()> {
    let mut topics = tap::default_topics();
    topics.push(format!(
        "{}{ROLE}",
        smokenav_platform_bus::topics::HEALTH_PREFIX
    ));
    let geometry = RobotGeometry::from_config(&p.config);
    let limits = Limits {
        stream_queue: args.queue.max(1),
        send_buffer: (args.send_buffer > 0).then_some(args.send_buffer),
        ..Limits::default()
    };
    let name = format!("smokenav {}", p.config.robot.name);
    // A few poses between two bus turns (an operator clicks, not a stream).
    let (pose_tx, poses) = std::sync::mpsc::sync_channel(4);
    let mut given = None;
    let server = if args.initial_pose {
        given = Some(
            p.bus
                .publisher(smokenav_platform_bus::topics::SLAM_INITIAL_POSE)?,
        );
        ViewServer::start_taking_poses(
            &args.listen,
            &name,
            channel_table(&topics, true),
            limits,
            pose_tx,
        )?
    } else {
        drop(pose_tx);
        ViewServer::start(&args.listen, &name, channel_table(&topics, true), limits)?
    };
    let taps: Vec<Box<dyn Tap>> = topics
        .iter()
        .map(|t| tap::open(&p.bus, t))
        .collect::<Result<_, _>>()?;
    let mut pump = Pump::new(&server, Some(geometry));
    pump.static_transforms(&server, monotonic_now_ns());

    let waiter = Waiter::new()?;
    let _attached: Vec<Attachment> = taps
        .iter()
        .map(|t| t.attach(&waiter))
        .collect::<Result<_, _>>()
        .context("cannot wait on the bus")?;
    let rate = p.health.add_rate("messages_hz", None);
    p.ready(&format!(
        "serving {} channels on ws://{}{}",
        server.channels().len(),
        server.local_addr(),
        if args.initial_pose {
            ", /initialpose in"
        } else {
            ""
        }
    ));
    let mut shown = String::new();
    while !p.shutdown_requested() {
        if waiter.wait(Some(Duration::from_millis(200)))? == WaitOutcome::Shutdown {
            break;
        }
        for t in &taps {
            t.drain(&mut |topic, msg| {
                pump.push(&server, topic, msg, monotonic_now_ns());
                p.health.mark(rate);
                Ok(())
            })?;
        }
        if let Some(publisher) = &mut given {
            while let Ok(pose) = poses.try_recv() {
                match publisher.publish(&pose.to_estimate(monotonic_now_ns())) {
                    Ok(_) => tracing::info!(
                        "initial pose from a client: x {:.2} m, y {:.2} m, heading {:.1}°",
                        pose.x,
                        pose.y,
                        pose.yaw.to_degrees()
                    ),
                    Err(e) => p
                        .health
                        .error(&format!("cannot publish slam/initial_pose: {e}")),
                }
            }
        }
        let status = report(p, &server, &taps, pump.unadvertised);
        if status != shown {
            tracing::info!("{status}");
            p.status(&status);
            shown = status;
        }
        p.tick()?;
    }
    Ok(())
}

/// Refreshes the health metrics; returns a one-line status.
fn report(
    p: &mut Process,
    server: &ViewServer,
    taps: &[Box<dyn Tap>],
    unadvertised: u64,
) -> String {
    let h = &mut p.health;
    let clients = server.client_stats();
    let totals = server.totals();
    let bus_lost: u64 = taps.iter().map(|t| t.stats().lost).sum();
    h.set_metric("clients", clients.len() as f64);
    h.set_metric("sent_total", totals.sent as f64);
    h.set_metric("dropped_total", totals.dropped as f64);
    h.set_metric("superseded_total", totals.superseded as f64);
    h.set_metric("bus_lost", bus_lost as f64);
    h.set_metric("unadvertised", unadvertised as f64);
    let poses = server.pose_stats();
    h.set_metric("initial_poses_taken", poses.taken as f64);
    h.set_metric("initial_poses_refused", poses.refused as f64);
    for (i, c) in clients.iter().take(CLIENTS_IN_HEALTH).enumerate() {
        h.set_metric(&format!("client{i}_id"), c.id as f64);
        h.set_metric(&format!("client{i}_dropped"), c.dropped as f64);
        h.set_metric(&format!("client{i}_queued"), c.queued as f64);
    }
    for i in clients.len()..CLIENTS_IN_HEALTH {
        for m in ["id", "dropped", "queued"] {
            h.set_metric(&format!("client{i}_{m}"), 0.0);
        }
    }
    // Drops change with every message to a slow client: they are in the
    // metrics, not in the status line (which is logged when it changes).
    format!(
        "{} client(s) on ws://{}",
        clients.len(),
        server.local_addr()
    )
}
