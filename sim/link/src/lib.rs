//! smokenav-simlink: the smoky world wired to the device emulators, so the
//! real drivers — or a user's own tools — connect to a simulated robot.
//!
//! [`SimLink::start`] creates the world of a scenario and starts, each on a
//! real pseudo-terminal behind a stable symlink, the URG-04LX emulator, the
//! base's emulator (ARCOS for a Pioneer, the Nomadic protocol for a Scout,
//! per the scenario's robot profile) and the smoke ADC board emulator. They
//! idle (no laser echo, robot at the origin, clean air) until
//! [`SimLink::run`] steps the world against the host clock (real time, or
//! `speed` times faster) and feeds them at the devices' own rates:
//!
//! * laser: each scan the emulated sensor sends is the world's frame for the
//!   same sweep (see [`laser`]), so the driver's stamp says when the world
//!   measured it;
//! * base: the world's wheel-odometry pose (with its slip and drift) every
//!   5 ms, each sonar ping when it fires; when the scenario has no scripted
//!   route, the velocity the driver commands moves the world's robot;
//! * smoke: the world's MQ303A output as ADC counts (see [`smoke`]).
//!
//! Ground truth: each true pose is handed out with its host-time stamp
//! (publish it with [`TruthPublisher`] on topic [`TRUTH_TOPIC`] = `sim/truth`,
//! a `PoseEstimate` in frame `world`), and [`SimLink::write_truth`] writes the
//! true map (map_server PGM/YAML) and trajectory (`timestamp x y theta`).
//!
//! [`direct::DirectDrivers`] turns the world's output into the messages the
//! drivers would publish, without emulators or processes: recordings as fast
//! as the CPU allows.
//!
//! ```no_run
//! use smokenav_sim_link::{SimLink, SimLinkConfig, Until};
//! let scenario = smokenav_sim_world::Scenario::builtin("mrl-clean")?;
//! let mut link = SimLink::start(SimLinkConfig::new(scenario, "/tmp/sim-devices"))?;
//! link.write_profile("/tmp/sim-devices/robot.toml".as_ref(), None)?;
//! // start smokenav-hokuyo, smokenav-pioneer, smokenav-smoke with --config /tmp/sim-devices/robot.toml
//! let summary = link.run(Until::ScenarioEnd, &|| false, &mut |_, _| {}, &mut |_| {});
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod base;
pub mod direct;
pub mod laser;
mod link;
pub mod smoke;
pub mod timebase;
pub mod truth;

pub use direct::{DirectDrivers, DirectMessage};
pub use link::{
    Devices, LEAD, Progress, RunSummary, STEP, SimLink, SimLinkConfig, SimLinkError, Until,
};
pub use timebase::TimeBase;
pub use truth::{TRUTH_FRAME, TRUTH_TOPIC, TruthPublisher, TruthTrack, truth_message};
