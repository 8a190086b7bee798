//! What a SLAM algorithm is to the pipeline: scans paired with odometry in,
//! a pose with its uncertainty and a map out.
//!
//! The pipeline ([`crate::pipeline`]) does everything around the algorithm
//! once for all of them (odometry pairing and resets, scan conversion, the
//! smoke noise model, the front end, the motion filter), so a back-end only
//! sees scans it should use ([`SlamBackend::process`]) and the odometry of the
//! scans the motion filter held back ([`SlamBackend::predict`]). The shape is
//! meant for the back-ends to come as well: a pose graph with loop closure
//! (which revises its whole trajectory and map at once: see
//! [`SlamBackend::map_revision`]), a fuzzy-map registration, and a vote over
//! several back-ends (which needs each one's covariance and a cheap way to
//! tell whether its map changed).

use crate::frontend::Tracked;
use crate::fuzzy::FuzzySlam;
use crate::graph::saved::SavedGraphError;
use crate::graph::{GraphParams, GraphSlam};
use crate::projected::{ProjectedMap, SensorRig};
use crate::rbpf::{Rbpf, RbpfParams};
use crate::scan::RangeScan;
use crate::vote::VoteSlam;
use nalgebra::Matrix3;
use smokenav_platform_config::{SlamBackendKind, SlamMode, SlamSection};
use smokenav_platform_map::OccupancyGrid;
use smokenav_shared_types::Pose2;
use std::path::Path;
use std::sync::Arc;

/// A scan the fusion withheld more than this share of beams from the laser
/// is not matched by a back-end's own scan matching: the particle filter
/// weighs its particles on it but does not refine them, the fuzzy
/// registration keeps the prediction. What is left is the laser's view past
/// the edge of the smoke, often one wall, and matching on it slid the pose
/// along that wall. Such scans keep the front end's heading-corrected pose
/// instead (its own threshold is [`crate::pipeline::MAX_WITHHELD_TO_MATCH`]).
/// Above the front end's 0.1 so that a scan with one of the Scout's
/// sections withheld (0.11 of the beams, as v2 keeps while its smoke sensor
/// warms up in clean air) is still matched.
///
/// Measured on four recordings of the dense-smoke trial, 8 seeds each, for
/// the RBPF: v2's mean map error / ATE went from 0.112 / 0.257 m (no gate)
/// to 0.098 / 0.113 m at 0.1, 0.092 / 0.099 m at 0.15 and 0.101 / 0.164 m
/// at 0.3; clean air stayed 0.033 m. For the fuzzy registration, on the
/// trial's recordings from simulator seeds 3, 5 and 7 (back-end seeds 1–4,
/// before the fuzzy map's evidence threshold rose to one reading's worth):
/// 0.161 / 0.364 / 0.166 m → 0.076 / 0.449 / 0.100 m, with the clean twins
/// unchanged (0.041–0.044 m). Seed 5 is the one whose odometry turned 20°
/// while the laser saw nothing: every back-end loses it.
///
/// Nor do such scans resample the particles: their weights come from the
/// sonar's coarse arcs and what the laser sees past the smoke, and
/// resampling on them through a blind stretch left the particles few
/// headings to offer when the laser came back. The weights carry on and
/// the first scan the laser sees again resamples on all of it. On three
/// recordings of the dense-smoke trial (the simulator's seeds 3, 5 and 7),
/// 8 filter seeds each, v2's mean map error went 0.097 / 0.401 / 0.159 m →
/// 0.084 / 0.400 / 0.158 m; their clean twins were unchanged (4 seeds).
pub const MAX_WITHHELD_TO_REFINE: f64 = 0.15;

/// A pose with the stamp of the scan it belongs to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StampedPose {
    pub stamp_ns: u64,
    pub pose: Pose2,
}

/// What a back-end reports after each scan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlamUpdate {
    /// Stamp of the scan.
    pub stamp_ns: u64,
    /// Best estimate of the robot pose in the map frame.
    pub pose: Pose2,
    /// Covariance of (x, y, θ) of the estimate (m², m·rad, rad²).
    pub covariance: Matrix3<f64>,
    /// Effective number of hypotheses behind the estimate (a particle
    /// filter's N_eff; 1 for a back-end that keeps one estimate).
    pub n_eff: f64,
    /// Hypotheses kept (particles; 1 for a single-estimate back-end).
    pub particles: usize,
    /// The scan was used (matched and weighed); false when only the odometry
    /// moved the estimate (the motion filter held the scan back).
    pub processed: bool,
    /// The filter resampled its particles at this scan.
    pub resampled: bool,
}

