//! The Rao-Blackwellised particle filter (Grisetti et al., GMapping class).
//!
//! Each particle carries a pose, a weight, its own occupancy grid (tiles
//! shared copy-on-write with its relatives) and, optionally, its trajectory as
//! a node in a tree shared with its ancestors. Per processed scan:
//!
//! 1. the odometry delta (corrected by the front end if enabled) moves every
//!    particle through the motion model;
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

use crate::frontend::{FrontEnd, FrontEndParams};
use crate::grid::{BeamEnd, LogOddsModel, TiledGrid};
use crate::matcher::{self, MatchParams, PreparedScan};
use crate::motion::MotionModel;
use crate::pose::Pose2;
use crate::rng::Rng;
use crate::scan::RangeScan;
use crate::{SlamBackend, SlamUpdate, StampedPose};
use smokenav_platform_config::SlamSection;
use smokenav_platform_map::OccupancyGrid;
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
    pub scans: u64,
    pub updates: u64,
    pub resamples: u64,
    /// Scans whose front-end match was not trusted (prediction used).
    pub frontend_fallbacks: u64,
    /// Scans with no usable beam (motion only).
    pub empty_scans: u64,
    /// Matching-score evaluations over all particles and scans.
    pub match_evaluations: u64,
    /// Updates that wrote the scan into the maps.
    pub map_updates: u64,
    /// Updates without scan matching: too few laser endpoints (odometry and the sonar only).
    pub unmatched_updates: u64,
}

pub struct Rbpf {
    cfg: SlamSection,
    mp: MatchParams,
    motion: MotionModel,
    model: LogOddsModel,
    /// The same with the sonar's hit log-odds.
    sonar_model: LogOddsModel,
    particles: Vec<Particle>,
    rng: Rng,
    frontend: Option<FrontEnd>,
    keep_paths: bool,
    prepared: PreparedScan,
    /// Odometry (front-end corrected) of the previous scan.
    last_odom: Option<Pose2>,
    /// Motion and time since the last filter update, for the update thresholds.
    since_update_dist: f64,
    since_update_rot: f64,
    last_update_ns: u64,
    /// Motion since the scans were last written into the maps.
    since_map_dist: f64,
    since_map_rot: f64,
    best: usize,
    initial_pose: Pose2,
    /// Without a front end: ignore the odometry difference at the next scan.
    odometry_jumped: bool,
    last_n_eff: f64,
    stats: FilterStats,
    // Reused buffers.
    world_beams: Vec<BeamEnd>,
    weights: Vec<f64>,
}

impl Rbpf {
    /// A filter with `cfg`'s parameters. `keep_paths` keeps every particle's
    /// trajectory (needed to write the smoothed trajectory of the best particle
    /// offline; memory grows with the number of scans).
    pub fn new(cfg: &SlamSection, keep_paths: bool) -> Self {
        let mp = MatchParams::from_config(cfg);
        let frontend = cfg.frontend.then(|| {
            FrontEnd::new(FrontEndParams {
                resolution: cfg.resolution_m,
                window_m: cfg.frontend_window_m,
                window_rad: cfg.frontend_window_rad,
                max_scans: cfg.frontend_scans as usize,
            })
        });
        Self {
            mp,
            motion: MotionModel::from_config(cfg),
            model: LogOddsModel::new(cfg.hit_logodds, cfg.miss_logodds, cfg.max_logodds),
            sonar_model: LogOddsModel::new(
                cfg.sonar_hit_logodds,
                cfg.miss_logodds,
                cfg.max_logodds,
            ),
            particles: Vec::new(),
            rng: Rng::new(cfg.seed),
            frontend,
            keep_paths,
            prepared: PreparedScan::default(),
            last_odom: None,
            since_update_dist: 0.0,
            since_update_rot: 0.0,
            last_update_ns: 0,
            since_map_dist: 0.0,
            since_map_rot: 0.0,
            best: 0,
            initial_pose: Pose2::default(),
            odometry_jumped: false,
            last_n_eff: cfg.particles as f64,
            stats: FilterStats::default(),
            world_beams: Vec::new(),
            weights: Vec::new(),
            cfg: cfg.clone(),
        }
    }

