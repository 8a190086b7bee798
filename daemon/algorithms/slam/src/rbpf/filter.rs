//! The Rao-Blackwellised particle filter (Grisetti et al., GMapping class).
//!
//! Each particle carries a pose, a weight, its own occupancy grid (tiles
//! shared copy-on-write with its relatives) and, optionally, its trajectory as
//! a node in a tree shared with its ancestors. Per processed scan:
//!
//! 1. the odometry delta (the pipeline's front end has corrected it) moves
//!    every particle through the motion model;
//! 2. each particle's pose is refined by scan matching against its own map
//!    (the improved proposal): hill climbing, then a few least-squares steps
//!    on the matched points;
//! 3. its weight grows by the scan likelihood at the refined pose, smoothed by
//!    `1 / (ogain · N)`;
//! 4. if the effective sample size falls below `resample_threshold · N` the
//!    particles are resampled (systematic resampling);
//! 5. once the robot moved `map_update_m` or turned `map_update_rad` since the
//!    last write, the scan is written into every particle's map at its pose.
//!    Writing every scan would copy each scan's small matching error into the
//!    map five times per metre, and a map built from a particle's own recent
//!    poses lets that error accumulate.
//!
//! Scans the pipeline's motion filter holds back only do step 1
//! ([`SlamBackend::predict`]).
//!
//! A scan the fusion mostly withheld from the laser (smoke) skips step 2 and
//! resampling, and in step 1 moves every particle by the odometry alone,
//! without sampling the motion noise: with the laser withheld nothing can
//! tell the sampled poses apart (the sonar's weight is no better than chance
//! at it), so the noise only made the best particle a random walk through the
//! smoke, and its map kept that walk. The particles keep the spread they had
//! when the laser went, and scan matching takes them up again when it is
//! back. On the dense-smoke trial's recording of `./demo` this took the RBPF
//! from 0.069–0.288 m map error over nine seeds (mean 0.110 m) to
//! 0.072–0.080 m (mean 0.074 m).
//!
//! Steps 2, 3 and 5 are each particle's own work: with `threads` > 1 they
//! run side by side on a pool of that many threads, made once with the
//! filter. That cuts the time from a scan to its pose (offline on two
//! cores by 45 %, live by 10–25 %), not the CPU time, and changes no result: each
//! particle reads only its own map and the shared scan, and the sums are of
//! integers or in particle order.

use super::matcher::{self, MatchParams, PreparedScan};
use super::motion::MotionModel;
use super::resample;
use crate::backend::{MAX_WITHHELD_TO_REFINE, SlamBackend, SlamUpdate, StampedPose};
use crate::grid::{BeamEnd, LogOddsModel, TiledGrid};
use crate::scan::RangeScan;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use smokenav_platform_config::SlamSection;
use smokenav_platform_map::OccupancyGrid;
use smokenav_shared_types::Pose2;
use smokenav_shared_types::Rng;
use std::collections::HashSet;
use std::sync::Arc;

/// A pose in a particle's history; parents are shared between descendants.
#[derive(Debug)]
pub struct PathNode {
    pub pose: Pose2,
    pub stamp_ns: u64,
    parent: Option<Arc<PathNode>>,
}

impl Drop for PathNode {
    fn drop(&mut self) {
        // Unlink iteratively: a long history would otherwise drop recursively and overflow the stack.
        let mut next = self.parent.take();
        while let Some(node) = next {
            match Arc::try_unwrap(node) {
                Ok(mut n) => next = n.parent.take(),
                Err(_) => break,
            }
        }
    }
}

#[derive(Debug, Clone)]
pub struct Particle {
    pub pose: Pose2,
    /// Log-weight accumulated since the last resampling (smoothed).
    pub log_weight: f64,
    /// Log-weight accumulated over the particle's whole ancestry: picks the best particle.
    pub total_log_weight: f64,
    pub grid: TiledGrid,
    path: Option<Arc<PathNode>>,
}

