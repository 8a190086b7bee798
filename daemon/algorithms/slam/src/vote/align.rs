//! Aligning a member's map to the reference member's (SLAMfusion, Sec. III-B:
//! "the best match (translation and rotation)", found on the GPU by a coarse
//! search with a jumping step, then a narrower one with a smaller step).
//!
//! Here on a CPU and around the shared odometry frame: every member starts at
//! the same pose and is fed the same corrected odometry, so their maps differ
//! by a small rigid motion (drift, a loop closure one made and another did
//! not). The search is over (x, y, θ) of the member → reference transform,
//! scored by the mean squared distance (truncated) of the member's wall cells
//! to the reference's walls, read from a distance field of the reference.
//! Coarse to fine: a 9 × 9 × 9 grid over the window (a thinned set of
//! points), then ±1 step around the best (every point) while halving the
//! steps until they are below a quarter cell. The residual is robust: the RMS
//! distance of the nearest 80 % of the member's walls to the reference's
//! after the alignment ([`TRIM_KEEP`]), so walls only one member mapped do
//! not read as misalignment.

use smokenav_platform_map::OccupancyGrid;
use smokenav_shared_types::Pose2;

/// Cells at or above this occupancy are walls (map_server's 0.65).
pub const WALL: i8 = 65;

/// Distance (m, truncated) of every cell of a grid to its nearest wall cell.
#[derive(Debug, Clone, Default)]
pub struct DistanceField {
    origin: (f64, f64),
    resolution: f64,
    width: usize,
    height: usize,
    truncation: f32,
    /// Distance, m (truncated), row-major, at the cell centres.
    d: Vec<f32>,
}

impl DistanceField {
    /// The field of `grid`'s wall cells, truncated at `truncation_m`.
    pub fn new(grid: &OccupancyGrid, truncation_m: f64) -> Self {
        let mut f = Self::default();
        f.rebuild(grid, truncation_m);
        f
    }

    /// Recomputes the field for `grid`, reusing the buffer.
    pub fn rebuild(&mut self, grid: &OccupancyGrid, truncation_m: f64) {
        let (w, h) = (grid.width, grid.height);
        self.origin = (grid.origin[0], grid.origin[1]);
        self.resolution = grid.resolution;
        self.width = w;
        self.height = h;
        self.truncation = truncation_m as f32;
        // Two-pass chamfer (1, √2) in cells; ample for a truncated score.
        let big = f32::MAX / 4.0;
        let mut d: Vec<f32> = grid
            .cells
            .iter()
            .map(|&c| if c >= WALL { 0.0 } else { big })
            .collect();
        let diag = std::f32::consts::SQRT_2;
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let mut v = d[i];
                if x > 0 {
                    v = v.min(d[i - 1] + 1.0);
                }
                if y > 0 {
                    v = v.min(d[i - w] + 1.0);
                    if x > 0 {
                        v = v.min(d[i - w - 1] + diag);
                    }
                    if x + 1 < w {
                        v = v.min(d[i - w + 1] + diag);
                    }
                }
                d[i] = v;
            }
        }
        for y in (0..h).rev() {
            for x in (0..w).rev() {
                let i = y * w + x;
                let mut v = d[i];
                if x + 1 < w {
                    v = v.min(d[i + 1] + 1.0);
                }
                if y + 1 < h {
                    v = v.min(d[i + w] + 1.0);
                    if x + 1 < w {
                        v = v.min(d[i + w + 1] + diag);
                    }
                    if x > 0 {
                        v = v.min(d[i + w - 1] + diag);
                    }
                }
                d[i] = v;
            }
        }
        let res = grid.resolution as f32;
        let t = self.truncation;
        self.d.clear();
        self.d.extend(d.iter().map(|&c| (c * res).min(t)));
    }

    /// Squared distance (m², truncated) at a point of the reference frame,
    /// the distance interpolated bilinearly between the four cell centres
    /// around it: read off the nearest cell it is flat over a cell, and an
    /// alignment could not tell shifts of less than a cell apart.
    #[inline]
    pub fn d2_at(&self, x: f64, y: f64) -> f32 {
        let fx = (x - self.origin.0) / self.resolution - 0.5;
        let fy = (y - self.origin.1) / self.resolution - 0.5;
        let (x0, y0) = (fx.floor(), fy.floor());
        let far = self.truncation;
        if !(x0 >= -1.0 && y0 >= -1.0 && x0 < self.width as f64 && y0 < self.height as f64) {
            return far * far;
        }
        let (tx, ty) = ((fx - x0) as f32, (fy - y0) as f32);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let at = |cx: i64, cy: i64| {
            if cx < 0 || cy < 0 || cx >= self.width as i64 || cy >= self.height as i64 {
                far
            } else {
                self.d[cy as usize * self.width + cx as usize]
            }
        };
        let bottom = at(x0, y0) * (1.0 - tx) + at(x0 + 1, y0) * tx;
        let top = at(x0, y0 + 1) * (1.0 - tx) + at(x0 + 1, y0 + 1) * tx;
        let d = bottom * (1.0 - ty) + top * ty;
        d * d
    }

    pub fn resolution(&self) -> f64 {
        self.resolution
    }

    pub fn is_empty(&self) -> bool {
        self.d.is_empty()
    }
}