impl SlamUpdate {
    /// The covariance row-major, as `PoseEstimate::covariance` carries it.
    pub fn covariance_row_major(&self) -> [f64; 9] {
        let c = &self.covariance;
        std::array::from_fn(|i| c[(i / 3, i % 3)])
    }
}

/// A SLAM algorithm: scans and odometry in, poses and a map out. `odom` is
/// always the odometry pose of the robot at the scan's stamp, in a frame that
/// only jumps where [`SlamBackend::odometry_reset`] says so.
pub trait SlamBackend: Send {
    /// Short name for logs and health (`rbpf`).
    fn name(&self) -> &'static str;
    /// Uses one scan (the first one starts the map).
    fn process(&mut self, scan: &RangeScan, odom: &Pose2) -> SlamUpdate;
    /// The pipeline's front end matched the next scan: `process` or `predict`
    /// follows with `tracked.pose` as its odometry. A back-end that tracks
    /// scans itself can take this match (and its covariance) instead of
    /// matching the scan a second time. Default: ignored.
    fn frontend_match(&mut self, _tracked: &Tracked) {}
    /// A scan the motion filter held back: only its odometry moves the estimate.
    fn predict(&mut self, stamp_ns: u64, odom: &Pose2) -> SlamUpdate;
    /// The odometry frame jumped: the next odometry must not be compared with the last.
    fn odometry_reset(&mut self);
    /// Where the first scan is placed in the map frame (default: the origin).
    /// Only has an effect before the first scan.
    fn set_initial_pose(&mut self, pose: Pose2);
    /// An operator says where the robot is now (map frame), give or take
    /// `sigma` (m, rad; zero: not said): RViz's "2D Pose Estimate" on
    /// `/initialpose`, or `smokenav initial-pose`. A back-end localising on
    /// a saved map searches around it over its next scans until one matches
    /// (and the next confirms it); before the first scan any back-end starts there
    /// ([`SlamBackend::set_initial_pose`], the default). A back-end that is
    /// mapping refuses it after its first scan: moving the robot in a map
    /// half built from where it thought it was would tear that map.
    fn relocalize(&mut self, pose: Pose2, sigma: (f64, f64)) -> Result<(), RelocalizeError> {
        if !(pose.is_finite() && sigma.0.is_finite() && sigma.1.is_finite()) {
            return Err(RelocalizeError::NotFinite);
        }
        if self.pose().is_some() {
            return Err(RelocalizeError::Mapping(self.name()));
        }
        self.set_initial_pose(pose);
        Ok(())
    }
    /// The current best pose, once a scan was processed.
    fn pose(&self) -> Option<Pose2>;
    /// Changes whenever the map would export differently (a write, a
    /// resampling that picked another particle, a loop closure): cheap, so a
    /// caller can skip [`SlamBackend::map`] while it stays the same.
    fn map_revision(&self) -> u64;
    /// The current best map, once a scan was processed (an export: costs a copy).
    fn map(&self) -> Option<OccupancyGrid>;
    /// [`SlamBackend::map`] to be drawn on another thread: what it is drawn
    /// from is taken now, cheaply, and the job draws it. For a back-end whose
    /// map costs more than a scan period to draw (the graph re-draws every
    /// node's scan: 176 ms for MIT CSAIL's 933 nodes), so a process
    /// publishing maps does not hold up its scans meanwhile. `None`: the map
    /// is cheap, call [`SlamBackend::map`] in place.
    fn map_job(&self) -> Option<MapJob> {
        None
    }
    /// The fuzzy back-end's combined confidence map, min(max(u, Mo), 1 − Ms)
    /// scaled 0–100 (-1 where no reading reached); `None` for the others.
    fn confidence_map(&self) -> Option<OccupancyGrid> {
        None
    }
    /// Obstacles out of the laser plane (occupied; unknown elsewhere) on
    /// [`SlamBackend::map`]'s grid, for a back-end that maps in height (the
    /// projected map); `None` for the laser-plane ones.
    fn out_of_plane_map(&self) -> Option<OccupancyGrid> {
        None
    }
    /// The best estimate of the whole trajectory so far (smoothed where the
    /// back-end can; empty if it keeps no history).
    fn trajectory(&self) -> Vec<StampedPose>;
    /// The back-end's own counters (cheap: called for every health report),
    /// as `(name, value)`.
    fn metrics(&self, emit: &mut dyn FnMut(&'static str, f64));
    /// A condition the back-end is in that its process's health should name
    /// (and be degraded for), e.g. a localisation that matches nothing;
    /// `None` while all is well. The same text while the condition lasts.
    fn health_condition(&self) -> Option<String> {
        None
    }
    /// Writes the back-end's pose graph to `path` (2D g2o) and its nodes'
    /// scans beside it (`path.scans`), what `--load-graph` continues or
    /// localises on; `None` for a back-end that keeps no pose graph.
    fn save_graph(&self, path: &Path) -> Option<Result<(), SavedGraphError>> {
        let _ = path;
        None
    }
    /// For tools that know the concrete back-end (benches, summaries).
    fn as_any(&self) -> &dyn std::any::Any;
}

/// Why a pose given by an operator was not taken ([`SlamBackend::relocalize`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RelocalizeError {
    #[error(
        "the {0} back-end is building its map: a pose is taken before its first scan, or while localising on a saved map ([slam] mode = \"localization\")"
    )]
    Mapping(&'static str),
    #[error("the pose or its uncertainty is not a finite number")]
    NotFinite,
}

