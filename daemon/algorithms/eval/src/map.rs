//! Map accuracy against a ground-truth map.
//!
//! * k-nearest-neighbour error (SmokeNav (Santos et al. 2015), Sec. 3 and Table 4, after Santos et
//!   al. 2013): after a best-fit alignment, for each occupied ground-truth
//!   cell the distance to the nearest occupied cell of the estimate (walls
//!   missed or misplaced), and — so phantom walls, e.g. smoke mapped as an
//!   obstacle, are penalised too — for each occupied estimated cell the
//!   distance to the nearest occupied ground-truth cell. Reported in metres
//!   and in cells of the ground truth (the paper's tables are in pixels).
//! * Pixel error (SLAMfusion (Fernandes & Alexandre)): with cells normalised to −1 unknown, 0 free, 1
//!   occupied (occupancy/100 in between), Error = (Σ (T − M)²)^½ over the
//!   ground-truth grid, and the same as a root mean square per cell.
//!
//! The alignment is rigid (x, y, θ), found by minimising the truncated squared
//! distance of the estimate's occupied cells to the ground truth's walls:
//! a coarse search over rotations and translations, then a pattern search
//! from the best few and from the best of each other rotation, with the
//! truncation shrinking to two cells, so a wall displaced by more than that
//! does not drag the whole map along. Of the refined fits the one that fits
//! both ways best wins (a turned-round building can fit the estimate's walls
//! alone as well). Ties keep the identity, so a map already in the ground
//! truth's frame is not moved by symmetric rooms.

use crate::nn::{PointIndex, distance_transform};
use serde::Serialize;
use smokenav_platform_map::OccupancyGrid;

/// Cells at or above this occupancy count as occupied (map_server's 0.65 threshold).
pub const DEFAULT_OCCUPIED: i8 = 65;

/// Most wall cells a map may have. The alignment costs each candidate pose a
/// pass over the estimate's walls: a building's map has tens of thousands; a
/// map millions of cells "occupied" is not a map of walls (an inverted
/// image, a wrong threshold) and would keep `smokenav eval` busy for minutes.
pub const MAX_WALL_CELLS: usize = 200_000;

/// Largest ratio between the two maps' cell sizes: beyond it the finer map's
/// walls fit in a handful of the coarser map's cells and the comparison says nothing.
pub const MAX_RESOLUTION_RATIO: f64 = 100.0;

#[derive(Debug, Clone, PartialEq)]
pub struct MapOptions {
    /// Search for the best rigid alignment (otherwise both maps are taken in one frame).
    pub align: bool,
    /// Occupancy at or above which a cell is a wall.
    pub occupied_threshold: i8,
    /// Largest rotation searched, degrees (180: any).
    pub max_rotation_deg: f64,
}

impl Default for MapOptions {
    fn default() -> Self {
        Self {
            align: true,
            occupied_threshold: DEFAULT_OCCUPIED,
            max_rotation_deg: 180.0,
        }
    }
}

/// Rigid transform taking estimate-map coordinates into ground-truth coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct Alignment {
    pub dx_m: f64,
    pub dy_m: f64,
    pub dtheta_deg: f64,
}

impl Alignment {
    fn apply(&self, (x, y): (f64, f64)) -> (f64, f64) {
        let (s, c) = self.dtheta_deg.to_radians().sin_cos();
        (c * x - s * y + self.dx_m, s * x + c * y + self.dy_m)
    }

    /// The transform that undoes this one.
    fn inverse(&self) -> Alignment {
        let (dx_m, dy_m) = Alignment {
            dx_m: 0.0,
            dy_m: 0.0,
            ..*self
        }
        .inverse_apply((-self.dx_m, -self.dy_m));
        Alignment {
            dx_m,
            dy_m,
            dtheta_deg: -self.dtheta_deg,
        }
    }

    fn inverse_apply(&self, (x, y): (f64, f64)) -> (f64, f64) {
        let (s, c) = self.dtheta_deg.to_radians().sin_cos();
        let (x, y) = (x - self.dx_m, y - self.dy_m);
        (c * x + s * y, -s * x + c * y)
    }
}

/// Summary of a set of distances, m.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct DistanceStats {
    pub count: usize,
    pub mean_m: f64,
    pub rms_m: f64,
    pub median_m: f64,
    pub max_m: f64,
}

impl DistanceStats {
    pub fn from_distances(mut d: Vec<f64>) -> Self {
        if d.is_empty() {
            return Self::default();
        }
        let n = d.len() as f64;
        let mean = d.iter().sum::<f64>() / n;
        let rms = (d.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
        d.sort_by(f64::total_cmp);
        let median = if d.len() % 2 == 1 {
            d[d.len() / 2]
        } else {
            (d[d.len() / 2 - 1] + d[d.len() / 2]) / 2.0
        };
        Self {
            count: d.len(),
            mean_m: mean,
            rms_m: rms,
            median_m: median,
            max_m: d[d.len() - 1],
        }
    }
}

/// Walls nearer than this to the other map's, in ground-truth cells, are on
/// it (the metric's own noise: a wall drawn one cell thick beside a wall one
/// cell thick is up to a cell and a half off).
pub const ON_WALL_CELLS: f64 = 1.5;
/// Walls further than this from the other map's, in ground-truth cells, are
/// not a misplaced copy of one: a wall the estimate lacks (truth → map) or
/// one the building lacks (map → truth: smoke mapped as an obstacle).
pub const NOT_A_WALL_CELLS: f64 = 6.0;

/// One band of one direction's distances: how many cells fall in it and how
/// much they add to the k-NN error (their sum over the direction's count,
/// halved), m. The six bands of a [`MapReport`] add up to its k-NN error.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct Band {
    pub cells: usize,
    pub knn_share_m: f64,
}

/// A group of cells more than [`NOT_A_WALL_CELLS`] from the other map's walls
/// (each within [`FAR_LINK_CELLS`] of another, in the ground truth's cells):
/// where a wall is missing or a phantom stands, in the ground truth's frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FarGroup {
    pub cells: usize,
    /// Mean position of its cells, m.
    pub x_m: f64,
    pub y_m: f64,
    /// What it adds to the k-NN error, m.
    pub knn_share_m: f64,
}

