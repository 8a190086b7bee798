//! Registering a new local fuzzy map to the previous one: motion-predicted
//! cropping (eqs. 8–9), an overlap cost, and two searches that maximise it.
//!
//! **Cropping.** With the predicted motion ΔX̂ (from the odometry), a cell
//! of the new map is kept only where the previous scan saw anything (an
//! obstacle or free space), and a cell of the previous map only where the
//! new scan did: what emerged or disappeared between the scans cannot be
//! matched and would pull the registration.
//!
//! **Cost.** The overlap of the cropped maps under the product t-norm,
//! normalised by the new map's mass: Σₖ wₖ·D(T pₖ) / Σₖ wₖ over the new local
//! map's peaks pₖ (its readings, confidence wₖ) moved by the candidate
//! motion T. D is the cropped reference `Mo` dilated by a parabola of
//! radius `match_radius_m` (the paper's profile again, so a reading near a
//! wall still overlaps a little and the cost has a slope for the search to
//! climb), bilinear between cells.
//!
//! Measured and dropped: min(wₖ, D) (the minimum t-norm) saturates wherever
//! the reference is the more confident — always against a global map built
//! by union — leaving a plateau around the optimum; D as the reference's
//! bare support (confidence ignored) made the registration to the global
//! map, whose walls the union thickens, several times less accurate in the
//! test room.
//!
//! **Searches.** [`cuckoo`], Cuckoo search by Lévy flights (Yang & Deb 2009),
//! as the paper uses, seeded; and [`correlative`], an exhaustive
//! coarse-to-fine grid on the same cost (deterministic, the comparison).

use super::map::{FuzzyBeam, FuzzyGrid};
use crate::scan::BeamKind;
use smokenav_shared_types::Pose2;
use smokenav_shared_types::Rng;

/// An occupied cell of a local map: position in the map's frame and `Mo`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FuzzyPoint {
    pub x: f32,
    pub y: f32,
    pub w: f32,
}

/// The occupied cells of `g`, thinned evenly to at most `max` points.
pub fn occupied_points(g: &FuzzyGrid, max: usize, out: &mut Vec<FuzzyPoint>) {
    out.clear();
    let n = g.mo.iter().filter(|v| **v > 0.0).count();
    let stride = n.div_ceil(max.max(1)).max(1);
    for (k, i) in
        g.mo.iter()
            .enumerate()
            .filter(|(_, v)| **v > 0.0)
            .map(|(i, _)| i)
            .enumerate()
    {
        if k % stride == 0 {
            let (x, y) = g.centre(i);
            out.push(FuzzyPoint {
                x: x as f32,
                y: y as f32,
                w: g.mo[i],
            });
        }
    }
}

/// The peaks of a local map's laser readings in polar form, B at each
/// reading itself (K), in the robot frame of `sensor`, thinned evenly to at
/// most `max` points. Matched instead of the Cartesian cells these readings
/// light, whose centres sit up to half a cell off the reading: that rounding
/// biases the registration, and its error adds up from scan to scan.
///
/// Sonar arcs are painted but not matched: an arc is drawn round the sensor
/// at its sector's nearest echo, wherever across the cone that echo came
/// from, so it says little about where the robot is and most about where it
/// was when the last arcs were painted. Matched, arcs hold the pose still
/// while the robot drives on (the dense-smoke trial lost the robot so).
pub fn reading_points(sensor: &Pose2, beams: &[FuzzyBeam], max: usize, out: &mut Vec<FuzzyPoint>) {
    out.clear();
    let matched =
        |b: &&FuzzyBeam| b.hit && b.kind == BeamKind::Laser && b.k * b.lateral * b.worth > 0.0;
    let n = beams.iter().filter(matched).count();
    let stride = n.div_ceil(max.max(1)).max(1);
    for (k, b) in beams.iter().filter(matched).enumerate() {
        if k % stride == 0 {
            let (s, c) = (sensor.theta + b.angle).sin_cos();
            out.push(FuzzyPoint {
                x: (sensor.x + c * b.range) as f32,
                y: (sensor.y + s * b.range) as f32,
                w: (b.k * b.lateral * b.worth) as f32,
            });
        }
    }
}

