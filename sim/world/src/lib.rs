//! smokenav's simulated world: a 2D arena with smoke, a differential-drive
//! robot and models of its laser, sonar ring and smoke sensor, stepped
//! deterministically so the device emulators (and tests) can be fed from it,
//! plus the ground truth every accuracy claim is measured against.
//!
//! ```no_run
//! use smokenav_sim_world::{Scenario, World};
//! use std::time::Duration;
//!
//! let mut world = World::new(Scenario::builtin("r32-dense-crossing")?)?;
//! while !world.is_finished() {
//!     let out = world.step(Duration::from_millis(10));
//!     for scan in &out.laser { /* feed scan.ranges_mm to the URG-04LX emulator */ }
//!     for ping in &out.sonar { /* ... */ }
//! }
//! # Ok::<(), smokenav_sim_world::SimError>(())
//! ```
//!
//! Modules: [`arena`] (walls, ray casting, map files), [`smoke`] (the density
//! field), [`robot`] (drive, odometry errors, route following), [`laser`],
//! [`sonar`], [`mq303a`] (sensor models), [`scenario`] (TOML files),
//! [`world`] (stepping), [`truth`] (ground-truth output).

pub mod arena;
pub mod geom;
pub mod laser;
pub mod mq303a;
pub mod robot;
pub mod scenario;
pub mod smoke;
pub mod sonar;
pub mod truth;
pub mod world;

pub use arena::{Arena, ArenaSource, BuiltinArena};
pub use geom::{Pose2, Position, Segment, Vec2};
pub use scenario::{BUILTIN_SCENARIOS, Scenario};
pub use truth::TruthSample;
pub use world::{LaserFrame, OdometrySample, SmokeSample, SonarSample, StepOutput, TICK_NS, World};

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A TOML file (scenario, vector arena, robot profile) is malformed or invalid.
    #[error(transparent)]
    Config(#[from] smokenav_platform_config::ConfigError),
    #[error(transparent)]
    Map(#[from] smokenav_platform_map::MapError),
    #[error("{}: key `{key}`: {reason}", file.display())]
    Invalid {
        file: PathBuf,
        key: String,
        reason: String,
    },
}