/// Figures about the filter's state, for logs and health.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FilterStats {
    /// Scans used (matched and weighed).
    pub updates: u64,
    /// Scans held back by the motion filter (odometry only).
    pub predictions: u64,
    pub resamples: u64,
    /// Updates with no usable beam (motion only).
    pub empty_scans: u64,
    /// Matching-score evaluations over all particles and scans.
    pub match_evaluations: u64,
    /// Updates that wrote the scan into the maps.
    pub map_updates: u64,
    /// Updates without scan matching: too few laser endpoints (odometry and the sonar only).
    pub unmatched_updates: u64,
    /// Of those, updates left unmatched because the fusion withheld more than
    /// [`MAX_WITHHELD_TO_REFINE`] of the scan from the laser.
    pub withheld_updates: u64,
    /// Resamplings put off: the weights fell below the threshold on a scan
    /// mostly withheld from the laser (see [`MAX_WITHHELD_TO_REFINE`]).
    pub held_resamples: u64,
}

/// The particle filter's own parameters (from `[slam]`).
#[derive(Debug, Clone)]
pub struct RbpfParams {
    pub particles: usize,
    /// Cell size of the particles' maps, m.
    pub resolution_m: f64,
    /// Seed of the filter's random numbers.
    pub seed: u64,
    /// Log-weights are divided by `ogain × particles`.
    pub ogain: f64,
    /// Scan-match only with at least this many laser endpoints.
    pub min_match_laser_points: usize,
    /// Resample below this share of N_eff.
    pub resample_threshold: f64,
    /// Motion since the last map write that makes the next write due, m and rad.
    pub map_update_m: f64,
    pub map_update_rad: f64,
    pub laser_model: LogOddsModel,
    /// The same with the sonar's hit log-odds.
    pub sonar_model: LogOddsModel,
    pub matching: MatchParams,
    pub motion: MotionModel,
    /// Threads that match, weigh and write the particles side by side (1: on
    /// the caller's thread alone).
    pub threads: usize,
}

impl RbpfParams {
    pub fn from_config(c: &SlamSection) -> Self {
        Self {
            particles: c.particles.max(1),
            resolution_m: c.resolution_m,
            seed: c.seed,
            ogain: c.ogain,
            min_match_laser_points: c.min_match_laser_points as usize,
            resample_threshold: c.resample_threshold,
            map_update_m: c.map_update_m,
            map_update_rad: c.map_update_rad,
            laser_model: LogOddsModel::new(c.hit_logodds, c.miss_logodds, c.max_logodds),
            sonar_model: LogOddsModel::new(c.sonar_hit_logodds, c.miss_logodds, c.max_logodds),
            matching: MatchParams::from_config(c),
            motion: MotionModel::from_config(c),
            threads: match c.threads {
                0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
                n => n,
            }
            .min(c.particles.max(1)),
        }
    }
}

pub struct Rbpf {
    p: RbpfParams,
    particles: Vec<Particle>,
    rng: Rng,
    keep_paths: bool,
    prepared: PreparedScan,
    /// Odometry of the previous scan.
    last_odom: Option<Pose2>,
    /// Motion since the scans were last written into the maps.
    since_map_dist: f64,
    since_map_rot: f64,
    best: usize,
    initial_pose: Pose2,
    /// Ignore the odometry difference at the next scan (its frame jumped).
    odometry_jumped: bool,
    last_n_eff: f64,
    stats: FilterStats,
    /// Bumped whenever the best particle's map may export differently.
    map_revision: u64,
    /// The threads of steps 2, 3 and 5 (`None`: one thread, the caller's).
    pool: Option<rayon::ThreadPool>,
    // Reused buffers.
    world_beams: Vec<BeamEnd>,
    weights: Vec<f64>,
}