/// How a back-end is built beyond its `[slam]` keys.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BackendOptions {
    /// Keep the whole trajectory for [`SlamBackend::trajectory`] (offline
    /// runs; memory grows with the number of scans).
    pub keep_trajectory: bool,
    /// Online (the SLAM process): work that may take long runs beside the
    /// scan path, which never waits for it — the graph's loop-closure search
    /// and optimisation run on a thread of their own, and their correction
    /// is applied at a later scan. Off (offline runs, benches, tests): the
    /// same work runs inline on the scan that calls for it, deterministic.
    pub online: bool,
    /// The sensors in 3D (the robot profile's mounts at `[mapping]`'s
    /// heights), for the projected map; without them it maps the laser only.
    pub sensors: Option<Arc<SensorRig>>,
    /// Radius (m) of the robot's footprint to mark free along the
    /// trajectory in every exported map ([`export_map`]); 0 leaves maps as drawn.
    pub footprint_m: f64,
}

/// Draws a back-end's map away from its owner ([`SlamBackend::map_job`]).
pub type MapJob = Box<dyn FnOnce() -> Option<OccupancyGrid> + Send>;

/// Draws an exported map, footprint cleared, away from its owner
/// ([`export_map_job`]).
pub type ExportJob = Box<dyn FnOnce() -> Option<(OccupancyGrid, usize)> + Send>;

/// The back-end's map with the cells within `footprint_m` of its
/// trajectory marked free ([`OccupancyGrid::clear_footprint`]), and how many
/// of them read occupied before.
pub fn export_map(backend: &dyn SlamBackend, footprint_m: f64) -> Option<(OccupancyGrid, usize)> {
    let mut map = backend.map()?;
    let cleared = map.clear_footprint(
        footprint_path(backend, footprint_m),
        footprint_m,
        OCCUPIED_AT,
    );
    Some((map, cleared))
}

/// [`export_map`] as a job for another thread, for a back-end that offers
/// one ([`SlamBackend::map_job`]); `None` otherwise.
pub fn export_map_job(backend: &dyn SlamBackend, footprint_m: f64) -> Option<ExportJob> {
    let job = backend.map_job()?;
    let path = footprint_path(backend, footprint_m);
    Some(Box::new(move || {
        let mut map = job()?;
        let cleared = map.clear_footprint(path, footprint_m, OCCUPIED_AT);
        Some((map, cleared))
    }))
}

/// Cells (width, height) the back-end's map has at least, at `resolution`:
/// the extent of its trajectory as it stands (the map holds every place
/// the robot was, and what it saw around it besides). Cheap, unlike
/// drawing the map, so a map gone too large (a pose astray by kilometres)
/// can be refused before it is drawn. (0, 0) without a trajectory.
pub fn map_cells_at_least(backend: &dyn SlamBackend, resolution: f64) -> (usize, usize) {
    let mut poses = backend.trajectory().into_iter().map(|p| p.pose);
    let Some(first) = poses.next() else {
        return (0, 0);
    };
    let (mut lo, mut hi) = ((first.x, first.y), (first.x, first.y));
    for p in poses.filter(|p| p.x.is_finite() && p.y.is_finite()) {
        lo = (lo.0.min(p.x), lo.1.min(p.y));
        hi = (hi.0.max(p.x), hi.1.max(p.y));
    }
    // f64::min/max pass over a NaN; a span still NaN (no finite pose)
    // casts to 0 (float-to-int casts saturate).
    let cells = |span: f64| (span / resolution).floor() as usize + 1;
    (cells(hi.0 - lo.0), cells(hi.1 - lo.1))
}