/// Centres of `grid`'s wall cells, evenly thinned to at most `max_points`.
pub fn wall_points(grid: &OccupancyGrid, max_points: usize, out: &mut Vec<(f64, f64)>) {
    out.clear();
    let walls = grid.cells.iter().filter(|&&c| c >= WALL).count();
    let stride = walls.div_ceil(max_points.max(1)).max(1);
    let mut n = 0usize;
    for y in 0..grid.height {
        for x in 0..grid.width {
            if grid.cells[y * grid.width + x] >= WALL {
                if n.is_multiple_of(stride) {
                    out.push(grid.cell_center(x, y));
                }
                n += 1;
            }
        }
    }
}

/// A member → reference transform and how well it fits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Alignment {
    /// Takes member-map coordinates into reference-map coordinates.
    pub transform: Pose2,
    /// Robust residual, m: the RMS distance to the reference's walls of the
    /// nearest [`TRIM_KEEP`] of the member's wall points after the alignment
    /// (see [`trimmed_residual`]).
    pub residual_m: f64,
    /// Wall points matched.
    pub points: usize,
    /// Candidate transforms scored.
    pub evaluations: u32,
}

/// Where and how wide to search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SearchWindow {
    pub center: Pose2,
    /// ± m.
    pub window_m: f64,
    /// ± rad.
    pub window_rad: f64,
}

/// Share of a member's wall points the residual keeps (the nearest ones).
///
/// Two members never map exactly the same walls: one paints a phantom cell,
/// another a wall the first never saw, the fuzzy map a thick band where the
/// others draw a line. Such points lie far from every reference wall however
/// well the maps are aligned, and with a plain RMS (even truncated) a few
/// percent of them push a perfect alignment over the threshold. Dropping the
/// farthest fifth keeps the residual a measure of the alignment: a map off by
/// a rigid motion moves *all* its walls, so its nearest 80 % are off too.
pub const TRIM_KEEP: f64 = 0.8;

/// Points the coarse level of a search scores at most (evenly thinned): the
/// coarse grid only has to find the basin, the fine levels use every point.
pub const COARSE_POINTS: usize = 500;

fn score(field: &DistanceField, points: &[(f64, f64)], t: &Pose2) -> f64 {
    let (s, c) = t.theta.sin_cos();
    let mut sum = 0.0f64;
    for &(x, y) in points {
        sum += f64::from(field.d2_at(c * x - s * y + t.x, s * x + c * y + t.y));
    }
    sum / points.len().max(1) as f64
}

/// The robust residual of `points` moved by `t` onto `field`: the root mean
/// of the smallest [`TRIM_KEEP`] of their squared (truncated) distances, m.
/// `scratch` is reused between calls.
pub fn trimmed_residual(
    field: &DistanceField,
    points: &[(f64, f64)],
    t: &Pose2,
    scratch: &mut Vec<f32>,
) -> f64 {
    if points.is_empty() {
        return 0.0;
    }
    let (s, c) = t.theta.sin_cos();
    scratch.clear();
    scratch.extend(
        points
            .iter()
            .map(|&(x, y)| field.d2_at(c * x - s * y + t.x, s * x + c * y + t.y)),
    );
    let keep = ((points.len() as f64 * TRIM_KEEP).ceil() as usize).clamp(1, points.len());
    if keep < scratch.len() {
        scratch.select_nth_unstable_by(keep - 1, f32::total_cmp);
    }
    let sum: f64 = scratch[..keep].iter().map(|&d| f64::from(d)).sum();
    (sum / keep as f64).sqrt()
}

