//! The mapper: laser scans and sonar echoes, at the poses SLAM publishes,
//! into a 3D octree (Bayes, the map the robot keeps) and a fused 2D grid in
//! the laser plane; optionally also per-sensor maps, so the other fusion
//! rules can pool them for comparison.
//!
//! A scan follows OctoMap's `insertPointCloud`: the cells its beams mark
//! free and occupied are gathered first (so a cell crossed by many beams in
//! one scan is updated once, and occupied wins over free), then applied with
//! clamping. Each sonar echo updates its own cone. Sensors are independent,
//! so laser and sonar updates of one cell add (Tran et al. 2021, eq. 15).
//! The laser's voxels are the 2D grid's cells at the laser's height, so both
//! maps cover the grid's extent (`grid_origin`, `grid_size_m`).

use crate::grid::{GridGeometry, LogOddsGrid, ProbGrid, walk_cells};
use crate::ism::{LaserIsm, SonarIsm};
use crate::logodds::{ClampLogOdds, Clamping, logodds, probability};
use crate::octree::{KEY_ORIGIN, Key, Octree, pack, unpack};
use crate::rules::{FusionRule, Opinion, fuse};
use rustc_hash::FxHashMap;
use smokenav_platform_config::RobotConfig;
use smokenav_shared_types::geometry::{Pose2, Sweep, Twist2};
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
    /// Sonar echoes farther than this are not mapped, m (2.5 m, the sonar
    /// cap the fusion layer also uses).
    pub sonar_map_range_m: f64,
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
            sonar_map_range_m: 2.5,
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

/// One scan's cells, gathered before they are applied: stamps say whether
/// a cell is already listed in this scan (no hashing, no allocation once
/// the lists have grown).
#[derive(Debug, Default)]
struct Scratch {
    generation: u32,
    free_stamp: Vec<u32>,
    occ_stamp: Vec<u32>,
    free: Vec<usize>,
    occ: Vec<usize>,
}

impl Scratch {
    fn start(&mut self, cells: usize) {
        if self.free_stamp.len() != cells {
            self.free_stamp = vec![0; cells];
            self.occ_stamp = vec![0; cells];
            self.generation = 0;
        }
        self.generation = self.generation.wrapping_add(1);
        if self.generation == 0 {
            self.free_stamp.fill(0);
            self.occ_stamp.fill(0);
            self.generation = 1;
        }
        self.free.clear();
        self.occ.clear();
    }

    fn mark_free(&mut self, i: usize) {
        if self.free_stamp[i] != self.generation {
            self.free_stamp[i] = self.generation;
            self.free.push(i);
        }
    }

