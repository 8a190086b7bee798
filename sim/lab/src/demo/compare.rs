//! The offline comparison: one recording through fusion + SLAM (the
//! libraries, in this process, deterministic) with each fusion method, each
//! result scored against the ground truth.

use super::recording::{Kind, SensorLog};
use smokenav_algorithms_eval::{MapOptions, MapReport, TrajectoryOptions, TrajectoryReport};
use smokenav_algorithms_fusion::engine::StepReport;
use smokenav_algorithms_fusion::pipeline::FusionPipeline;
use smokenav_algorithms_slam::backend::footprint_radius;
use smokenav_algorithms_slam::noise::LaserNoiseModel;
use smokenav_algorithms_slam::offline::{Received, replay};
use smokenav_algorithms_slam::projected::SensorRig;
use smokenav_algorithms_slam::{BackendOptions, Pose2, SlamPipeline, StampedPose};
use smokenav_platform_config::RobotConfig;
use smokenav_platform_map::OccupancyGrid;
use smokenav_shared_types::{FusedScan, FusionMethod, LaserScan, SectionSource};
use smokenav_sim_link::TruthTrack;
use std::sync::Arc;

pub const METHODS: [FusionMethod; 3] =
    [FusionMethod::LaserOnly, FusionMethod::V1, FusionMethod::V2];

/// One fused scan, for the time plot.
#[derive(Debug, Clone, Copy)]
pub struct SeriesPoint {
    pub stamp_ns: u64,
    pub smoke_level: f32,
    /// Standard deviation of the valid laser ranges, m.
    pub laser_spread: f32,
    pub sonar_usage: f32,
}

pub struct MethodResult {
    pub method: FusionMethod,
    pub map: Option<OccupancyGrid>,
    /// The fuzzy back-end's combined confidence map (eq. 7, 0–100) of the run shown.
    pub confidence_map: Option<OccupancyGrid>,
    /// What that map says of the true walls, by who painted them.
    pub fuzzy_walls: Option<FuzzyWalls>,
    /// That map's confident phantom cells, where they are (truth frame).
    pub fuzzy_phantoms: Vec<Phantom>,
    /// The best particle's (smoothed) trajectory, of the median run.
    pub trajectory: Vec<StampedPose>,
    pub series: Vec<SeriesPoint>,
    /// Share of sections that used the sonar (the SmokeNav paper's "sonar usage").
    pub sonar_usage: f64,
    pub scans: u64,
    /// Fusion gave SLAM exactly the same scans as this method did (so the SLAM result is shared).
    pub same_slam_input_as: Option<FusionMethod>,
    /// The median SLAM run's scores (its map and trajectory are the ones above).
    pub map_report: Result<MapReport, String>,
    pub trajectory_report: Result<TrajectoryReport, String>,
    /// (map error, ATE) of every SLAM run, one per random seed; the median by map error is the one above.
    pub runs: Vec<(Option<f64>, Option<f64>)>,
    /// What the method did with the beams the smoke changed and those it left
    /// alone, against the smoke-free twin (set when the twin ran).
    pub laser_verdict: Option<LaserVerdict>,
}

/// A range moved by more than this between a scan and the same scan of the
/// smoke-free twin is the smoke's doing (the twin has the same noise).
pub const SMOKE_CHANGED_M: f32 = 0.1;

/// Whether the smoke changed a beam: its range (`smoky`) against the same
/// beam of the smoke-free twin moved by more than [`SMOKE_CHANGED_M`], or
/// one of them returned and the other did not.
pub fn smoke_changed(smoky: Option<f32>, twin: Option<f32>) -> bool {
    match (smoky, twin) {
        (Some(x), Some(y)) => (x - y).abs() > SMOKE_CHANGED_M,
        (None, None) => false,
        _ => true,
    }
}

