//! Per-particle scan matching against the particle's own grid, and the scan
//! likelihood that weights the particle.
//!
//! For an endpoint the matcher looks at the cells within `kernel_size` of the
//! cell it falls in for the nearest occupied one whose partner cell, one step
//! back towards the sensor, is not occupied (so a wall seen from the wrong
//! side does not match). The distance `d` to that cell's centre gives the
//! match score `exp(-d²/2σ²)` and the log-likelihood `-d²/2σ_l²` (or the null
//! likelihood if nothing matches). σ is per beam: laser beams widen with the
//! obscurant, sonar beams use the sonar's own σ.
//!
//! The pose is refined by deterministic hill climbing: try ± one step in x, y
//! and θ, move to the best if it improves the score, otherwise halve the
//! steps, `iterations` times (GMapping's optimiser).
//!
//! Then the degeneracy check: along a corridor longer than the laser's range
//! the score is flat except where the particle's map ends, and the climb
//! slides back onto it (the corridor shrinks). The refined pose keeps its
//! correction only in the directions the scan's geometry constrains
//! ([`ScanConstraint`]); elsewhere the particle stays where the motion model
//! put it.

use crate::degeneracy::{DegeneracyParams, ScanConstraint};
use crate::grid::{TILE, TILE_SHIFT, Tile, TiledGrid};
use crate::scan::{BeamKind, Endpoint, EndpointLimits, RangeScan};
use smokenav_platform_config::SlamSection;
use smokenav_shared_types::Pose2;

/// An endpoint prepared for matching, in the robot frame.
#[derive(Debug, Clone, Copy)]
pub struct MatchPoint {
    pub hx: f64,
    pub hy: f64,
    /// A point one cell diagonal back along the beam: must not be occupied for a match.
    pub fx: f64,
    pub fy: f64,
    /// 1 / (2σ²) of the matching score.
    pub score_k: f64,
    /// 1 / (2σ_l²) of the likelihood.
    pub lik_k: f64,
    /// Search radius in cells.
    pub kernel: i32,
    /// The range came from the laser (not painted from a sonar cone).
    pub from_laser: bool,
}

/// A beam for map integration: endpoint in the robot frame, and whether it ends on an obstacle.
#[derive(Debug, Clone, Copy)]
pub struct RobotBeam {
    pub x: f64,
    pub y: f64,
    pub hit: bool,
    /// Painted from a sonar cone: its end is somewhere on an arc, not a point.
    pub sonar: bool,
    /// Painted from a sonar, off the middle of its arc (beyond
    /// `[slam] sonar_arc_middle`): the graph's map clears its cone but draws
    /// no wall at its end.
    pub arc_flank: bool,
    /// A laser return the sonar contradicts that jitters like a smoke
    /// cloud's (rougher than `[slam] smoke_return_rough_m`, see
    /// [`crate::scan::RangeScan::laser_roughness`]): the maps clear space
    /// up to it but draw no wall at its end.
    pub smoke_return: bool,
}

/// A scan turned into what matching and mapping need, computed once per scan
/// and shared by all particles. Buffers are reused between scans.
#[derive(Debug, Clone, Default)]
pub struct PreparedScan {
    pub sensor: Pose2,
    pub points: Vec<MatchPoint>,
    pub beams: Vec<RobotBeam>,
    /// What the laser endpoints constrain (robot frame).
    pub constraint: Option<ScanConstraint>,
    /// Share (0–1) of the endpoints painted from sonar cones.
    pub sonar_share: f64,
    /// The laser endpoints leave some direction of the pose unconstrained.
    pub degenerate: bool,
    endpoints: Vec<Endpoint>,
    laser_xy: Vec<(f64, f64)>,
}