/// The trajectory's positions, when a footprint is to be cleared along them
/// (none when not: [`OccupancyGrid::clear_footprint`] then clears nothing).
fn footprint_path(backend: &dyn SlamBackend, footprint_m: f64) -> Vec<(f64, f64)> {
    if footprint_m > 0.0 {
        backend
            .trajectory()
            .iter()
            .map(|p| (p.pose.x, p.pose.y))
            .collect()
    } else {
        Vec::new()
    }
}

/// The footprint radius to clear in exported maps ([`BackendOptions::footprint_m`]) for a
/// robot of `robot_radius_m` under `cfg` (`[slam] clear_footprint`):
/// `footprint_radius_m` when given, else the robot's radius less half a cell, so a cell the
/// robot's edge only brushed keeps a wall it may hold; 0 when off, and in localisation,
/// whose map stays as it was loaded.
pub fn footprint_radius(cfg: &SlamSection, robot_radius_m: f64) -> f64 {
    if !(cfg.clear_footprint && cfg.mode == SlamMode::Mapping) {
        return 0.0;
    }
    let r = if cfg.footprint_radius_m > 0.0 {
        cfg.footprint_radius_m
    } else {
        robot_radius_m - 0.5 * cfg.resolution_m
    };
    if r.is_finite() { r.max(0.0) } else { 0.0 }
}

/// The occupancy (0..100) a map's reader takes for a wall (map_server's threshold).
const OCCUPIED_AT: i8 = (smokenav_platform_map::OCCUPIED_THRESH * 100.0) as i8;

/// The back-end `[slam] backend` names, with its parameters from the section.
pub fn from_config(cfg: &SlamSection, opts: &BackendOptions) -> Box<dyn SlamBackend> {
    match cfg.backend {
        // The footprint is cleared along the best particle's path: kept then
        // online too (one shared node a scan, ~56 bytes).
        SlamBackendKind::Rbpf => Box::new(Rbpf::new(
            RbpfParams::from_config(cfg),
            opts.keep_trajectory || opts.footprint_m > 0.0,
        )),
        SlamBackendKind::Graph => {
            let mut g = GraphSlam::new(cfg, GraphParams::from_config(cfg));
            g.set_online(opts.online);
            Box::new(g)
        }
        SlamBackendKind::Fuzzy => Box::new(FuzzySlam::new(cfg, opts.keep_trajectory)),
        SlamBackendKind::Projected => {
            Box::new(ProjectedMap::new(cfg, opts.sensors.clone(), opts.online))
        }
        // A thread that cannot be spawned is the machine's failure, not the
        // input's (as `std::thread::spawn` itself treats it).
        SlamBackendKind::Vote => Box::new(
            VoteSlam::new(cfg, opts, None).expect("cannot start the vote's member threads"),
        ),
    }
}

#[cfg(test)]
mod footprint_tests {
    use super::*;

    #[test]
    fn a_wall_is_what_map_server_reads_as_occupied() {
        assert_eq!(OCCUPIED_AT, 65);
    }

    #[test]
    fn the_footprint_is_the_robot_less_half_a_cell_and_only_while_mapping() {
        let cfg = SlamSection::default();
        let r = footprint_radius(&cfg, 0.21);
        assert!((r - (0.21 - 0.5 * cfg.resolution_m)).abs() < 1e-12, "{r}");
        let off = SlamSection {
            clear_footprint: false,
            ..SlamSection::default()
        };
        assert_eq!(footprint_radius(&off, 0.21), 0.0);
        let localising = SlamSection {
            mode: SlamMode::Localization,
            ..SlamSection::default()
        };
        assert_eq!(footprint_radius(&localising, 0.21), 0.0);
        assert_eq!(footprint_radius(&cfg, f64::NAN), 0.0);
        assert_eq!(footprint_radius(&cfg, 0.01), 0.0);
        // A robot longer than wide gives its inscribed radius.
        let given = SlamSection {
            footprint_radius_m: 0.185,
            ..SlamSection::default()
        };
        assert_eq!(footprint_radius(&given, 0.26), 0.185);
    }
}