/// Where one direction's part of the k-NN error comes from.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct ErrorBands {
    /// Within [`ON_WALL_CELLS`].
    pub on_wall: Band,
    /// Between [`ON_WALL_CELLS`] and [`NOT_A_WALL_CELLS`]: a wall drawn off its place.
    pub misplaced: Band,
    /// Beyond [`NOT_A_WALL_CELLS`]: missing (truth → map) or phantom (map → truth) walls.
    pub far: Band,
    /// The far cells' largest groups, largest share first (at most [`MAX_FAR_GROUPS`]).
    pub far_groups: Vec<FarGroup>,
}

/// Far groups a report lists.
pub const MAX_FAR_GROUPS: usize = 5;
/// Far cells this close (in cells, either axis) belong to one group: smoke
/// mapped from afar is a scatter, not a line.
pub const FAR_LINK_CELLS: i64 = 3;

/// Which band a wall `d` m from the other map's walls falls in (cells of `resolution` m).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum BandOf {
    OnWall,
    Misplaced,
    Far,
}

fn band_of(d: f64, resolution: f64) -> BandOf {
    if d < ON_WALL_CELLS * resolution {
        BandOf::OnWall
    } else if d <= NOT_A_WALL_CELLS * resolution {
        BandOf::Misplaced
    } else {
        BandOf::Far
    }
}

impl ErrorBands {
    /// `points` (ground-truth frame) with their distances to the other map's walls.
    fn new(points: &[(f64, f64)], distances: &[f64], resolution: f64) -> Self {
        let n = distances.len().max(1) as f64;
        let share = |d: f64| d / n / 2.0;
        let mut bands = Self::default();
        let mut far = std::collections::HashMap::new();
        for (&p, &d) in points.iter().zip(distances) {
            let band = match band_of(d, resolution) {
                BandOf::OnWall => &mut bands.on_wall,
                BandOf::Misplaced => &mut bands.misplaced,
                BandOf::Far => {
                    let cell = (
                        (p.0 / resolution).floor() as i64,
                        (p.1 / resolution).floor() as i64,
                    );
                    // Two estimated cells can fall in one ground-truth cell once turned.
                    let e = far.entry(cell).or_insert((0usize, 0.0, 0.0, 0.0));
                    *e = (e.0 + 1, e.1 + p.0, e.2 + p.1, e.3 + d);
                    &mut bands.far
                }
            };
            band.cells += 1;
            band.knn_share_m += share(d);
        }
        // Flood the far cells into groups, visiting cells in a
        // fixed order so equal inputs give equal reports.
        let mut cells: Vec<(i64, i64)> = far.keys().copied().collect();
        cells.sort_unstable();
        let mut seen = std::collections::HashSet::new();
        let mut stack = Vec::new();
        for start in cells {
            if !seen.insert(start) {
                continue;
            }
            stack.push(start);
            let (mut count, mut sx, mut sy, mut sum) = (0usize, 0.0, 0.0, 0.0);
            while let Some((cx, cy)) = stack.pop() {
                let (k, x, y, d) = far[&(cx, cy)];
                count += k;
                sx += x;
                sy += y;
                sum += d;
                for dy in -FAR_LINK_CELLS..=FAR_LINK_CELLS {
                    for dx in -FAR_LINK_CELLS..=FAR_LINK_CELLS {
                        let next = (cx + dx, cy + dy);
                        if far.contains_key(&next) && seen.insert(next) {
                            stack.push(next);
                        }
                    }
                }
            }
            bands.far_groups.push(FarGroup {
                cells: count,
                x_m: sx / count as f64,
                y_m: sy / count as f64,
                knn_share_m: share(sum),
            });
        }
        bands
            .far_groups
            .sort_by(|a, b| b.knn_share_m.total_cmp(&a.knn_share_m));
        bands.far_groups.truncate(MAX_FAR_GROUPS);
        bands
    }
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MapReport {
    /// Ground-truth cell side, m.
    pub resolution_m: f64,
    pub alignment: Alignment,
    /// Ground-truth walls → nearest estimated wall (missed or misplaced walls).
    pub truth_to_map: DistanceStats,
    /// Estimated walls → nearest ground-truth wall (phantom or misplaced walls).
    pub map_to_truth: DistanceStats,
    /// Where the k-NN error comes from, each direction in three bands.
    pub truth_to_map_bands: ErrorBands,
    pub map_to_truth_bands: ErrorBands,
    /// The k-NN error: mean of the two directions' mean distances, m.
    pub knn_error_m: f64,
    /// The same in ground-truth cells (pixels).
    pub knn_error_cells: f64,
    /// SLAMfusion's pixel error: (Σ (T − M)²)^½ over the ground-truth grid.
    pub pixel_error: f64,
    /// Per-cell root mean square of T − M.
    pub pixel_rms: f64,
    pub pixel_count: usize,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MapMetricError {
    #[error("the {which} map has no occupied cells (occupancy ≥ {threshold})")]
    NoWalls { which: &'static str, threshold: i8 },
    #[error("the {which} map has an invalid geometry: {reason}")]
    Geometry { which: &'static str, reason: String },
    #[error(
        "the {which} map has {cells} occupied cells (occupancy ≥ {threshold}), more than the {MAX_WALL_CELLS} a map of walls has"
    )]
    TooManyWalls {
        which: &'static str,
        cells: usize,
        threshold: i8,
    },
    #[error(
        "the estimated map's cells ({estimate_m} m) and the ground truth's ({truth_m} m) differ by more than {MAX_RESOLUTION_RATIO}×"
    )]
    Incomparable { truth_m: f64, estimate_m: f64 },
}

fn occupied(g: &OccupancyGrid, threshold: i8) -> Vec<(f64, f64)> {
    g.occupied_points(threshold)
}

fn check_geometry(g: &OccupancyGrid, which: &'static str) -> Result<(), MapMetricError> {
    let bad = |reason: String| MapMetricError::Geometry { which, reason };
    if !(g.resolution.is_finite() && g.resolution > 0.0) {
        return Err(bad(format!("resolution {}", g.resolution)));
    }
    if g.cells.len() != g.width * g.height {
        return Err(bad(format!(
            "{} cells for {}×{}",
            g.cells.len(),
            g.width,
            g.height
        )));
    }
    if g.origin.iter().any(|v| !v.is_finite()) {
        return Err(bad("origin is not finite".into()));
    }
    Ok(())
}

