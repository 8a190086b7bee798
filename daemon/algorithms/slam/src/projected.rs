//! The laser and the sonar cones mapped in 3D at the pose the pipeline's
//! front end tracks, and projected to the floor: the Bayesian occupancy
//! mapper of seed 003 (`smokenav_algorithms_mapping`) as a back-end.
//!
//! Its poses are a pose graph's (an inner [`GraphSlam`], as RTAB-Map is a
//! graph SLAM with 3D maps); the 3D map is written at the graph's pose of
//! each scan and is not re-rendered after a loop closure. What it adds is height:
//! a column is an obstacle when anything between the floor and the robot's
//! top is, so a low box the laser passes over but the sonar cones hit is on
//! its map. In the vote (seed 004) it has RTAB-Map's role in SLAMfusion, the
//! member that "can easily detect other obstacles under and above the fake
//! laser scanner": [`ProjectedMap::out_of_plane_map`] says where, and the
//! laser-plane members abstain there (see `vote`).
//!
//! Only the sonar echoes the laser cannot account for are mapped: an echo
//! with laser returns in its cone, none of them within
//! [`OUT_OF_PLANE_MARGIN_M`] of the echo's range, comes from something out
//! of the laser's plane. The others (a wall both sensors see) only clear
//! the free space of their cones: their arcs, off a wall's line, would be
//! clutter no laser beam clears at the sonar's height.

use crate::backend::{SlamBackend, SlamUpdate, StampedPose};
use crate::frontend::Tracked;
use crate::graph::{GraphParams, GraphSlam};
use crate::scan::{BeamKind, RangeScan};
use smokenav_algorithms_mapping::{
    FusionRule, Heights, MapParams, MapSet, Mapper, Mount, ProbGrid, Rig,
};
use smokenav_platform_config::{RobotConfig, SlamSection};
use smokenav_platform_map::{OCCUPIED, OccupancyGrid, UNKNOWN};
use smokenav_shared_types::Pose2;
use std::sync::Arc;

/// Where the sensors sit in 3D: the profile's mounts at `[mapping]`'s heights.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorRig {
    pub rig: Rig,
    pub heights: Heights,
    /// Side of the square the map covers, centred on the first pose, m.
    pub size_m: f64,
    /// The highest floor obstacle the base drives over, m (`[mapping]`).
    pub climb_height_m: f64,
}

impl SensorRig {
    /// The robot profile's laser and sonar mounts at `[mapping]`'s heights and extent.
    pub fn from_config(cfg: &RobotConfig) -> Self {
        let m = &cfg.mapping;
        let heights = Heights {
            laser_m: m.laser_height_m,
            sonar_m: m.sonar_height_m,
            robot_m: m.robot_height_m,
        };
        Self {
            rig: Rig::from_config(cfg, &heights),
            heights,
            size_m: m.size_m,
            climb_height_m: m.climb_height_m,
        }
    }

    /// The ring's side transducers ([`crate::side_wall`]).
    pub fn side_sonars(&self) -> crate::side_wall::SideSonars {
        crate::side_wall::SideSonars::from_mounts(
            self.rig.sonars.iter().map(|(i, m)| (*i, m.pose)),
            self.rig.sonar_range_m[1],
        )
    }

    /// A laser at `mount` (0.40 m up) and no sonar: what is left without a profile.
    fn laser_only(mount: Pose2) -> Self {
        let heights = Heights::default();
        Self {
            rig: Rig {
                laser: Mount {
                    pose: mount,
                    z: heights.laser_m,
                },
                laser_range_m: [0.02, 5.6],
                sonars: Vec::new(),
                sonar_cone_deg: 20.0,
                sonar_range_m: [0.15, 5.0],
            },
            heights,
            size_m: 40.0,
            climb_height_m: 0.0,
        }
    }
}

/// Probability a projected column must reach to count as an obstacle out of
/// the laser plane: three echoes more than misses (OctoMap's hit, 0.7, is
/// +0.85 in log-odds), so a single crosstalk echo is not an obstacle.
const OUT_OF_PLANE_P: f32 = 0.9;
/// Probability below which the laser plane's cell is free: there the laser
/// passed, so an obstacle in the column lies above or below its plane.
const PLANE_FREE_P: f32 = 0.35;

