//! The mapper: laser scans and sonar echoes, at the poses SLAM publishes,
//! into a 3D octree (Bayes, the map the robot keeps) and a fused 2D grid in
//! the laser plane; optionally also per-sensor maps, so the other fusion
//! rules can pool them for comparison.
//!
//! Each update follows OctoMap's `insertPointCloud`: the cells one sensor's
//! reading set marks free and occupied are gathered in two key sets first (so
//! a cell crossed by many beams in one scan is updated once, and occupied
//! wins over free), then applied with clamping. Sensors are independent, so
//! laser and sonar updates of one cell add (eq. 15 of the fusion paper).

use crate::grid::{GridGeometry, LogOddsGrid, ProbGrid, walk_cells};
use crate::ism::{LaserIsm, SonarIsm};
use crate::logodds::{ClampLogOdds, Clamping, logodds, probability};
use crate::octree::{KEY_ORIGIN, Key, Octree, pack, unpack};
use crate::rules::{FusionRule, Opinion, fuse};
use rustc_hash::{FxHashMap, FxHashSet};
use smokenav_platform_config::RobotConfig;
use smokenav_shared_types::geometry::Pose2;
use smokenav_shared_types::{LaserScan, SonarRing, SonarStatus};

/// Heights of the sensors and the robot above the floor, m. The robot
/// profiles give planar mounts only; these complete them for 3D.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Heights {
    /// The laser's scan plane.
    pub laser_m: f64,
    /// The sonar ring's axes.
    pub sonar_m: f64,
    /// The robot's top: anything below it blocks the robot.
    pub robot_m: f64,
}

impl Default for Heights {
    /// A Nomad Scout with its ring at 0.30 m and a URG-04LX on top at 0.40 m.
    fn default() -> Self {
        Self {
            laser_m: 0.40,
            sonar_m: 0.30,
            robot_m: 0.60,
        }
    }
}

/// A sensor's pose on the robot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mount {
    /// Planar pose in the base frame.
    pub pose: Pose2,
    /// Height above the floor, m.
    pub z: f64,
}

/// The sensors' geometry.
#[derive(Debug, Clone, PartialEq)]
pub struct Rig {
    pub laser: Mount,
    pub laser_range_m: [f64; 2],
    /// `(index, mount)` per transducer.
    pub sonars: Vec<(u8, Mount)>,
    pub sonar_cone_deg: f64,
    pub sonar_range_m: [f64; 2],
}

impl Rig {
    /// The robot profile's mounts (laser mount, sonar transducers) at `heights`.
    pub fn from_config(cfg: &RobotConfig, heights: &Heights) -> Self {
        let m = &cfg.laser.mount;
        let laser_range_m = cfg.laser.scan.map_or([0.02, 5.6], |s| {
            [
                s.range_min_mm as f64 / 1000.0,
                s.range_max_mm as f64 / 1000.0,
            ]
        });
        Self {
            laser: Mount {
                pose: Pose2::new(m.x, m.y, m.yaw_rad()),
                z: heights.laser_m,
            },
            laser_range_m,
            sonars: cfg
                .sonar
                .transducers
                .iter()
                .map(|t| {
                    (
                        t.index,
                        Mount {
                            pose: Pose2::new(t.x, t.y, t.yaw_deg.to_radians()),
                            z: heights.sonar_m,
                        },
                    )
                })
                .collect(),
            sonar_cone_deg: cfg.sonar.cone_deg,
            sonar_range_m: [cfg.sonar.min_range_m, cfg.sonar.max_range_m],
        }
    }

    fn sonar(&self, index: u8) -> Option<&Mount> {
        self.sonars
            .iter()
            .find(|(i, _)| *i == index)
            .map(|(_, m)| m)
    }
}

/// Mapping parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct MapParams {
    /// Voxel and cell side, m.
    pub resolution: f64,
    pub clamping: Clamping,
    pub laser: LaserIsm,
    /// Sonar cap thickness, m (at least one cell is used).
    pub sonar_thickness_m: f64,
    pub heights: Heights,
    /// Highest voxel the octree keeps, m (the floor is 0).
    pub ceiling_m: f64,
    /// The 2D grids' extent.
    pub grid_origin: [f64; 2],
    pub grid_size_m: [f64; 2],
    /// LOP/LIOP weights of laser and sonar (the paper weighs the sonar less).
    pub laser_weight: f64,
    pub sonar_weight: f64,
}

