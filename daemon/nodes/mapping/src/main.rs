//! `smokenav-mapping`: the 2D/3D occupancy mapping library as a process.
//!
//! Subscribes to `slam/pose`, `laser/scan`, `base/sonar` and `base/odom`;
//! pairs every scan and sonar ring with the SLAM pose nearest to it in time
//! (the pose of a scan carries that scan's stamp, so a scan usually finds
//! its own), deskews each laser sweep by the odometry's velocity at its
//! stamp (as the SLAM pipeline does; `[slam] deskew`), and inserts them
//! into the mapper of `smokenav-algorithms-mapping`: the Bayes
//! octree and the fused 2D grid in the laser plane. At `[mapping]
//! publish_rate_hz` it publishes the fused grid on `mapping/grid`, the
//! octree projected to 2D (everything under the robot's height) on
//! `mapping/projected`, both under `[mapping] rule`, and the occupied voxels
//! on `mapping/voxels` (at most `MAX_VOXELS`, the rest counted). SIGUSR1
//! writes the octree as `octree.bt` (OctoMap's format) to `--map-dir` (else
//! `[mapping] map_dir`) and counts it in health's `octree_saves`: that is
//! how `smokenav map save` gets the 3D map (it signals the pid of
//! `health/mapping`, waits for the count to move and copies the file).
//! The sensors' and the robot's heights are `[mapping]` keys.
//!
//! A process of its own rather than a part of the SLAM process: the octree
//! update and the projection take milliseconds the pose estimate should not
//! wait for, and the map is built from the published poses whichever SLAM
//! back-end made them. Input waits in bounded buffers (`PENDING` scans and
//! rings); when no pose comes, the oldest are dropped and counted.
//!
//! ```text
//! smokenav-mapping --config robot.toml [--map-dir DIR]
//! ```

use anyhow::Context;
use clap::Parser;
use smokenav_algorithms_mapping::{
    FusionRule, Heights, MapParams, MapSet, Mapper, Octree, ProbGrid, Rig,
};
use smokenav_platform_bus::{MapPublisher, Publisher, WaitOutcome, Waiter, topics};
use smokenav_platform_config::{MappingRule, MappingSection};
use smokenav_platform_runtime::{CommonArgs, Process};
use smokenav_shared_types::geometry::{Pose2, Twist2};
use smokenav_shared_types::{
    Header, LaserScan, MAX_VOXELS, MapInfo, Odometry, PoseEstimate, SonarRing, VoxelCloud,
};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(
    version,
    about = "Mapping: slam/pose, laser, sonar and odometry in; mapping/grid, mapping/projected, mapping/voxels out"
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// Folder SIGUSR1 (and `smokenav map save`) writes the octree to, as
    /// octree.bt [default: the profile's `[mapping] map_dir`, else .].
    #[arg(long, value_name = "DIR")]
    map_dir: Option<PathBuf>,
}

/// Longest wait on the bus, so signals and the publishing timer are served promptly.
const POLL: Duration = Duration::from_millis(50);
/// Scans and rings waiting for a pose at most (a second of 10 Hz scans).
const PENDING: usize = 10;
/// A scan or ring farther than this in time from every pose is not mapped.
const POSE_TOLERANCE_NS: u64 = 150_000_000;
/// Odometry velocities kept for deskewing (over a second and a half at the
/// drivers' 10–20 Hz: longer than a scan waits for its pose).
const VELOCITIES: usize = 32;
/// A scan takes the odometry velocity nearest its stamp within this.
const VELOCITY_TOLERANCE_NS: u64 = 100_000_000;
/// The file SIGUSR1 writes in `--map-dir`.
const BT_NAME: &str = "octree.bt";

fn main() -> ExitCode {
    let args = Args::parse();
    smokenav_platform_runtime::main("mapping", &args.common, |p| run(p, &args))
}

fn fusion_rule(r: MappingRule) -> FusionRule {
    match r {
        MappingRule::Lop => FusionRule::Lop,
        MappingRule::Liop => FusionRule::Liop,
        MappingRule::Iop => FusionRule::Iop,
        MappingRule::Bayes => FusionRule::Bayes,
    }
}

/// The sensors' and the robot's heights `[mapping]` gives.
fn heights(cfg: &MappingSection) -> Heights {
    Heights {
        laser_m: cfg.laser_height_m,
        sonar_m: cfg.sonar_height_m,
        robot_m: cfg.robot_height_m,
    }
}