impl Rbpf {
    /// A filter with parameters `p`. `keep_paths` keeps every particle's
    /// trajectory (needed to write the smoothed trajectory of the best particle
    /// offline; memory grows with the number of scans).
    pub fn new(p: RbpfParams, keep_paths: bool) -> Self {
        let pool = (p.threads > 1)
            .then(|| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(p.threads)
                    .thread_name(|i| format!("rbpf-{i}"))
                    .build()
                    .map_err(|e| {
                        tracing::warn!(error = %e, threads = p.threads, "particle filter threads not started; matching on one thread");
                    })
                    .ok()
            })
            .flatten();
        Self {
            pool,
            particles: Vec::new(),
            rng: Rng::new(p.seed, 0),
            keep_paths,
            prepared: PreparedScan::default(),
            last_odom: None,
            since_map_dist: 0.0,
            since_map_rot: 0.0,
            best: 0,
            initial_pose: Pose2::default(),
            odometry_jumped: false,
            last_n_eff: p.particles as f64,
            stats: FilterStats::default(),
            map_revision: 0,
            world_beams: Vec::new(),
            weights: Vec::new(),
            p,
        }
    }

    /// Threads the particles are matched on: the pool's, or 1 without one
    /// (asked for one, or the pool could not be started).
    pub fn threads(&self) -> usize {
        self.pool.as_ref().map_or(1, |p| p.current_num_threads())
    }

    pub fn particles(&self) -> &[Particle] {
        &self.particles
    }

    pub fn stats(&self) -> FilterStats {
        self.stats
    }

    pub fn best_index(&self) -> usize {
        self.best
    }

    /// Distinct map tiles held by all particles together, and what they weigh in bytes.
    pub fn map_memory(&self) -> (usize, usize) {
        let mut seen = HashSet::new();
        for p in &self.particles {
            seen.extend(p.grid.tile_ptrs());
        }
        (seen.len(), seen.len() * TiledGrid::TILE_BYTES)
    }

    /// Writes the scan into every particle's map (step 5).
    fn integrate_all(&mut self) {
        let (prepared, p) = (&self.prepared, &self.p);
        match &self.pool {
            Some(pool) => pool.install(|| {
                // A buffer per piece of work rayon splits off: a few per map
                // write, which comes every half metre, not per scan.
                self.particles
                    .par_iter_mut()
                    .for_each_init(Vec::new, |buf, part| integrate(part, prepared, p, buf));
            }),
            None => {
                for part in &mut self.particles {
                    integrate(part, prepared, p, &mut self.world_beams);
                }
            }
        }
    }

    fn push_path(&mut self, stamp_ns: u64) {
        if !self.keep_paths {
            return;
        }
        for p in &mut self.particles {
            p.path = Some(Arc::new(PathNode {
                pose: p.pose,
                stamp_ns,
                parent: p.path.take(),
            }));
        }
    }

    /// Normalised weights into `self.weights`; returns N_eff.
    fn normalise(&mut self) -> f64 {
        let max = self
            .particles
            .iter()
            .map(|p| p.log_weight)
            .fold(f64::NEG_INFINITY, f64::max);
        self.weights.clear();
        self.weights
            .extend(self.particles.iter().map(|p| (p.log_weight - max).exp()));
        let sum: f64 = self.weights.iter().sum();
        if !(sum.is_finite() && sum > 0.0) {
            let n = self.weights.len() as f64;
            self.weights.iter_mut().for_each(|w| *w = 1.0 / n);
        } else {
            self.weights.iter_mut().for_each(|w| *w /= sum);
        }
        1.0 / self.weights.iter().map(|w| w * w).sum::<f64>()
    }

    fn resample(&mut self) {
        let picks = resample::systematic(&self.weights, self.rng.uniform());
        let next: Vec<Particle> = picks
            .map(|i| {
                let mut child = self.particles[i].clone();
                child.log_weight = 0.0;
                child
            })
            .collect();
        self.particles = next;
        self.stats.resamples += 1;
        // The best index may now name a copy of another particle.
        self.map_revision += 1;
    }

    fn pick_best(&mut self) {
        let before = self.best;
        self.best = self
            .particles
            .iter()
            .enumerate()
            .fold((0, f64::NEG_INFINITY), |(bi, bw), (i, p)| {
                if p.total_log_weight > bw {
                    (i, p.total_log_weight)
                } else {
                    (bi, bw)
                }
            })
            .0;
        if self.best != before {
            self.map_revision += 1;
        }
    }

    /// Weighted covariance of the particles' poses (the heading's mean is circular).
    fn covariance(&self) -> Matrix3<f64> {
        let w = &self.weights;
        let n = self.particles.len();
        if w.len() != n || n == 0 {
            return Matrix3::zeros();
        }
        let (mut mx, mut my, mut ms, mut mc) = (0.0, 0.0, 0.0, 0.0);
        for (p, &wi) in self.particles.iter().zip(w) {
            mx += wi * p.pose.x;
            my += wi * p.pose.y;
            ms += wi * p.pose.theta.sin();
            mc += wi * p.pose.theta.cos();
        }
        let mt = ms.atan2(mc);
        let mut c = Matrix3::zeros();
        for (p, &wi) in self.particles.iter().zip(w) {
            let d = Vector3::new(
                p.pose.x - mx,
                p.pose.y - my,
                smokenav_shared_types::odom::normalize_angle(p.pose.theta - mt),
            );
            c += (d * wi) * d.transpose();
        }
        c
    }

    fn output(&self, stamp_ns: u64, processed: bool, resampled: bool) -> SlamUpdate {
        SlamUpdate {
            stamp_ns,
            pose: self
                .particles
                .get(self.best)
                .map(|p| p.pose)
                .unwrap_or_default(),
            covariance: self.covariance(),
            n_eff: self.last_n_eff,
            particles: self.particles.len(),
            processed,
            resampled,
        }
    }

    /// Every particle starts at the initial pose with the same map.
    fn start(&mut self, odom: Pose2, stamp_ns: u64) -> SlamUpdate {
        self.last_odom = Some(odom);
        let n = self.p.particles;
        let first = Particle {
            pose: self.initial_pose,
            log_weight: 0.0,
            total_log_weight: 0.0,
            grid: TiledGrid::new(self.p.resolution_m),
            path: None,
        };
        self.particles = vec![first];
        integrate(
            &mut self.particles[0],
            &self.prepared,
            &self.p,
            &mut self.world_beams,
        );
        let template = self.particles[0].clone();
        self.particles.resize(n, template);
        self.weights = vec![1.0 / n as f64; n];
        self.push_path(stamp_ns);
        self.stats.updates += 1;
        self.stats.map_updates += 1;
        self.map_revision += 1;
        self.output(stamp_ns, true, false)
    }

    /// Moves every particle by the odometry since the previous scan, through
    /// the motion model, or exactly by it without `noise`; `None` before the
    /// first scan.
    fn move_particles(&mut self, odom: &Pose2, noise: bool) -> Option<()> {
        let odom = if odom.is_finite() {
            *odom
        } else {
            self.last_odom?
        };
        let last = self.last_odom.replace(odom)?;
        let delta = if std::mem::take(&mut self.odometry_jumped) {
            Pose2::default()
        } else {
            last.between(&odom)
        };
        for i in 0..self.particles.len() {
            let pose = self.particles[i].pose;
            self.particles[i].pose = if noise {
                self.p.motion.sample(&pose, &delta, &mut self.rng)
            } else {
                pose.compose(&delta)
            };
        }
        self.since_map_dist += delta.translation_norm();
        self.since_map_rot += delta.theta.abs();
        Some(())
    }
}