/// A sonar echo is out of the laser's plane when the laser's returns in its
/// cone all lie farther than its range plus this, m.
pub const OUT_OF_PLANE_MARGIN_M: f64 = 0.3;

impl EchoGate {
    /// The echoes of `scan` the laser cannot account for, into `mapped`, the
    /// others into `cleared`.
    fn sort(&mut self, scan: &RangeScan, rig: &Rig) {
        self.mapped.clear();
        self.cleared.clear();
        self.endpoints.clear();
        let l = scan.sensor_pose;
        self.endpoints.extend(scan.beams.iter().filter_map(|b| {
            let r = f64::from(b.range?);
            if b.kind != BeamKind::Laser || !r.is_finite() {
                return None;
            }
            let a = f64::from(b.angle);
            Some(apply(&l, r * a.cos(), r * a.sin()))
        }));
        let half = rig.sonar_cone_deg.to_radians() / 2.0;
        for &(index, range) in &scan.sonar {
            let last = &mut self.last_range[usize::from(index)];
            if last.to_bits() == range.to_bits() {
                continue;
            }
            *last = range;
            let Some((_, m)) = rig.sonars.iter().find(|(i, _)| *i == index) else {
                continue;
            };
            if !(range >= rig.sonar_range_m[0] && range < rig.sonar_range_m[1]) {
                continue;
            }
            let inv = m.pose.inverse();
            let (mut inside, mut near) = (0usize, false);
            for &(x, y) in &self.endpoints {
                let (sx, sy) = apply(&inv, x, y);
                if sx <= 0.0 || sy.atan2(sx).abs() > half {
                    continue;
                }
                inside += 1;
                if sx.hypot(sy) <= range + OUT_OF_PLANE_MARGIN_M {
                    near = true;
                    break;
                }
            }
            if inside > 0 && !near && range <= self.floor_range_m {
                self.mapped.push((index, range));
            } else {
                self.cleared.push((index, range));
            }
        }
    }
}

/// The projected 3D map at a pose graph's poses.
pub struct ProjectedMap {
    resolution: f64,
    sensors: Option<Arc<SensorRig>>,
    mapper: Option<Mapper>,
    graph: GraphSlam,
    initial: Pose2,
    revision: u64,
    scans: u64,
    echoes: u64,
    /// Echoes mapped: those the laser could not account for.
    out_of_plane_echoes: u64,
    gate: EchoGate,
}

/// Sorts a scan's sonar echoes into those mapped as obstacles and those
/// whose free space alone is mapped.
struct EchoGate {
    /// Laser endpoints of the current scan in the robot frame (scratch).
    endpoints: Vec<(f64, f64)>,
    mapped: Vec<(u8, f64)>,
    /// The other echoes: their free space only (scratch).
    cleared: Vec<(u8, f64)>,
    /// Farther than this an echo may come from the floor or from what the
    /// base drives over: the cones' lower edge is that low there, m.
    floor_range_m: f64,
    /// The last range used per transducer: the ring repeats a transducer's
    /// reading until it fires again, and a repeat is not a new echo.
    last_range: [f64; 256],
}

impl ProjectedMap {
    /// `sensors`: the robot's rig in 3D (without it: the laser alone, at the
    /// scan's mount); `online`: the graph's loop closures run beside the scan path.
    pub fn new(cfg: &SlamSection, sensors: Option<Arc<SensorRig>>, online: bool) -> Self {
        let mut graph = GraphSlam::new(cfg, GraphParams::from_config(cfg));
        graph.set_online(online);
        Self {
            resolution: cfg.resolution_m,
            sensors,
            mapper: None,
            graph,
            initial: Pose2::default(),
            revision: 0,
            scans: 0,
            echoes: 0,
            out_of_plane_echoes: 0,
            gate: EchoGate {
                endpoints: Vec::new(),
                mapped: Vec::new(),
                cleared: Vec::new(),
                floor_range_m: f64::INFINITY,
                last_range: [f64::NAN; 256],
            },
        }
    }