/// The parameters of matching, taken from the config once.
#[derive(Debug, Clone)]
pub struct MatchParams {
    pub resolution: f64,
    pub max_range: f64,
    pub max_urange: f64,
    pub sigma: f64,
    pub sonar_sigma: f64,
    pub lsigma: f64,
    pub kernel: i32,
    pub lskip: usize,
    pub lstep: f64,
    pub astep: f64,
    pub iterations: u32,
    pub null_likelihood: f64,
    pub degeneracy: DegeneracyParams,
    /// `[slam] sonar_arc_middle`.
    pub sonar_arc_middle: f64,
    /// `[slam] smoke_return_rough_m` (0: off).
    pub smoke_return_rough_m: f64,
}

impl MatchParams {
    pub fn from_config(c: &SlamSection) -> Self {
        Self {
            resolution: c.resolution_m,
            max_range: c.max_range_m,
            max_urange: c.max_urange_m,
            sigma: c.sigma_m,
            sonar_sigma: c.sonar_sigma_m,
            lsigma: c.lsigma_m,
            kernel: c.kernel_size as i32,
            lskip: c.lskip as usize,
            lstep: c.lstep_m,
            astep: c.astep_rad,
            iterations: c.iterations,
            null_likelihood: c.null_likelihood,
            degeneracy: DegeneracyParams::default(),
            sonar_arc_middle: c.sonar_arc_middle,
            smoke_return_rough_m: c.smoke_return_rough_m,
        }
    }
}

/// Hill-climbing moves tried per round before the steps are halved, at most.
const MAX_CLIMB_ROUNDS: u32 = 80;

impl MatchParams {
    /// The endpoints matching uses.
    pub fn endpoint_limits(&self) -> EndpointLimits {
        EndpointLimits {
            max_range: self.max_range,
            max_urange: self.max_urange,
            lskip: self.lskip,
            min_spacing: self.resolution,
        }
    }
}

impl PreparedScan {
    pub fn prepare(&mut self, scan: &RangeScan, p: &MatchParams) {
        self.sensor = scan.sensor_pose;
        self.points.clear();
        self.beams.clear();
        let back = p.resolution * std::f64::consts::SQRT_2;
        let laser_factor = if scan.laser_noise_factor.is_finite() && scan.laser_noise_factor > 0.0 {
            scan.laser_noise_factor
        } else {
            1.0
        };
        for (i, beam) in scan.beams.iter().enumerate() {
            let Some(r) = beam.range else { continue };
            let r = r as f64;
            if !(r > 0.0 && r < p.max_range && beam.angle.is_finite()) {
                continue;
            }
            let (s, c) = (self.sensor.theta + beam.angle as f64).sin_cos();
            let cropped = r > p.max_urange;
            let re = r.min(p.max_urange);
            self.beams.push(RobotBeam {
                x: self.sensor.x + c * re,
                y: self.sensor.y + s * re,
                hit: !cropped,
                sonar: beam.kind == BeamKind::Sonar,
                arc_flank: scan
                    .arc_offset
                    .get(i)
                    .is_some_and(|&o| f64::from(o) > p.sonar_arc_middle),
                smoke_return: p.smoke_return_rough_m > 0.0
                    && scan
                        .laser_roughness
                        .get(i)
                        .is_some_and(|&r| f64::from(r) > p.smoke_return_rough_m),
            });
        }
        scan.endpoints(&p.endpoint_limits(), &mut self.endpoints);
        for e in &self.endpoints {
            let (sigma, lsigma) = match e.kind {
                BeamKind::Laser => (p.sigma * laser_factor, p.lsigma * laser_factor),
                BeamKind::Sonar => (p.sonar_sigma, p.sonar_sigma.max(p.lsigma)),
            };
            // Wider beams search further, within bounds that keep the cost predictable.
            let kernel = ((sigma / p.resolution).round() as i32).clamp(p.kernel, p.kernel + 3);
            let rb = (e.range - back).max(0.0);
            self.points.push(MatchPoint {
                hx: e.x,
                hy: e.y,
                fx: self.sensor.x + e.cos * rb,
                fy: self.sensor.y + e.sin * rb,
                score_k: 1.0 / (2.0 * sigma * sigma),
                lik_k: 1.0 / (2.0 * lsigma * lsigma),
                kernel,
                from_laser: e.kind == BeamKind::Laser,
            });
        }
        self.laser_xy.clear();
        self.laser_xy.extend(
            self.points
                .iter()
                .filter(|p| p.from_laser)
                .map(|p| (p.hx, p.hy)),
        );
        self.sonar_share = if self.points.is_empty() {
            0.0
        } else {
            1.0 - self.laser_xy.len() as f64 / self.points.len() as f64
        };
        let constraint = ScanConstraint::from_points(&self.laser_xy);
        self.degenerate = constraint.degenerate_directions(&p.degeneracy, None) > 0;
        self.constraint = Some(constraint);
    }
}