/// What a fusion method did with the laser's beams, judged against the
/// scenario's smoke-free twin (same seed, same route and noise: the smoke is
/// the only difference). A beam the smoke changed (its range moved by more
/// than [`SMOKE_CHANGED_M`], or it returned where the twin's did not) and
/// that the method handed to SLAM as the laser's is a phantom SLAM saw; a
/// beam the smoke left alone that the method withheld is a wall SLAM lost.
/// The fusion's own confusion matrix, beside the map error it leads to.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct LaserVerdict {
    /// Fused scans paired with a scan of the twin.
    pub scans: u64,
    /// Beams with a return the smoke changed.
    pub smoke_beams: u64,
    /// … that reached SLAM as the laser's.
    pub smoke_beams_kept: u64,
    /// Beams with a return within [`SMOKE_CHANGED_M`] of the twin's.
    pub clean_beams: u64,
    /// … that did not reach SLAM as the laser's.
    pub clean_beams_withheld: u64,
}

impl LaserVerdict {
    /// Share of the smoke-changed beams that reached SLAM (`None` without any).
    pub fn smoke_kept_share(&self) -> Option<f64> {
        (self.smoke_beams > 0).then(|| self.smoke_beams_kept as f64 / self.smoke_beams as f64)
    }

    /// Share of the smoke-free beams the method withheld (`None` without any).
    pub fn clean_withheld_share(&self) -> Option<f64> {
        (self.clean_beams > 0).then(|| self.clean_beams_withheld as f64 / self.clean_beams as f64)
    }
}

/// Scans of `log` by their time since its first, in tenths of a second (how
/// a recording and its twin's are paired: their clocks start apart).
pub fn scans_by_tick(log: &SensorLog) -> std::collections::HashMap<i64, &LaserScan> {
    let Some(t0) = log.lasers.first().map(|s| s.header.stamp_ns) else {
        return Default::default();
    };
    log.lasers
        .iter()
        .map(|s| (tick(s.header.stamp_ns, t0), &**s))
        .collect()
}

/// Tenths of a second from `t0` to `stamp`, rounded.
pub fn tick(stamp: u64, t0: u64) -> i64 {
    (stamp.saturating_sub(t0) as f64 / 1e8).round() as i64
}

/// The [`LaserVerdict`] of `fused` (fused from `smoky`) against the twin's scans.
pub fn laser_verdict(fused: &[Emitted], smoky: &SensorLog, twin: &SensorLog) -> LaserVerdict {
    let mut v = LaserVerdict::default();
    let Some(t0) = smoky.lasers.first().map(|s| s.header.stamp_ns) else {
        return v;
    };
    let raw: std::collections::HashMap<u64, &LaserScan> = smoky
        .lasers
        .iter()
        .map(|s| (s.header.stamp_ns, &**s))
        .collect();
    let twin = scans_by_tick(twin);
    for (_, f) in fused {
        let stamp = f.scan.header.stamp_ns;
        let (Some(s), Some(c)) = (raw.get(&stamp), twin.get(&tick(stamp, t0))) else {
            continue;
        };
        v.scans += 1;
        let n = s.len().min(c.len()).min(f.scan.len());
        for i in 0..n {
            let Some(r) = s.beam(i).range() else { continue };
            // Handed to SLAM as the laser's: a laser beam, or a beam where
            // the laser was nearer than the sonar superimposed on it.
            let kept = match f.beam_source(i) {
                SectionSource::Laser => true,
                SectionSource::Both => f.scan.beam(i).range() == Some(r),
                _ => false,
            } && f.scan.beam(i).range().is_some();
            if smoke_changed(Some(r), c.beam(i).range()) {
                v.smoke_beams += 1;
                v.smoke_beams_kept += u64::from(kept);
            } else {
                v.clean_beams += 1;
                v.clean_beams_withheld += u64::from(!kept);
            }
        }
    }
    v
}

/// The fuzzy map against the truth: the mean eq. 7 confidence on true wall
/// cells that only sonar-painted beams ended at, beside those a laser beam
/// ended at, and the confident cells (≥ 0.65) nowhere near a true wall —
/// over the whole map and inside the region where the smoke was.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct FuzzyWalls {
    pub laser_wall_confidence: f64,
    pub laser_wall_cells: usize,
    pub sonar_only_wall_confidence: f64,
    pub sonar_only_wall_cells: usize,
    /// Cells at ≥ 0.65 confidence more than 0.3 m from every true wall.
    pub confident_phantom_cells: usize,
    /// Of those, the ones inside the smoke region ([`super::smoke_region`];
    /// `None` without smoke).
    pub confident_phantom_cells_in_smoke: Option<usize>,
    /// Of those in the smoke, the ones 0.3–0.6 m from a wall (a wall drawn
    /// a little off, rather than a wall where there is none).
    pub in_smoke_near_wall: Option<usize>,
    /// Where the others are (every confident phantom cell is in exactly one):
    /// outside the smoke, 0.3–0.6 m from a true wall (registration error) …
    pub clear_air_near_wall: usize,
    /// … outside the smoke, further from every wall, outside the arena's walls …
    pub clear_air_outside_arena: usize,
    /// … and outside the smoke, further from every wall, inside the arena.
    pub clear_air_open_space: usize,
    /// Size of the smoke region, m² (`None` without smoke).
    pub smoke_region_m2: Option<f64>,
}