/// The mapper's parameters for `[mapping]`: a square of `size_m` centred on
/// the map origin (where SLAM starts the robot).
fn map_params(cfg: &MappingSection) -> MapParams {
    let half = cfg.size_m / 2.0;
    MapParams {
        resolution: cfg.resolution_m,
        heights: heights(cfg),
        grid_origin: [-half, -half],
        grid_size_m: [cfg.size_m, cfg.size_m],
        ..MapParams::default()
    }
}

/// Where the octree is saved: `--map-dir`, else `[mapping] map_dir`, else here.
fn save_dir(arg: Option<&Path>, cfg: &MappingSection) -> PathBuf {
    arg.map(Path::to_path_buf)
        .or_else(|| cfg.map_dir.as_ref().map(PathBuf::from))
        .unwrap_or_else(|| PathBuf::from("."))
}

/// Messages waiting for a pose: `N` slots allocated once, reused.
struct Pending<T: Copy + Default> {
    slots: Vec<Box<T>>,
    /// Stamp of each slot's message; `None` for a free slot.
    stamps: Vec<Option<u64>>,
    dropped: u64,
}

impl<T: Copy + Default> Pending<T> {
    fn new(n: usize) -> Self {
        Self {
            slots: (0..n).map(|_| Box::default()).collect(),
            stamps: vec![None; n],
            dropped: 0,
        }
    }

    /// Keeps a copy of `msg`; when full, the oldest waiting one makes room.
    fn push(&mut self, stamp: u64, msg: &T) {
        let slot = match self.stamps.iter().position(Option::is_none) {
            Some(i) => i,
            None => {
                self.dropped += 1;
                self.oldest().expect("a full buffer has an oldest")
            }
        };
        *self.slots[slot] = *msg;
        self.stamps[slot] = Some(stamp);
    }

    fn oldest(&self) -> Option<usize> {
        (0..self.stamps.len())
            .filter(|&i| self.stamps[i].is_some())
            .min_by_key(|&i| self.stamps[i])
    }

    /// Takes out, oldest first, every message stamped at or before `until`.
    fn take_until(&mut self, until: u64, mut f: impl FnMut(u64, &T)) {
        while let Some(i) = self.oldest() {
            let stamp = self.stamps[i].expect("oldest is in use");
            if stamp > until {
                break;
            }
            self.stamps[i] = None;
            f(stamp, &self.slots[i]);
        }
    }
}

/// The last two poses: a message between them takes the nearer one.
#[derive(Default)]
struct Poses {
    prev: Option<(u64, Pose2)>,
    last: Option<(u64, Pose2)>,
}

impl Poses {
    fn push(&mut self, p: &PoseEstimate) {
        let stamp = p.header.stamp_ns;
        if self.last.is_some_and(|(t, _)| stamp <= t) {
            return; // out of order or repeated: the newer pose stays
        }
        self.prev = self.last;
        self.last = Some((stamp, Pose2::new(p.x, p.y, p.theta)));
    }

    /// The pose nearest in time to `stamp`, if within the tolerance.
    fn at(&self, stamp: u64) -> Option<Pose2> {
        [self.prev, self.last]
            .into_iter()
            .flatten()
            .map(|(t, p)| (t.abs_diff(stamp), p))
            .filter(|(d, _)| *d <= POSE_TOLERANCE_NS)
            .min_by_key(|(d, _)| *d)
            .map(|(_, p)| p)
    }
}

/// The odometry's recent velocities, in a ring allocated once (the oldest overwritten).
struct Velocities {
    ring: [(u64, Twist2); VELOCITIES],
    len: usize,
    next: usize,
}

impl Default for Velocities {
    fn default() -> Self {
        Self {
            ring: [(0, Twist2::default()); VELOCITIES],
            len: 0,
            next: 0,
        }
    }
}

impl Velocities {
    fn push(&mut self, o: &Odometry) {
        let twist = Twist2::new(o.linear, 0.0, o.angular);
        if !twist.is_finite() {
            return;
        }
        self.ring[self.next] = (o.header.stamp_ns, twist);
        self.next = (self.next + 1) % VELOCITIES;
        self.len = (self.len + 1).min(VELOCITIES);
    }

    /// The velocity stamped nearest `stamp`, if within the tolerance.
    fn at(&self, stamp: u64) -> Option<Twist2> {
        self.ring[..self.len]
            .iter()
            .map(|(t, v)| (t.abs_diff(stamp), *v))
            .filter(|(d, _)| *d <= VELOCITY_TOLERANCE_NS)
            .min_by_key(|(d, _)| *d)
            .map(|(_, v)| v)
    }
}