impl Default for MapParams {
    fn default() -> Self {
        Self {
            resolution: 0.05,
            clamping: Clamping::default(),
            laser: LaserIsm::default(),
            sonar_thickness_m: 0.08,
            heights: Heights::default(),
            ceiling_m: 2.0,
            grid_origin: [-20.0, -20.0],
            grid_size_m: [40.0, 40.0],
            laser_weight: 0.7,
            sonar_weight: 0.3,
        }
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MapperError {
    #[error("mapping.{key}: {reason}")]
    Param { key: &'static str, reason: String },
}

/// Which maps to keep.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MapSet {
    /// The Bayes octree and fused grid only (what runs on the robot).
    Bayes,
    /// Also one octree and one grid per sensor, for the other rules.
    Comparison,
}

#[derive(Debug, Clone)]
struct PerSensor {
    laser_tree: Octree,
    sonar_tree: Octree,
    laser_grid: LogOddsGrid,
    sonar_grid: LogOddsGrid,
}

/// One sensor's update, gathered before it is applied.
#[derive(Debug, Default)]
struct Scratch {
    free3: FxHashSet<u64>,
    occ3: FxHashSet<u64>,
    free2: FxHashSet<usize>,
    occ2: FxHashSet<usize>,
}

impl Scratch {
    fn clear(&mut self) {
        self.free3.clear();
        self.occ3.clear();
        self.free2.clear();
        self.occ2.clear();
    }
}

#[derive(Debug, Clone, Copy)]
enum Sensor {
    Laser,
    Sonar,
}

#[derive(Debug)]
pub struct Mapper {
    rig: Rig,
    params: MapParams,
    clamp: ClampLogOdds,
    sonar_ism: SonarIsm,
    joint_tree: Octree,
    joint_grid: LogOddsGrid,
    per_sensor: Option<Box<PerSensor>>,
    scratch: Scratch,
}

impl Mapper {
    pub fn new(rig: Rig, params: MapParams, set: MapSet) -> Result<Self, MapperError> {
        let bad = |key, reason: String| Err(MapperError::Param { key, reason });
        if !(params.resolution >= 0.01 && params.resolution <= 1.0) {
            return bad(
                "resolution_m",
                format!("must be 0.01–1 m, got {}", params.resolution),
            );
        }
        let c = params.clamping;
        if !(0.0 < c.min && c.min < 0.5 && 0.5 < c.max && c.max < 1.0) {
            return bad(
                "clamping",
                format!("need 0 < min < 0.5 < max < 1, got {} … {}", c.min, c.max),
            );
        }
        for (key, p) in [
            ("laser.p_free", params.laser.p_free),
            ("laser.p_occupied", params.laser.p_occupied),
        ] {
            if !(p > 0.0 && p < 1.0) {
                return bad(key, format!("must be inside (0, 1), got {p}"));
            }
        }
        let cells = |m: f64| (m / params.resolution).ceil();
        let (w, h) = (cells(params.grid_size_m[0]), cells(params.grid_size_m[1]));
        if !(w >= 1.0 && h >= 1.0 && w * h <= 64e6) {
            return bad(
                "grid_size_m",
                format!(
                    "{:?} at {} m is {w} × {h} cells (1 … 64 million)",
                    params.grid_size_m, params.resolution
                ),
            );
        }
        if !(rig.sonar_cone_deg > 0.0 && rig.sonar_cone_deg < 90.0) {
            return bad(
                "sonar.cone_deg",
                format!("must be inside (0, 90), got {}", rig.sonar_cone_deg),
            );
        }
        let geometry = GridGeometry {
            origin: params.grid_origin,
            resolution: params.resolution,
            width: w as usize,
            height: h as usize,
        };
        let clamp = ClampLogOdds::from(params.clamping);
        let mut sonar_ism = SonarIsm::new(rig.sonar_cone_deg);
        sonar_ism.thickness_m = params.sonar_thickness_m.max(params.resolution);
        let tree = Octree::new(params.resolution, clamp);
        let grid = LogOddsGrid::new(geometry, clamp);
        let per_sensor = (set == MapSet::Comparison).then(|| {
            Box::new(PerSensor {
                laser_tree: tree.clone(),
                sonar_tree: tree.clone(),
                laser_grid: grid.clone(),
                sonar_grid: grid.clone(),
            })
        });
        Ok(Self {
            rig,
            clamp,
            sonar_ism,
            joint_tree: tree,
            joint_grid: grid,
            per_sensor,
            scratch: Scratch::default(),
            params,
        })
    }

    pub fn params(&self) -> &MapParams {
        &self.params
    }

    pub fn rig(&self) -> &Rig {
        &self.rig
    }

    /// The Bayes octree.
    pub fn octree(&self) -> &Octree {
        &self.joint_tree
    }

    pub fn grid_geometry(&self) -> GridGeometry {
        self.joint_grid.geometry
    }

    /// A laser scan taken at robot pose `pose`.
    pub fn insert_scan(&mut self, pose: &Pose2, scan: &LaserScan) {
        self.insert_laser(
            pose,
            scan.beams()
                .map(|(a, r)| (a as f64, r.range().map(|r| r as f64))),
        );
    }

    /// Laser beams `(angle in the laser frame, range if measured)` at robot pose `pose`.
    pub fn insert_laser(
        &mut self,
        pose: &Pose2,
        beams: impl IntoIterator<Item = (f64, Option<f64>)>,
    ) {
        let s = pose.compose(&self.rig.laser.pose);
        let res = self.params.resolution;
        let geo = self.joint_grid.geometry;
        let Some(kz) = self.joint_tree.key_of(self.rig.laser.z) else {
            return;
        };
        let [rmin, rmax] = self.rig.laser_range_m;
        let mut sc = std::mem::take(&mut self.scratch);
        sc.clear();
        let o = [s.x, s.y];
        let tree_offset = [0.0, 0.0];
        for (angle, range) in beams {
            let Some(r) = range else { continue };
            if !(r.is_finite() && r >= rmin && r <= rmax) {
                continue;
            }
            let (sn, cs) = (s.theta + angle).sin_cos();
            let e = [s.x + r * cs, s.y + r * sn];
            // Thrun's model with α = one cell: crossed cells free, end cell occupied.
            let (ex, ey) = walk_cells(o, e, res, tree_offset, |cx, cy| {
                if let Some(k) = tree_key(cx, cy, kz) {
                    sc.free3.insert(pack(k));
                }
            });
            if let Some(k) = tree_key(ex, ey, kz) {
                sc.occ3.insert(pack(k));
            }
            let (ex, ey) = walk_cells(o, e, res, geo.origin, |cx, cy| {
                if let Some(i) = geo.index_of_cell(cx, cy) {
                    sc.free2.insert(i);
                }
            });
            if let Some(i) = geo.index_of_cell(ex, ey) {
                sc.occ2.insert(i);
            }
        }
        let (lf, lo) = (
            logodds(self.params.laser.p_free) as f32,
            logodds(self.params.laser.p_occupied) as f32,
        );
        self.apply(&sc, Sensor::Laser, lf, lo);
        self.scratch = sc;
    }

    /// A sonar ring at robot pose `pose` (valid echoes only; saturated and
    /// invalid readings say nothing).
    pub fn insert_ring(&mut self, pose: &Pose2, ring: &SonarRing) {
        self.insert_sonar(
            pose,
            ring.readings()
                .iter()
                .filter(|r| SonarStatus::from_u8(r.status) == SonarStatus::Valid)
                .map(|r| (r.index, r.range as f64)),
        );
    }

    /// Sonar echoes `(transducer index, range)` at robot pose `pose`.
    pub fn insert_sonar(&mut self, pose: &Pose2, echoes: impl IntoIterator<Item = (u8, f64)>) {
        let mut sc = std::mem::take(&mut self.scratch);
        sc.clear();
        for (index, range) in echoes {
            let Some(m) = self.rig.sonar(index).copied() else {
                continue;
            };
            let [rmin, rmax] = self.rig.sonar_range_m;
            if !(range.is_finite() && range >= rmin && range < rmax) {
                continue;
            }
            self.gather_cone(pose, &m, range, &mut sc);
        }
        let ism = self.sonar_ism;
        self.apply(
            &sc,
            Sensor::Sonar,
            logodds(ism.p_free) as f32,
            logodds(ism.p_occupied) as f32,
        );
        self.scratch = sc;
    }

    /// The voxels (and laser-plane cells) one cone marks.
    fn gather_cone(&self, pose: &Pose2, m: &Mount, range: f64, sc: &mut Scratch) {
        let s = pose.compose(&m.pose);
        let ism = &self.sonar_ism;
        let res = self.params.resolution;
        let reach = range + ism.thickness_m / 2.0;
        let (sn, cs) = s.theta.sin_cos();
        // The horizontal sector's bounding box: apex, both edges and the axis end.
        let half = ism.half_cone_rad;
        let mut lo = [s.x, s.y];
        let mut hi = [s.x, s.y];
        for a in [-half, -half / 2.0, 0.0, half / 2.0, half] {
            let (es, ec) = (s.theta + a).sin_cos();
            // 1/cos(half): the edge of the sector's arc reaches past `reach` along x/y.
            let r = reach / half.cos();
            for (i, v) in [s.x + r * ec, s.y + r * es].into_iter().enumerate() {
                lo[i] = lo[i].min(v);
                hi[i] = hi[i].max(v);
            }
        }
        let tree = &self.joint_tree;
        let geo = self.joint_grid.geometry;
        let z_floor = 0.0;
        let z_top = self.params.ceiling_m;
        let plane_dz = self.rig.laser.z - m.z;
        let key_lo = |c: f64| (c / res).floor() as i64;
        for cy in key_lo(lo[1])..=key_lo(hi[1]) {
            for cx in key_lo(lo[0])..=key_lo(hi[0]) {
                let (x, y) = ((cx as f64 + 0.5) * res, (cy as f64 + 0.5) * res);
                let (dx, dy) = (x - s.x, y - s.y);
                let a = dx * cs + dy * sn;
                let b = -dx * sn + dy * cs;
                let Some(dz_max) = ism.vertical_extent(a, b) else {
                    continue;
                };
                if a * a + b * b > reach * reach {
                    continue;
                }
                // Voxels of this column inside the cone, between floor and ceiling.
                let z0 = (m.z - dz_max).max(z_floor);
                let z1 = (m.z + dz_max).min(z_top);
                if z0 <= z1
                    && let (Some(k0), Some(k1)) = (tree.key_of(z0), tree.key_of(z1))
                {
                    for kz in k0..=k1 {
                        let z = tree.coord(kz);
                        if z < z_floor || z > z_top {
                            continue;
                        }
                        let Some(p) = ism.at([a, b, z - m.z], range) else {
                            continue;
                        };
                        if let Some(k) = tree_key(cx, cy, kz) {
                            if p > 0.5 {
                                sc.occ3.insert(pack(k));
                            } else {
                                sc.free3.insert(pack(k));
                            }
                        }
                    }
                }
            }
        }
        // The cone's slice at the laser's height, in the 2D grid.
        let (gc0, gc1) = (geo.cell(lo[0], lo[1]), geo.cell(hi[0], hi[1]));
        for gy in gc0.1..=gc1.1 {
            for gx in gc0.0..=gc1.0 {
                let Some(i) = geo.index_of_cell(gx, gy) else {
                    continue;
                };
                let (x, y) = geo.center(gx, gy);
                let (dx, dy) = (x - s.x, y - s.y);
                let a = dx * cs + dy * sn;
                let b = -dx * sn + dy * cs;
                if let Some(p) = ism.at([a, b, plane_dz], range) {
                    if p > 0.5 {
                        sc.occ2.insert(i);
                    } else {
                        sc.free2.insert(i);
                    }
                }
            }
        }
    }

    fn apply(&mut self, sc: &Scratch, sensor: Sensor, free: f32, occ: f32) {
        for &k in &sc.free3 {
            if !sc.occ3.contains(&k) {
                self.joint_tree.integrate_logodds(unpack(k), free);
            }
        }
        for &k in &sc.occ3 {
            self.joint_tree.integrate_logodds(unpack(k), occ);
        }
        for &i in &sc.free2 {
            if !sc.occ2.contains(&i) {
                self.joint_grid.add(i, free);
            }
        }
        for &i in &sc.occ2 {
            self.joint_grid.add(i, occ);
        }
        if let Some(ps) = self.per_sensor.as_deref_mut() {
            let (tree, grid) = match sensor {
                Sensor::Laser => (&mut ps.laser_tree, &mut ps.laser_grid),
                Sensor::Sonar => (&mut ps.sonar_tree, &mut ps.sonar_grid),
            };
            for &k in &sc.free3 {
                if !sc.occ3.contains(&k) {
                    tree.integrate_logodds(unpack(k), free);
                }
            }
            for &k in &sc.occ3 {
                tree.integrate_logodds(unpack(k), occ);
            }
            for &i in &sc.free2 {
                if !sc.occ2.contains(&i) {
                    grid.add(i, free);
                }
            }
            for &i in &sc.occ2 {
                grid.add(i, occ);
            }
        }
    }

    fn weights(&self) -> (f64, f64) {
        (self.params.laser_weight, self.params.sonar_weight)
    }

    /// The laser-only 2D grid (needs [`MapSet::Comparison`]).
    pub fn laser_grid(&self) -> Option<ProbGrid> {
        Some(self.per_sensor.as_ref()?.laser_grid.probabilities())
    }

    /// The fused 2D grid in the laser plane under `rule`. Bayes is always
    /// available; the other rules pool the per-sensor grids and need
    /// [`MapSet::Comparison`].
    pub fn fused_grid(&self, rule: FusionRule) -> Option<ProbGrid> {
        if rule == FusionRule::Bayes {
            return Some(self.joint_grid.probabilities());
        }
        let ps = self.per_sensor.as_ref()?;
        let (wl, ws) = self.weights();
        let geo = self.joint_grid.geometry;
        let mut out = ProbGrid::unknown(geo);
        for (i, p) in out.p.iter_mut().enumerate() {
            let (l, s) = (ps.laser_grid.logodds(i), ps.sonar_grid.logodds(i));
            if l == 0.0 && s == 0.0 {
                continue;
            }
            *p = fuse(
                rule,
                &[
                    Opinion::new(probability(l as f64), wl),
                    Opinion::new(probability(s as f64), ws),
                ],
            ) as f32;
        }
        Some(out)
    }

    /// The octree under `rule` projected to 2D: a column is occupied when any
    /// voxel from the floor to the robot's height is, free when it has a free
    /// voxel and no occupied one, unknown otherwise. The probability kept is
    /// the column's maximum.
    pub fn projected(&self, rule: FusionRule) -> Option<ProbGrid> {
        let top = self.params.heights.robot_m;
        let tree = &self.joint_tree;
        let (Some(kz0), Some(kz1)) = (tree.key_of(0.0), tree.key_of(top)) else {
            return None;
        };
        let in_band = |k: &Key| k[2] >= kz0 && k[2] <= kz1;
        let geo = self.joint_grid.geometry;
        let mut out = ProbGrid::unknown(geo);
        let mut put = |k: Key, p: f64| {
            let (x, y) = (tree.coord(k[0]), tree.coord(k[1]));
            if let Some(i) = geo.index(x, y) {
                let q = &mut out.p[i];
                if q.is_nan() || (p as f32) > *q {
                    *q = p as f32;
                }
            }
        };
        if rule == FusionRule::Bayes {
            tree.for_each_voxel(|k, l| {
                if in_band(&k) {
                    put(k, probability(l as f64));
                }
            });
            return Some(out);
        }
        let ps = self.per_sensor.as_ref()?;
        let mut both: FxHashMap<u64, (f32, f32)> = FxHashMap::default();
        ps.laser_tree.for_each_voxel(|k, l| {
            if in_band(&k) {
                both.entry(pack(k)).or_insert((0.0, 0.0)).0 = l;
            }
        });
        ps.sonar_tree.for_each_voxel(|k, l| {
            if in_band(&k) {
                both.entry(pack(k)).or_insert((0.0, 0.0)).1 = l;
            }
        });
        let (wl, ws) = self.weights();
        for (k, (l, s)) in both {
            let p = fuse(
                rule,
                &[
                    Opinion::new(probability(l as f64), wl),
                    Opinion::new(probability(s as f64), ws),
                ],
            );
            put(unpack(k), p);
        }
        Some(out)
    }

    /// Bytes a dense 3D grid of f32 log-odds would take for the box from
    /// `lo` to `hi` (m) at this resolution, floor to ceiling.
    pub fn dense_grid_bytes(&self, lo: [f64; 2], hi: [f64; 2]) -> usize {
        let n = |a: f64, b: f64| ((b - a) / self.params.resolution).ceil().max(0.0) as usize;
        n(lo[0], hi[0])
            * n(lo[1], hi[1])
            * n(0.0, self.params.ceiling_m)
            * std::mem::size_of::<f32>()
    }

    pub fn clamping(&self) -> ClampLogOdds {
        self.clamp
    }
}

/// An octree key from cell coordinates (cells of the tree's resolution from 0).
fn tree_key(cx: i64, cy: i64, kz: u16) -> Option<Key> {
    let k = |c: i64| {
        let v = c + KEY_ORIGIN;
        (0..=u16::MAX as i64).contains(&v).then_some(v as u16)
    };
    Some([k(cx)?, k(cy)?, kz])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::CellClass;

    fn rig() -> Rig {
        Rig {
            laser: Mount {
                pose: Pose2::new(0.0, 0.0, 0.0),
                z: 0.40,
            },
            laser_range_m: [0.02, 5.6],
            sonars: vec![(
                0,
                Mount {
                    pose: Pose2::new(0.0, 0.0, 0.0),
                    z: 0.30,
                },
            )],
            sonar_cone_deg: 20.0,
            sonar_range_m: [0.15, 6.0],
        }
    }

    fn mapper() -> Mapper {
        let params = MapParams {
            grid_origin: [-5.0, -5.0],
            grid_size_m: [10.0, 10.0],
            ..MapParams::default()
        };
        Mapper::new(rig(), params, MapSet::Comparison).unwrap()
    }

    #[test]
    fn a_laser_beam_frees_its_path_and_marks_its_end_in_grid_and_octree() {
        let mut m = mapper();
        m.insert_laser(&Pose2::new(0.0, 0.0, 0.0), [(0.0, Some(2.02))]);
        let g = m.fused_grid(FusionRule::Bayes).unwrap();
        let geo = g.geometry;
        assert_eq!(g.class(geo.index(2.02, 0.0).unwrap()), CellClass::Occupied);
        assert_eq!(g.class(geo.index(1.0, 0.0).unwrap()), CellClass::Free);
        assert_eq!(g.class(geo.index(3.0, 0.0).unwrap()), CellClass::Unknown);
        let t = m.octree();
        let k = t.key([2.02, 0.0, 0.40]).unwrap();
        assert!(t.search(k).unwrap() > 0.0);
        // Only the laser plane's layer is touched.
        assert_eq!(t.search(t.key([1.0, 0.0, 0.30]).unwrap()), None);
    }

    #[test]
    fn a_sonar_echo_from_below_the_laser_plane_shows_in_the_projection_only() {
        let mut m = mapper();
        let pose = Pose2::new(0.0, 0.0, 0.0);
        // A low box at 1.5 m: the laser passes over it (sees the wall at 4 m),
        // the sonar cone (down to 0.30 − 1.5 · tan 10° = 0.04 m) echoes off it.
        for _ in 0..3 {
            m.insert_laser(&pose, [(0.0, Some(4.0))]);
            m.insert_sonar(&pose, [(0, 1.5)]);
        }
        let laser = m.laser_grid().unwrap();
        let geo = laser.geometry;
        let at = |x: f64, y: f64| geo.index(x, y).unwrap();
        assert_eq!(laser.class(at(1.5, 0.0)), CellClass::Free);
        let proj = m.projected(FusionRule::Bayes).unwrap();
        assert_eq!(proj.class(at(1.5, 0.0)), CellClass::Occupied);
        assert_eq!(proj.class(at(0.8, 0.0)), CellClass::Free);
        // The same cell in the per-sensor comparison: IOP follows the sonar
        // where the laser never looked (other heights of the column).
        assert_eq!(
            m.projected(FusionRule::Iop).unwrap().class(at(1.5, 0.0)),
            CellClass::Occupied
        );
        // The cone's cap at 1.5 m spans ±0.26 m vertically: z 0.04–0.56.
        let t = m.octree();
        assert!(t.search(t.key([1.5, 0.0, 0.1]).unwrap()).unwrap() > 0.0);
        assert!(t.search(t.key([1.48, 0.0, 0.52]).unwrap()).unwrap() > 0.0);
        assert_eq!(t.search(t.key([1.5, 0.0, 0.7]).unwrap()), None);
    }

    #[test]
    fn saturated_or_unknown_transducers_change_nothing() {
        let mut m = mapper();
        m.insert_sonar(
            &Pose2::new(0.0, 0.0, 0.0),
            [(0, 6.0), (7, 1.0), (0, f64::NAN)],
        );
        assert_eq!(m.octree().node_count(), 1);
    }

    #[test]
    fn bad_parameters_name_their_key() {
        let p = MapParams {
            resolution: 0.0,
            ..MapParams::default()
        };
        let e = Mapper::new(rig(), p, MapSet::Bayes).unwrap_err();
        assert!(e.to_string().starts_with("mapping.resolution_m"), "{e}");
    }
}