/// Distance field of one map's walls, padded so aligned points just outside
/// its grid still find their distance.
struct WallField {
    origin: (f64, f64),
    res: f64,
    w: usize,
    h: usize,
    /// Distance in metres from each cell centre to the nearest wall centre.
    dist: Vec<f64>,
}

impl WallField {
    fn new(truth: &OccupancyGrid, threshold: i8) -> Self {
        let pad = 20usize;
        let (w, h) = (truth.width + 2 * pad, truth.height + 2 * pad);
        let mut sites = vec![false; w * h];
        for y in 0..truth.height {
            for x in 0..truth.width {
                if truth.cells[y * truth.width + x] >= threshold {
                    sites[(y + pad) * w + x + pad] = true;
                }
            }
        }
        let dist = distance_transform(w, h, &sites)
            .into_iter()
            .map(|d| d * truth.resolution)
            .collect();
        Self {
            origin: (
                truth.origin[0] - pad as f64 * truth.resolution,
                truth.origin[1] - pad as f64 * truth.resolution,
            ),
            res: truth.resolution,
            w,
            h,
            dist,
        }
    }

    /// Bilinear distance to the nearest wall at a world point; `far` outside the field.
    fn at(&self, (x, y): (f64, f64), far: f64) -> f64 {
        let fx = (x - self.origin.0) / self.res - 0.5;
        let fy = (y - self.origin.1) / self.res - 0.5;
        if !(fx >= 0.0 && fy >= 0.0 && fx < (self.w - 1) as f64 && fy < (self.h - 1) as f64) {
            return far;
        }
        let (x0, y0) = (fx as usize, fy as usize);
        let (tx, ty) = (fx - x0 as f64, fy - y0 as f64);
        let i = y0 * self.w + x0;
        let d = &self.dist;
        let a = d[i] * (1.0 - tx) + d[i + 1] * tx;
        let b = d[i + self.w] * (1.0 - tx) + d[i + self.w + 1] * tx;
        (a * (1.0 - ty) + b * ty).min(far)
    }

    /// Mean truncated squared distance of the aligned points.
    fn cost(&self, pts: &[(f64, f64)], al: &Alignment, trunc: f64) -> f64 {
        let t2 = trunc * trunc;
        let (s, c) = al.dtheta_deg.to_radians().sin_cos();
        let mut sum = 0.0;
        for &(x, y) in pts {
            let p = (c * x - s * y + al.dx_m, s * x + c * y + al.dy_m);
            let d = self.at(p, trunc);
            sum += (d * d).min(t2);
        }
        sum / pts.len().max(1) as f64
    }
}

/// Every `step`-th point, so the coarse search stays cheap on big maps.
fn subsample(pts: &[(f64, f64)], max: usize) -> Vec<(f64, f64)> {
    let step = pts.len().div_ceil(max.max(1)).max(1);
    pts.iter().step_by(step).copied().collect()
}

fn centroid(pts: &[(f64, f64)]) -> (f64, f64) {
    let n = pts.len().max(1) as f64;
    let (sx, sy) = pts.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
    (sx / n, sy / n)
}

/// Pattern search from `start` at truncation `trunc`, halving steps down to the floor.
fn refine(
    field: &WallField,
    pts: &[(f64, f64)],
    start: Alignment,
    trunc: f64,
    res: f64,
) -> (Alignment, f64) {
    let mut best = start;
    let mut best_cost = field.cost(pts, &best, trunc);
    let (mut step_t, mut step_r) = (4.0 * res, 2.0);
    while step_t >= res / 8.0 {
        let mut improved = true;
        let mut guard = 0;
        while improved && guard < 200 {
            improved = false;
            guard += 1;
            for (dx, dy, dr) in [
                (step_t, 0.0, 0.0),
                (-step_t, 0.0, 0.0),
                (0.0, step_t, 0.0),
                (0.0, -step_t, 0.0),
                (0.0, 0.0, step_r),
                (0.0, 0.0, -step_r),
            ] {
                let cand = Alignment {
                    dx_m: best.dx_m + dx,
                    dy_m: best.dy_m + dy,
                    dtheta_deg: best.dtheta_deg + dr,
                };
                let c = field.cost(pts, &cand, trunc);
                // Strictly better only: ties keep the incumbent.
                if c < best_cost - 1e-15 {
                    best = cand;
                    best_cost = c;
                    improved = true;
                }
            }
        }
        step_t /= 2.0;
        step_r /= 2.0;
    }
    (best, best_cost)
}