#[inline]
fn apply(t: &Pose2, (s, c): (f64, f64), p: &FuzzyPoint) -> (f64, f64) {
    let (x, y) = (f64::from(p.x), f64::from(p.y));
    (t.x + c * x - s * y, t.y + s * x + c * y)
}

/// Eqs. 8–9: the points of one map that the other map's scan saw, with `t`
/// taking `points`' frame into `other`'s (the predicted motion or its inverse).
pub fn crop(points: &[FuzzyPoint], other: &FuzzyGrid, t: &Pose2, out: &mut Vec<FuzzyPoint>) {
    out.clear();
    let sc = t.theta.sin_cos();
    out.extend(points.iter().copied().filter(|p| {
        let (x, y) = apply(t, sc, p);
        other.seen(x, y)
    }));
}

/// The reference side of the cost: the cropped reference `Mo`, dilated.
#[derive(Debug, Clone, Default)]
pub struct Reference {
    resolution: f64,
    origin: (f64, f64),
    width: usize,
    height: usize,
    values: Vec<f32>,
}

impl Reference {
    /// Rebuilds over `geometry`'s cells from `points` (in that frame).
    pub fn build(&mut self, geometry: &FuzzyGrid, points: &[FuzzyPoint], radius: f64) {
        self.resolution = geometry.resolution;
        self.origin = geometry.origin;
        self.width = geometry.width;
        self.height = geometry.height;
        self.values.clear();
        self.values.resize(self.width * self.height, 0.0);
        let res = self.resolution;
        let cells = (radius / res).ceil() as isize + 1;
        for p in points {
            let cx = ((f64::from(p.x) - self.origin.0) / res).floor() as isize;
            let cy = ((f64::from(p.y) - self.origin.1) / res).floor() as isize;
            for dy in -cells..=cells {
                for dx in -cells..=cells {
                    let (gx, gy) = (cx + dx, cy + dy);
                    if gx < 0 || gy < 0 || gx >= self.width as isize || gy >= self.height as isize {
                        continue;
                    }
                    // From the point itself, not its cell's centre (that rounding biases the match).
                    let ccx = self.origin.0 + (gx as f64 + 0.5) * res;
                    let ccy = self.origin.1 + (gy as f64 + 0.5) * res;
                    let d = (ccx - f64::from(p.x)).hypot(ccy - f64::from(p.y));
                    let v = if radius > 0.0 {
                        p.w * super::confidence::parabola(d, radius) as f32
                    } else {
                        p.w
                    };
                    let i = gy as usize * self.width + gx as usize;
                    if v > self.values[i] {
                        self.values[i] = v;
                    }
                }
            }
        }
    }

    /// D at (x, y), bilinear between cell centres: a nearest-cell lookup
    /// makes the cost a staircase with cell-wide flat steps, and the search
    /// would wander anywhere on the top one.
    #[inline]
    fn at(&self, x: f64, y: f64) -> f32 {
        let u = (x - self.origin.0) / self.resolution - 0.5;
        let v = (y - self.origin.1) / self.resolution - 0.5;
        if !(u >= 0.0 && v >= 0.0) {
            return 0.0;
        }
        let (cx, cy) = (u as usize, v as usize);
        if cx + 1 >= self.width || cy + 1 >= self.height {
            return 0.0;
        }
        let (fx, fy) = ((u - cx as f64) as f32, (v - cy as f64) as f32);
        let i = cy * self.width + cx;
        let row0 = self.values[i] + fx * (self.values[i + 1] - self.values[i]);
        let j = i + self.width;
        let row1 = self.values[j] + fx * (self.values[j + 1] - self.values[j]);
        row0 + fy * (row1 - row0)
    }

