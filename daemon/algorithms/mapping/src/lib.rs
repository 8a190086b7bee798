//! Bayesian multi-sensor occupancy mapping in 2D and 3D, after Tran et al.
//! 2021 (2D laser and 3D ultrasonic sensor fusion): an inverse sensor model
//! per sensor, four fusion rules compared, the Bayes filter with OctoMap's
//! clamping kept, a fused 2D grid in the laser plane, a log-odds octree, its
//! projection to 2D (everything under the robot's height), and export to
//! OctoMap's `.bt` format. No knowledge of the bus: a caller hands in poses,
//! scans and sonar echoes.
//!
//! - [`logodds`]: log-odds and OctoMap's clamping defaults.
//! - [`rules`]: LOP, LIOP, IOP, Bayes.
//! - [`ism`]: Thrun's laser model, the 3D sonar cone.
//! - [`grid`], [`octree`]: the maps.
//! - [`mapper`]: sensors into maps, per-rule outputs.

pub mod grid;
pub mod ism;
pub mod logodds;
pub mod mapper;
pub mod octree;
pub mod rules;

pub use grid::{CellClass, GridGeometry, LogOddsGrid, ProbGrid};
pub use ism::{LaserIsm, SonarIsm};
pub use logodds::{ClampLogOdds, Clamping};
pub use mapper::{Heights, MapParams, MapSet, Mapper, MapperError, Mount, Rig};
pub use octree::{BtError, BtStats, Octree};
pub use rules::{FusionRule, Opinion, fuse};