#[derive(Default)]
struct Counters {
    scans_mapped: u64,
    scans_deskewed: u64,
    rings_mapped: u64,
    unpaired: u64,
    maps_published: u64,
    voxels_truncated: u64,
    publish_errors: u64,
    saves: u64,
}

fn map_info(grid: &ProbGrid, stamp_ns: u64) -> MapInfo {
    let g = grid.geometry;
    MapInfo {
        header: Header::new(stamp_ns, 0, "map"),
        resolution: g.resolution as f32,
        width: g.width as u32,
        height: g.height as u32,
        _reserved: 0,
        origin_x: g.origin[0],
        origin_y: g.origin[1],
        origin_theta: 0.0,
    }
}

/// `grid` as ROS occupancy values (0–100, −1 unknown) into `cells`, reused.
fn fill_cells(grid: &ProbGrid, cells: &mut Vec<i8>) {
    cells.clear();
    cells.extend(grid.p.iter().map(|p| {
        if p.is_nan() {
            -1
        } else {
            (p * 100.0).round().clamp(0.0, 100.0) as i8
        }
    }));
}

/// The octree's occupied voxel centres into `cloud`. When there are more
/// than it holds, every k-th is kept so the cloud still covers the whole
/// map evenly (a prefix in traversal order would show one corner), and the
/// rest are counted in `truncated`.
fn fill_voxels(tree: &Octree, stamp_ns: u64, cloud: &mut VoxelCloud) {
    cloud.header = Header::new(stamp_ns, 0, "map");
    cloud.resolution = tree.resolution() as f32;
    cloud.clear();
    let mut occupied = 0usize;
    tree.for_each_voxel(|_, l| occupied += usize::from(l > 0.0));
    let stride = occupied.div_ceil(MAX_VOXELS).max(1);
    let mut i = 0usize;
    tree.for_each_voxel(|k, l| {
        if l > 0.0 {
            if i.is_multiple_of(stride) {
                cloud.push([
                    tree.coord(k[0]) as f32,
                    tree.coord(k[1]) as f32,
                    tree.coord(k[2]) as f32,
                ]);
            }
            i += 1;
        }
    });
    cloud.truncated = u32::try_from(occupied - cloud.len()).unwrap_or(u32::MAX);
}

/// Writes the octree to `dir/octree.bt` through a temporary file, so a
/// reader never sees half a tree.
fn save_bt(tree: &Octree, dir: &Path) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let path = dir.join(BT_NAME);
    let tmp = dir.join(format!(".{BT_NAME}.tmp"));
    let file =
        std::fs::File::create(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?;
    let mut w = std::io::BufWriter::new(file);
    tree.write_bt(&mut w)
        .and_then(|_| std::io::Write::flush(&mut w))
        .with_context(|| format!("cannot write {}", tmp.display()))?;
    drop(w);
    std::fs::rename(&tmp, &path)
        .with_context(|| format!("cannot rename {} to {}", tmp.display(), path.display()))?;
    Ok(path)
}

struct Outputs {
    grid: MapPublisher,
    projected: MapPublisher,
    voxels: Publisher<VoxelCloud>,
    cells: Vec<i8>,
}

impl Outputs {
    fn publish(
        &mut self,
        mapper: &Mapper,
        rule: FusionRule,
        stamp_ns: u64,
        c: &mut Counters,
    ) -> Vec<String> {
        let mut errors = Vec::new();
        for (which, grid) in [
            ("mapping/grid", mapper.fused_grid(rule)),
            ("mapping/projected", mapper.projected(rule)),
        ] {
            let Some(grid) = grid else {
                errors.push(format!("{which}: the mapper has no {rule} map"));
                continue;
            };
            fill_cells(&grid, &mut self.cells);
            let publisher = if which == "mapping/grid" {
                &mut self.grid
            } else {
                &mut self.projected
            };
            match publisher.publish(&map_info(&grid, stamp_ns), &self.cells) {
                Ok(_) => c.maps_published += 1,
                Err(e) => errors.push(format!("cannot publish {which}: {e}")),
            }
        }
        let tree = mapper.octree();
        let mut truncated = 0;
        let sent = self.voxels.publish_with(|cloud| {
            fill_voxels(tree, stamp_ns, cloud);
            truncated = cloud.truncated;
        });
        c.voxels_truncated = truncated.into();
        if let Err(e) = sent {
            errors.push(format!("cannot publish mapping/voxels: {e}"));
        }
        c.publish_errors += errors.len() as u64;
        errors
    }
}