/// Where a confident phantom cell lies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum PhantomPlace {
    /// In the smoke region, 0.3–0.6 m from a true wall.
    SmokeNearWall,
    /// In the smoke region, further from every wall.
    Smoke,
    /// Clear air, 0.3–0.6 m from a true wall.
    NearWall,
    /// Clear air, further from every wall, outside the walls' bounding box.
    OutsideArena,
    /// Clear air, further from every wall, inside the arena.
    OpenSpace,
}

impl PhantomPlace {
    pub fn as_str(self) -> &'static str {
        match self {
            PhantomPlace::SmokeNearWall => "smoke-near-wall",
            PhantomPlace::Smoke => "smoke",
            PhantomPlace::NearWall => "near-wall",
            PhantomPlace::OutsideArena => "outside-arena",
            PhantomPlace::OpenSpace => "open-space",
        }
    }
}

/// One confident phantom cell: its centre in the truth frame, its eq. 7 confidence (0–100).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Phantom {
    pub x: f64,
    pub y: f64,
    pub confidence: i8,
    pub place: PhantomPlace,
}

/// [`FuzzyWalls`] of one run: its beams' end points at its own poses, in its
/// map; the truth reached through the k-NN alignment; `smoke` the smoke
/// region on the truth map's grid. Also every confident phantom cell.
pub fn fuzzy_walls(
    fused: &[Emitted],
    trajectory: &[StampedPose],
    conf: &OccupancyGrid,
    align: &smokenav_algorithms_eval::Alignment,
    truth_map: &OccupancyGrid,
    smoke: Option<&OccupancyGrid>,
    mount: Pose2,
) -> (FuzzyWalls, Vec<Phantom>) {
    use smokenav_shared_types::{BeamReading, SectionSource};
    let poses: std::collections::HashMap<u64, Pose2> =
        trajectory.iter().map(|p| (p.stamp_ns, p.pose)).collect();
    // Per map cell: bit 0 a laser beam ended here, bit 1 a sonar-painted one.
    let mut painted = vec![0u8; conf.cells.len()];
    for (_, f) in fused {
        let Some(p) = poses.get(&f.scan.header.stamp_ns) else {
            continue;
        };
        let l = p.compose(&mount);
        for i in 0..f.scan.len() {
            let BeamReading::Range(r) = f.scan.beam(i) else {
                continue;
            };
            let bit = match f.beam_source(i) {
                SectionSource::Laser | SectionSource::Both => 1,
                SectionSource::Sonar => 2,
                _ => continue,
            };
            let a = l.theta + f64::from(f.scan.angle(i));
            let (x, y) = (l.x + f64::from(r) * a.cos(), l.y + f64::from(r) * a.sin());
            if let Some((cx, cy)) = conf.world_to_cell(x, y) {
                painted[cy * conf.width + cx] |= bit;
            }
        }
    }
    let (s, c) = align.dtheta_deg.to_radians().sin_cos();
    let to_truth = |x: f64, y: f64| (c * x - s * y + align.dx_m, s * x + c * y + align.dy_m);
    // A truth cell within `k` cells of (x, y) (truth frame) is occupied.
    let wall_within = |x: f64, y: f64, k: i64| -> bool {
        let Some((cx, cy)) = truth_map.world_to_cell(x, y) else {
            return false;
        };
        (-k..=k).any(|dy| {
            (-k..=k).any(|dx| {
                let (gx, gy) = (cx as i64 + dx, cy as i64 + dy);
                gx >= 0
                    && gy >= 0
                    && truth_map.get(gx as usize, gy as usize)
                        == Some(smokenav_platform_map::OCCUPIED)
            })
        })
    };
    let in_smoke = |x: f64, y: f64| {
        smoke.is_some_and(|m| {
            m.world_to_cell(x, y)
                .and_then(|(cx, cy)| m.get(cx, cy))
                .is_some_and(|v| v > 0)
        })
    };
    let walls = wall_bounds(truth_map);
    let far = (0.3 / truth_map.resolution).round() as i64;
    let farther = (0.6 / truth_map.resolution).round() as i64;
    let (mut lsum, mut ln, mut ssum, mut sn) = (0.0, 0, 0.0, 0);
    let mut phantoms = Vec::new();
    for (i, &v) in conf.cells.iter().enumerate() {
        let (x, y) = (
            conf.origin[0] + ((i % conf.width) as f64 + 0.5) * conf.resolution,
            conf.origin[1] + ((i / conf.width) as f64 + 0.5) * conf.resolution,
        );
        let (tx, ty) = to_truth(x, y);
        if v >= 65 && !wall_within(tx, ty, far) {
            let near = wall_within(tx, ty, farther);
            let place = match (in_smoke(tx, ty), near) {
                (true, true) => PhantomPlace::SmokeNearWall,
                (true, false) => PhantomPlace::Smoke,
                (false, true) => PhantomPlace::NearWall,
                (false, false) => match walls {
                    Some((x0, y0, x1, y1)) if tx < x0 || tx > x1 || ty < y0 || ty > y1 => {
                        PhantomPlace::OutsideArena
                    }
                    _ => PhantomPlace::OpenSpace,
                },
            };
            phantoms.push(Phantom {
                x: tx,
                y: ty,
                confidence: v,
                place,
            });
        }
        if painted[i] == 0 || !wall_within(tx, ty, 1) {
            continue;
        }
        let v = f64::from(v.max(0)) / 100.0;
        if painted[i] & 1 != 0 {
            (lsum, ln) = (lsum + v, ln + 1);
        } else {
            (ssum, sn) = (ssum + v, sn + 1);
        }
    }
    let count = |p: &[PhantomPlace]| phantoms.iter().filter(|f| p.contains(&f.place)).count();
    let smoky = smoke.is_some();
    let walls = FuzzyWalls {
        laser_wall_confidence: lsum / f64::from(ln.max(1)),
        laser_wall_cells: ln as usize,
        sonar_only_wall_confidence: ssum / f64::from(sn.max(1)),
        sonar_only_wall_cells: sn as usize,
        confident_phantom_cells: phantoms.len(),
        confident_phantom_cells_in_smoke: smoky
            .then(|| count(&[PhantomPlace::Smoke, PhantomPlace::SmokeNearWall])),
        in_smoke_near_wall: smoky.then(|| count(&[PhantomPlace::SmokeNearWall])),
        clear_air_near_wall: count(&[PhantomPlace::NearWall]),
        clear_air_outside_arena: count(&[PhantomPlace::OutsideArena]),
        clear_air_open_space: count(&[PhantomPlace::OpenSpace]),
        smoke_region_m2: smoke.map(|m| {
            m.cells.iter().filter(|&&v| v > 0).count() as f64 * m.resolution * m.resolution
        }),
    };
    (walls, phantoms)
}