/// An endpoint's match: squared distance to the obstacle point, the endpoint and the obstacle point.
#[derive(Debug, Clone, Copy)]
struct Match {
    d2: f64,
    end: (f64, f64),
    obstacle: (f64, f64),
}

/// The nearest obstacle point (mean endpoint of an occupied cell whose
/// free-check partner is not occupied) within the kernel around the endpoint, if any.
#[inline]
fn nearest_obstacle(
    grid: &TiledGrid,
    pose_sc: (f64, f64),
    pose: &Pose2,
    pt: &MatchPoint,
) -> Option<Match> {
    let (s, c) = pose_sc;
    let wx = pose.x + c * pt.hx - s * pt.hy;
    let wy = pose.y + s * pt.hx + c * pt.hy;
    let fwx = pose.x + c * pt.fx - s * pt.fy;
    let fwy = pose.y + s * pt.fx + c * pt.fy;
    let (cx, cy) = grid.world_to_cell(wx, wy);
    let (fcx, fcy) = grid.world_to_cell(fwx, fwy);
    let k = pt.kernel;
    let (lx, ly) = (cx & (TILE - 1), cy & (TILE - 1));
    let inside = |l: i32| l >= k && l < TILE - k;
    if inside(lx) && inside(ly) {
        // Fast path: the whole kernel lies in one tile.
        let tile = grid.tile_at(cx, cy)?;
        let free_tile =
            if (fcx >> TILE_SHIFT, fcy >> TILE_SHIFT) == (cx >> TILE_SHIFT, cy >> TILE_SHIFT) {
                Some(tile)
            } else {
                None
            };
        return nearest_in_tile(grid, tile, free_tile, (cx, cy), (fcx, fcy), (wx, wy), k);
    }
    let mut best = f64::INFINITY;
    let mut at = (0.0, 0.0);
    let width = 2 * k + 1;
    for dy in -k..=k {
        let mut bits = grid.occupied_bits(cx - k, cy + dy, width);
        while bits != 0 {
            let dx = bits.trailing_zeros() as i32 - k;
            bits &= bits - 1;
            let (mx, my) = grid.mean_hit(cx + dx, cy + dy);
            let (ox, oy) = (mx - wx, my - wy);
            let d2 = ox * ox + oy * oy;
            // Unknown (the most negative value) counts as not occupied.
            if d2 < best && grid.get(fcx + dx, fcy + dy) <= 0 {
                best = d2;
                at = (mx, my);
            }
        }
    }
    best.is_finite().then_some(Match {
        d2: best,
        end: (wx, wy),
        obstacle: at,
    })
}