/// Finds the rigid transform that best lays the estimate over the truth.
fn align(
    field: &WallField,
    est_field: &WallField,
    truth_pts: &[(f64, f64)],
    est_pts: &[(f64, f64)],
    opts: &MapOptions,
) -> Alignment {
    let res = field.res;
    let coarse = subsample(est_pts, 300);
    let identity = Alignment::default();
    // Coarse: rotations every 3°, translations on a grid around the centroid
    // match, with a generous truncation (walls within 0.5 m count). The grid
    // spans half the truth's extent each way (0.6 m at least, 10 m at most):
    // an estimate of one room of a building has its centroid metres from the
    // whole building's. Its step, at most 41 × 41 positions, stays inside
    // the truncation's reach.
    let trunc_coarse = 0.5;
    let ct = centroid(truth_pts);
    let ce = centroid(est_pts);
    let extent = {
        let (lo, hi) = truth_pts.iter().fold(
            ((f64::MAX, f64::MAX), (f64::MIN, f64::MIN)),
            |(lo, hi), p| {
                (
                    (lo.0.min(p.0), lo.1.min(p.1)),
                    (hi.0.max(p.0), hi.1.max(p.1)),
                )
            },
        );
        (hi.0 - lo.0).hypot(hi.1 - lo.1)
    };
    let half_span = (extent / 2.0).clamp(0.6, 10.0);
    let step = (half_span / 20.0).max(0.1);
    let n_step = (half_span / step).round() as i64;
    let mut candidates: Vec<(f64, Alignment)> = Vec::new();
    let max_rot = opts.max_rotation_deg.clamp(0.0, 180.0);
    let n_rot = (max_rot / 3.0).floor() as i64;
    for k in -n_rot..=n_rot {
        let th = k as f64 * 3.0;
        if th <= -180.0 {
            continue;
        }
        let (s, c) = th.to_radians().sin_cos();
        let rc = (c * ce.0 - s * ce.1, s * ce.0 + c * ce.1);
        let base = (ct.0 - rc.0, ct.1 - rc.1);
        for iy in -n_step..=n_step {
            for ix in -n_step..=n_step {
                let a = Alignment {
                    dx_m: base.0 + ix as f64 * step,
                    dy_m: base.1 + iy as f64 * step,
                    dtheta_deg: th,
                };
                candidates.push((field.cost(&coarse, &a, trunc_coarse), a));
            }
        }
    }
    // Seeds: the identity, the best few, and the best of every other
    // rotation 15° or more from those: in a nearly symmetric building the
    // best few can all be the turned-round fit.
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut seeds = vec![identity];
    seeds.extend(candidates.iter().take(6).map(|c| c.1));
    let turn = |a: &Alignment, b: &Alignment| {
        (a.dtheta_deg - b.dtheta_deg + 180.0).rem_euclid(360.0) - 180.0
    };
    for c in &candidates[candidates.len().min(6)..] {
        if seeds.len() >= 32 {
            break;
        }
        if seeds[1..].iter().all(|s| turn(s, &c.1).abs() >= 15.0) {
            seeds.push(c.1);
        }
    }
    // Refine each against the truth's walls with shrinking truncation. The
    // fit both ways (the estimate's walls on the truth's and the truth's on
    // the estimate's) picks the basin: the estimate's walls alone can fit a
    // turned-round building as well when it has phantom walls where the
    // truth's were not seen. Within that basin the estimate's fit decides,
    // so a wall the estimate missed does not drag the rest.
    let final_trunc = 2.0 * res;
    let pick_trunc = 0.5f64.max(8.0 * res);
    let refined: Vec<Alignment> = seeds
        .into_iter()
        .map(|mut a| {
            for trunc in [pick_trunc, 4.0 * res, final_trunc] {
                a = refine(field, est_pts, a, trunc, res).0;
            }
            a
        })
        .collect();
    let both = |a: &Alignment| {
        field.cost(est_pts, a, pick_trunc) + est_field.cost(truth_pts, &a.inverse(), pick_trunc)
    };
    let mut basin = identity;
    let mut basin_cost = both(&identity);
    for a in &refined {
        let c = both(a);
        if c < basin_cost - 1e-15 {
            basin = *a;
            basin_cost = c;
        }
    }
    let near = |a: &Alignment| {
        (a.dx_m - basin.dx_m).hypot(a.dy_m - basin.dy_m) <= 4.0 * res
            && turn(a, &basin).abs() <= 2.0
    };
    // The basin's fits, identity first: ties keep the identity, then the
    // earlier seed. The basin itself is one of them.
    let mut best: Option<(Alignment, f64)> = None;
    for a in std::iter::once(&identity)
        .chain(&refined)
        .filter(|a| near(a))
    {
        let c = field.cost(est_pts, a, final_trunc);
        if best.is_none_or(|(_, b)| c < b - 1e-15) {
            best = Some((*a, c));
        }
    }
    let mut best = best.map_or(basin, |(a, _)| a);
    best.dtheta_deg = ((best.dtheta_deg + 180.0).rem_euclid(360.0)) - 180.0;
    best
}

/// Normalised cell value for the pixel metric: −1 unknown, 0..1 occupancy.
fn pixel_value(v: i8) -> f64 {
    if v < 0 {
        -1.0
    } else {
        v.min(100) as f64 / 100.0
    }
}

/// Compares an estimated map with the ground truth.
pub fn evaluate_maps(
    truth: &OccupancyGrid,
    est: &OccupancyGrid,
    opts: &MapOptions,
) -> Result<MapReport, MapMetricError> {
    check_geometry(truth, "ground-truth")?;
    check_geometry(est, "estimated")?;
    let ratio = est.resolution / truth.resolution;
    if !(1.0 / MAX_RESOLUTION_RATIO..=MAX_RESOLUTION_RATIO).contains(&ratio) {
        return Err(MapMetricError::Incomparable {
            truth_m: truth.resolution,
            estimate_m: est.resolution,
        });
    }
    let thr = opts.occupied_threshold;
    for (g, which) in [(truth, "ground-truth"), (est, "estimated")] {
        let cells = g.cells.iter().filter(|&&c| c >= thr).count();
        if cells > MAX_WALL_CELLS {
            return Err(MapMetricError::TooManyWalls {
                which,
                cells,
                threshold: thr,
            });
        }
    }
    let truth_pts = occupied(truth, thr);
    let est_pts = occupied(est, thr);
    if truth_pts.is_empty() {
        return Err(MapMetricError::NoWalls {
            which: "ground-truth",
            threshold: thr,
        });
    }
    if est_pts.is_empty() {
        return Err(MapMetricError::NoWalls {
            which: "estimated",
            threshold: thr,
        });
    }
    let field = WallField::new(truth, thr);
    let alignment = if opts.align {
        let est_field = WallField::new(est, thr);
        align(&field, &est_field, &truth_pts, &est_pts, opts)
    } else {
        Alignment::default()
    };
    let est_aligned: Vec<(f64, f64)> = est_pts.iter().map(|&p| alignment.apply(p)).collect();
    let (to_map, to_truth) = wall_distances(&truth_pts, &est_aligned, truth.resolution);
    let truth_to_map_bands = ErrorBands::new(&truth_pts, &to_map, truth.resolution);
    let map_to_truth_bands = ErrorBands::new(&est_aligned, &to_truth, truth.resolution);
    let truth_to_map = DistanceStats::from_distances(to_map);
    let map_to_truth = DistanceStats::from_distances(to_truth);
    let knn_error_m = (truth_to_map.mean_m + map_to_truth.mean_m) / 2.0;

    // SLAMfusion's pixel error over the ground-truth grid, the estimate sampled at each aligned cell centre.
    let mut sum2 = 0.0;
    for y in 0..truth.height {
        for x in 0..truth.width {
            let t = pixel_value(truth.cells[y * truth.width + x]);
            let c = truth.cell_center(x, y);
            let (ex, ey) = alignment.inverse_apply(c);
            let m = est
                .world_to_cell(ex, ey)
                .and_then(|(i, j)| est.get(i, j))
                .map_or(-1.0, pixel_value);
            sum2 += (t - m) * (t - m);
        }
    }
    let pixel_count = truth.width * truth.height;
    Ok(MapReport {
        resolution_m: truth.resolution,
        alignment,
        truth_to_map,
        map_to_truth,
        truth_to_map_bands,
        map_to_truth_bands,
        knn_error_m,
        knn_error_cells: knn_error_m / truth.resolution,
        pixel_error: sum2.sqrt(),
        pixel_rms: (sum2 / pixel_count.max(1) as f64).sqrt(),
        pixel_count,
    })
}

