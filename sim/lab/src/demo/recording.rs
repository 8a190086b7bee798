//! The demo's recordings: MCAP files (smokenav-recording) of the sensor
//! topics, written live from the bus or straight from the simulator, and
//! read back for the offline comparison.

use anyhow::{Context, bail};
use smokenav_platform_config::RobotConfig;
use smokenav_platform_map::OccupancyGrid;
use smokenav_platform_recording::{AnyMessage, AnyMessageRef, Playback, Recorder, SinkOptions};
use smokenav_shared_types::catalog::topic_names;
use smokenav_shared_types::{LaserScan, Odometry, SmokeReading, SonarRing};
use smokenav_sim_link::{DirectDrivers, DirectMessage, TruthTrack, Until};
use smokenav_sim_world::{Scenario, StepOutput, World};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;
use std::time::Duration;

/// The sensor topics the comparison needs.
pub const SENSOR_TOPICS: [&str; 4] = [
    topic_names::LASER_SCAN,
    topic_names::BASE_SONAR,
    topic_names::SMOKE_LEVEL,
    topic_names::BASE_ODOM,
];

/// Stamp of sim time 0 in a recording made straight from the simulator, ns.
pub const DIRECT_T0_NS: u64 = 1_000_000_000;

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Kind {
    Laser,
    Sonar,
    Smoke,
    Odometry,
}

/// The sensor messages of a recording, in the order they were received.
#[derive(Default)]
pub struct SensorLog {
    pub lasers: Vec<Box<LaserScan>>,
    pub sonars: Vec<SonarRing>,
    pub smokes: Vec<SmokeReading>,
    /// In receive order (as `order` indexes them).
    pub odoms: Vec<Odometry>,
    /// (receive time, kind, index into its vector), in receive order.
    pub order: Vec<(u64, Kind, usize)>,
}

impl SensorLog {
    pub fn push(&mut self, log_time: u64, msg: AnyMessage) {
        let (kind, i) = match msg {
            AnyMessage::LaserScan(s) => {
                self.lasers.push(s);
                (Kind::Laser, self.lasers.len() - 1)
            }
            AnyMessage::SonarRing(r) => {
                self.sonars.push(r);
                (Kind::Sonar, self.sonars.len() - 1)
            }
            AnyMessage::SmokeReading(r) => {
                self.smokes.push(r);
                (Kind::Smoke, self.smokes.len() - 1)
            }
            AnyMessage::Odometry(o) => {
                self.odoms.push(o);
                (Kind::Odometry, self.odoms.len() - 1)
            }
            _ => return,
        };
        self.order.push((log_time, kind, i));
    }

    /// Reads the sensor topics of an MCAP recording.
    pub fn read(path: &Path) -> anyhow::Result<Self> {
        let mut playback =
            Playback::open(path).with_context(|| format!("cannot open {}", path.display()))?;
        let mut log = SensorLog::default();
        while let Some(p) = playback
            .read_next()
            .with_context(|| format!("cannot read {}", path.display()))?
        {
            if SENSOR_TOPICS.contains(&p.topic.as_str()) {
                log.push(p.log_time, p.message);
            }
        }
        log.order.sort_by_key(|&(t, _, _)| t);
        if log.lasers.is_empty() || log.odoms.is_empty() {
            bail!(
                "{}: no laser scans or no odometry ({} scans, {} odometry messages)",
                path.display(),
                log.lasers.len(),
                log.odoms.len()
            );
        }
        Ok(log)
    }
}

pub fn create_recorder(
    path: &Path,
    profile: &RobotConfig,
    meta: &BTreeMap<String, String>,
    now_ns: u64,
) -> anyhow::Result<Recorder<BufWriter<File>>> {
    let file = File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
    Recorder::create(
        BufWriter::with_capacity(1 << 20, file),
        SinkOptions::default(),
        Some(smokenav_platform_recording::RobotGeometry::from_config(
            profile,
        )),
        meta,
        now_ns,
    )
    .with_context(|| format!("cannot start the recording {}", path.display()))
}

/// What a recording straight from the simulator produced.
pub struct DirectRun {
    pub truth: TruthTrack,
    pub truth_map: OccupancyGrid,
    pub messages: u64,
    pub sim_s: f64,
}

/// Runs `scenario` as fast as the CPU allows and records what the drivers
/// would have published (see `smokenav_sim_link::direct`) to `path`.
pub fn record_direct(
    scenario: Scenario,
    profile: &RobotConfig,
    until: Until,
    path: &Path,
    meta: &BTreeMap<String, String>,
) -> anyhow::Result<DirectRun> {
    let mut drivers = DirectDrivers::new(profile, DIRECT_T0_NS)?;
    let mut world = World::new(scenario)?;
    let duration_ns = (world.scenario().duration_s * 1e9) as u64;
    let end_ns = match until {
        Until::SimSeconds(s) if s.is_finite() && s > 0.0 => ((s * 1e9) as u64).min(duration_ns),
        _ => duration_ns,
    };
    let mut rec = create_recorder(path, profile, meta, DIRECT_T0_NS)?;
    let mut truth = TruthTrack::default();
    let mut out = StepOutput::default();
    let mut messages = 0u64;
    let mut route_done_at: Option<u64> = None;
    let mut error: Option<anyhow::Error> = None;
    loop {
        let end = match (until, route_done_at) {
            (Until::RouteDone, Some(t)) => (t + 1_000_000_000u64).min(end_ns),
            _ => end_ns,
        };
        if world.time_ns() >= end {
            break;
        }
        out.clear();
        let step = Duration::from_nanos((end - world.time_ns()).min(100_000_000));
        world.step_into(step, &mut out);
        if route_done_at.is_none() && world.route_done() {
            route_done_at = Some(world.time_ns());
        }
        for t in &out.truth {
            truth.push(DIRECT_T0_NS + t.t_ns, t.pose, t.smoke_gpm3);
        }
        drivers.convert(&out, |log_time, msg| {
            if error.is_some() {
                return;
            }
            let r = match &msg {
                DirectMessage::Laser(s) => {
                    rec.record(msg.topic(), AnyMessageRef::LaserScan(s), log_time)
                }
                DirectMessage::Odometry(o) => {
                    rec.record(msg.topic(), AnyMessageRef::Odometry(o), log_time)
                }
                DirectMessage::Sonar(r) => {
                    rec.record(msg.topic(), AnyMessageRef::SonarRing(r), log_time)
                }
                DirectMessage::Smoke(s) => {
                    rec.record(msg.topic(), AnyMessageRef::SmokeReading(s), log_time)
                }
            };
            match r {
                Ok(()) => messages += 1,
                Err(e) => {
                    error = Some(
                        anyhow::Error::new(e).context(format!("cannot write {}", path.display())),
                    )
                }
            }
        });
        if let Some(e) = error.take() {
            return Err(e);
        }
    }
    rec.finish(None)
        .with_context(|| format!("cannot finish {}", path.display()))?;
    Ok(DirectRun {
        truth,
        truth_map: world.truth_map(),
        messages,
        sim_s: world.time_ns() as f64 * 1e-9,
    })
}