    /// The overlap of `points` moved by `t` with this reference, 0–1.
    pub fn overlap(&self, points: &[FuzzyPoint], t: &Pose2) -> f64 {
        let sc = t.theta.sin_cos();
        let (mut hit, mut mass) = (0.0f64, 0.0f64);
        for p in points {
            let (x, y) = apply(t, sc, p);
            hit += f64::from(p.w * self.at(x, y));
            mass += f64::from(p.w);
        }
        if mass > 0.0 { hit / mass } else { 0.0 }
    }
}

/// The search box around a predicted motion: ± `window_m` in x and y, ± `window_rad`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    pub centre: Pose2,
    pub window_m: f64,
    pub window_rad: f64,
}

impl Window {
    fn half(&self) -> [f64; 3] {
        [self.window_m, self.window_m, self.window_rad]
    }
    fn lo_hi(&self, d: usize) -> (f64, f64) {
        let c = [self.centre.x, self.centre.y, self.centre.theta][d];
        (c - self.half()[d], c + self.half()[d])
    }
    fn clamp(&self, v: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|d| {
            let (lo, hi) = self.lo_hi(d);
            v[d].clamp(lo, hi)
        })
    }
}

/// What a search found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SearchResult {
    pub motion: Pose2,
    pub cost: f64,
    /// Cost evaluations spent.
    pub evaluations: u32,
}

/// Cuckoo search's parameters (`[slam.fuzzy] cuckoo_*`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CuckooParams {
    pub nests: usize,
    pub generations: usize,
    /// p_a: share of nests abandoned per generation.
    pub abandon: f64,
    /// Lévy exponent β.
    pub beta: f64,
    /// Step scale α, as a share of the window.
    pub alpha: f64,
}

/// Lévy-stable steps by Mantegna's algorithm: u / |v|^(1/β), u ~ N(0, σᵤ²), v ~ N(0, 1).
#[derive(Debug, Clone, Copy)]
struct Levy {
    beta: f64,
    sigma_u: f64,
}

