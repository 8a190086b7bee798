//! `smokenav status`: one line per process, from the `health/<role>` topics.

use crate::topic::BusArgs;
use anyhow::Context;
use clap::Args;
use serde::Serialize;
use smokenav_platform_bus::{Bus, Subscriber, Waiter, topics};
use smokenav_platform_config::RobotConfig;
use smokenav_shared_types::{Health, HealthState, clock::monotonic_now_ns};
use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

#[derive(Debug, Args)]
pub struct StatusArgs {
    /// Print JSON (one object with a `processes` array) instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Refresh every N seconds until Ctrl-C.
    #[arg(long, value_name = "SECONDS", num_args = 0..=1, default_missing_value = "1")]
    pub watch: Option<f64>,
    /// Roles to expect (default: from the profile's platform, else every role).
    #[arg(long, value_delimiter = ',')]
    roles: Vec<String>,
    /// A heartbeat older than this many seconds means the process is down.
    #[arg(long, default_value_t = 3.0)]
    pub stale_after: f64,
    /// Watch robots over Zenoh instead of the local bus: a router's or a
    /// robot bridge's endpoint (`tcp/HOST:PORT`; repeat for several).
    #[arg(long, value_name = "ENDPOINT")]
    pub zenoh: Vec<String>,
    /// The ROS domain id on Zenoh.
    #[arg(long, default_value_t = 0, requires = "zenoh")]
    pub domain: u32,
    /// Robots (ROS namespaces) to expect over Zenoh: `/robot1,/robot2`.
    #[arg(long, value_delimiter = ',', requires = "zenoh")]
    pub robots: Vec<String>,
    #[command(flatten)]
    bus: BusArgs,
}

/// What `status` concludes about one process.
#[derive(Debug, Clone, Serialize)]
pub struct ProcessStatus {
    pub role: String,
    /// `up`, `degraded`, `error`, `starting`, `stopping` or `down`.
    pub status: String,
    pub healthy: bool,
    pub pid: Option<u32>,
    /// Seconds since the last heartbeat.
    pub heartbeat_age_s: Option<f64>,
    pub uptime_s: Option<f64>,
    pub rates: Vec<RateStatus>,
    pub counters: Vec<(String, f64)>,
    pub latency_p99_us: Option<f32>,
    pub deadline_misses: Option<u64>,
    pub last_error: Option<String>,
}

#[derive(Debug, Clone, Serialize)]
pub struct RateStatus {
    pub name: String,
    pub hz: f64,
    pub expected_hz: Option<f64>,
    /// Below the process's rate floor (80 % unless configured) of the expected rate.
    pub low: bool,
}