/// [`nearest_obstacle_d2`] when the kernel around (cx, cy) lies inside `tile`;
/// `free_tile` is `tile` again when the free-check cell's kernel is in it too.
#[inline]
fn nearest_in_tile(
    grid: &TiledGrid,
    tile: &Tile,
    free_tile: Option<&Tile>,
    (cx, cy): (i32, i32),
    (fcx, fcy): (i32, i32),
    (wx, wy): (f64, f64),
    k: i32,
) -> Option<Match> {
    let res = grid.resolution();
    let lx = cx & (TILE - 1);
    let (flx, fly) = (fcx & (TILE - 1), fcy & (TILE - 1));
    let free_inside =
        free_tile.is_some() && flx >= k && flx < TILE - k && fly >= k && fly < TILE - k;
    let mask = (1u32 << (2 * k + 1)) - 1;
    let mut best = f64::INFINITY;
    let mut at = (0.0, 0.0);
    for dy in -k..=k {
        let mut bits = (tile.occupied_row(cy + dy) >> (lx - k)) & mask;
        while bits != 0 {
            let dx = bits.trailing_zeros() as i32 - k;
            bits &= bits - 1;
            let (fx, fy) = tile.mean_hit_fraction(cx + dx, cy + dy);
            let ox = ((cx + dx) as f64 + fx) * res - wx;
            let oy = ((cy + dy) as f64 + fy) * res - wy;
            let d2 = ox * ox + oy * oy;
            if d2 < best {
                // Unknown (the most negative value) counts as not occupied.
                let free = if free_inside {
                    tile.cell(fcx + dx, fcy + dy) <= 0
                } else {
                    grid.get(fcx + dx, fcy + dy) <= 0
                };
                if free {
                    best = d2;
                    at = (ox + wx, oy + wy);
                }
            }
        }
    }
    best.is_finite().then_some(Match {
        d2: best,
        end: (wx, wy),
        obstacle: at,
    })
}

const EXP_TABLE_SIZE: usize = 1024;
const EXP_TABLE_MAX: f64 = 16.0;

/// `exp(-x)` for `x >= 0` by table with linear interpolation (error < 1e-4):
/// the matcher evaluates it for every beam of every candidate pose.
#[inline]
fn exp_neg(x: f64) -> f64 {
    static TABLE: std::sync::OnceLock<Vec<f64>> = std::sync::OnceLock::new();
    let t = TABLE.get_or_init(|| {
        (0..=EXP_TABLE_SIZE + 1)
            .map(|i| (-(i as f64) * EXP_TABLE_MAX / EXP_TABLE_SIZE as f64).exp())
            .collect()
    });
    let f = x.max(0.0) * (EXP_TABLE_SIZE as f64 / EXP_TABLE_MAX);
    if f >= EXP_TABLE_SIZE as f64 {
        return 0.0;
    }
    let i = f as usize;
    let frac = f - i as f64;
    t[i] + frac * (t[i + 1] - t[i])
}

/// Matching score of the scan at `pose` (higher is better).
pub fn score(grid: &TiledGrid, scan: &PreparedScan, pose: &Pose2) -> f64 {
    score_strided(grid, scan, pose, 1)
}

/// Score over every `stride`-th endpoint.
fn score_strided(grid: &TiledGrid, scan: &PreparedScan, pose: &Pose2, stride: usize) -> f64 {
    let sc = pose.theta.sin_cos();
    let mut total = 0.0;
    for pt in scan.points.iter().step_by(stride) {
        if let Some(m) = nearest_obstacle(grid, sc, pose, pt) {
            total += exp_neg(m.d2 * pt.score_k);
        }
    }
    total
}

/// Log-likelihood of the scan at `pose`, and the number of endpoints that matched.
pub fn log_likelihood(
    grid: &TiledGrid,
    scan: &PreparedScan,
    pose: &Pose2,
    null: f64,
) -> (f64, usize) {
    let sc = pose.theta.sin_cos();
    let mut total = 0.0;
    let mut matched = 0;
    for pt in &scan.points {
        match nearest_obstacle(grid, sc, pose, pt) {
            Some(m) => {
                total += (-m.d2 * pt.lik_k).max(-null);
                matched += 1;
            }
            // In a degenerate scan (a corridor longer than the range) the only
            // thing that tells particles apart along it is where each one's map
            // ends: penalising endpoints in space a particle never observed
            // favours those that lag behind, and shrinks the corridor. There
            // such an endpoint says nothing. (Elsewhere it still counts: with
            // features in view it does separate good particles from bad.)
            None if scan.degenerate => {
                let (s, c) = sc;
                let wx = pose.x + c * pt.hx - s * pt.hy;
                let wy = pose.y + s * pt.hx + c * pt.hy;
                let (cx, cy) = grid.world_to_cell(wx, wy);
                if grid.get(cx, cy) != crate::grid::UNKNOWN {
                    total -= null;
                }
            }
            None => total -= null,
        }
    }
    (total, matched)
}