    fn mapper_for(&mut self, scan: &RangeScan) -> Option<&mut Mapper> {
        if self.mapper.is_none() {
            let s = match &self.sensors {
                Some(s) => SensorRig::clone(s),
                None => SensorRig::laser_only(scan.sensor_pose),
            };
            let half = s.size_m / 2.0;
            let lower_edge = (s.rig.sonar_cone_deg.to_radians() / 2.0).tan();
            let drop = s.heights.sonar_m - s.climb_height_m;
            self.gate.floor_range_m = if lower_edge > 0.0 && drop > 0.0 {
                drop / lower_edge
            } else {
                0.0
            };
            let params = MapParams {
                resolution: self.resolution,
                heights: s.heights,
                grid_origin: [self.initial.x - half, self.initial.y - half],
                grid_size_m: [s.size_m, s.size_m],
                ..MapParams::default()
            };
            match Mapper::new(s.rig, params, MapSet::Bayes) {
                Ok(m) => self.mapper = Some(m),
                Err(e) => {
                    tracing::error!("projected map: {e}");
                    return None;
                }
            }
        }
        self.mapper.as_mut()
    }

    /// Obstacles out of the laser plane: occupied where the projected column
    /// is an obstacle but the laser's own cell is free (it passed over or
    /// under the obstacle), unknown elsewhere; on [`SlamBackend::map`]'s grid.
    pub fn out_of_plane_map(&self) -> Option<OccupancyGrid> {
        let (plane, below) = self.layers()?;
        let mut out = plane.to_occupancy_grid();
        for (o, b) in out.cells.iter_mut().zip(below) {
            *o = if b { OCCUPIED } else { UNKNOWN };
        }
        Some(out)
    }

    /// The laser plane's grid, and per cell whether it holds an obstacle
    /// out of that plane.
    fn layers(&self) -> Option<(ProbGrid, Vec<bool>)> {
        let m = self.mapper.as_ref()?;
        let projected = m.projected(FusionRule::Bayes)?;
        let plane = m.fused_grid(FusionRule::Bayes)?;
        let below = projected
            .p
            .iter()
            .zip(&plane.p)
            .map(|(&p, &q)| p >= OUT_OF_PLANE_P && q < PLANE_FREE_P)
            .collect();
        Some((plane, below))
    }
}