fn run(p: &mut Process, args: &Args) -> anyhow::Result<()> {
    let cfg = p.config.mapping.clone();
    let rule = fusion_rule(cfg.rule);
    let heights = heights(&cfg);
    let rig = Rig::from_config(&p.config, &heights);
    let map_dir = save_dir(args.map_dir.as_deref(), &cfg);
    // Only Bayes lives in the joint maps; the other rules pool per-sensor maps.
    let set = if rule == FusionRule::Bayes {
        MapSet::Bayes
    } else {
        MapSet::Comparison
    };
    let mut mapper = Mapper::new(rig, map_params(&cfg), set)?;
    let save_requested = Arc::new(AtomicBool::new(false));
    signal_hook::flag::register(signal_hook::consts::SIGUSR1, Arc::clone(&save_requested))
        .context("cannot install the SIGUSR1 handler")?;

    let pose_sub = p.bus.subscriber::<PoseEstimate>(topics::SLAM_POSE)?;
    let scan_sub = p.bus.subscriber::<LaserScan>(topics::LASER_SCAN)?;
    let sonar_sub = p.bus.subscriber::<SonarRing>(topics::BASE_SONAR)?;
    let odom_sub = p.bus.subscriber::<Odometry>(topics::BASE_ODOM)?;
    let deskew = p.config.slam.deskew;
    let mut out = Outputs {
        grid: p.bus.map_publisher(topics::MAPPING_GRID)?,
        projected: p.bus.map_publisher(topics::MAPPING_PROJECTED)?,
        voxels: p.bus.publisher(topics::MAPPING_VOXELS)?,
        cells: Vec::new(),
    };
    let waiter = Waiter::new()?;
    let _attached = [
        waiter.attach(&pose_sub)?,
        waiter.attach(&scan_sub)?,
        waiter.attach(&sonar_sub)?,
        waiter.attach(&odom_sub)?,
    ];

    let mut scans: Pending<LaserScan> = Pending::new(PENDING);
    let mut rings: Pending<SonarRing> = Pending::new(PENDING);
    let mut poses = Poses::default();
    let mut velocities = Velocities::default();
    let mut counters = Counters::default();
    let mut newest_mapped = None;
    let period = Duration::from_secs_f64(1.0 / cfg.publish_rate_hz);
    let mut next_publish = Instant::now() + period;
    let scan_rate = p.health.add_rate("scans_mapped_hz", Some(10.0));
    let map_rate = p
        .health
        .add_rate("maps_hz", Some(cfg.publish_rate_hz.max(1.0)));
    p.ready(&format!(
        "{rule} maps at {} m from {} + {} + {}, {}, published every {:.1} s, octree saved to {}",
        cfg.resolution_m,
        topics::SLAM_POSE.name(),
        topics::LASER_SCAN.name(),
        topics::BASE_SONAR.name(),
        if deskew {
            format!("sweeps deskewed by {}", topics::BASE_ODOM.name())
        } else {
            "sweeps not deskewed ([slam] deskew = false)".to_owned()
        },
        period.as_secs_f64(),
        map_dir.display()
    ));

    while !p.shutdown_requested() {
        if waiter.wait(Some(POLL))? == WaitOutcome::Shutdown {
            break;
        }
        // Scans and rings first: a pose is published after its scan.
        while let Some(s) = scan_sub.receive()? {
            scans.push(s.header.stamp_ns, &s);
        }
        while let Some(r) = sonar_sub.receive()? {
            rings.push(r.header.stamp_ns, &r);
        }
        while let Some(o) = odom_sub.receive()? {
            velocities.push(&o);
        }
        while let Some(pose) = pose_sub.receive()? {
            poses.push(&pose);
        }
        if let Some((last, _)) = poses.last {
            // Anything up to the newest pose (and a little after it: a
            // ring between poses) has all the poses it will get.
            let until = last.saturating_add(POSE_TOLERANCE_NS / 2);
            let t0 = Instant::now();
            scans.take_until(until, |stamp, scan| match poses.at(stamp) {
                Some(pose) => {
                    match velocities.at(stamp).filter(|_| deskew) {
                        Some(twist) if mapper.insert_sweep(&pose, scan, twist) => {
                            counters.scans_deskewed += 1;
                        }
                        Some(_) => {} // no time increment: inserted as taken at once
                        None => mapper.insert_scan(&pose, scan),
                    }
                    counters.scans_mapped += 1;
                    newest_mapped = newest_mapped.max(Some(stamp));
                    p.health.mark(scan_rate);
                }
                None => counters.unpaired += 1,
            });
            rings.take_until(until, |stamp, ring| match poses.at(stamp) {
                Some(pose) => {
                    mapper.insert_ring(&pose, ring);
                    counters.rings_mapped += 1;
                }
                None => counters.unpaired += 1,
            });
            if newest_mapped.is_some() {
                p.health.record_latency(t0.elapsed());
            }
        }

        let now = Instant::now();
        if now >= next_publish {
            next_publish = now + period;
            if let Some(stamp) = newest_mapped {
                let errors = out.publish(&mapper, rule, stamp, &mut counters);
                if errors.is_empty() {
                    p.health.mark(map_rate);
                }
                for e in errors {
                    p.health.error(&e);
                }
            }
        }
        if save_requested.swap(false, Ordering::Relaxed) {
            match save_bt(mapper.octree(), &map_dir) {
                Ok(path) => {
                    counters.saves += 1;
                    tracing::info!("octree saved to {}", path.display());
                }
                Err(e) => p.health.error(&format!(
                    "cannot save the octree: {}",
                    smokenav_platform_runtime::error_line(&e)
                )),
            }
        }
        report(p, &mapper, &counters, &scans, &rings);
        p.tick()?;
    }
    Ok(())
}