/// Writes the scan into one particle's map at its pose, laser beams first,
/// then sonar beams with their weaker hit (an arc's end is a guess at where
/// in the cone the echo came from). `buf` is scratch.
fn integrate(
    p: &mut Particle,
    prepared: &PreparedScan,
    params: &RbpfParams,
    buf: &mut Vec<BeamEnd>,
) {
    let sensor = p.pose.compose(&prepared.sensor);
    let (s, c) = p.pose.theta.sin_cos();
    for sonar in [false, true] {
        buf.clear();
        for b in prepared.beams.iter().filter(|b| b.sonar == sonar) {
            buf.push(BeamEnd {
                ex: p.pose.x + c * b.x - s * b.y,
                ey: p.pose.y + s * b.x + c * b.y,
                hit: b.hit && !b.smoke_return,
            });
        }
        let model = if sonar {
            &params.sonar_model
        } else {
            &params.laser_model
        };
        p.grid.integrate(&sensor, buf, model);
    }
}

impl SlamBackend for Rbpf {
    fn name(&self) -> &'static str {
        "rbpf"
    }

    fn process(&mut self, scan: &RangeScan, odom: &Pose2) -> SlamUpdate {
        let stamp_ns = scan.stamp_ns;
        self.prepared.prepare(scan, &self.p.matching);
        if self.prepared.points.is_empty() {
            self.stats.empty_scans += 1;
        }
        if self.particles.is_empty() {
            let odom = if odom.is_finite() {
                *odom
            } else {
                Pose2::default()
            };
            return self.start(odom, stamp_ns);
        }
        let withheld = scan.withheld_share > MAX_WITHHELD_TO_REFINE;
        self.move_particles(odom, !withheld);
        self.stats.updates += 1;

        let gain = 1.0 / (self.p.ogain * self.particles.len() as f64);
        if !self.prepared.points.is_empty() {
            let laser_points = self.prepared.points.iter().filter(|p| p.from_laser).count();
            let match_scan = laser_points >= self.p.min_match_laser_points && !withheld;
            if !match_scan {
                self.stats.unmatched_updates += 1;
                self.stats.withheld_updates += u64::from(withheld);
            }
            let (prepared, matching) = (&self.prepared, &self.p.matching);
            // Steps 2 and 3 for one particle; returns its matcher evaluations.
            let refine_and_weigh = |p: &mut Particle| -> u64 {
                let mut evaluations = 0;
                if match_scan {
                    let refined = matcher::refine(&p.grid, prepared, &p.pose, matching);
                    evaluations = refined.evaluations as u64;
                    if refined.score > 0.0 {
                        p.pose = refined.pose;
                    }
                }
                let (l, _) =
                    matcher::log_likelihood(&p.grid, prepared, &p.pose, matching.null_likelihood);
                p.log_weight += gain * l;
                p.total_log_weight += gain * l;
                evaluations
            };
            self.stats.match_evaluations += match &self.pool {
                Some(pool) => {
                    pool.install(|| self.particles.par_iter_mut().map(refine_and_weigh).sum())
                }
                None => self.particles.iter_mut().map(refine_and_weigh).sum::<u64>(),
            };
        }
        self.last_n_eff = self.normalise();
        self.pick_best();
        let mut resampled = false;
        let degenerate = self.last_n_eff < self.p.resample_threshold * self.particles.len() as f64;
        if degenerate && withheld {
            self.stats.held_resamples += 1;
        } else if degenerate {
            self.resample();
            resampled = true;
            self.weights
                .iter_mut()
                .for_each(|w| *w = 1.0 / self.particles.len() as f64);
            self.pick_best();
        }
        if self.since_map_dist >= self.p.map_update_m || self.since_map_rot >= self.p.map_update_rad
        {
            self.since_map_dist = 0.0;
            self.since_map_rot = 0.0;
            self.stats.map_updates += 1;
            self.map_revision += 1;
            self.integrate_all();
        }
        self.push_path(stamp_ns);
        self.output(stamp_ns, true, resampled)
    }

    fn predict(&mut self, stamp_ns: u64, odom: &Pose2) -> SlamUpdate {
        if self.move_particles(odom, true).is_some() {
            self.stats.predictions += 1;
            self.push_path(stamp_ns);
        }
        self.output(stamp_ns, false, false)
    }

    fn odometry_reset(&mut self) {
        self.odometry_jumped = true;
    }

    fn set_initial_pose(&mut self, pose: Pose2) {
        if self.particles.is_empty() && pose.is_finite() {
            self.initial_pose = pose;
        }
    }

    fn pose(&self) -> Option<Pose2> {
        self.particles.get(self.best).map(|p| p.pose)
    }

    fn map_revision(&self) -> u64 {
        self.map_revision
    }

    fn map(&self) -> Option<OccupancyGrid> {
        self.particles
            .get(self.best)
            .map(|p| p.grid.to_occupancy_grid())
    }

    /// The best particle's grid shares its tiles (a tile written meanwhile
    /// is copied then): cheap to take, and a map grown large, or far by a
    /// pose gone wrong, is then drawn off the scans' path.
    fn map_job(&self) -> Option<crate::backend::MapJob> {
        let grid = self.particles.get(self.best).map(|p| p.grid.clone());
        Some(Box::new(move || grid.map(|g| g.to_occupancy_grid())))
    }

    fn trajectory(&self) -> Vec<StampedPose> {
        let mut out = Vec::new();
        let mut node = self
            .particles
            .get(self.best)
            .and_then(|p| p.path.as_deref());
        while let Some(n) = node {
            out.push(StampedPose {
                stamp_ns: n.stamp_ns,
                pose: n.pose,
            });
            node = n.parent.as_deref();
        }
        out.reverse();
        out
    }

    fn metrics(&self, emit: &mut dyn FnMut(&'static str, f64)) {
        let s = &self.stats;
        emit("updates", s.updates as f64);
        emit("predictions", s.predictions as f64);
        emit("resamples", s.resamples as f64);
        emit("map_updates", s.map_updates as f64);
        emit("unmatched_updates", s.unmatched_updates as f64);
        emit("withheld_updates", s.withheld_updates as f64);
        emit("n_eff", self.last_n_eff);
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scan::BeamKind;
    use crate::testkit::scan_at;

    fn rbpf(c: &SlamSection) -> Rbpf {
        Rbpf::new(RbpfParams::from_config(c), false)
    }

    fn cfg(particles: usize) -> SlamSection {
        SlamSection {
            particles,
            ..SlamSection::default()
        }
    }

    #[test]
    fn sonar_arcs_mark_walls_more_weakly_than_laser_endpoints() {
        // One scan of the room from the start, once as laser and once as sonar:
        // the same free space, but a sonar arc's cells are less sure to be wall.
        let p = Pose2::new(-3.5, -1.5, 0.0);
        let occupancy = |kind: BeamKind| {
            let mut slam = rbpf(&cfg(1));
            let mut scan = scan_at(&p, 0);
            scan.beams.iter_mut().for_each(|b| b.kind = kind);
            slam.process(&scan, &Pose2::default());
            let map = slam.map().unwrap();
            // Straight ahead (the map frame is the first pose) lies the room's
            // east wall, x = 5 in the room, 8.5 m away.
            let (cx, cy) = map.world_to_cell(8.5, 0.0).unwrap();
            let wall = (cx.saturating_sub(1)..cx + 2)
                .filter_map(|x| map.get(x, cy))
                .max()
                .unwrap();
            let (fx, fy) = map.world_to_cell(4.0, 0.0).unwrap();
            (wall, map.get(fx, fy).unwrap())
        };
        let (laser_wall, laser_free) = occupancy(BeamKind::Laser);
        let (sonar_wall, sonar_free) = occupancy(BeamKind::Sonar);
        assert!(
            sonar_wall > 50 && sonar_wall < laser_wall,
            "{sonar_wall} vs {laser_wall}"
        );
        assert_eq!(sonar_free, laser_free);
    }

    #[test]
    fn particles_matched_on_several_threads_come_out_as_on_one() {
        // The same drive on the caller's thread and on a pool of three: every
        // particle's pose and weights, the counters and the best map, bit for bit.
        let run = |threads: usize| {
            let c = SlamSection {
                threads,
                map_update_m: 0.2,
                ..cfg(12)
            };
            let mut slam = rbpf(&c);
            assert_eq!(slam.threads(), threads);
            let mut truth = Pose2::new(-3.5, -1.5, 0.0);
            for k in 0..12 {
                // The wheels claim 10 % more than the robot drove: matching has work.
                let odom = Pose2::new(0.11 * k as f64, 0.0, 0.0);
                slam.process(&scan_at(&truth, k * 100_000_000), &odom);
                truth.x += 0.1;
            }
            let particles: Vec<_> = slam
                .particles
                .iter()
                .map(|p| (p.pose, p.log_weight, p.total_log_weight))
                .collect();
            (particles, slam.stats(), slam.map().unwrap())
        };
        let (one, three) = (run(1), run(3));
        assert!(
            one.1.match_evaluations > 0 && one.1.map_updates > 2,
            "{:?}",
            one.1
        );
        assert_eq!(one.0, three.0);
        assert_eq!(one.1, three.1);
        assert_eq!(one.2, three.2);
    }

    /// A map job taken now draws the map of now, on another thread, though
    /// the filter writes on in the tiles it shares with the job meanwhile.
    #[test]
    fn a_map_job_draws_the_best_particles_map_as_it_was_when_taken() {
        let mut slam = rbpf(&SlamSection {
            map_update_m: 0.2,
            ..cfg(6)
        });
        assert!(slam.map_job().unwrap()().is_none(), "nothing before a scan");
        let mut truth = Pose2::new(-3.5, -1.5, 0.0);
        let mut k = 0;
        let mut drive = |slam: &mut Rbpf, steps: u64| {
            for _ in 0..steps {
                slam.process(
                    &scan_at(&truth, k * 100_000_000),
                    &Pose2::new(0.1 * k as f64, 0.0, 0.0),
                );
                truth.x += 0.1;
                k += 1;
            }
        };
        drive(&mut slam, 8);
        let (job, then) = (slam.map_job().unwrap(), slam.map().unwrap());
        drive(&mut slam, 20);
        assert!(slam.stats().map_updates > 4);
        let drawn = std::thread::spawn(job).join().unwrap().unwrap();
        assert_eq!(drawn, then);
        assert_ne!(slam.map().unwrap(), drawn, "the filter mapped on");
    }

    /// What the SLAM process checks before drawing a map: never more than
    /// the map drawn, and the trajectory's span.
    #[test]
    fn the_map_has_at_least_the_cells_its_trajectory_spans() {
        use crate::backend::map_cells_at_least;
        let c = cfg(6);
        // The path kept, as the SLAM process keeps it to clear the footprint.
        let mut slam = Rbpf::new(RbpfParams::from_config(&c), true);
        assert_eq!(map_cells_at_least(&slam, c.resolution_m), (0, 0));
        let mut truth = Pose2::new(-3.5, -1.5, 0.0);
        for k in 0..20u64 {
            slam.process(
                &scan_at(&truth, k * 100_000_000),
                &Pose2::new(0.1 * k as f64, 0.0, 0.0),
            );
            truth.x += 0.1;
        }
        let (w, h) = map_cells_at_least(&slam, c.resolution_m);
        let map = slam.map().unwrap();
        // 1.9 m driven along x at 5 cm cells.
        assert!((35..=40).contains(&w) && h >= 1, "{w} × {h}");
        assert!(
            w <= map.width && h <= map.height,
            "{w} × {h} of {} × {}",
            map.width,
            map.height
        );
    }

    #[test]
    fn systematic_resampling_copies_heavy_particles() {
        let mut slam = rbpf(&cfg(4));
        slam.process(&scan_at(&Pose2::new(-3.5, -1.5, 0.0), 0), &Pose2::default());
        for (i, p) in slam.particles.iter_mut().enumerate() {
            p.pose.x = i as f64;
            p.log_weight = if i == 2 { 0.0 } else { -10.0 };
        }
        let n_eff = slam.normalise();
        assert!(n_eff < 1.01, "{n_eff}");
        slam.resample();
        assert!(
            slam.particles
                .iter()
                .all(|p| p.pose.x == 2.0 && p.log_weight == 0.0)
        );
    }

    #[test]
    fn resampled_particles_share_tiles_until_they_write() {
        let c = SlamSection {
            map_update_m: 0.0,
            map_update_rad: 0.0,
            ..cfg(30)
        };
        let mut slam = rbpf(&c);
        let mut truth = Pose2::new(-3.5, -1.5, 0.0);
        for k in 0..5 {
            slam.process(
                &scan_at(&truth, k * 100_000_000),
                &Pose2::new(0.1 * k as f64, 0.0, 0.0),
            );
            truth.x += 0.1;
        }
        // Everything onto particle 0: 30 particles, one map.
        for (i, p) in slam.particles.iter_mut().enumerate() {
            p.log_weight = if i == 0 { 0.0 } else { -50.0 };
        }
        slam.normalise();
        slam.resample();
        let one = slam.particles[0].grid.tile_count();
        assert_eq!(slam.map_memory().0, one);
        // A scan with one 1 m beam: each particle copies only the one or two
        // 1.6 m tiles that beam crosses, not its whole map.
        let mut one_beam = scan_at(&truth, 500_000_000);
        one_beam.beams.iter_mut().for_each(|b| b.range = None);
        one_beam.beams[180].range = Some(1.0);
        slam.process(&one_beam, &Pose2::new(0.5, 0.0, 0.0));
        let (distinct, bytes) = slam.map_memory();
        assert!(distinct > one, "the beam was written");
        assert!(
            distinct <= one + 2 * 30,
            "{distinct} distinct tiles, {one} per particle"
        );
        assert!(
            distinct < 3 * one,
            "{distinct} distinct tiles, {one} per particle"
        );
        assert_eq!(bytes, distinct * TiledGrid::TILE_BYTES);
    }

    #[test]
    fn a_scan_mostly_withheld_from_the_laser_weighs_the_particles_but_does_not_move_them() {
        // The robot stands still while the wheels claim 0.2 m: matched, the
        // room pulls the particles back; withheld by the fusion, the same
        // laser beams only weigh them and the odometry carries the position.
        let p = Pose2::new(-3.5, -1.5, 0.0);
        let after = |withheld_share: f64| {
            let mut slam = rbpf(&cfg(10));
            for k in 0..3 {
                slam.process(&scan_at(&p, k * 100_000_000), &Pose2::default());
            }
            let before = slam.stats().match_evaluations;
            let mut scan = scan_at(&p, 300_000_000);
            scan.withheld_share = withheld_share;
            slam.process(&scan, &Pose2::new(0.2, 0.0, 0.0));
            let evaluations = slam.stats().match_evaluations - before;
            (slam.pose().unwrap(), evaluations, slam.stats())
        };
        let (matched, evaluations, stats) = after(MAX_WITHHELD_TO_REFINE);
        assert!(matched.x.abs() < 0.05, "{matched:?}");
        assert!(evaluations > 0);
        assert_eq!(stats.withheld_updates, 0);
        let (carried, evaluations, stats) = after(0.5);
        assert!((carried.x - 0.2).abs() < 0.05, "{carried:?}");
        assert_eq!(evaluations, 0);
        assert_eq!((stats.unmatched_updates, stats.withheld_updates), (1, 1));
    }

    #[test]
    fn a_scan_mostly_withheld_from_the_laser_moves_the_particles_by_the_odometry_alone() {
        // Seen by the laser the particles spread by the motion noise (and
        // matching); withheld, each moves exactly by the odometry and keeps
        // its place in the spread it had.
        let p = Pose2::new(-3.5, -1.5, 0.0);
        let step = 0.2;
        let moved = |withheld_share: f64| {
            let mut slam = rbpf(&cfg(10));
            slam.process(&scan_at(&p, 0), &Pose2::default());
            let before: Vec<Pose2> = slam.particles.iter().map(|q| q.pose).collect();
            let mut scan = scan_at(&p, 100_000_000);
            scan.withheld_share = withheld_share;
            slam.process(&scan, &Pose2::new(step, 0.0, 0.05));
            before
                .iter()
                .zip(&slam.particles)
                .map(|(b, q)| b.compose(&Pose2::new(step, 0.0, 0.05)).between(&q.pose))
                .map(|d| d.translation_norm() + d.theta.abs())
                .fold(0.0f64, f64::max)
        };
        assert!(moved(0.0) > 1e-3, "seen: {}", moved(0.0));
        assert!(moved(0.5) < 1e-12, "withheld: {}", moved(0.5));
    }

    #[test]
    fn a_scan_mostly_withheld_from_the_laser_never_resamples() {
        // Weights gone to one particle: a scan the laser sees resamples, one
        // the fusion mostly withheld puts it off until the laser is back.
        let p = Pose2::new(-3.5, -1.5, 0.0);
        let mut slam = rbpf(&cfg(10));
        slam.process(&scan_at(&p, 0), &Pose2::default());
        let degenerate = |slam: &mut Rbpf| {
            for (i, q) in slam.particles.iter_mut().enumerate() {
                q.log_weight = if i == 3 { 0.0 } else { -50.0 };
            }
        };
        let step = |slam: &mut Rbpf, k: u64, withheld_share: f64| {
            let mut scan = scan_at(&p, k * 100_000_000);
            scan.withheld_share = withheld_share;
            slam.process(&scan, &Pose2::default())
        };
        degenerate(&mut slam);
        let u = step(&mut slam, 1, 0.5);
        assert!(!u.resampled);
        assert_eq!(
            (slam.stats().resamples, slam.stats().held_resamples),
            (0, 1)
        );
        // The weights carried on: still one heavy particle, resampled on the
        // first scan the laser sees.
        let u = step(&mut slam, 2, 0.0);
        assert!(u.resampled);
        assert_eq!(
            (slam.stats().resamples, slam.stats().held_resamples),
            (1, 1)
        );
        degenerate(&mut slam);
        assert!(step(&mut slam, 3, MAX_WITHHELD_TO_REFINE).resampled);
    }

    #[test]
    fn maps_are_written_only_after_enough_motion() {
        let mut slam = rbpf(&cfg(3));
        for k in 0..12 {
            let truth = Pose2::new(-3.5 + 0.1 * k as f64, -1.5, 0.0);
            slam.process(
                &scan_at(&truth, k * 100_000_000),
                &Pose2::new(0.1 * k as f64, 0.0, 0.0),
            );
        }
        // Every scan updates the filter; the first scan, then every 0.5 m of the
        // 1.1 m driven, is written into the maps.
        assert_eq!(slam.stats().updates, 12);
        assert_eq!(slam.stats().map_updates, 3);
    }
}