    fn mark_occupied(&mut self, i: usize) {
        if self.occ_stamp[i] != self.generation {
            self.occ_stamp[i] = self.generation;
            self.occ.push(i);
        }
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
        // On the octree's lattice, so a grid cell is the laser plane's voxel column.
        let snap = |v: f64| (v / params.resolution).floor() * params.resolution;
        let geometry = GridGeometry {
            origin: [snap(params.grid_origin[0]), snap(params.grid_origin[1])],
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

    /// A laser scan taken at robot pose `pose` (the pose at its stamp, the
    /// first beam) while the robot moved at `twist`: each beam goes where
    /// the sweep's first beam would have seen it ([`Sweep`]), so a turning
    /// robot's walls do not bend. Says whether it was deskewed: a scan
    /// without a plausible `time_increment` goes in as taken at once.
    pub fn insert_sweep(&mut self, pose: &Pose2, scan: &LaserScan, twist: Twist2) -> bool {
        let Some(sweep) = scan
            .sweep_time_increment()
            .and_then(|dt| Sweep::new(self.rig.laser.pose, twist, dt))
        else {
            self.insert_scan(pose, scan);
            return false;
        };
        self.insert_laser(
            pose,
            scan.beams().enumerate().map(|(i, (a, r))| {
                let a = f64::from(a);
                match r.range() {
                    Some(r) => {
                        let (a, r) = sweep.beam(i, a, f64::from(r));
                        (a, Some(r))
                    }
                    None => (a, None),
                }
            }),
        );
        true
    }

    /// Laser beams `(angle in the laser frame, range if measured)` at robot pose `pose`.
    pub fn insert_laser(
        &mut self,
        pose: &Pose2,
        beams: impl IntoIterator<Item = (f64, Option<f64>)>,
    ) {
        let s = pose.compose(&self.rig.laser.pose);
        if !s.is_finite() {
            return;
        }
        let res = self.params.resolution;
        let geo = self.joint_grid.geometry;
        let Some(kz) = self.joint_tree.key_of(self.rig.laser.z) else {
            return;
        };
        let [rmin, rmax] = self.rig.laser_range_m;
        let mut sc = std::mem::take(&mut self.scratch);
        sc.start(geo.len());
        let o = [s.x, s.y];
        for (angle, range) in beams {
            let Some(r) = range else { continue };
            if !(r.is_finite() && r >= rmin && r <= rmax) {
                continue;
            }
            if !angle.is_finite() {
                continue;
            }
            let (sn, cs) = (s.theta + angle).sin_cos();
            let e = [s.x + r * cs, s.y + r * sn];
            // Thrun's model with α = one cell: crossed cells free, end cell occupied.
            let (ex, ey) = walk_cells(o, e, res, geo.origin, |cx, cy| {
                if let Some(i) = geo.index_of_cell(cx, cy) {
                    sc.mark_free(i);
                }
            });
            if let Some(i) = geo.index_of_cell(ex, ey) {
                sc.mark_occupied(i);
            }
        }
        let free = logodds(self.params.laser.p_free) as f32;
        let occ = logodds(self.params.laser.p_occupied) as f32;
        // Row by row, neighbours share most of their octree path (the search
        // starts where the last one's path parts).
        sc.free.sort_unstable();
        let col = self.column_keys();
        for k in 0..sc.free.len() + sc.occ.len() {
            let (i, delta) = if k < sc.free.len() {
                let i = sc.free[k];
                if sc.occ_stamp[i] == sc.generation {
                    continue; // occupied wins within a scan
                }
                (i, free)
            } else {
                (sc.occ[k - sc.free.len()], occ)
            };
            let key = col(i, kz);
            self.apply(Sensor::Laser, key, Some(i), delta);
        }
        self.scratch = sc;
    }

    /// The octree key of grid cell `i` at height key `kz`.
    fn column_keys(&self) -> impl Fn(usize, u16) -> Option<Key> + use<> {
        let geo = self.joint_grid.geometry;
        let res = self.params.resolution;
        let x0 = (geo.origin[0] / res).round() as i64;
        let y0 = (geo.origin[1] / res).round() as i64;
        let w = geo.width;
        move |i, kz| tree_key(x0 + (i % w) as i64, y0 + (i / w) as i64, kz)
    }

    /// One update of one sensor: the octree voxel `key` (if any) and the
    /// laser-plane cell `cell` (if any), in the joint maps and, when kept,
    /// that sensor's own.
    fn apply(&mut self, sensor: Sensor, key: Option<Key>, cell: Option<usize>, delta: f32) {
        if let Some(k) = key {
            self.joint_tree.integrate_logodds(k, delta);
        }
        if let Some(i) = cell {
            self.joint_grid.add(i, delta);
        }
        if let Some(ps) = self.per_sensor.as_deref_mut() {
            let (tree, grid) = match sensor {
                Sensor::Laser => (&mut ps.laser_tree, &mut ps.laser_grid),
                Sensor::Sonar => (&mut ps.sonar_tree, &mut ps.sonar_grid),
            };
            if let Some(k) = key {
                tree.integrate_logodds(k, delta);
            }
            if let Some(i) = cell {
                grid.add(i, delta);
            }
        }
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

    /// Sonar echoes `(transducer index, range)` at robot pose `pose`. Each
    /// echo updates its cone directly (a 20° cone on a ring at 22.5° steps
    /// overlaps no neighbour, so there is nothing to merge). Echoes beyond
    /// `sonar_map_range_m` say nothing: far cones are wide, mostly guessed, and
    /// would cost tens of thousands of voxels each.
    pub fn insert_sonar(&mut self, pose: &Pose2, echoes: impl IntoIterator<Item = (u8, f64)>) {
        self.insert_echoes(pose, echoes, true);
    }

    /// Sonar echoes whose obstacle is mapped already (another sensor saw
    /// it): only the free space inside each cone, short of the echo's cap.
    pub fn insert_sonar_free(&mut self, pose: &Pose2, echoes: impl IntoIterator<Item = (u8, f64)>) {
        self.insert_echoes(pose, echoes, false);
    }

    fn insert_echoes(
        &mut self,
        pose: &Pose2,
        echoes: impl IntoIterator<Item = (u8, f64)>,
        cap: bool,
    ) {
        if !pose.is_finite() {
            return;
        }
        let [rmin, rmax] = self.rig.sonar_range_m;
        let rmax = rmax.min(self.params.sonar_map_range_m);
        for (index, range) in echoes {
            let Some(m) = self.rig.sonar(index).copied() else {
                continue;
            };
            if !(range.is_finite() && range >= rmin && range < rmax) {
                continue;
            }
            self.insert_cone(pose, &m, range, cap);
        }
    }

    /// The voxels (and laser-plane cells) one cone marks; without `cap`,
    /// only its free space.
    fn insert_cone(&mut self, pose: &Pose2, m: &Mount, range: f64, cap: bool) {
        let s = pose.compose(&m.pose);
        let ism = self.sonar_ism;
        let reach = range + ism.thickness_m / 2.0;
        let (sn, cs) = s.theta.sin_cos();
        // The horizontal sector's bounding box: apex, edges and axis end.
        let half = ism.half_cone_rad;
        let mut lo = [s.x, s.y];
        let mut hi = [s.x, s.y];
        for a in [-half, -half / 2.0, 0.0, half / 2.0, half] {
            let (es, ec) = (s.theta + a).sin_cos();
            let r = reach / half.cos();
            for (i, v) in [s.x + r * ec, s.y + r * es].into_iter().enumerate() {
                lo[i] = lo[i].min(v);
                hi[i] = hi[i].max(v);
            }
        }
        let geo = self.joint_grid.geometry;
        let (z_floor, z_top) = (0.0, self.params.ceiling_m);
        let plane_dz = self.rig.laser.z - m.z;
        let (free, occ) = (logodds(ism.p_free) as f32, logodds(ism.p_occupied) as f32);
        let half_t = ism.thickness_m / 2.0;
        let slice_occ = logodds(ism.slice_p_occupied(range, self.params.resolution)) as f32;
        let col = self.column_keys();
        let (c0, c1) = (geo.cell(lo[0], lo[1]), geo.cell(hi[0], hi[1]));
        for gy in c0.1..=c1.1 {
            for gx in c0.0..=c1.0 {
                let Some(i) = geo.index_of_cell(gx, gy) else {
                    continue;
                };
                let (x, y) = geo.center(gx, gy);
                let (dx, dy) = (x - s.x, y - s.y);
                let a = dx * cs + dy * sn;
                let b = -dx * sn + dy * cs;
                if a * a + b * b > reach * reach {
                    continue;
                }
                let Some(dz_max) = ism.vertical_extent(a, b) else {
                    continue;
                };
                // The column's voxels inside the cone, floor to ceiling.
                let z0 = (m.z - dz_max).max(z_floor);
                let z1 = (m.z + dz_max).min(z_top);
                if z0 <= z1
                    && let (Some(k0), Some(k1)) =
                        (self.joint_tree.key_of(z0), self.joint_tree.key_of(z1))
                {
                    // Inside the cone by construction (|dz| ≤ dz_max): only
                    // the distance decides (`SonarIsm::at` without its cone test).
                    let h2 = a * a + b * b;
                    for kz in k0..=k1 {
                        let dz = self.joint_tree.coord(kz) - m.z;
                        if dz.abs() > dz_max || !(z_floor..=z_top).contains(&(dz + m.z)) {
                            continue;
                        }
                        let d = (h2 + dz * dz).sqrt();
                        let upd = if d < range - half_t {
                            free
                        } else if cap && d <= range + half_t {
                            occ
                        } else {
                            continue;
                        };
                        let key = col(i, kz);
                        self.apply(Sensor::Sonar, key, None, upd);
                    }
                }
                // The cone's slice at the laser's height, in the 2D grid.
                if let Some(p) = ism.at([a, b, plane_dz], range)
                    && (cap || p <= 0.5)
                {
                    let d = if p > 0.5 { slice_occ } else { free };
                    self.apply(Sensor::Sonar, None, Some(i), d);
                }
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
    use smokenav_shared_types::BeamReading;

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

    /// The URG-04LX's scan of a wall across x = `wall` (m) from a robot at
    /// the origin turning at `w` rad/s: 682 beams over 240° in 67 ms, each
    /// measured from where the laser had turned to by then.
    fn turning_scan(wall: f64, w: f64) -> LaserScan {
        let mut scan = LaserScan {
            angle_min: -120f32.to_radians(),
            angle_increment: 240f32.to_radians() / 681.0,
            time_increment: 67e-3 / 682.0,
            range_min: 0.02,
            range_max: 5.6,
            count: 682,
            ..Default::default()
        };
        for i in 0..682 {
            let heading = w * i as f64 * f64::from(scan.time_increment);
            let a = f64::from(scan.angle(i)) + heading;
            let r = wall / a.cos();
            scan.set_beam(
                i,
                if a.cos() > 0.0 && r < 5.6 {
                    BeamReading::Range(r as f32)
                } else {
                    BeamReading::NoReturn
                },
            );
        }
        scan
    }

    /// Occupied cells of the fused grid and how many of them lie more than a
    /// cell off the wall across x = `wall`.
    fn off_the_wall(m: &Mapper, wall: f64) -> (usize, usize) {
        let g = m.fused_grid(FusionRule::Bayes).unwrap();
        let geo = g.geometry;
        let occupied: Vec<f64> = (0..geo.len())
            .filter(|&i| g.class(i) == CellClass::Occupied)
            .map(|i| geo.origin[0] + ((i % geo.width) as f64 + 0.5) * geo.resolution)
            .collect();
        let off = occupied
            .iter()
            .filter(|&&x| (x - wall).abs() > geo.resolution)
            .count();
        (occupied.len(), off)
    }

    #[test]
    fn a_sweep_taken_while_turning_maps_a_straight_wall_once_deskewed() {
        let (wall, w) = (3.0, 1.0);
        let scan = turning_scan(wall, w);
        let origin = Pose2::new(0.0, 0.0, 0.0);
        let mut skewed = mapper();
        skewed.insert_scan(&origin, &scan);
        let (n, off) = off_the_wall(&skewed, wall);
        // Beams 50° off the axis are taken 2.6° round, 0.3 m off the wall.
        assert!(n > 50 && off > n / 4, "{off} of {n} cells off the wall");
        let mut deskewed = mapper();
        assert!(deskewed.insert_sweep(&origin, &scan, Twist2::new(0.0, 0.0, w)));
        let (n, off) = off_the_wall(&deskewed, wall);
        assert!(n > 50 && off == 0, "{off} of {n} cells off the wall");
        // Without a plausible time increment the beams count as taken at once.
        let mut at_once = mapper();
        let mut garbage = scan;
        garbage.time_increment = f32::NAN;
        assert!(!at_once.insert_sweep(&origin, &garbage, Twist2::new(0.0, 0.0, w)));
        assert_eq!(off_the_wall(&at_once, wall), off_the_wall(&skewed, wall));
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
    fn an_echo_inserted_as_free_space_clears_its_cone_and_marks_no_cap() {
        let mut m = mapper();
        let pose = Pose2::new(0.0, 0.0, 0.0);
        for _ in 0..3 {
            m.insert_sonar_free(&pose, [(0, 1.5)]);
        }
        let proj = m.projected(FusionRule::Bayes).unwrap();
        let geo = proj.geometry;
        let at = |x: f64, y: f64| geo.index(x, y).unwrap();
        assert_eq!(proj.class(at(0.8, 0.0)), CellClass::Free);
        assert_eq!(proj.class(at(1.5, 0.0)), CellClass::Unknown, "no cap");
        let t = m.octree();
        assert_eq!(t.search(t.key([1.5, 0.0, 0.3]).unwrap()), None);
        assert!(t.search(t.key([1.0, 0.0, 0.3]).unwrap()).unwrap() < 0.0);
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
    fn non_finite_poses_angles_and_ranges_change_nothing() {
        let mut m = mapper();
        let nan = f64::NAN;
        m.insert_laser(&Pose2::new(nan, 0.0, 0.0), [(0.0, Some(2.0))]);
        m.insert_laser(&Pose2::new(0.0, 0.0, f64::INFINITY), [(0.0, Some(2.0))]);
        m.insert_laser(
            &Pose2::default(),
            [(nan, Some(2.0)), (0.0, Some(nan)), (0.0, Some(-1.0))],
        );
        m.insert_sonar(&Pose2::new(0.0, nan, 0.0), [(0, 1.0)]);
        assert_eq!(m.octree().node_count(), 1);
        let g = m.fused_grid(FusionRule::Bayes).unwrap();
        assert!(g.p.iter().all(|p| p.is_nan()), "no cell observed");
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