impl SlamBackend for ProjectedMap {
    fn name(&self) -> &'static str {
        "projected"
    }

    fn process(&mut self, scan: &RangeScan, odom: &Pose2) -> SlamUpdate {
        let u = self.graph.process(scan, odom);
        let pose = u.pose;
        if self.mapper_for(scan).is_none() {
            return u;
        }
        let (Some(m), gate) = (self.mapper.as_mut(), &mut self.gate) else {
            return u;
        };
        gate.sort(scan, m.rig());
        // Only what the laser itself measured: sonar-painted and withheld
        // beams say nothing about the laser's plane.
        m.insert_laser(
            &pose,
            scan.beams
                .iter()
                .filter(|b| b.kind == BeamKind::Laser)
                .map(|b| (f64::from(b.angle), b.range.map(f64::from))),
        );
        m.insert_sonar(&pose, gate.mapped.iter().copied());
        m.insert_sonar_free(&pose, gate.cleared.iter().copied());
        self.scans += 1;
        self.echoes += scan.sonar.len() as u64;
        self.out_of_plane_echoes += gate.mapped.len() as u64;
        self.revision += 1;
        u
    }

    fn frontend_match(&mut self, tracked: &Tracked) {
        self.graph.frontend_match(tracked);
    }

    fn predict(&mut self, stamp_ns: u64, odom: &Pose2) -> SlamUpdate {
        self.graph.predict(stamp_ns, odom)
    }

    fn odometry_reset(&mut self) {
        self.graph.odometry_reset();
    }

    fn set_initial_pose(&mut self, pose: Pose2) {
        if self.mapper.is_none() {
            self.initial = pose;
        }
        self.graph.set_initial_pose(pose);
    }

    fn pose(&self) -> Option<Pose2> {
        self.graph.pose()
    }

    fn map_revision(&self) -> u64 {
        self.revision
    }

    /// The laser plane's grid with the obstacles out of it (the projection
    /// of what the gated echoes confirmed; see [`ProjectedMap::out_of_plane_map`]).
    fn map(&self) -> Option<OccupancyGrid> {
        let (plane, below) = self.layers()?;
        let mut out = plane.to_occupancy_grid();
        for (o, b) in out.cells.iter_mut().zip(below) {
            if b {
                *o = OCCUPIED;
            }
        }
        Some(out)
    }

    fn out_of_plane_map(&self) -> Option<OccupancyGrid> {
        ProjectedMap::out_of_plane_map(self)
    }

    fn trajectory(&self) -> Vec<StampedPose> {
        self.graph.trajectory()
    }

    fn metrics(&self, emit: &mut dyn FnMut(&'static str, f64)) {
        self.graph.metrics(emit);
        emit("projected_scans", self.scans as f64);
        emit("projected_sonar_echoes", self.echoes as f64);
        emit(
            "projected_out_of_plane_echoes",
            self.out_of_plane_echoes as f64,
        );
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

/// `p` applied to the point (x, y).
fn apply(p: &Pose2, x: f64, y: f64) -> (f64, f64) {
    let (s, c) = p.theta.sin_cos();
    (p.x + c * x - s * y, p.y + s * x + c * y)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testkit::scan_at;

    fn scout() -> ProjectedMap {
        let profile = RobotConfig::builtin("nomad-scout").unwrap();
        ProjectedMap::new(
            &SlamSection::default(),
            Some(Arc::new(SensorRig::from_config(&profile))),
            false,
        )
    }

    /// Scans at `at` in the test room, the front sonar (0) hearing `ranges` in turn.
    fn feed(p: &mut ProjectedMap, at: Pose2, ranges: &[f64]) {
        for (i, &r) in ranges.iter().enumerate() {
            let mut s = scan_at(&at, 1_000_000_000 + i as u64 * 100_000_000);
            s.sonar.push((0, r));
            p.process(&s, &at);
        }
    }

    fn out_of_plane_cells(p: &ProjectedMap) -> Vec<(f64, f64)> {
        p.out_of_plane_map().unwrap().occupied_points(OCCUPIED)
    }

    // 3.5 m along the room, facing +x: the laser sees the end wall 1.5 m
    // ahead (1.31 m from the front sonar, 0.19 m ahead of the centre).
    const AT: Pose2 = Pose2 {
        x: 3.5,
        y: -1.5,
        theta: 0.0,
    };

    #[test]
    fn an_echo_the_laser_cannot_account_for_is_an_obstacle_out_of_its_plane() {
        let mut p = scout();
        feed(&mut p, AT, &[0.80, 0.801, 0.802, 0.803, 0.804, 0.805]);
        let cells = out_of_plane_cells(&p);
        assert!(!cells.is_empty());
        // On the echo's arc, 0.8 m ahead of the sonar (the first scan is the
        // map's origin).
        assert!(
            cells.iter().all(|&(x, y)| {
                let d = (x - 0.19).hypot(y);
                (d - 0.8).abs() < 0.15
            }),
            "{cells:?}"
        );
        let mut metrics = Vec::new();
        p.metrics(&mut |k, v| metrics.push((k, v)));
        assert!(
            metrics.contains(&("projected_out_of_plane_echoes", 6.0)),
            "{metrics:?}"
        );
    }

    #[test]
    fn an_echo_from_the_wall_the_laser_sees_is_not() {
        let mut p = scout();
        feed(&mut p, AT, &[1.31, 1.311, 1.312, 1.313, 1.314, 1.315]);
        assert!(out_of_plane_cells(&p).is_empty());
    }

    #[test]
    fn a_reading_the_ring_repeats_is_one_echo_not_an_obstacle() {
        let mut p = scout();
        feed(&mut p, AT, &[0.8; 6]);
        assert!(out_of_plane_cells(&p).is_empty(), "one echo is below 0.9");
    }

    #[test]
    fn an_echo_beyond_where_the_cone_meets_the_floor_is_not_mapped() {
        // The ring at 0.30 m, a 20° cone: its lower edge meets the floor
        // 1.70 m out, where the floor itself (or a cable) may answer.
        let mut p = scout();
        let at = Pose2::new(0.5, -1.5, 0.0);
        feed(&mut p, at, &[1.9, 1.901, 1.902, 1.903, 1.904, 1.905]);
        assert!(out_of_plane_cells(&p).is_empty());
        let mut near = scout();
        feed(&mut near, at, &[1.5, 1.501, 1.502, 1.503, 1.504, 1.505]);
        assert!(!out_of_plane_cells(&near).is_empty(), "nearer, it is");
    }
}