/// Coarse-to-fine search for the transform taking `points` (member walls)
/// onto `field` (reference walls) within `win`: a 9 × 9 × 9 grid over the
/// window scored with at most [`COARSE_POINTS`] points, then ±1 step around
/// the best with every point (repeated while it moves, up to 3 times) while
/// halving the steps until they are below a quarter cell. Scored by the truncated mean squared distance (smooth enough
/// to descend); the residual reported is the trimmed one. Ties keep the
/// candidate met first, which is the centre: a map that already fits is not
/// moved.
pub fn align(field: &DistanceField, points: &[(f64, f64)], win: &SearchWindow) -> Alignment {
    let mut scratch = Vec::new();
    align_with(field, points, win, &mut scratch)
}

/// [`align`] reusing `scratch` (thinned points and residual buffer).
pub fn align_with(
    field: &DistanceField,
    points: &[(f64, f64)],
    win: &SearchWindow,
    scratch: &mut Vec<f32>,
) -> Alignment {
    const HALF: i32 = 4;
    let stride = points.len().div_ceil(COARSE_POINTS).max(1);
    let coarse: Vec<(f64, f64)> = points.iter().step_by(stride).copied().collect();
    let mut best = win.center;
    let mut evaluations = 1u32;
    let res = field.resolution().max(1e-3);
    let mut step_t = (win.window_m / f64::from(HALF)).max(0.0);
    let mut step_r = (win.window_rad / f64::from(HALF)).max(0.0);
    let mut half = HALF;
    let mut set: &[(f64, f64)] = &coarse;
    let mut best_score = score(field, set, &best);
    // A fine level repeats its ±1 pass while it moves (at most this often):
    // one pass reaches only a step from where the level started.
    const FINE_PASSES: u32 = 3;
    let mut passes = 0u32;
    loop {
        let center = best;
        for i in -half..=half {
            for j in -half..=half {
                for k in -half..=half {
                    if i == 0 && j == 0 && k == 0 {
                        continue;
                    }
                    let cand = Pose2::new(
                        center.x + f64::from(i) * step_t,
                        center.y + f64::from(j) * step_t,
                        center.theta + f64::from(k) * step_r,
                    );
                    let s = score(field, set, &cand);
                    evaluations += 1;
                    if s < best_score {
                        best_score = s;
                        best = cand;
                    }
                }
            }
        }
        passes += 1;
        if half == 1 && best != center && passes < FINE_PASSES {
            continue;
        }
        passes = 0;
        // A quarter cell in translation, and the rotation that moves a wall
        // 10 m away by as much: finer says nothing on this grid.
        if step_t < res / 4.0 && step_r < res / 40.0 {
            break;
        }
        step_t /= 2.0;
        step_r /= 2.0;
        if half == HALF {
            // From the coarse level to the fine ones: every point.
            set = points;
            best_score = score(field, set, &best);
            evaluations += 1;
        }
        half = 1;
        if step_t == 0.0 && step_r == 0.0 {
            break;
        }
    }
    let transform = Pose2::new(
        best.x,
        best.y,
        smokenav_shared_types::normalize_angle(best.theta),
    );
    Alignment {
        transform,
        residual_m: trimmed_residual(field, points, &transform, scratch),
        points: points.len(),
        evaluations,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An L-shaped room with an inner pillar: no symmetry a search could confuse.
    fn room(shift: Pose2) -> OccupancyGrid {
        let res = 0.05;
        let mut g = OccupancyGrid::new(200, 200, res, [-5.0, -5.0, 0.0]);
        let mut wall = |x0: f64, y0: f64, x1: f64, y1: f64| {
            let n = (((x1 - x0).hypot(y1 - y0)) / (res / 2.0)).ceil() as usize;
            for i in 0..=n {
                let t = i as f64 / n as f64;
                let (x, y) = (x0 + t * (x1 - x0), y0 + t * (y1 - y0));
                let (s, c) = shift.theta.sin_cos();
                let (wx, wy) = (c * x - s * y + shift.x, s * x + c * y + shift.y);
                if let Some((cx, cy)) = g.world_to_cell(wx, wy) {
                    g.set(cx, cy, 100);
                }
            }
        };
        wall(-3.0, -3.0, 3.0, -3.0);
        wall(3.0, -3.0, 3.0, 1.0);
        wall(3.0, 1.0, 0.5, 1.0);
        wall(0.5, 1.0, 0.5, 3.0);
        wall(0.5, 3.0, -3.0, 3.0);
        wall(-3.0, 3.0, -3.0, -3.0);
        wall(-1.2, -1.0, -0.6, -1.0);
        wall(-0.6, -1.0, -0.6, -0.2);
        g
    }

    #[test]
    fn recovers_a_known_shift_and_rotation() {
        let reference = room(Pose2::default());
        // The member's map is the room moved by (0.23, −0.17) m and 0.06 rad:
        // the alignment must bring it back, i.e. find the inverse motion.
        let motion = Pose2::new(0.23, -0.17, 0.06);
        let member = room(motion);
        let field = DistanceField::new(&reference, 0.5);
        let mut pts = Vec::new();
        wall_points(&member, 3000, &mut pts);
        let a = align(
            &field,
            &pts,
            &SearchWindow {
                center: Pose2::default(),
                window_m: 0.5,
                window_rad: 0.1,
            },
        );
        let expect = motion.inverse();
        assert!(
            (a.transform.x - expect.x).abs() < 0.03
                && (a.transform.y - expect.y).abs() < 0.03
                && (a.transform.theta - expect.theta).abs() < 0.01,
            "found {:?}, expected {expect:?}",
            a.transform
        );
        assert!(a.residual_m < 0.04, "residual {}", a.residual_m);
        // Unaligned, the same walls lie far off.
        let before = score(&field, &pts, &Pose2::default()).sqrt();
        assert!(
            before > 3.0 * a.residual_m,
            "before {before}, after {}",
            a.residual_m
        );
    }

    #[test]
    fn an_aligned_map_stays_put() {
        let reference = room(Pose2::default());
        let field = DistanceField::new(&reference, 0.5);
        let mut pts = Vec::new();
        wall_points(&reference, 3000, &mut pts);
        let a = align(
            &field,
            &pts,
            &SearchWindow {
                center: Pose2::default(),
                window_m: 0.5,
                window_rad: 0.1,
            },
        );
        assert_eq!(a.transform, Pose2::default());
        assert_eq!(a.residual_m, 0.0);
    }

    /// `room` with `n` phantom wall cells scattered over the free space.
    fn with_phantoms(mut g: OccupancyGrid, n: usize) -> OccupancyGrid {
        let mut r = 7u64;
        for _ in 0..n {
            r = r
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let i = (r >> 33) as usize % g.cells.len();
            g.cells[i] = 100;
        }
        g
    }

    #[test]
    fn phantom_cells_do_not_read_as_misalignment() {
        let reference = room(Pose2::default());
        let field = DistanceField::new(&reference, 0.5);
        let member = with_phantoms(room(Pose2::new(0.1, 0.05, 0.02)), 150);
        let mut pts = Vec::new();
        wall_points(&member, 3000, &mut pts);
        let win = SearchWindow {
            center: Pose2::default(),
            window_m: 0.5,
            window_rad: 0.1,
        };
        let a = align(&field, &pts, &win);
        // The plain RMS at the found transform is above the vote's 0.15 m
        // threshold only because of the phantoms; the trimmed one is not.
        let plain = score(&field, &pts, &a.transform).sqrt();
        assert!(plain > 0.15, "plain RMS {plain}");
        assert!(a.residual_m < 0.04, "trimmed residual {}", a.residual_m);
        // The phantoms do not move the alignment: it is the clean map's.
        let mut clean_pts = Vec::new();
        wall_points(&room(Pose2::new(0.1, 0.05, 0.02)), 3000, &mut clean_pts);
        let clean = align(&field, &clean_pts, &win).transform;
        assert!(
            (a.transform.x - clean.x).abs() < 0.01
                && (a.transform.y - clean.y).abs() < 0.01
                && (a.transform.theta - clean.theta).abs() < 0.003,
            "with phantoms {:?}, clean {clean:?}",
            a.transform
        );
        // And that is the motion undone, to within a cell (rasterisation).
        let expect = Pose2::new(0.1, 0.05, 0.02).inverse();
        assert!(
            (clean.x - expect.x).abs() < 0.05 && (clean.y - expect.y).abs() < 0.05,
            "clean {clean:?}, expected {expect:?}"
        );
    }

    #[test]
    fn trimming_does_not_hide_a_rigid_offset() {
        let reference = room(Pose2::default());
        let field = DistanceField::new(&reference, 0.5);
        let mut scratch = Vec::new();
        // Trimming drops the farthest fifth: a map moved as a whole keeps
        // most of its offset in the residual.
        for off in [Pose2::new(0.25, 0.25, 0.0), Pose2::new(0.0, 0.0, 0.1)] {
            let mut pts = Vec::new();
            wall_points(&room(off), 3000, &mut pts);
            let r = trimmed_residual(&field, &pts, &Pose2::default(), &mut scratch);
            let plain = score(&field, &pts, &Pose2::default()).sqrt();
            assert!(r > 0.6 * plain, "{off:?}: trimmed {r}, plain {plain}");
            assert!(r > 0.1, "{off:?}: trimmed residual {r}");
        }
        let mut pts = Vec::new();
        wall_points(&room(Pose2::new(0.25, 0.25, 0.0)), 3000, &mut pts);
        let r = trimmed_residual(&field, &pts, &Pose2::default(), &mut scratch);
        assert!(r > 0.15, "a quarter metre off both ways: {r}");
    }

    #[test]
    fn a_narrow_window_cannot_reach_a_far_alignment() {
        // What the vote relies on to fall back to the wide search: a warm
        // start in the wrong place leaves the residual above the threshold.
        let reference = room(Pose2::default());
        let field = DistanceField::new(&reference, 0.5);
        let mut pts = Vec::new();
        wall_points(&room(Pose2::new(0.4, -0.3, 0.0)), 3000, &mut pts);
        let near = align(
            &field,
            &pts,
            &SearchWindow {
                center: Pose2::default(),
                window_m: 0.1,
                window_rad: 0.02,
            },
        );
        assert!(near.residual_m > 0.15, "{}", near.residual_m);
        let wide = align(
            &field,
            &pts,
            &SearchWindow {
                center: Pose2::default(),
                window_m: 0.6,
                window_rad: 0.1,
            },
        );
        assert!(wide.residual_m < 0.04, "{}", wide.residual_m);
    }

    #[test]
    fn a_shift_of_less_than_a_cell_is_found() {
        // The member's walls 2 cm and 0.3° off: read off the nearest cell, the
        // score is flat over a cell and any shift within it is as good.
        let reference = room(Pose2::default());
        let field = DistanceField::new(&reference, 0.3);
        let mut pts = Vec::new();
        wall_points(&reference, 3000, &mut pts);
        let moved: Vec<(f64, f64)> = {
            let t = Pose2::new(0.02, -0.015, 0.3f64.to_radians());
            let (s, c) = t.theta.sin_cos();
            pts.iter()
                .map(|&(x, y)| (c * x - s * y + t.x, s * x + c * y + t.y))
                .collect()
        };
        let a = align(
            &field,
            &moved,
            &SearchWindow {
                center: Pose2::default(),
                window_m: 0.2,
                window_rad: 0.05,
            },
        );
        // The inverse of the shift, to a few millimetres.
        let back = a
            .transform
            .compose(&Pose2::new(0.02, -0.015, 0.3f64.to_radians()));
        assert!(
            back.x.abs() < 0.006 && back.y.abs() < 0.006 && back.theta.abs() < 0.1f64.to_radians(),
            "{:?} → {back:?}",
            a.transform
        );
    }

    #[test]
    fn distance_field_is_truncated_and_zero_on_walls() {
        let g = room(Pose2::default());
        let f = DistanceField::new(&g, 0.3);
        // On a wall cell's centre; half a cell off it, half a cell.
        assert_eq!(f.d2_at(-2.975, 0.025), 0.0);
        assert!((f.d2_at(-2.95, 0.025).sqrt() - 0.025).abs() < 1e-6);
        assert!(
            (f.d2_at(-2.0, 0.0) - 0.09).abs() < 1e-6,
            "{}",
            f.d2_at(-2.0, 0.0)
        );
        assert!((f.d2_at(-2.85, 0.0).sqrt() - 0.15).abs() < 0.051);
        // Outside the grid: the truncation.
        assert!((f.d2_at(50.0, 0.0) - 0.09).abs() < 1e-6);
    }
}