/// ln Γ(x) for x > 0 (Lanczos, g = 7, 9 terms): enough for σᵤ.
fn ln_gamma(x: f64) -> f64 {
    const G: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        let pi = std::f64::consts::PI;
        return (pi / (pi * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = G[0];
    let t = x + 7.5;
    for (i, g) in G.iter().enumerate().skip(1) {
        a += g / (x + i as f64);
    }
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

impl Levy {
    fn new(beta: f64) -> Self {
        let num = ln_gamma(1.0 + beta) + (std::f64::consts::PI * beta / 2.0).sin().ln();
        let den = ln_gamma((1.0 + beta) / 2.0) + beta.ln() + (beta - 1.0) / 2.0 * 2f64.ln();
        Self {
            beta,
            sigma_u: ((num - den) / beta).exp(),
        }
    }
    fn sample(&self, rng: &mut Rng) -> f64 {
        let u = rng.gaussian(self.sigma_u);
        let v = rng.normal().abs().max(1e-12);
        u / v.powf(1.0 / self.beta)
    }
}

fn pose(v: [f64; 3]) -> Pose2 {
    Pose2::new(v[0], v[1], v[2])
}

/// Cuckoo search (Yang & Deb 2009) for the motion in `w` maximising `cost`.
///
/// Nests start at the prediction (so a search never ends worse than it) and
/// uniformly over the window. Each generation every cuckoo lays an egg a
/// Lévy flight away, xᵢ + α·h·L (h the window's half-size per axis, L
/// heavy-tailed: mostly short steps, now and then a long jump), which
/// replaces a nest picked at random if better; then each nest but the best
/// is abandoned with probability p_a and rebuilt by a biased random walk
/// xᵢ + r·(xⱼ − xₖ) between two other nests, kept if better. Out-of-window
/// moves are clamped to the window. `rng` makes it reproducible.
pub fn cuckoo(
    w: &Window,
    p: &CuckooParams,
    rng: &mut Rng,
    mut cost: impl FnMut(&Pose2) -> f64,
) -> SearchResult {
    let n = p.nests.max(2);
    let levy = Levy::new(p.beta);
    let half = w.half();
    let c = [w.centre.x, w.centre.y, w.centre.theta];
    let mut evaluations = 0u32;
    let mut eval = |v: &[f64; 3]| {
        evaluations += 1;
        cost(&pose(*v))
    };
    let mut nests: Vec<[f64; 3]> = (0..n)
        .map(|i| {
            if i == 0 {
                c
            } else {
                std::array::from_fn(|d| c[d] + half[d] * (2.0 * rng.uniform() - 1.0))
            }
        })
        .collect();
    let mut fit: Vec<f64> = nests.iter().map(&mut eval).collect();
    let best_of = |fit: &[f64]| (0..fit.len()).fold(0, |b, i| if fit[i] > fit[b] { i } else { b });
    for _ in 0..p.generations {
        for i in 0..n {
            let egg = w.clamp(std::array::from_fn(|d| {
                nests[i][d] + p.alpha * half[d] * levy.sample(rng)
            }));
            let f = eval(&egg);
            let j = (rng.next_u64() % n as u64) as usize;
            if f > fit[j] {
                nests[j] = egg;
                fit[j] = f;
            }
        }
        let best = best_of(&fit);
        for i in 0..n {
            if i == best || rng.uniform() >= p.abandon {
                continue;
            }
            let j = (rng.next_u64() % n as u64) as usize;
            let k = (rng.next_u64() % n as u64) as usize;
            let r = rng.uniform();
            let fresh = w.clamp(std::array::from_fn(|d| {
                nests[i][d] + r * (nests[j][d] - nests[k][d])
            }));
            let f = eval(&fresh);
            if f > fit[i] {
                nests[i] = fresh;
                fit[i] = f;
            }
        }
    }
    let best = best_of(&fit);
    SearchResult {
        motion: pose(nests[best]),
        cost: fit[best],
        evaluations,
    }
}

/// Exhaustive search of `w` on a grid of `step_m` × `step_rad`, then of one
/// coarse cell around the best at a quarter of the steps. Ties keep the
/// candidate found first (deterministic).
pub fn correlative(
    w: &Window,
    step_m: f64,
    step_rad: f64,
    mut cost: impl FnMut(&Pose2) -> f64,
) -> SearchResult {
    let mut evaluations = 0u32;
    let mut best = (w.centre, cost(&w.centre));
    evaluations += 1;
    let mut scan_grid =
        |centre: Pose2, hm: f64, hr: f64, sm: f64, sr: f64, best: &mut (Pose2, f64)| {
            let nm = (hm / sm).round() as i64;
            let nr = (hr / sr).round() as i64;
            for it in -nr..=nr {
                for iy in -nm..=nm {
                    for ix in -nm..=nm {
                        if ix == 0 && iy == 0 && it == 0 {
                            continue;
                        }
                        let cand = Pose2::new(
                            centre.x + ix as f64 * sm,
                            centre.y + iy as f64 * sm,
                            centre.theta + it as f64 * sr,
                        );
                        evaluations += 1;
                        let f = cost(&cand);
                        if f > best.1 {
                            *best = (cand, f);
                        }
                    }
                }
            }
        };
    scan_grid(
        w.centre,
        w.window_m,
        w.window_rad,
        step_m,
        step_rad,
        &mut best,
    );
    let coarse = best.0;
    scan_grid(
        coarse,
        step_m,
        step_rad,
        step_m / 4.0,
        step_rad / 4.0,
        &mut best,
    );
    SearchResult {
        motion: best.0,
        cost: best.1,
        evaluations,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bowl(t: &Pose2) -> f64 {
        // A smooth peak at (0.1, -0.05, 0.03).
        1.0 / (1.0
            + 50.0 * ((t.x - 0.1).powi(2) + (t.y + 0.05).powi(2))
            + 200.0 * (t.theta - 0.03).powi(2))
    }

    fn window() -> Window {
        Window {
            centre: Pose2::default(),
            window_m: 0.25,
            window_rad: 0.15,
        }
    }

    fn params() -> CuckooParams {
        CuckooParams {
            nests: 15,
            generations: 40,
            abandon: 0.25,
            beta: 1.5,
            alpha: 0.05,
        }
    }

    #[test]
    fn mantegna_sigma_matches_yangs_value_for_beta_1_5() {
        // σᵤ(1.5) = 0.6966 (Yang & Deb's reference implementation).
        assert!(
            (Levy::new(1.5).sigma_u - 0.6966).abs() < 1e-3,
            "{}",
            Levy::new(1.5).sigma_u
        );
        assert!((ln_gamma(5.0) - 24f64.ln()).abs() < 1e-10);
    }

    #[test]
    fn cuckoo_finds_the_peak_and_is_reproducible() {
        let a = cuckoo(&window(), &params(), &mut Rng::new(3, 0), bowl);
        assert!((a.motion.x - 0.1).abs() < 0.01, "{a:?}");
        assert!((a.motion.y + 0.05).abs() < 0.01, "{a:?}");
        assert!((a.motion.theta - 0.03).abs() < 0.005, "{a:?}");
        let b = cuckoo(&window(), &params(), &mut Rng::new(3, 0), bowl);
        assert_eq!(a, b, "same seed, same result");
    }

    #[test]
    fn cuckoo_never_ends_below_the_prediction() {
        // A cost that is best at the centre and flat zero elsewhere.
        let spike = |t: &Pose2| {
            if t.x == 0.0 && t.y == 0.0 && t.theta == 0.0 {
                1.0
            } else {
                0.0
            }
        };
        let r = cuckoo(&window(), &params(), &mut Rng::new(1, 0), spike);
        assert_eq!(r.cost, 1.0);
    }

    #[test]
    fn correlative_reaches_the_peak_to_a_fine_step() {
        let r = correlative(&window(), 0.05, 0.025, bowl);
        assert!((r.motion.x - 0.1).abs() <= 0.0125 / 2.0 + 1e-9, "{r:?}");
        assert!(
            (r.motion.theta - 0.03).abs() <= 0.00625 / 2.0 + 1e-9,
            "{r:?}"
        );
        assert_eq!(r.evaluations, 11 * 11 * 13 + 9 * 9 * 9 - 1);
    }

    #[test]
    fn overlap_is_one_on_itself_and_falls_when_shifted() {
        let mut g = FuzzyGrid::square(0.05, 3.0);
        // A wall at x = 1 and one at y = 1.5.
        for k in 0..40 {
            let i = g.index(1.025, -0.975 + 0.05 * k as f64).unwrap();
            g.mo[i] = 0.7;
            let j = g.index(-0.975 + 0.05 * k as f64, 1.525).unwrap();
            g.mo[j] = 0.7;
        }
        let mut pts = Vec::new();
        occupied_points(&g, 1000, &mut pts);
        assert_eq!(pts.len(), 80);
        let mut r = Reference::default();
        r.build(&g, &pts, 0.15);
        // The product t-norm: a 0.7 cell on a 0.7 cell overlaps by 0.49 of its 0.7.
        assert!((r.overlap(&pts, &Pose2::default()) - 0.7).abs() < 1e-6);
        let near = r.overlap(&pts, &Pose2::new(0.05, 0.0, 0.0));
        let far = r.overlap(&pts, &Pose2::new(0.3, 0.3, 0.0));
        assert!(near < 1.0 && near > far, "{near} {far}");
        assert!(far < 0.1, "{far}");
    }

    #[test]
    fn cropping_drops_what_the_other_scan_never_saw() {
        let mut other = FuzzyGrid::square(0.05, 3.0);
        let i = other.index(1.0, 0.0).unwrap();
        other.ms[i] = 1.0;
        let pts = [
            FuzzyPoint {
                x: 1.0,
                y: 0.0,
                w: 0.5,
            },
            FuzzyPoint {
                x: -1.0,
                y: 0.0,
                w: 0.5,
            },
        ];
        let mut out = Vec::new();
        crop(&pts, &other, &Pose2::default(), &mut out);
        assert_eq!(out, vec![pts[0]]);
        // Predicted motion: the other frame sits 2 m along x.
        crop(&pts, &other, &Pose2::new(2.0, 0.0, 0.0), &mut out);
        assert_eq!(out, vec![pts[1]]);
    }
}