fn report(
    p: &mut Process,
    mapper: &Mapper,
    c: &Counters,
    scans: &Pending<LaserScan>,
    rings: &Pending<SonarRing>,
) {
    let h = &mut p.health;
    h.set_metric("scans_mapped", c.scans_mapped as f64);
    h.set_metric("scans_deskewed", c.scans_deskewed as f64);
    h.set_metric("rings_mapped", c.rings_mapped as f64);
    h.set_metric("unpaired", c.unpaired as f64);
    h.set_metric("dropped_waiting", (scans.dropped + rings.dropped) as f64);
    h.set_metric("maps_published", c.maps_published as f64);
    h.set_metric("voxels_truncated", c.voxels_truncated as f64);
    h.set_metric("publish_errors", c.publish_errors as f64);
    h.set_metric("octree_saves", c.saves as f64);
    h.set_metric("octree_nodes", mapper.octree().node_count() as f64);
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_algorithms_mapping::{ClampLogOdds, Clamping};

    fn pose(stamp: u64, x: f64) -> PoseEstimate {
        PoseEstimate {
            header: Header::new(stamp, 0, "map"),
            x,
            ..Default::default()
        }
    }

    #[test]
    fn a_message_takes_the_pose_nearest_in_time_within_the_tolerance() {
        let mut poses = Poses::default();
        poses.push(&pose(1_000_000_000, 1.0));
        poses.push(&pose(1_100_000_000, 2.0));
        poses.push(&pose(1_050_000_000, 9.0)); // older than the last: ignored
        assert_eq!(poses.at(1_040_000_000).map(|p| p.x), Some(1.0));
        assert_eq!(poses.at(1_100_000_000).map(|p| p.x), Some(2.0));
        assert_eq!(poses.at(1_240_000_000).map(|p| p.x), Some(2.0));
        assert_eq!(poses.at(1_300_000_000), None);
        assert_eq!(poses.at(800_000_000), None);
    }

    fn odometry(stamp: u64, linear: f64, angular: f64) -> Odometry {
        Odometry {
            header: Header::new(stamp, 0, "odom"),
            linear,
            angular,
            ..Default::default()
        }
    }

    #[test]
    fn a_scan_takes_the_odometry_velocity_nearest_its_stamp_within_the_tolerance() {
        let mut v = Velocities::default();
        assert_eq!(v.at(1_000_000_000), None);
        // More than the ring holds: the oldest go.
        for i in 0..VELOCITIES as u64 + 8 {
            v.push(&odometry(1_000_000_000 + i * 50_000_000, i as f64, -0.5));
        }
        v.push(&odometry(9_000_000_000, f64::NAN, 0.0)); // ignored
        assert_eq!(v.at(1_000_000_000), None, "pushed out of the ring");
        let last = 1_000_000_000 + (VELOCITIES as u64 + 7) * 50_000_000;
        assert_eq!(v.at(last + 10_000_000), Some(Twist2::new(39.0, 0.0, -0.5)));
        assert_eq!(v.at(last - 30_000_000).map(|t| t.vx), Some(38.0));
        assert_eq!(v.at(last + VELOCITY_TOLERANCE_NS + 1), None);
    }

    #[test]
    fn pending_messages_come_out_oldest_first_and_a_full_buffer_drops_the_oldest() {
        let mut p: Pending<PoseEstimate> = Pending::new(3);
        for (i, t) in [30u64, 10, 20, 40].into_iter().enumerate() {
            p.push(t, &pose(t, i as f64));
        }
        assert_eq!(p.dropped, 1);
        let mut out = Vec::new();
        p.take_until(30, |t, m| out.push((t, m.x)));
        assert_eq!(out, [(20, 2.0), (30, 0.0)]);
        out.clear();
        p.take_until(u64::MAX, |t, m| out.push((t, m.x)));
        assert_eq!(out, [(40, 3.0)]);
    }

    #[test]
    fn the_published_maps_cover_the_configured_square() {
        let cfg = MappingSection {
            size_m: 10.0,
            resolution_m: 0.1,
            ..MappingSection::default()
        };
        let params = map_params(&cfg);
        assert_eq!(params.grid_origin, [-5.0, -5.0]);
        let mapper = Mapper::new(
            Rig::from_config(
                &smokenav_platform_config::RobotConfig::builtin("nomad-scout").unwrap(),
                &Heights::default(),
            ),
            params,
            MapSet::Bayes,
        )
        .unwrap();
        let g = mapper.grid_geometry();
        assert_eq!((g.width, g.height), (100, 100));
        let grid = mapper.fused_grid(FusionRule::Bayes).unwrap();
        let mut cells = Vec::new();
        fill_cells(&grid, &mut cells);
        assert!(cells.iter().all(|&c| c == -1));
        assert_eq!(map_info(&grid, 5).cell_count(), cells.len());
    }

    #[test]
    fn a_saved_octree_reads_back() {
        let clamp = ClampLogOdds::from(Clamping::default());
        let mut tree = Octree::new(0.05, clamp);
        let k = tree.key([1.01, 2.01, 0.31]).unwrap();
        tree.integrate(k, true);
        let dir = tempfile::tempdir().unwrap();
        let path = save_bt(&tree, &dir.path().join("new")).unwrap();
        let back = Octree::read_bt(
            &mut std::io::BufReader::new(std::fs::File::open(&path).unwrap()),
            clamp,
        )
        .unwrap();
        assert!(back.search(k).is_some_and(|l| l > 0.0));
        let mut cloud = Box::<VoxelCloud>::default();
        fill_voxels(&tree, 9, &mut cloud);
        assert_eq!(cloud.len(), 1);
        let [x, y, z] = cloud.points()[0];
        assert!((x - 1.025).abs() < 1e-6 && (y - 2.025).abs() < 1e-6 && (z - 0.325).abs() < 1e-6);
    }

    #[test]
    fn an_overfull_cloud_keeps_an_even_subset_and_counts_the_rest() {
        let mut tree = Octree::new(0.05, ClampLogOdds::from(Clamping::default()));
        // A 200 × 100 wall of occupied voxels, one voxel thick: 20 000 > MAX_VOXELS.
        let n = 20_000;
        for i in 0..200 {
            for j in 0..100 {
                let k = tree.key([0.01 + i as f64 * 0.05, 1.01, 0.01 + j as f64 * 0.05]);
                tree.integrate(k.unwrap(), true);
            }
        }
        let mut cloud = Box::<VoxelCloud>::default();
        fill_voxels(&tree, 1, &mut cloud);
        assert_eq!(cloud.len() + cloud.truncated as usize, n);
        assert!(cloud.len() >= n / 2, "{}", cloud.len());
        // Spread over the whole wall, not a corner of it.
        let xs = cloud.points().iter().map(|p| p[0]);
        let (lo, hi) = xs.fold((f32::MAX, f32::MIN), |(a, b), x| (a.min(x), b.max(x)));
        assert!(lo < 0.2 && hi > 9.8, "{lo} … {hi}");
        let zs = cloud.points().iter().map(|p| p[2]);
        let (lo, hi) = zs.fold((f32::MAX, f32::MIN), |(a, b), z| (a.min(z), b.max(z)));
        assert!(lo < 0.2 && hi > 4.8, "{lo} … {hi}");
    }
}