/// Least-squares iterations after the hill climb.
const POLISH_ITERATIONS: u32 = 4;

/// Weighted point-to-point least squares (closed-form 2D Procrustes): each
/// endpoint pulls towards its matched obstacle point with weight
/// `exp(-d²/2σ²)`; the rigid transform that best maps endpoints onto their
/// matches is applied, and the matches are searched again. Returns the pose
/// and the number of passes over the scan.
fn polish(grid: &TiledGrid, scan: &PreparedScan, start: &Pose2, iterations: u32) -> (Pose2, u32) {
    let mut pose = *start;
    let mut passes = 0;
    for _ in 0..iterations {
        let sc = pose.theta.sin_cos();
        // One pass of weighted sums (coordinates relative to the pose, so the
        // products stay small): centroids and the cross-covariance terms.
        let (mut sw, mut spx, mut spy, mut sqx, mut sqy, mut sdot, mut scross) =
            (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let mut pairs = 0usize;
        for pt in &scan.points {
            if let Some(m) = nearest_obstacle(grid, sc, &pose, pt) {
                let w = exp_neg(m.d2 * pt.score_k);
                let (px, py) = (m.end.0 - pose.x, m.end.1 - pose.y);
                let (qx, qy) = (m.obstacle.0 - pose.x, m.obstacle.1 - pose.y);
                sw += w;
                spx += w * px;
                spy += w * py;
                sqx += w * qx;
                sqy += w * qy;
                sdot += w * (px * qx + py * qy);
                scross += w * (px * qy - py * qx);
                pairs += 1;
            }
        }
        passes += 1;
        if pairs < 10 || sw <= 0.0 {
            break;
        }
        let (px, py, qx, qy) = (spx / sw, spy / sw, sqx / sw, sqy / sw);
        let sxx = sdot - sw * (px * qx + py * qy);
        let sxy = scross - sw * (px * qy - py * qx);
        let dtheta = sxy.atan2(sxx);
        let (s, c) = dtheta.sin_cos();
        // Rotate about the endpoints' centroid, then move it onto the matches'
        // centroid (all relative to the current pose, which sits at the origin).
        let (tx, ty) = (qx - (c * px - s * py), qy - (s * px + c * py));
        let next = Pose2::new(pose.x + tx, pose.y + ty, pose.theta + dtheta);
        let moved = tx.hypot(ty);
        pose = next;
        if moved < 1e-4 && dtheta.abs() < 1e-5 {
            break;
        }
    }
    (pose, passes)
}

/// Result of refining one particle's pose.
#[derive(Debug, Clone, Copy)]
pub struct Refined {
    pub pose: Pose2,
    pub score: f64,
    /// Score evaluations spent.
    pub evaluations: u32,
}

/// Endpoint stride at refinement level `level` (0 = the initial, largest steps):
/// large steps only need a coarse score, so they look at every 4th, then every
/// 2nd endpoint; the fine steps use all (coarse-to-fine in the data as well as the steps).
fn stride_at(level: u32, points: usize) -> usize {
    let stride = match level {
        0 => 4,
        1 => 2,
        _ => 1,
    };
    // Never judge a pose on fewer than ~60 endpoints.
    if points / stride < 60 { 1 } else { stride }
}

/// Hill-climbs from `start` to a local maximum of the matching score.
pub fn refine(grid: &TiledGrid, scan: &PreparedScan, start: &Pose2, p: &MatchParams) -> Refined {
    let mut pose = *start;
    let mut level = 0;
    let mut stride = stride_at(level, scan.points.len());
    let mut best = score_strided(grid, scan, &pose, stride);
    let mut evaluations = 1;
    let (mut ld, mut ad) = (p.lstep, p.astep);
    for _ in 0..MAX_CLIMB_ROUNDS {
        let mut round_best = best;
        let mut round_pose = pose;
        for (dx, dy, dt) in [
            (ld, 0.0, 0.0),
            (-ld, 0.0, 0.0),
            (0.0, ld, 0.0),
            (0.0, -ld, 0.0),
            (0.0, 0.0, ad),
            (0.0, 0.0, -ad),
        ] {
            let cand = Pose2::new(pose.x + dx, pose.y + dy, pose.theta + dt);
            let s = score_strided(grid, scan, &cand, stride);
            evaluations += 1;
            if s > round_best {
                round_best = s;
                round_pose = cand;
            }
        }
        if round_best > best {
            best = round_best;
            pose = round_pose;
        } else {
            level += 1;
            if level > p.iterations {
                break;
            }
            ld *= 0.5;
            ad *= 0.5;
            let next = stride_at(level, scan.points.len());
            if next != stride {
                stride = next;
                best = score_strided(grid, scan, &pose, stride);
                evaluations += 1;
            }
        }
    }
    if stride != 1 {
        best = score(grid, scan, &pose);
        evaluations += 1;
    }
    // The hill climb stops within a step of the optimum, at a point that depends
    // on where it started; least squares on its correspondences lands on the
    // same optimum from any start in the basin.
    let (polished, e) = polish(grid, scan, &pose, POLISH_ITERATIONS);
    evaluations += e;
    if polished != pose {
        let s = score(grid, scan, &polished);
        evaluations += 1;
        if s >= best - 1e-9 * best.abs() {
            best = s;
            pose = polished;
        }
    }
    if let Some(c) = &scan.constraint {
        let kept = c.remap(start, &pose, &p.degeneracy, None);
        if kept != pose {
            pose = kept;
            best = score(grid, scan, &pose);
            evaluations += 1;
        }
    }
    pose.theta = smokenav_shared_types::odom::normalize_angle(pose.theta);
    Refined {
        pose,
        score: best,
        evaluations,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::{BeamEnd, LogOddsModel};
    use crate::scan::Beam;

    fn params() -> MatchParams {
        MatchParams::from_config(&SlamSection::default())
    }

    /// A 6 m × 4 m room whose walls are observed from its centre.
    fn room() -> TiledGrid {
        let mut g = TiledGrid::new(0.05);
        let m = LogOddsModel::new(0.9, 0.4, 4.0);
        let mut ends = Vec::new();
        for i in 0..720 {
            let a = i as f64 * std::f64::consts::TAU / 720.0;
            let (s, c) = a.sin_cos();
            // Distance to the rectangle [-3, 3] × [-2, 2] along (c, s).
            let tx = if c.abs() > 1e-9 {
                3.0 / c.abs()
            } else {
                f64::INFINITY
            };
            let ty = if s.abs() > 1e-9 {
                2.0 / s.abs()
            } else {
                f64::INFINITY
            };
            let t = tx.min(ty);
            ends.push(BeamEnd {
                ex: c * t,
                ey: s * t,
                hit: true,
            });
        }
        for _ in 0..3 {
            g.integrate(&Pose2::new(0.3, 0.2, 0.0), &ends, &m);
        }
        g
    }

    fn room_scan_from(pose: &Pose2) -> RangeScan {
        let mut scan = RangeScan {
            laser_noise_factor: 1.0,
            ..Default::default()
        };
        for i in 0..361 {
            let a = -std::f64::consts::FRAC_PI_2 + i as f64 * std::f64::consts::PI / 360.0;
            let (s, c) = (pose.theta + a).sin_cos();
            let tx = if c > 1e-9 {
                (3.0 - pose.x) / c
            } else if c < -1e-9 {
                (-3.0 - pose.x) / c
            } else {
                f64::INFINITY
            };
            let ty = if s > 1e-9 {
                (2.0 - pose.y) / s
            } else if s < -1e-9 {
                (-2.0 - pose.y) / s
            } else {
                f64::INFINITY
            };
            scan.beams.push(Beam {
                angle: a as f32,
                range: Some(tx.min(ty) as f32),
                kind: BeamKind::Laser,
            });
        }
        scan
    }

    #[test]
    fn a_rough_contradicted_laser_return_is_flagged_as_smoke_unless_turned_off() {
        let mut scan = RangeScan::default();
        for (i, rough) in [f32::NAN, 0.1, 0.6].into_iter().enumerate() {
            scan.beams.push(Beam {
                angle: 0.1 * i as f32,
                range: Some(1.0),
                kind: BeamKind::Laser,
            });
            scan.laser_roughness.push(rough);
        }
        let mut prepared = PreparedScan::default();
        let flags = |p: &PreparedScan| p.beams.iter().map(|b| b.smoke_return).collect::<Vec<_>>();
        prepared.prepare(&scan, &params());
        assert_eq!(flags(&prepared), [false, false, true]);
        // Every beam still ends on an obstacle as far as matching goes.
        assert!(prepared.beams.iter().all(|b| b.hit));
        let off = MatchParams {
            smoke_return_rough_m: 0.0,
            ..params()
        };
        prepared.prepare(&scan, &off);
        assert_eq!(flags(&prepared), [false, false, false]);
    }

    #[test]
    fn hill_climb_recovers_a_10cm_3deg_offset_in_a_room() {
        let grid = room();
        let truth = Pose2::new(0.5, -0.3, 0.2);
        let mut prepared = PreparedScan::default();
        prepared.prepare(&room_scan_from(&truth), &params());
        let start = Pose2::new(0.6, -0.25, 0.2 + 3f64.to_radians());
        let r = refine(&grid, &prepared, &start, &params());
        assert!((r.pose.x - truth.x).abs() < 0.03, "{:?}", r.pose);
        assert!((r.pose.y - truth.y).abs() < 0.03, "{:?}", r.pose);
        assert!((r.pose.theta - truth.theta).abs() < 0.01, "{:?}", r.pose);
        assert!(r.score > score(&grid, &prepared, &start));
    }

    #[test]
    fn likelihood_prefers_the_true_pose() {
        let grid = room();
        let truth = Pose2::new(0.5, -0.3, 0.2);
        let mut prepared = PreparedScan::default();
        prepared.prepare(&room_scan_from(&truth), &params());
        let (good, matched) = log_likelihood(&grid, &prepared, &truth, 2.0);
        let (bad, _) = log_likelihood(&grid, &prepared, &Pose2::new(0.7, -0.3, 0.25), 2.0);
        assert!(good > bad, "{good} vs {bad}");
        assert!(
            matched as f64 > 0.9 * prepared.points.len() as f64,
            "{matched}"
        );
    }

    /// A scan from `pose` of a corridor's walls (y = ±1.2), ranges up to 5 m.
    fn corridor_scan_from(pose: &Pose2) -> RangeScan {
        let mut scan = RangeScan {
            laser_noise_factor: 1.0,
            ..Default::default()
        };
        for i in 0..481 {
            let a = -2.0 + i as f64 * 4.0 / 480.0;
            let s = (pose.theta + a).sin();
            let r = if s > 1e-9 {
                (1.2 - pose.y) / s
            } else if s < -1e-9 {
                (-1.2 - pose.y) / s
            } else {
                f64::INFINITY
            };
            scan.beams.push(Beam {
                angle: a as f32,
                range: (r < 5.0).then_some(r as f32),
                kind: BeamKind::Laser,
            });
        }
        scan
    }

    #[test]
    fn a_corridor_scan_does_not_favour_a_pose_that_lags_behind_the_map() {
        // The map holds the corridor's walls for x ≤ 3 only (seen from the origin, 3 m range).
        let mut grid = TiledGrid::new(0.05);
        let m = LogOddsModel::new(0.9, 0.4, 4.0);
        let ends: Vec<BeamEnd> = (0..=120)
            .flat_map(|i| {
                let x = -3.0 + i as f64 * 0.05;
                [(x, 1.2), (x, -1.2)]
            })
            .map(|(ex, ey)| BeamEnd { ex, ey, hit: true })
            .collect();
        for _ in 0..3 {
            grid.integrate(&Pose2::default(), &ends, &m);
        }
        // The robot is at x = 1 and sees the walls out to x = 5.6, past the map's end.
        let truth = Pose2::new(1.0, 0.0, 0.0);
        let mut prepared = PreparedScan::default();
        prepared.prepare(&corridor_scan_from(&truth), &params());
        assert!(prepared.degenerate);
        let null = params().null_likelihood;
        let (at_truth, _) = log_likelihood(&grid, &prepared, &truth, null);
        let (lagging, _) = log_likelihood(&grid, &prepared, &Pose2::new(0.5, 0.0, 0.0), null);
        // Pulled back, more endpoints fall on the mapped walls; that is no evidence.
        assert!(at_truth >= lagging - 1.0, "{at_truth} vs {lagging}");
    }

    #[test]
    fn exp_table_matches_exp() {
        for i in 0..2000 {
            let x = i as f64 * 0.01;
            assert!((exp_neg(x) - (-x).exp()).abs() < 1e-4, "{x}");
        }
        assert_eq!(exp_neg(100.0), 0.0);
    }

    #[test]
    fn sonar_beams_get_a_wider_sigma_and_kernel() {
        let mut scan = room_scan_from(&Pose2::default());
        let mut prepared = PreparedScan::default();
        prepared.prepare(&scan, &params());
        let laser = prepared.points[0];
        scan.beams[0].kind = BeamKind::Sonar;
        prepared.prepare(&scan, &params());
        let sonar = prepared.points[0];
        assert!(sonar.score_k < laser.score_k);
        assert!(sonar.kernel > laser.kernel);
    }

    #[test]
    fn obscurant_widens_the_laser_likelihood() {
        let mut scan = room_scan_from(&Pose2::default());
        let mut clear = PreparedScan::default();
        clear.prepare(&scan, &params());
        scan.laser_noise_factor = (13.75f64 / 5.0).sqrt();
        let mut fog = PreparedScan::default();
        fog.prepare(&scan, &params());
        assert!((clear.points[0].lik_k / fog.points[0].lik_k - 13.75 / 5.0).abs() < 1e-9);
    }

    #[test]
    fn beams_beyond_usable_range_only_clear_space() {
        let mut scan = room_scan_from(&Pose2::default());
        scan.beams[0].range = Some(20.0);
        scan.beams[1].range = Some(90.0);
        let mut prepared = PreparedScan::default();
        prepared.prepare(&scan, &params());
        assert_eq!(
            prepared.beams.len(),
            360,
            "the 90 m reading is beyond max_range"
        );
        assert!(!prepared.beams[0].hit);
        assert!((prepared.beams[0].x.hypot(prepared.beams[0].y) - 16.0).abs() < 1e-9);
        assert!(prepared.points.iter().all(|p| p.hx.hypot(p.hy) <= 16.0));
        // The room's walls are 2–3.6 m away: 0.5° apart is 1.7–3.2 cm, so about
        // every second endpoint is within a 5 cm cell of the previous one.
        assert!(
            prepared.points.len() > 120 && prepared.points.len() < 300,
            "{}",
            prepared.points.len()
        );
    }
}