/// The bounding box of the true walls (truth frame), cell centres.
fn wall_bounds(truth_map: &OccupancyGrid) -> Option<(f64, f64, f64, f64)> {
    let mut b: Option<(f64, f64, f64, f64)> = None;
    for (i, &v) in truth_map.cells.iter().enumerate() {
        if v != smokenav_platform_map::OCCUPIED {
            continue;
        }
        let (x, y) = (
            truth_map.origin[0] + ((i % truth_map.width) as f64 + 0.5) * truth_map.resolution,
            truth_map.origin[1] + ((i / truth_map.width) as f64 + 0.5) * truth_map.resolution,
        );
        b = Some(match b {
            None => (x, y, x, y),
            Some((x0, y0, x1, y1)) => (x0.min(x), y0.min(y), x1.max(x), y1.max(y)),
        });
    }
    b
}

fn mean(v: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    let v: Vec<f64> = v.flatten().filter(|x| x.is_finite()).collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

impl MethodResult {
    /// k-NN map error, m: the mean over the SLAM seeds.
    pub fn map_error_m(&self) -> Option<f64> {
        mean(self.runs.iter().map(|r| r.0))
    }

    /// ATE (RMS), m: the mean over the SLAM seeds.
    pub fn ate_m(&self) -> Option<f64> {
        mean(self.runs.iter().map(|r| r.1))
    }
}

/// A fused scan and when fusion emitted it (the receive time of the input
/// that completed its set): when the SLAM process would have received it.
pub type Emitted = (u64, FusedScan);

/// Fuses the recording with `method`, in receive order, exactly as the fusion
/// process would have; returns the fused scans in the order they were
/// emitted and the pipeline's sonar usage.
pub fn fuse(
    log: &SensorLog,
    profile: &RobotConfig,
    method: FusionMethod,
) -> anyhow::Result<(Vec<Emitted>, f64)> {
    let mut pipeline = FusionPipeline::from_config(profile, Some(method))?;
    let mut fused: Vec<Emitted> = Vec::with_capacity(log.lasers.len());
    let mut end = 0;
    for &(now, kind, i) in &log.order {
        let mut emit = |f: &FusedScan, _: &StepReport| fused.push((now, *f));
        match kind {
            Kind::Laser => pipeline.push_laser(&log.lasers[i], now, &mut emit),
            Kind::Sonar => pipeline.push_sonar(&log.sonars[i], now, &mut emit),
            Kind::Smoke => pipeline.push_smoke(&log.smokes[i], now, &mut emit),
            Kind::Odometry => continue,
        }
        pipeline.poll(now, &mut emit);
        end = now;
    }
    pipeline.flush(&mut |f: &FusedScan, _: &StepReport| fused.push((end, *f)));
    let usage = pipeline.stats().sonar_usage();
    Ok((fused, usage))
}

/// What SLAM made of one sequence of fused scans, scored.
#[derive(Clone)]
struct SlamOutcome {
    map: Option<OccupancyGrid>,
    confidence_map: Option<OccupancyGrid>,
    trajectory: Vec<StampedPose>,
    map_report: Result<MapReport, String>,
    trajectory_report: Result<TrajectoryReport, String>,
}

/// The SLAM input of a fused scan: every beam as the filter reads it, and the laser noise factor.
fn same_slam_input(a: &FusedScan, b: &FusedScan, noise: &LaserNoiseModel) -> bool {
    let (x, y) = (&a.scan, &b.scan);
    let n = x.len();
    x.header.stamp_ns == y.header.stamp_ns
        && n == y.len()
        && x.angle_min.to_bits() == y.angle_min.to_bits()
        && x.angle_increment.to_bits() == y.angle_increment.to_bits()
        && x.range_min.to_bits() == y.range_min.to_bits()
        && x.range_max.to_bits() == y.range_max.to_bits()
        && (0..n).all(|i| x.beam(i) == y.beam(i) && a.beam_source[i] == b.beam_source[i])
        && noise.factor(f64::from(a.smoke_level)).to_bits()
            == noise.factor(f64::from(b.smoke_level)).to_bits()
}

/// A SLAM pipeline for `profile` fed `fused` and the odometry of `log` in
/// receive order, exactly as the SLAM process would have been.
pub(crate) fn replay_slam(
    log: &SensorLog,
    profile: &RobotConfig,
    fused: &[Emitted],
) -> SlamPipeline {
    let mount = profile.laser.mount;
    let mut slam = SlamPipeline::from_config(
        &profile.slam,
        &BackendOptions {
            keep_trajectory: true,
            sensors: Some(Arc::new(SensorRig::from_config(profile))),
            footprint_m: footprint_radius(&profile.slam, profile.robot.radius_m),
            ..BackendOptions::default()
        },
    )
    .with_sensor_pose(Pose2::new(mount.x, mount.y, mount.yaw_rad()))
    .with_robot(profile);
    // Odometry ahead of a scan received at the same time, as the process drains it first.
    let mut received: Vec<(u64, Received<'_>)> = log
        .order
        .iter()
        .filter(|&&(_, kind, _)| kind == Kind::Odometry)
        .map(|&(t, _, i)| (t, Received::Odometry(&log.odoms[i])))
        .chain(fused.iter().map(|(t, f)| (*t, Received::Fused(f))))
        .collect();
    received.sort_by_key(|&(t, _)| t);
    replay(&mut slam, received, |_| {});
    slam
}

/// A SLAM map against the truth (k-NN map error of the SmokeNav paper).
pub(crate) fn score_map(
    truth_map: &OccupancyGrid,
    map: Option<&OccupancyGrid>,
) -> Result<MapReport, String> {
    match map {
        Some(m) => smokenav_algorithms_eval::evaluate_maps(truth_map, m, &MapOptions::default())
            .map_err(|e| e.to_string()),
        None => Err("SLAM processed no scan".into()),
    }
}

/// A SLAM trajectory against the true one.
pub(crate) fn score_trajectory(
    truth: &TruthTrack,
    trajectory: &[StampedPose],
) -> Result<TrajectoryReport, String> {
    let truth_poses: Vec<_> = truth
        .samples()
        .iter()
        .map(|s| smokenav_algorithms_eval::StampedPose::from_ns(s.t_ns, &s.pose))
        .collect();
    let est: Vec<_> = trajectory
        .iter()
        .map(|p| smokenav_algorithms_eval::StampedPose::from_ns(p.stamp_ns, &p.pose))
        .collect();
    smokenav_algorithms_eval::evaluate_trajectories(
        &truth_poses,
        &est,
        &TrajectoryOptions::default(),
    )
    .map_err(|e| e.to_string())
}

/// SLAM over `fused` and the odometry of `log` ([`replay_slam`]), scored against the truth.
fn slam_and_score(
    log: &SensorLog,
    profile: &RobotConfig,
    fused: &[Emitted],
    truth: &TruthTrack,
    truth_map: &OccupancyGrid,
) -> SlamOutcome {
    let slam = replay_slam(log, profile, fused);
    let mut trajectory = slam.trajectory();
    // One pose per stamp (a trajectory file's stamps must increase).
    trajectory.dedup_by_key(|p| p.stamp_ns);
    let map = slam.map();
    let confidence_map = slam.confidence_map();
    let map_report = score_map(truth_map, map.as_ref());
    let trajectory_report = score_trajectory(truth, &trajectory);
    SlamOutcome {
        map,
        confidence_map,
        trajectory,
        map_report,
        trajectory_report,
    }
}

/// Index of the run with the median map error (the lower middle of an even
/// count); runs without a score sort last; 0 when there is none.
fn median_run(runs: &[(Option<f64>, Option<f64>)]) -> usize {
    let mut order: Vec<usize> = (0..runs.len()).collect();
    order.sort_by(|&a, &b| {
        let key = |i: usize| runs[i].0.filter(|x| x.is_finite()).unwrap_or(f64::INFINITY);
        key(a).total_cmp(&key(b)).then(a.cmp(&b))
    });
    let scored = runs
        .iter()
        .filter(|r| r.0.is_some_and(f64::is_finite))
        .count();
    match scored {
        0 => 0,
        n => order[(n - 1) / 2],
    }
}

/// Every method over the same recording. Fusion runs first (cheap); SLAM
/// runs once per distinct sequence of fused scans (in clean air v1 and v2
/// usually hand SLAM the very same scans, and SLAM is deterministic) and per
/// random seed (`seeds` runs: the profile's `[slam] seed`, +1, …), up to
/// `threads` at a time. `smoke`: where the smoke was, on the truth map's
/// grid ([`super::smoke_region`]), for the fuzzy map's phantom count.
pub fn run_all(
    log: &SensorLog,
    profile: &RobotConfig,
    truth: &TruthTrack,
    truth_map: &OccupancyGrid,
    smoke: Option<&OccupancyGrid>,
    threads: usize,
    seeds: usize,
) -> anyhow::Result<Vec<MethodResult>> {
    let seeds = seeds.max(1);
    let mut fused: Vec<(Vec<Emitted>, f64)> = Vec::with_capacity(METHODS.len());
    for m in METHODS {
        fused.push(fuse(log, profile, m)?);
    }
    let noise = LaserNoiseModel::from_config(&profile.slam);
    // The first method with the same SLAM input does the work.
    let owner: Vec<usize> = (0..METHODS.len())
        .map(|i| {
            (0..i)
                .find(|&j| {
                    fused[j].0.len() == fused[i].0.len()
                        && fused[j]
                            .0
                            .iter()
                            .zip(&fused[i].0)
                            .all(|(a, b)| a.0 == b.0 && same_slam_input(&a.1, &b.1, &noise))
                })
                .unwrap_or(i)
        })
        .collect();
    let jobs: Vec<(usize, usize)> = (0..METHODS.len())
        .filter(|&i| owner[i] == i)
        .flat_map(|i| (0..seeds).map(move |k| (i, k)))
        .collect();
    let profiles: Vec<RobotConfig> = (0..seeds)
        .map(|k| {
            let mut p = profile.clone();
            p.slam.seed = p.slam.seed.wrapping_add(k as u64);
            p
        })
        .collect();
    let next = std::sync::atomic::AtomicUsize::new(0);
    let outcomes: std::sync::Mutex<Vec<Vec<Option<SlamOutcome>>>> =
        std::sync::Mutex::new(vec![vec![None; seeds]; METHODS.len()]);
    std::thread::scope(|s| {
        for _ in 0..threads.clamp(1, jobs.len().max(1)) {
            s.spawn(|| {
                loop {
                    let k = next.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                    let Some(&(i, seed)) = jobs.get(k) else { break };
                    let o = slam_and_score(log, &profiles[seed], &fused[i].0, truth, truth_map);
                    if let Ok(mut g) = outcomes.lock() {
                        g[i][seed] = Some(o);
                    }
                }
            });
        }
    });
    let outcomes = outcomes
        .into_inner()
        .map_err(|_| anyhow::anyhow!("a SLAM run panicked"))?;
    let mut results = Vec::with_capacity(METHODS.len());
    for (i, m) in METHODS.into_iter().enumerate() {
        let all = &outcomes[owner[i]];
        let runs: Vec<(Option<f64>, Option<f64>)> = all
            .iter()
            .map(|o| match o {
                Some(o) => (
                    o.map_report.as_ref().ok().map(|r| r.knn_error_m),
                    o.trajectory_report.as_ref().ok().map(|r| r.ate_m.rmse),
                ),
                None => (None, None),
            })
            .collect();
        // The run shown (map, trajectory, per-direction errors): the median
        // by map error, so one lucky or unlucky seed is not the picture.
        let shown = median_run(&runs);
        let o = all
            .get(shown)
            .cloned()
            .flatten()
            .ok_or_else(|| anyhow::anyhow!("the {} SLAM run did not finish", m.as_str()))?;
        let (f, usage) = &fused[i];
        let (walls, phantoms) = match (&o.confidence_map, &o.map_report) {
            (Some(conf), Ok(rep)) => {
                let mt = profile.laser.mount;
                let (w, p) = fuzzy_walls(
                    &fused[i].0,
                    &o.trajectory,
                    conf,
                    &rep.alignment,
                    truth_map,
                    smoke,
                    Pose2::new(mt.x, mt.y, mt.yaw_rad()),
                );
                (Some(w), p)
            }
            _ => (None, Vec::new()),
        };
        results.push(MethodResult {
            method: m,
            fuzzy_walls: walls,
            fuzzy_phantoms: phantoms,
            map: o.map,
            confidence_map: o.confidence_map,
            trajectory: o.trajectory,
            series: f
                .iter()
                .map(|(_, f)| SeriesPoint {
                    stamp_ns: f.scan.header.stamp_ns,
                    smoke_level: f.smoke_level,
                    laser_spread: f.laser_spread,
                    sonar_usage: f.sonar_usage(),
                })
                .collect(),
            sonar_usage: *usage,
            scans: f.len() as u64,
            same_slam_input_as: (owner[i] != i).then(|| METHODS[owner[i]]),
            map_report: o.map_report,
            trajectory_report: o.trajectory_report,
            runs,
            laser_verdict: None,
        });
    }
    Ok(results)
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_shared_types::BeamReading;

    /// A 6-beam scan at `stamp_ns` with these ranges (`None`: no return).
    fn scan(stamp_ns: u64, ranges: [Option<f32>; 6]) -> Box<LaserScan> {
        let mut s = Box::new(LaserScan::default());
        s.header.stamp_ns = stamp_ns;
        s.count = 6;
        for (i, r) in ranges.into_iter().enumerate() {
            s.set_beam(i, r.map_or(BeamReading::NoReturn, BeamReading::Range));
        }
        s
    }

    /// The beams of a scan the smoke changed or left alone, kept or withheld,
    /// are counted as such; the twin is paired by time since its own start.
    #[test]
    fn the_laser_verdict_counts_phantoms_kept_and_walls_withheld() {
        let mut smoky = SensorLog::default();
        let mut twin = SensorLog::default();
        // Beams: 0 untouched and kept; 1 untouched, withheld; 2 a smoke
        // return kept (a phantom); 3 a smoke return withheld; 4 a return
        // where the twin had none, kept; 5 no return in the smoky scan.
        let smoky_scan = scan(
            5_000_000_000,
            [Some(2.0), Some(3.0), Some(0.8), Some(0.9), Some(1.2), None],
        );
        smoky.lasers.push(smoky_scan.clone());
        // The twin's clock started 1 s later; its ranges differ by the noise only.
        twin.lasers.push(scan(
            6_000_000_000,
            [
                Some(2.05),
                Some(2.95),
                Some(2.5),
                Some(2.6),
                None,
                Some(4.0),
            ],
        ));
        let mut f = FusedScan {
            scan: *smoky_scan,
            ..FusedScan::default()
        };
        for i in [1, 3] {
            f.beam_source[i] = SectionSource::Neither as u8;
            f.scan.set_beam(i, BeamReading::BeyondMax);
        }
        let v = laser_verdict(&[(0, f)], &smoky, &twin);
        assert_eq!(
            v,
            LaserVerdict {
                scans: 1,
                smoke_beams: 3,
                smoke_beams_kept: 2,
                clean_beams: 2,
                clean_beams_withheld: 1,
            }
        );
        assert_eq!(v.smoke_kept_share(), Some(2.0 / 3.0));
        assert_eq!(v.clean_withheld_share(), Some(0.5));
        // A fused scan without a twin scan at its time is not judged.
        let mut late = f;
        late.scan.header.stamp_ns += 1_000_000_000;
        assert_eq!(laser_verdict(&[(0, late)], &smoky, &twin).scans, 0);
    }

    #[test]
    fn the_run_shown_is_the_median_by_map_error() {
        let r = |e: Option<f64>| (e, Some(0.1));
        assert_eq!(
            median_run(&[r(Some(0.38)), r(Some(0.13)), r(Some(0.12))]),
            1
        );
        assert_eq!(median_run(&[r(Some(0.2)), r(Some(0.1))]), 1);
        assert_eq!(median_run(&[r(None), r(Some(0.3)), r(Some(0.1))]), 2);
        assert_eq!(median_run(&[r(Some(0.5))]), 0);
        assert_eq!(median_run(&[r(None), r(Some(f64::NAN))]), 0);
        assert_eq!(median_run(&[]), 0);
    }

    #[test]
    fn slam_results_are_shared_only_for_identical_scans() {
        let profile = smokenav_sim_world::Scenario::builtin("mrl-clean")
            .unwrap()
            .profile;
        let mut a = FusedScan::default();
        a.scan.count = 3;
        a.scan.range_max = 5.6;
        for i in 0..3 {
            a.scan
                .set_beam(i, smokenav_shared_types::BeamReading::Range(1.0 + i as f32));
        }
        let noise = LaserNoiseModel::from_config(&profile.slam);
        let b = a;
        assert!(same_slam_input(&a, &b, &noise));
        // A beam that came from the sonar has another noise model in SLAM.
        let mut c = a;
        c.beam_source[1] = smokenav_shared_types::SectionSource::Sonar as u8;
        assert!(!same_slam_input(&a, &c, &noise));
        // A smoke level that changes the laser noise factor changes the input.
        let mut d = a;
        d.smoke_level = 300.0;
        assert!(!same_slam_input(&a, &d, &noise));
        let mut e = a;
        e.scan
            .set_beam(2, smokenav_shared_types::BeamReading::NoReturn);
        assert!(!same_slam_input(&a, &e, &noise));
    }
}