/// Each ground-truth wall's distance to the nearest of the (aligned)
/// estimate's walls, and each of those's to the nearest ground-truth wall, m.
fn wall_distances(
    truth_pts: &[(f64, f64)],
    est_aligned: &[(f64, f64)],
    resolution: f64,
) -> (Vec<f64>, Vec<f64>) {
    let bucket = 4.0 * resolution;
    let est_index = PointIndex::new(est_aligned.to_vec(), bucket);
    let truth_index = PointIndex::new(truth_pts.to_vec(), bucket);
    let to_map = truth_pts
        .iter()
        .map(|&(x, y)| est_index.nearest_distance(x, y))
        .collect();
    let to_truth = est_aligned
        .iter()
        .map(|&(x, y)| truth_index.nearest_distance(x, y))
        .collect();
    (to_map, to_truth)
}

/// What one cell of an [`ErrorPicture`] shows, in the bands of the k-NN
/// error's breakdown ([`ErrorBands`]). An estimated wall wins over a
/// ground-truth wall in the same cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorClass {
    /// No wall, and the estimate never saw the place.
    Unknown,
    /// No wall, and the estimate has it free.
    Free,
    /// A ground-truth wall the estimate has within [`ON_WALL_CELLS`] (drawn beside it).
    TruthOnWall,
    /// A ground-truth wall the estimate draws off its place (up to [`NOT_A_WALL_CELLS`] away).
    TruthMisplaced,
    /// A ground-truth wall the estimate lacks.
    Missing,
    /// An estimated wall within [`ON_WALL_CELLS`] of a ground-truth wall.
    EstimateOnWall,
    /// An estimated wall off its place.
    EstimateMisplaced,
    /// An estimated wall the building lacks (smoke mapped as an obstacle).
    Phantom,
}

impl ErrorClass {
    /// The colour `smokenav eval --error-image` and the demo's `errors.png`
    /// draw a cell of this class in (RGB): estimated walls black on their
    /// place, red off it, magenta phantom; true walls pale green beside an
    /// estimated one, light blue where it is drawn off its place, blue
    /// missing; free white, unknown grey.
    pub fn rgb(self) -> [u8; 3] {
        match self {
            ErrorClass::Unknown => [205, 205, 205],
            ErrorClass::Free => [255, 255, 255],
            ErrorClass::TruthOnWall => [180, 225, 180],
            ErrorClass::TruthMisplaced => [140, 170, 255],
            ErrorClass::Missing => [0, 0, 255],
            ErrorClass::EstimateOnWall => [0, 0, 0],
            ErrorClass::EstimateMisplaced => [230, 0, 0],
            ErrorClass::Phantom => [255, 0, 255],
        }
    }
}

/// Where a map's error lies, cell by cell, in the ground truth's frame and
/// cells: the picture `smokenav eval --error-image` draws.
#[derive(Debug, Clone, PartialEq)]
pub struct ErrorPicture {
    pub width: usize,
    pub height: usize,
    /// Ground-truth frame position of cell (0, 0)'s corner, m.
    pub origin: (f64, f64),
    pub resolution: f64,
    /// Row-major, row 0 at the lowest y.
    pub cells: Vec<ErrorClass>,
}

impl ErrorPicture {
    pub fn get(&self, x: usize, y: usize) -> Option<ErrorClass> {
        (x < self.width && y < self.height).then(|| self.cells[y * self.width + x])
    }

    /// How many cells show `class`.
    pub fn count(&self, class: ErrorClass) -> usize {
        self.cells.iter().filter(|&&c| c == class).count()
    }

    /// What the picture shows at `(x, y)` in the ground truth's frame, m
    /// (unknown outside it).
    pub fn at(&self, x: f64, y: f64) -> ErrorClass {
        self.index(x, y)
            .map_or(ErrorClass::Unknown, |i| self.cells[i])
    }

    fn index(&self, x: f64, y: f64) -> Option<usize> {
        let cx = ((x - self.origin.0) / self.resolution).floor();
        let cy = ((y - self.origin.1) / self.resolution).floor();
        ((0.0..self.width as f64).contains(&cx) && (0.0..self.height as f64).contains(&cy))
            .then(|| cy as usize * self.width + cx as usize)
    }
}

/// Largest picture drawn around the ground truth, in cells: an estimate
/// whose walls reach far beyond the building (a wild phantom) is cut to
/// the ground truth's grid and this margin instead.
pub const PICTURE_MAX_CELLS: usize = 16_000_000;
const PICTURE_MARGIN_CELLS: i64 = 20;