    /// The odometry frame jumped (base reset or reconnected): the next scan's
    /// odometry is not compared with the previous one.
    pub fn odometry_reset(&mut self) {
        match &mut self.frontend {
            Some(fe) => fe.odometry_reset(),
            None => self.odometry_jumped = true,
        }
    }

    /// Where the first scan is placed in the map frame (default: the origin).
    /// Only has an effect before the first scan.
    pub fn set_initial_pose(&mut self, pose: Pose2) {
        if self.particles.is_empty() && pose.is_finite() {
            self.initial_pose = pose;
        }
    }

    /// The front end's corrected odometry of the last scan (its own drifting frame), if enabled.
    pub fn frontend_pose(&self) -> Option<Pose2> {
        self.frontend.as_ref().and(self.last_odom)
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

    fn integrate(&mut self, i: usize) {
        let p = &mut self.particles[i];
        let sensor = p.pose.compose(&self.prepared.sensor);
        let (s, c) = p.pose.theta.sin_cos();
        // Laser beams first, then sonar beams with their weaker hit (an arc's
        // end is a guess at where in the cone the echo came from).
        for sonar in [false, true] {
            self.world_beams.clear();
            for b in self.prepared.beams.iter().filter(|b| b.sonar == sonar) {
                self.world_beams.push(BeamEnd {
                    ex: p.pose.x + c * b.x - s * b.y,
                    ey: p.pose.y + s * b.x + c * b.y,
                    hit: b.hit,
                });
            }
            let model = if sonar {
                &self.sonar_model
            } else {
                &self.model
            };
            p.grid.integrate(&sensor, &self.world_beams, model);
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

    /// Systematic (low-variance) resampling.
    fn resample(&mut self) {
        let n = self.particles.len();
        let step = 1.0 / n as f64;
        let mut u = self.rng.uniform() * step;
        let mut cumulative = self.weights[0];
        let mut i = 0;
        let mut next = Vec::with_capacity(n);
        for _ in 0..n {
            while u > cumulative && i + 1 < n {
                i += 1;
                cumulative += self.weights[i];
            }
            let mut child = self.particles[i].clone();
            child.log_weight = 0.0;
            next.push(child);
            u += step;
        }
        self.particles = next;
        self.stats.resamples += 1;
    }

    fn pick_best(&mut self) {
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
    }

    fn covariance(&self) -> [f64; 9] {
        let w = &self.weights;
        let n = self.particles.len();
        if w.len() != n || n == 0 {
            return [0.0; 9];
        }
        let (mut mx, mut my, mut ms, mut mc) = (0.0, 0.0, 0.0, 0.0);
        for (p, &wi) in self.particles.iter().zip(w) {
            mx += wi * p.pose.x;
            my += wi * p.pose.y;
            ms += wi * p.pose.theta.sin();
            mc += wi * p.pose.theta.cos();
        }
        let mt = ms.atan2(mc);
        let mut c = [0.0; 9];
        for (p, &wi) in self.particles.iter().zip(w) {
            let d = [
                p.pose.x - mx,
                p.pose.y - my,
                smokenav_shared_types::odom::normalize_angle(p.pose.theta - mt),
            ];
            for r in 0..3 {
                for k in 0..3 {
                    c[r * 3 + k] += wi * d[r] * d[k];
                }
            }
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
}

impl SlamBackend for Rbpf {
    fn process(&mut self, scan: &RangeScan, odom: &Pose2) -> SlamUpdate {
        self.stats.scans += 1;
        let stamp_ns = scan.stamp_ns;
        self.prepared.prepare(scan, &self.mp);
        if self.prepared.points.is_empty() {
            self.stats.empty_scans += 1;
        }
        let odom = if odom.is_finite() {
            *odom
        } else {
            self.last_odom.unwrap_or_default()
        };
        let corrected = match &mut self.frontend {
            Some(fe) => {
                let t = fe.track(
                    self.prepared
                        .points
                        .iter()
                        .filter(|p| p.from_laser)
                        .map(|p| (p.hx, p.hy)),
                    &odom,
                    stamp_ns,
                );
                if t.score.is_none() && self.last_odom.is_some() {
                    self.stats.frontend_fallbacks += 1;
                }
                t.pose
            }
            None => odom,
        };

        let Some(last) = self.last_odom else {
            // First scan: every particle starts at the initial pose with the same map.
            self.last_odom = Some(corrected);
            self.last_update_ns = stamp_ns;
            let n = self.cfg.particles.max(1);
            let first = Particle {
                pose: self.initial_pose,
                log_weight: 0.0,
                total_log_weight: 0.0,
                grid: TiledGrid::new(self.cfg.resolution_m),
                path: None,
            };
            self.particles = vec![first];
            self.integrate(0);
            let template = self.particles[0].clone();
            self.particles.resize(n, template);
            self.weights = vec![1.0 / n as f64; n];
            self.push_path(stamp_ns);
            self.stats.updates += 1;
            self.stats.map_updates += 1;
            return self.output(stamp_ns, true, false);
        };

        let delta = if std::mem::take(&mut self.odometry_jumped) {
            Pose2::default()
        } else {
            corrected.relative_to(&last)
        };
        self.last_odom = Some(corrected);
        for i in 0..self.particles.len() {
            let pose = self.particles[i].pose;
            self.particles[i].pose = self.motion.sample(&pose, &delta, &mut self.rng);
        }
        self.since_update_dist += delta.translation_norm();
        self.since_update_rot += delta.theta.abs();
        self.since_map_dist += delta.translation_norm();
        self.since_map_rot += delta.theta.abs();
        let elapsed_s = stamp_ns.saturating_sub(self.last_update_ns) as f64 * 1e-9;
        let due = self.since_update_dist >= self.cfg.linear_update_m
            || self.since_update_rot >= self.cfg.angular_update_rad
            || (self.cfg.temporal_update_s >= 0.0 && elapsed_s > self.cfg.temporal_update_s);
        if !due {
            self.push_path(stamp_ns);
            return self.output(stamp_ns, false, false);
        }
        self.since_update_dist = 0.0;
        self.since_update_rot = 0.0;
        self.last_update_ns = stamp_ns;
        self.stats.updates += 1;

        let gain = 1.0 / (self.cfg.ogain * self.particles.len() as f64);
        if !self.prepared.points.is_empty() {
            let laser_points = self.prepared.points.iter().filter(|p| p.from_laser).count();
            let match_scan = laser_points >= self.cfg.min_match_laser_points as usize;
            if !match_scan {
                self.stats.unmatched_updates += 1;
            }
            for p in &mut self.particles {
                if match_scan {
                    let refined = matcher::refine(&p.grid, &self.prepared, &p.pose, &self.mp);
                    self.stats.match_evaluations += refined.evaluations as u64;
                    if refined.score > 0.0 {
                        p.pose = refined.pose;
                    }
                }
                let (l, _) = matcher::log_likelihood(
                    &p.grid,
                    &self.prepared,
                    &p.pose,
                    self.mp.null_likelihood,
                );
                p.log_weight += gain * l;
                p.total_log_weight += gain * l;
            }
        }
        self.last_n_eff = self.normalise();
        self.pick_best();
        let mut resampled = false;
        if self.last_n_eff < self.cfg.resample_threshold * self.particles.len() as f64 {
            self.resample();
            resampled = true;
            self.weights
                .iter_mut()
                .for_each(|w| *w = 1.0 / self.particles.len() as f64);
            self.pick_best();
        }
        if self.since_map_dist >= self.cfg.map_update_m
            || self.since_map_rot >= self.cfg.map_update_rad
        {
            self.since_map_dist = 0.0;
            self.since_map_rot = 0.0;
            self.stats.map_updates += 1;
            for i in 0..self.particles.len() {
                self.integrate(i);
            }
        }
        self.push_path(stamp_ns);
        self.output(stamp_ns, true, resampled)
    }

    fn pose(&self) -> Option<Pose2> {
        self.particles.get(self.best).map(|p| p.pose)
    }

    fn map(&self) -> Option<OccupancyGrid> {
        self.particles
            .get(self.best)
            .map(|p| p.grid.to_occupancy_grid())
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
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scan::{Beam, BeamKind};

    /// Wall segments of a 10 m × 6 m room with an inner wall and two pillars.
    const WALLS: [(f64, f64, f64, f64); 10] = [
        (-5.0, -3.0, 5.0, -3.0),
        (5.0, -3.0, 5.0, 3.0),
        (5.0, 3.0, -5.0, 3.0),
        (-5.0, 3.0, -5.0, -3.0),
        (0.0, 3.0, 0.0, 1.0),
        (2.0, -1.0, 2.3, -1.0),
        (2.3, -1.0, 2.3, -0.7),
        (-2.5, 0.5, -2.2, 0.5),
        (-2.2, 0.5, -2.2, 0.8),
        (-3.0, -3.0, -4.0, -2.0),
    ];

    /// Ray-cast range from `(x, y)` along `a` to the nearest wall.
    fn cast(x: f64, y: f64, a: f64) -> Option<f64> {
        let (dx, dy) = (a.cos(), a.sin());
        let mut best: Option<f64> = None;
        for (x1, y1, x2, y2) in WALLS {
            let (ex, ey) = (x2 - x1, y2 - y1);
            let den = dx * ey - dy * ex;
            if den.abs() < 1e-12 {
                continue;
            }
            let t = ((x1 - x) * ey - (y1 - y) * ex) / den;
            let u = ((x1 - x) * dy - (y1 - y) * dx) / den;
            if t > 0.0 && (0.0..=1.0).contains(&u) && best.is_none_or(|b| t < b) {
                best = Some(t);
            }
        }
        best
    }

    fn scan_at(truth: &Pose2, stamp_ns: u64) -> RangeScan {
        let mut s = RangeScan {
            stamp_ns,
            laser_noise_factor: 1.0,
            ..Default::default()
        };
        for i in 0..361 {
            let a = -std::f64::consts::FRAC_PI_2 + i as f64 * std::f64::consts::PI / 360.0;
            s.beams.push(Beam {
                angle: a as f32,
                range: cast(truth.x, truth.y, truth.theta + a).map(|r| r as f32),
                kind: BeamKind::Laser,
            });
        }
        s
    }

    fn cfg(particles: usize) -> SlamSection {
        SlamSection {
            particles,
            ..SlamSection::default()
        }
    }

    /// Drives an arc through the room; odometry over-reads distance by 5 % and
    /// turns by 3 %, so it drifts while the filter should not.
    fn drive(slam: &mut Rbpf, steps: usize) -> (Pose2, Pose2) {
        let start_truth = Pose2::new(-3.5, -1.5, 0.0);
        let mut truth = start_truth;
        let mut odom = Pose2::new(10.0, 20.0, 1.0);
        for k in 0..steps {
            slam.process(&scan_at(&truth, k as u64 * 100_000_000), &odom);
            let step = Pose2::new(0.1, 0.0, if k < 40 { 0.0 } else { 0.05 });
            truth = truth.compose(&step);
            odom = odom.compose(&Pose2::new(step.x * 1.05, 0.0, step.theta * 1.03));
        }
        // The map frame is the pose of the first scan: express the last scan's pose in it.
        let previous_truth = {
            // `truth` has advanced one step past the last scan; step back.
            let step = Pose2::new(0.1, 0.0, if steps - 1 < 40 { 0.0 } else { 0.05 });
            truth.compose(&step.inverse())
        };
        (
            previous_truth.relative_to(&start_truth),
            slam.pose().unwrap(),
        )
    }

    #[test]
    fn filter_tracks_a_robot_whose_odometry_drifts() {
        let mut slam = Rbpf::new(&cfg(10), true);
        let (truth, est) = drive(&mut slam, 70);
        // 7 m driven with odometry 5 % long and turns 3 % wide (0.35 m, 0.1 rad of drift).
        assert!(
            (est.x - truth.x).abs() < 0.05 && (est.y - truth.y).abs() < 0.05,
            "{est:?} vs {truth:?}"
        );
        assert!(
            (est.theta - truth.theta).abs() < 0.02,
            "{est:?} vs {truth:?}"
        );
        assert_eq!(slam.trajectory().len(), 70);
        assert_eq!(slam.stats().updates, 70);
        let map = slam.map().unwrap();
        // The map shows the inner wall at x = 0 (3.5 m right of the start), y from 1 to 3.
        let (cx, cy) = map.world_to_cell(3.5, 3.5).unwrap();
        let near_wall =
            (cx.saturating_sub(2)..cx + 3).any(|x| map.get(x, cy).is_some_and(|v| v > 50));
        assert!(near_wall);
    }

    #[test]
    fn scan_without_ranges_moves_the_particles_by_odometry() {
        let mut slam = Rbpf::new(&cfg(5), false);
        let p = Pose2::new(-3.5, -1.5, 0.0);
        slam.process(&scan_at(&p, 0), &Pose2::default());
        let mut empty = scan_at(&p, 100_000_000);
        empty.beams.iter_mut().for_each(|b| b.range = None);
        let u = slam.process(&empty, &Pose2::new(0.2, 0.0, 0.0));
        assert!(u.pose.is_finite());
        assert!((u.pose.x - 0.2).abs() < 0.1, "{u:?}");
        assert_eq!(slam.stats().empty_scans, 1);
        // No beams at all, and a NaN odometry reading: still no panic, pose kept finite.
        let none = RangeScan {
            stamp_ns: 200_000_000,
            ..Default::default()
        };
        let u = slam.process(&none, &Pose2::new(f64::NAN, 0.0, 0.0));
        assert!(u.pose.is_finite());
    }

    #[test]
    fn sonar_only_scans_weigh_but_do_not_drag_the_particles() {
        // In dense smoke the fused scan is sonar arcs only. Here they show the
        // room as seen from the start while the wheels report 0.5 m of travel:
        // a matcher would pull the pose back; the filter must follow the odometry.
        let mut slam = Rbpf::new(&cfg(10), false);
        let p = Pose2::new(-3.5, -1.5, 0.0);
        for k in 0..3 {
            slam.process(&scan_at(&p, k * 100_000_000), &Pose2::default());
        }
        let mut stale = scan_at(&p, 0);
        stale
            .beams
            .iter_mut()
            .for_each(|b| b.kind = BeamKind::Sonar);
        for k in 1..=5u64 {
            stale.stamp_ns = (3 + k) * 100_000_000;
            slam.process(&stale, &Pose2::new(0.1 * k as f64, 0.0, 0.0));
        }
        let est = slam.pose().unwrap();
        assert!((est.x - 0.5).abs() < 0.15, "{est:?}");
        assert!(slam.stats().unmatched_updates >= 1, "{:?}", slam.stats());
        // Laser scans are matched again as soon as they return.
        let before = slam.stats().match_evaluations;
        slam.process(
            &scan_at(&Pose2::new(-3.0, -1.5, 0.0), 900_000_000),
            &Pose2::new(0.5, 0.0, 0.0),
        );
        assert!(slam.stats().match_evaluations > before);
    }

    #[test]
    fn sonar_arcs_mark_walls_more_weakly_than_laser_endpoints() {
        // One scan of the room from the start, once as laser and once as sonar:
        // the same free space, but a sonar arc's cells are less sure to be wall.
        let p = Pose2::new(-3.5, -1.5, 0.0);
        let occupancy = |kind: BeamKind| {
            let mut slam = Rbpf::new(&cfg(1), false);
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
    fn systematic_resampling_copies_heavy_particles() {
        let mut slam = Rbpf::new(&cfg(4), false);
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
        let mut slam = Rbpf::new(&c, false);
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
    fn maps_are_written_only_after_enough_motion() {
        let mut slam = Rbpf::new(&cfg(3), false);
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

    #[test]
    fn update_thresholds_skip_scans_until_the_robot_moved() {
        let mut c = cfg(3);
        c.linear_update_m = 0.5;
        c.angular_update_rad = 0.8;
        let mut slam = Rbpf::new(&c, false);
        let mut processed = 0;
        for k in 0..12 {
            let truth = Pose2::new(-3.5 + 0.1 * k as f64, -1.5, 0.0);
            let u = slam.process(
                &scan_at(&truth, k * 100_000_000),
                &Pose2::new(0.1 * k as f64, 0.0, 0.0),
            );
            processed += usize::from(u.processed);
        }
        // The first scan, then every 0.5 m of the 1.1 m driven.
        assert_eq!(processed, 3);
    }
}
