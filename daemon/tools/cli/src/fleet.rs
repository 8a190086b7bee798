//! `smokenav status --zenoh ENDPOINT`: every robot on a Zenoh network, from
//! the operator's machine — reachable or not (its bridge's liveliness
//! token), each process's health and the SLAM pose, from the samples the
//! robots' `smokenav-zenoh` publish.

use crate::status::{ProcessStatus, StatusArgs, evaluate};
use serde::Serialize;
use smokenav_nodes_zenoh::fleet::{Fleet, RobotView};
use std::io::{IsTerminal, Write};
use std::process::ExitCode;
use std::time::Duration;

#[derive(Debug, Serialize)]
struct PoseView {
    x: f64,
    y: f64,
    theta: f64,
    age_s: f64,
}

#[derive(Debug, Serialize)]
struct RobotStatus {
    namespace: String,
    reachable: bool,
    /// Reachable and every process it reports is up.
    healthy: bool,
    /// Seconds since it became unreachable.
    lost_s: Option<f64>,
    pose: Option<PoseView>,
    processes: Vec<ProcessStatus>,
}

fn summarise(r: &RobotView, stale_after: f64) -> RobotStatus {
    let processes: Vec<ProcessStatus> = if r.reachable {
        r.health
            .iter()
            .map(|(role, (h, arrived))| {
                // The robot's stamps are on its own monotonic clock: age is
                // judged by arrival here.
                let now = h.header.stamp_ns + arrived.elapsed().as_nanos() as u64;
                evaluate(role, Some(h), now, stale_after)
            })
            .collect()
    } else {
        Vec::new()
    };
    RobotStatus {
        namespace: r.namespace.clone(),
        reachable: r.reachable,
        healthy: r.reachable && !processes.is_empty() && processes.iter().all(|p| p.healthy),
        lost_s: r
            .lost_at
            .filter(|_| !r.reachable)
            .map(|t| t.elapsed().as_secs_f64()),
        pose: r
            .pose
            .as_ref()
            .filter(|_| r.reachable)
            .map(|(p, t)| PoseView {
                x: p.x,
                y: p.y,
                theta: p.theta,
                age_s: t.elapsed().as_secs_f64(),
            }),
        processes,
    }
}

fn print_table(out: &mut impl Write, robots: &[RobotStatus]) -> std::io::Result<()> {
    if robots.is_empty() {
        writeln!(out, "no robot seen")?;
    }
    for r in robots {
        let name = if r.namespace.is_empty() {
            "/"
        } else {
            &r.namespace
        };
        if !r.reachable {
            let lost = r
                .lost_s
                .map_or(String::new(), |s| format!(" (lost {s:.1}s ago)"));
            writeln!(out, "robot {name:<12} unreachable{lost}")?;
            continue;
        }
        let pose = r.pose.as_ref().map_or("no pose".into(), |p| {
            format!(
                "pose x {:.2} y {:.2} θ {:.1}° ({:.1}s ago)",
                p.x,
                p.y,
                p.theta.to_degrees(),
                p.age_s
            )
        });
        let state = if r.healthy { "healthy" } else { "unhealthy" };
        writeln!(out, "robot {name:<12} reachable {state}  {pose}")?;
        for p in &r.processes {
            writeln!(
                out,
                "  {:<8} {:<9} beat {:.1}s ago",
                p.role,
                p.status,
                p.heartbeat_age_s.unwrap_or(0.0)
            )?;
        }
    }
    Ok(())
}

/// Exit status 0 when every robot seen (and every one expected) is reachable and healthy.
pub fn run(args: &StatusArgs) -> anyhow::Result<ExitCode> {
    let mut fleet = Fleet::open(&args.zenoh, args.domain)?;
    for ns in &args.robots {
        fleet.expect(ns);
    }
    let stop = smokenav_platform_runtime::Shutdown::install()?;
    // First look: a little more than the default 1 s health period.
    let mut window = Duration::from_millis(1500);
    loop {
        fleet.poll(window);
        let robots: Vec<RobotStatus> = fleet
            .robots
            .values()
            .map(|r| summarise(r, args.stale_after))
            .collect();
        let healthy = !robots.is_empty() && robots.iter().all(|r| r.healthy);
        let mut out = std::io::stdout().lock();
        if args.json {
            serde_json::to_writer(
                &mut out,
                &serde_json::json!({
                    "domain": fleet.domain(),
                    "healthy": healthy,
                    "robots": robots,
                    "dropped": fleet.dropped(),
                    "undecodable": fleet.undecodable,
                }),
            )?;
            writeln!(out)?;
        } else {
            if args.watch.is_some() && out.is_terminal() {
                write!(out, "\x1b[2J\x1b[H")?;
            }
            print_table(&mut out, &robots)?;
        }
        out.flush()?;
        match args.watch {
            Some(secs) if !stop.requested() => {
                window = Duration::from_secs_f64(secs.max(0.1));
            }
            _ => {
                return Ok(if healthy {
                    ExitCode::SUCCESS
                } else {
                    ExitCode::from(1)
                });
            }
        }
    }
}