/// Draws where `est`'s error lies against `truth`, `est` moved by
/// `alignment` (the one its [`MapReport`] found) into the ground truth's
/// frame: every wall of either map classed by its distance to the other's,
/// as the k-NN error's bands count it, on the estimate's free and unknown space.
pub fn error_picture(
    truth: &OccupancyGrid,
    est: &OccupancyGrid,
    alignment: &Alignment,
    occupied_threshold: i8,
) -> Result<ErrorPicture, MapMetricError> {
    check_geometry(truth, "ground-truth")?;
    check_geometry(est, "estimated")?;
    let res = truth.resolution;
    let truth_pts = occupied(truth, occupied_threshold);
    let est_aligned: Vec<(f64, f64)> = occupied(est, occupied_threshold)
        .into_iter()
        .map(|p| alignment.apply(p))
        .collect();
    let (to_map, to_truth) = wall_distances(&truth_pts, &est_aligned, res);
    // Cells in the ground truth's grid, covering both maps' walls.
    let cell = |(x, y): (f64, f64)| {
        (
            ((x - truth.origin[0]) / res).floor(),
            ((y - truth.origin[1]) / res).floor(),
        )
    };
    let m = PICTURE_MARGIN_CELLS;
    let around = (-m, -m, truth.width as i64 + m, truth.height as i64 + m);
    let mut bounds = around;
    // Beyond this many cells from the ground truth a wall cannot be in a
    // picture of at most PICTURE_MAX_CELLS (and the i64 sums stay small).
    let reach = PICTURE_MAX_CELLS as f64;
    for &p in &est_aligned {
        let (cx, cy) = cell(p);
        if !(cx.abs() <= reach && cy.abs() <= reach) {
            bounds = around;
            break;
        }
        let (cx, cy) = (cx as i64, cy as i64);
        bounds = (
            bounds.0.min(cx - 2),
            bounds.1.min(cy - 2),
            bounds.2.max(cx + 3),
            bounds.3.max(cy + 3),
        );
    }
    if ((bounds.2 - bounds.0) as f64) * ((bounds.3 - bounds.1) as f64) > PICTURE_MAX_CELLS as f64 {
        bounds = around;
    }
    let (width, height) = (
        (bounds.2 - bounds.0) as usize,
        (bounds.3 - bounds.1) as usize,
    );
    let origin = (
        truth.origin[0] + bounds.0 as f64 * res,
        truth.origin[1] + bounds.1 as f64 * res,
    );
    let mut cells = Vec::with_capacity(width * height);
    for y in 0..height {
        for x in 0..width {
            let c = (
                origin.0 + (x as f64 + 0.5) * res,
                origin.1 + (y as f64 + 0.5) * res,
            );
            let (ex, ey) = alignment.inverse_apply(c);
            let seen = est
                .world_to_cell(ex, ey)
                .and_then(|(i, j)| est.get(i, j))
                .is_some_and(|v| v >= 0);
            cells.push(if seen {
                ErrorClass::Free
            } else {
                ErrorClass::Unknown
            });
        }
    }
    let mut picture = ErrorPicture {
        width,
        height,
        origin,
        resolution: res,
        cells,
    };
    // The estimate's walls second: they win a shared cell.
    use ErrorClass::*;
    for (points, distances, [on_wall, misplaced, far]) in [
        (&truth_pts, &to_map, [TruthOnWall, TruthMisplaced, Missing]),
        (
            &est_aligned,
            &to_truth,
            [EstimateOnWall, EstimateMisplaced, Phantom],
        ),
    ] {
        for (&p, &d) in points.iter().zip(distances) {
            let class = match band_of(d, res) {
                BandOf::OnWall => on_wall,
                BandOf::Misplaced => misplaced,
                BandOf::Far => far,
            };
            if let Some(i) = picture.index(p.0, p.1) {
                picture.cells[i] = class;
            }
        }
    }
    Ok(picture)
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_platform_map::{FREE, OCCUPIED};

    const RES: f64 = 0.05;

    // Both used to keep `smokenav eval` busy for minutes (ring searches
    // across 1e300 m, alignment passes over 4 M "walls"); now they are errors.
    #[test]
    fn a_map_of_absurd_cell_size_is_incomparable() {
        let mut est = room(40);
        est.resolution = 1e300;
        assert_eq!(
            evaluate_maps(&room(40), &est, &MapOptions::default()),
            Err(MapMetricError::Incomparable {
                truth_m: RES,
                estimate_m: 1e300
            })
        );
    }

    #[test]
    fn a_fully_occupied_map_is_not_a_map_of_walls() {
        let mut est = OccupancyGrid::new(2000, 2000, RES, [0.0, 0.0, 0.0]);
        est.cells.fill(OCCUPIED);
        let err = evaluate_maps(&room(40), &est, &MapOptions::default()).unwrap_err();
        assert_eq!(
            err,
            MapMetricError::TooManyWalls {
                which: "estimated",
                cells: 4_000_000,
                threshold: DEFAULT_OCCUPIED
            }
        );
        assert!(err.to_string().contains("4000000"), "{err}");
    }

    /// A 4 × 3 m room (80 × 60 cells inside a 1-cell wall) with a free-standing
    /// partition at column `partition_x`, rows 10 to 40 (31 cells, 8 cells
    /// clear of the outer wall).
    fn room(partition_x: usize) -> OccupancyGrid {
        let (w, h) = (84, 64);
        let mut g = OccupancyGrid::new(w, h, RES, [-0.1, -0.1, 0.0]);
        for y in 0..h {
            for x in 0..w {
                let wall = x == 1 || y == 1 || x == w - 2 || y == h - 2;
                let inside = x > 1 && y > 1 && x < w - 2 && y < h - 2;
                if wall {
                    g.set(x, y, OCCUPIED);
                } else if inside {
                    g.set(x, y, FREE);
                }
            }
        }
        for y in 10..=40 {
            g.set(partition_x, y, OCCUPIED);
        }
        g
    }

    fn count_occupied(g: &OccupancyGrid) -> usize {
        g.cells.iter().filter(|&&c| c >= DEFAULT_OCCUPIED).count()
    }

    #[test]
    fn identical_maps_score_zero() {
        let g = room(30);
        let r = evaluate_maps(&g, &g, &MapOptions::default()).unwrap();
        assert_eq!(r.alignment, Alignment::default());
        assert_eq!(r.knn_error_m, 0.0);
        assert_eq!(r.truth_to_map.max_m, 0.0);
        assert_eq!(r.map_to_truth.max_m, 0.0);
        assert_eq!(r.pixel_error, 0.0);
        assert_eq!(r.truth_to_map.count, count_occupied(&g));
    }

    #[test]
    fn partition_shifted_by_k_cells_is_off_by_k_times_resolution() {
        let truth = room(30);
        for k in [3usize, 5, 8] {
            let est = room(30 + k);
            let r = evaluate_maps(&truth, &est, &MapOptions::default()).unwrap();
            assert_eq!(
                r.alignment,
                Alignment::default(),
                "k = {k}: the rest of the room pins the alignment"
            );
            let expect = k as f64 * RES;
            // The 31 partition cells are exactly k cells from their copy; every other wall matches.
            let n = count_occupied(&truth) as f64;
            assert!(
                (r.truth_to_map.max_m - expect).abs() < 1e-9,
                "k = {k}: {:?}",
                r.truth_to_map
            );
            assert!(
                (r.map_to_truth.max_m - expect).abs() < 1e-9,
                "k = {k}: {:?}",
                r.map_to_truth
            );
            assert!(
                (r.truth_to_map.mean_m - expect * 31.0 / n).abs() < 1e-9,
                "k = {k}: {:?}",
                r.truth_to_map
            );
            assert!((r.knn_error_cells - k as f64 * 31.0 / n).abs() < 1e-6);
            // Shifted by up to 6 cells it is a misplaced wall; by 8, a missing one and a phantom.
            let (misplaced, far) = if k <= 6 { (31, 0) } else { (0, 31) };
            for b in [&r.truth_to_map_bands, &r.map_to_truth_bands] {
                assert_eq!(
                    (b.misplaced.cells, b.far.cells),
                    (misplaced, far),
                    "k = {k}"
                );
            }
            assert_bands_add_up(&r);
            // SLAMfusion's error: 31 cells went occupied → free and 31 free → occupied, each (1 − 0)² = 1.
            assert!(
                (r.pixel_error - 62f64.sqrt()).abs() < 1e-9,
                "k = {k}: {}",
                r.pixel_error
            );
        }
    }

    #[test]
    fn the_error_picture_shows_a_wall_where_it_is_and_where_it_should_be() {
        let truth = room(30);
        let m = PICTURE_MARGIN_CELLS as usize;
        for (k, off_place, should_be) in [
            (3, ErrorClass::EstimateMisplaced, ErrorClass::TruthMisplaced),
            (8, ErrorClass::Phantom, ErrorClass::Missing),
        ] {
            let est = room(30 + k);
            let r = evaluate_maps(&truth, &est, &MapOptions::default()).unwrap();
            let pic = error_picture(&truth, &est, &r.alignment, DEFAULT_OCCUPIED).unwrap();
            assert_eq!((pic.width, pic.height), (84 + 2 * m, 64 + 2 * m), "k = {k}");
            assert_eq!(pic.resolution, RES);
            assert!((pic.origin.0 - (-0.1 - m as f64 * RES)).abs() < 1e-9);
            for y in 10..=40 {
                assert_eq!(pic.get(30 + m, y + m), Some(should_be), "k = {k}, row {y}");
                assert_eq!(
                    pic.get(30 + k + m, y + m),
                    Some(off_place),
                    "k = {k}, row {y}"
                );
            }
            assert_eq!(pic.count(off_place), 31, "k = {k}");
            assert_eq!(pic.count(should_be), 31, "k = {k}");
            // The room's walls are where they belong; inside is free, outside never seen.
            assert_eq!(
                pic.count(ErrorClass::EstimateOnWall),
                count_occupied(&truth) - 31
            );
            assert_eq!(pic.get(1 + m, 1 + m), Some(ErrorClass::EstimateOnWall));
            assert_eq!(pic.get(10 + m, 20 + m), Some(ErrorClass::Free));
            assert_eq!(pic.get(0, 0), Some(ErrorClass::Unknown));
            // Cell for cell what the report's bands count.
            let bands = &r.map_to_truth_bands;
            assert_eq!(
                pic.count(ErrorClass::EstimateMisplaced) + pic.count(ErrorClass::Phantom),
                bands.misplaced.cells + bands.far.cells
            );
        }
    }

    #[test]
    fn an_error_picture_stays_around_the_building_whatever_the_estimate_holds() {
        let truth = room(30);
        // Walls a thousand kilometres off, or further than any integer
        // reaches, compared in one frame.
        let mut est = room(30);
        for x in [1e6, -1e300, 1e300] {
            est.origin = [x, 0.0, 0.0];
            let pic = error_picture(&truth, &est, &Alignment::default(), DEFAULT_OCCUPIED).unwrap();
            let m = PICTURE_MARGIN_CELLS as usize;
            assert_eq!((pic.width, pic.height), (84 + 2 * m, 64 + 2 * m), "{x}");
            assert_eq!(pic.count(ErrorClass::Missing), count_occupied(&truth));
            assert_eq!(pic.count(ErrorClass::Free), 0);
        }
        // A grid whose shape does not hold is an error, not a panic.
        est.cells.pop();
        assert!(matches!(
            error_picture(&truth, &est, &Alignment::default(), DEFAULT_OCCUPIED),
            Err(MapMetricError::Geometry {
                which: "estimated",
                ..
            })
        ));
    }

    /// A 14 × 10 m hall (280 × 200 cells) in three bays: partitions at
    /// x = 4.5 m and 9 m up to y = 6.75 m, a box in each outer bay. Walls of
    /// the left bay only with `left_bay_only`.
    fn hall(left_bay_only: bool) -> OccupancyGrid {
        let (w, h) = (284, 204);
        let mut g = OccupancyGrid::new(w, h, RES, [-0.1, -0.1, 0.0]);
        let mut wall = |x0: usize, y0: usize, x1: usize, y1: usize| {
            for y in y0..=y1 {
                for x in x0..=x1 {
                    if !left_bay_only || x <= 92 {
                        g.set(x, y, OCCUPIED);
                    }
                }
            }
        };
        wall(2, 2, 281, 2);
        wall(2, 201, 281, 201);
        wall(2, 2, 2, 201);
        wall(281, 2, 281, 201);
        wall(92, 2, 92, 137);
        wall(182, 2, 182, 137);
        wall(30, 70, 43, 70);
        wall(30, 92, 43, 92);
        wall(30, 70, 30, 92);
        wall(43, 70, 43, 92);
        wall(230, 40, 250, 55);
        g
    }

    #[test]
    fn inverse_undoes_the_alignment() {
        let a = Alignment {
            dx_m: 1.3,
            dy_m: -0.7,
            dtheta_deg: 73.0,
        };
        for p in [(0.0, 0.0), (2.5, -1.0), (-4.0, 3.2)] {
            let (x, y) = a.inverse().apply(a.apply(p));
            assert!((x - p.0).abs() < 1e-12 && (y - p.1).abs() < 1e-12, "{p:?}");
            let q = a.inverse().apply(p);
            let r = a.inverse_apply(p);
            assert!((q.0 - r.0).abs() < 1e-12 && (q.1 - r.1).abs() < 1e-12);
        }
    }

    #[test]
    fn a_map_of_one_bay_is_found_in_the_whole_building() {
        // The estimate mapped the left bay only, in a frame 2 m right and
        // 1.5 m down of the truth's: its centroid lies 4.7 m from the
        // hall's, beyond the ±0.6 m a search around the centroids reached.
        let truth = hall(false);
        let mut est = hall(true);
        est.origin = [-0.1 + 2.0, -0.1 - 1.5, 0.0];
        let r = evaluate_maps(&truth, &est, &MapOptions::default()).unwrap();
        assert!(
            (r.alignment.dx_m + 2.0).abs() < 0.02
                && (r.alignment.dy_m - 1.5).abs() < 0.02
                && r.alignment.dtheta_deg.abs() < 0.2,
            "{:?}",
            r.alignment
        );
        assert!(r.map_to_truth.mean_m < 0.005, "{:?}", r.map_to_truth);
    }

    #[test]
    fn whole_map_shifted_and_turned_is_realigned() {
        let truth = room(30);
        let mut est = room(30);
        // Same cells, but the estimate's frame is offset by (0.37, -0.22) m.
        est.origin = [-0.1 + 0.37, -0.1 - 0.22, 0.0];
        let r = evaluate_maps(&truth, &est, &MapOptions::default()).unwrap();
        assert!(
            (r.alignment.dx_m + 0.37).abs() < 0.01 && (r.alignment.dy_m - 0.22).abs() < 0.01,
            "{:?}",
            r.alignment
        );
        assert!(r.knn_error_m < 0.005, "{}", r.knn_error_m);
        let unaligned = evaluate_maps(
            &truth,
            &est,
            &MapOptions {
                align: false,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(unaligned.knn_error_m > 0.1);
    }

    #[test]
    fn rotated_map_is_realigned() {
        let truth = room(30);
        // Rotate the estimate's cells by 90° about the grid's corner.
        let (w, h) = (truth.width, truth.height);
        let mut est = OccupancyGrid::new(h, w, RES, [0.0, 0.0, 0.0]);
        for y in 0..h {
            for x in 0..w {
                est.set(h - 1 - y, x, truth.get(x, y).unwrap());
            }
        }
        let r = evaluate_maps(&truth, &est, &MapOptions::default()).unwrap();
        assert!(
            (r.alignment.dtheta_deg.abs() - 90.0).abs() < 0.5,
            "{:?}",
            r.alignment
        );
        assert!(r.knn_error_m < 0.01, "{r:?}");
    }

    #[test]
    fn phantom_wall_is_penalised_only_map_to_truth() {
        let truth = room(30);
        let mut est = room(30);
        // Smoke mapped as a wall: a 20-cell bar across the open right half, 0.5 m from anything.
        for x in 50..70 {
            est.set(x, 30, OCCUPIED);
        }
        let r = evaluate_maps(&truth, &est, &MapOptions::default()).unwrap();
        assert_eq!(r.alignment, Alignment::default());
        assert_eq!(r.truth_to_map.max_m, 0.0, "no truth wall is missing");
        assert!(r.map_to_truth.max_m > 0.5, "{:?}", r.map_to_truth);
        assert!(r.knn_error_m > 0.0);
        let clean = evaluate_maps(&truth, &truth, &MapOptions::default()).unwrap();
        assert!(r.knn_error_m > clean.knn_error_m && r.pixel_error > clean.pixel_error);
        // The breakdown names it: one phantom where the bar is, nothing missing.
        let b = &r.map_to_truth_bands;
        assert_eq!(r.truth_to_map_bands.far.cells, 0);
        assert_eq!(b.far_groups.len(), 1, "{b:?}");
        let g = b.far_groups[0];
        assert_eq!(g.cells, b.far.cells);
        assert!(
            (g.x_m - 2.9).abs() < 1e-9 && (g.y_m - 1.425).abs() < 1e-9,
            "{g:?}"
        );
        assert!((g.knn_share_m - b.far.knn_share_m).abs() < 1e-12);
        assert_bands_add_up(&r);
        assert_eq!(
            clean.map_to_truth_bands.far.cells + clean.truth_to_map_bands.far.cells,
            0
        );
    }

    /// The six bands are the k-NN error, split.
    fn assert_bands_add_up(r: &MapReport) {
        let sum: f64 = [&r.truth_to_map_bands, &r.map_to_truth_bands]
            .iter()
            .flat_map(|b| [b.on_wall, b.misplaced, b.far])
            .map(|band| band.knn_share_m)
            .sum();
        assert!(
            (sum - r.knn_error_m).abs() < 1e-12,
            "{sum} vs {}",
            r.knn_error_m
        );
        assert_eq!(
            r.truth_to_map_bands.on_wall.cells
                + r.truth_to_map_bands.misplaced.cells
                + r.truth_to_map_bands.far.cells,
            r.truth_to_map.count
        );
        assert_eq!(
            r.map_to_truth_bands.on_wall.cells
                + r.map_to_truth_bands.misplaced.cells
                + r.map_to_truth_bands.far.cells,
            r.map_to_truth.count
        );
    }

    #[test]
    fn missing_wall_is_penalised_truth_to_map() {
        let truth = room(30);
        let mut est = room(30);
        for y in 10..=40 {
            est.set(30, y, FREE);
        }
        let r = evaluate_maps(&truth, &est, &MapOptions::default()).unwrap();
        assert!(r.truth_to_map.max_m > 1.0, "{:?}", r.truth_to_map);
        assert_eq!(r.map_to_truth.max_m, 0.0);
        // The whole partition is missing, as one group along x = 1.425 m.
        let b = &r.truth_to_map_bands;
        assert_eq!((b.far.cells, b.far_groups.len()), (31, 1), "{b:?}");
        let g = b.far_groups[0];
        assert!(
            (g.x_m - 1.425).abs() < 1e-9 && (g.y_m - 1.175).abs() < 1e-9,
            "{g:?}"
        );
        assert_eq!(r.map_to_truth_bands.far.cells, 0);
        assert_bands_add_up(&r);
    }

    #[test]
    fn empty_estimate_is_an_error_not_a_zero() {
        let truth = room(30);
        let est = OccupancyGrid::new(10, 10, RES, [0.0, 0.0, 0.0]);
        assert_eq!(
            evaluate_maps(&truth, &est, &MapOptions::default()),
            Err(MapMetricError::NoWalls {
                which: "estimated",
                threshold: 65
            })
        );
    }
}