fn expected_roles(args: &StatusArgs) -> anyhow::Result<Vec<String>> {
    if !args.roles.is_empty() {
        return Ok(args.roles.clone());
    }
    if let Some(path) = &args.bus.config {
        let cfg = RobotConfig::load(path)
            .with_context(|| format!("invalid robot profile {}", path.display()))?;
        return Ok([
            "hokuyo",
            cfg.robot.platform.driver_role(),
            "smoke",
            "fusion",
            "slam",
            "mapping",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect());
    }
    Ok(topics::ROLES.iter().map(|s| s.to_string()).collect())
}

/// Collects the newest heartbeat of each role. Health is published with a
/// history of one, so a subscriber gets the last report when the publisher
/// next sends; waiting a little over one health period sees every live process.
fn collect(
    bus: &Bus,
    subs: &[(String, Subscriber<Health>)],
    waiter: &Waiter,
    window: Duration,
) -> anyhow::Result<Vec<Option<Health>>> {
    let _ = bus;
    let mut latest: Vec<Option<Health>> = vec![None; subs.len()];
    let end = Instant::now() + window;
    loop {
        for (i, (_, sub)) in subs.iter().enumerate() {
            while let Some(h) = sub.receive()? {
                latest[i] = Some(*h);
            }
        }
        let now = Instant::now();
        if now >= end {
            return Ok(latest);
        }
        waiter.wait(Some(end - now))?;
    }
}

pub fn evaluate(
    role: &str,
    health: Option<&Health>,
    now_ns: u64,
    stale_after: f64,
) -> ProcessStatus {
    let Some(h) = health else {
        return ProcessStatus {
            role: role.to_owned(),
            status: "down".into(),
            healthy: false,
            pid: None,
            heartbeat_age_s: None,
            uptime_s: None,
            rates: vec![],
            counters: vec![],
            latency_p99_us: None,
            deadline_misses: None,
            last_error: None,
        };
    };
    let age = now_ns.saturating_sub(h.header.stamp_ns) as f64 * 1e-9;
    let (mut rates, mut counters) = (Vec::new(), Vec::new());
    // The floor the process applies to itself; older processes do not report one.
    let floor = h
        .metric("rate_floor")
        .unwrap_or(smokenav_platform_runtime::DEFAULT_RATE_FLOOR);
    for m in h.metrics() {
        if m.expected.is_finite() {
            rates.push(RateStatus {
                name: m.name.as_str().to_owned(),
                hz: m.value,
                expected_hz: Some(m.expected),
                low: m.value < floor * m.expected,
            });
        } else {
            counters.push((m.name.as_str().to_owned(), m.value));
        }
    }
    let state = h.state();
    let stale = age > stale_after;
    let status = if stale || state == HealthState::Stopping {
        "down"
    } else {
        match state {
            HealthState::Ok if rates.iter().any(|r| r.low) => "degraded",
            HealthState::Ok => "up",
            HealthState::Degraded => "degraded",
            HealthState::Error => "error",
            HealthState::Starting => "starting",
            HealthState::Stopping => "down",
        }
    };
    ProcessStatus {
        role: role.to_owned(),
        status: status.into(),
        healthy: status == "up",
        pid: Some(h.pid),
        heartbeat_age_s: Some(age),
        uptime_s: Some(h.uptime_s),
        rates,
        counters,
        latency_p99_us: Some(h.latency_p99_us),
        deadline_misses: Some(h.deadline_misses),
        last_error: (!h.last_error.is_empty()).then(|| h.last_error.as_str().to_owned()),
    }
}

fn print_table(out: &mut impl Write, rows: &[ProcessStatus], color: bool) -> std::io::Result<()> {
    let paint = |s: &str, code: &str| {
        if color {
            format!("\x1b[{code}m{s}\x1b[0m")
        } else {
            s.to_owned()
        }
    };
    for r in rows {
        let code = match r.status.as_str() {
            "up" => "32",
            "degraded" | "starting" => "33",
            _ => "31",
        };
        let mut line = format!("{:<8} {}", r.role, paint(&format!("{:<9}", r.status), code));
        if let Some(pid) = r.pid {
            line.push_str(&format!(
                " pid {:<7} beat {:>4.1}s ago  up {:>6.0}s",
                pid,
                r.heartbeat_age_s.unwrap_or(0.0),
                r.uptime_s.unwrap_or(0.0)
            ));
        }
        for rate in &r.rates {
            let txt = match rate.expected_hz {
                Some(e) => format!(" {} {:.1}/{:.0} Hz", rate.name, rate.hz, e),
                None => format!(" {} {:.1} Hz", rate.name, rate.hz),
            };
            line.push_str(&if rate.low { paint(&txt, "33") } else { txt });
        }
        for (name, v) in r.counters.iter().take(6) {
            line.push_str(&format!(" {name}={}", fmt_num(*v)));
        }
        if let Some(p99) = r.latency_p99_us
            && p99 > 0.0
        {
            line.push_str(&format!(" p99 {p99:.0}µs"));
        }
        if let Some(e) = &r.last_error {
            line.push_str(&paint(&format!("  last error: {e}"), "31"));
        }
        writeln!(out, "{line}")?;
    }
    Ok(())
}

fn fmt_num(v: f64) -> String {
    if v.fract() == 0.0 && v.abs() < 1e15 {
        format!("{}", v as i64)
    } else {
        format!("{v:.3}")
    }
}

/// Exit status 0 when every expected process is up, 1 otherwise.
pub fn run(args: StatusArgs) -> anyhow::Result<std::process::ExitCode> {
    if !args.zenoh.is_empty() {
        return crate::fleet::run(&args);
    }
    let bus = args.bus.open("status")?;
    let roles = expected_roles(&args)?;
    let subs: Vec<(String, Subscriber<Health>)> = roles
        .iter()
        .map(|r| Ok((r.clone(), bus.subscriber(topics::health(r))?)))
        .collect::<anyhow::Result<_>>()?;
    let waiter = Waiter::new()?;
    let _guards = subs
        .iter()
        .map(|(_, s)| waiter.attach(s))
        .collect::<Result<Vec<_>, _>>()?;
    let stop = smokenav_platform_runtime::Shutdown::install()?;
    let mut latest: Vec<Option<Health>> = vec![None; subs.len()];
    // First look: a little more than the default 1 s health period.
    let mut window = Duration::from_millis(1300);
    loop {
        for (i, h) in collect(&bus, &subs, &waiter, window)?
            .into_iter()
            .enumerate()
        {
            if h.is_some() {
                latest[i] = h;
            }
        }
        let now = monotonic_now_ns();
        let rows: Vec<ProcessStatus> = roles
            .iter()
            .zip(&latest)
            .map(|(r, h)| evaluate(r, h.as_ref(), now, args.stale_after))
            .collect();
        let healthy = rows.iter().all(|r| r.healthy);
        let mut out = std::io::stdout().lock();
        if args.json {
            serde_json::to_writer(
                &mut out,
                &serde_json::json!({ "instance": bus.instance(), "healthy": healthy, "processes": rows }),
            )?;
            writeln!(out)?;
        } else {
            if args.watch.is_some() && out.is_terminal() {
                write!(out, "\x1b[2J\x1b[H")?;
            }
            let color = out.is_terminal();
            print_table(&mut out, &rows, color)?;
        }
        out.flush()?;
        match args.watch {
            Some(secs) if !stop.requested() => {
                window = Duration::from_secs_f64(secs.max(0.1));
            }
            _ => {
                return Ok(if healthy {
                    std::process::ExitCode::SUCCESS
                } else {
                    std::process::ExitCode::from(1)
                });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn beat(state: HealthState, stamp_ns: u64) -> Health {
        let mut h = Health::new("hokuyo", 42);
        h.header.stamp_ns = stamp_ns;
        h.set_state(state);
        h.set_metric("scan_hz", 10.0, Some(10.0));
        h.set_metric("checksum_errors", 3.0, None);
        h
    }

    #[test]
    fn missing_heartbeat_is_down() {
        let s = evaluate("slam", None, 10_000_000_000, 3.0);
        assert_eq!(s.status, "down");
        assert!(!s.healthy);
    }

    #[test]
    fn stale_heartbeat_is_down() {
        let h = beat(HealthState::Ok, 1_000_000_000);
        let s = evaluate("hokuyo", Some(&h), 5_000_000_000, 3.0);
        assert_eq!(s.status, "down");
    }

    #[test]
    fn fresh_ok_heartbeat_is_up_with_rates_and_counters() {
        let h = beat(HealthState::Ok, 4_500_000_000);
        let s = evaluate("hokuyo", Some(&h), 5_000_000_000, 3.0);
        assert_eq!(s.status, "up");
        assert!(s.healthy);
        assert_eq!(s.rates.len(), 1);
        assert_eq!(s.counters, vec![("checksum_errors".to_string(), 3.0)]);
    }

    #[test]
    fn low_rate_is_degraded() {
        let mut h = beat(HealthState::Ok, 4_500_000_000);
        h.set_metric("scan_hz", 5.0, Some(10.0));
        let s = evaluate("hokuyo", Some(&h), 5_000_000_000, 3.0);
        assert_eq!(s.status, "degraded");
        assert!(!s.healthy);
    }

    #[test]
    fn stopping_process_is_down() {
        let h = beat(HealthState::Stopping, 4_900_000_000);
        assert_eq!(
            evaluate("hokuyo", Some(&h), 5_000_000_000, 3.0).status,
            "down"
        );
    }
}
