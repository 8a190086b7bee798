//! Fuzzy maps: `Mo` (occupied confidence) and `Ms` (free-space confidence)
//! on a Cartesian grid, built from readings in polar form by fuzzy union
//! (eqs. 5–6), and the combined map of eq. 7.
//!
//! Polar → Cartesian: a cell takes the confidence of the readings at its
//! centre, seen from the sensor. The paper's bounds are far below a cell (±10
//! mm, 0.36°) and a centre would fall between them, so a bound is widened to
//! at least one cell (δr ≥ cell, δθ ≥ the angle a cell subtends): a return
//! always lights the cell it ends in. The values at the paper's bounds are
//! those of [`super::confidence`].

use super::confidence::{self, ConfidenceModel};
use crate::scan::{BeamKind, RangeScan};
use smokenav_platform_map::{OccupancyGrid, UNKNOWN};
use smokenav_shared_types::Pose2;
use smokenav_shared_types::geometry::normalize_angle;

/// One reading in the model's terms (sensor frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FuzzyBeam {
    pub angle: f64,
    pub range: f64,
    /// The reading ends on an obstacle within the map's radius (else it only clears space).
    pub hit: bool,
    /// Peak confidence K.
    pub k: f64,
    pub dr: f64,
    pub dtheta: f64,
    /// Lateral confidence of this beam inside its sonar cone (1 for a laser beam).
    pub lateral: f64,
    /// What the reading is worth at all, scaling both what it says of the
    /// obstacle and of the free space before it: 1, or less for a laser
    /// return in smoke ([`ConfidenceModel::laser_worth`]).
    pub worth: f64,
    pub kind: BeamKind,
}

/// The readings of `scan` as fuzzy beams, into `out` (cleared first).
///
/// A fused scan paints a sonar echo as an arc of laser-spaced beams across
/// the cone: the echo came from somewhere on it. Each contiguous run of
/// sonar beams is one reading whose lateral bound is half the cone (or the
/// run's half-width, if wider as seen from the laser), so the arc is most
/// confident on the cone's axis and fades to 0 at its edges — a wide, weak
/// arc rather than a sharp wall.
pub fn fuzzy_beams(
    scan: &RangeScan,
    model: &ConfidenceModel,
    max_range: f64,
    radius: f64,
    out: &mut Vec<FuzzyBeam>,
) {
    out.clear();
    let beams = &scan.beams;
    let spacing = if beams.len() >= 2 {
        (f64::from(beams[beams.len() - 1].angle) - f64::from(beams[0].angle)).abs()
            / (beams.len() - 1) as f64
    } else {
        model.laser_dtheta
    };
    let laser_worth = model.laser_worth(scan.laser_noise_factor);
    let mut i = 0;
    while i < beams.len() {
        let b = &beams[i];
        let usable = |r: Option<f32>, a: f32| {
            r.map(f64::from)
                .filter(|r| r.is_finite() && *r > 0.0 && *r < max_range && a.is_finite())
        };
        let Some(r) = usable(b.range, b.angle) else {
            i += 1;
            continue;
        };
        match b.kind {
            BeamKind::Laser => {
                out.push(FuzzyBeam {
                    angle: f64::from(b.angle),
                    range: r,
                    hit: r <= radius,
                    k: model.peak(BeamKind::Laser, r),
                    dr: model.range_error(BeamKind::Laser, r),
                    dtheta: model.laser_dtheta,
                    lateral: 1.0,
                    worth: laser_worth,
                    kind: BeamKind::Laser,
                });
                i += 1;
            }
            BeamKind::Sonar => {
                let start = i;
                let mut end = i;
                while end + 1 < beams.len()
                    && beams[end + 1].kind == BeamKind::Sonar
                    && usable(beams[end + 1].range, beams[end + 1].angle).is_some()
                {
                    end += 1;
                }
                let (a0, a1) = (f64::from(beams[start].angle), f64::from(beams[end].angle));
                let centre = 0.5 * (a0 + a1);
                let bound = model.sonar_half_cone.max(0.5 * (a1 - a0).abs() + spacing);
                for s in &beams[start..=end] {
                    let Some(r) = usable(s.range, s.angle) else {
                        continue;
                    };
                    let a = f64::from(s.angle);
                    out.push(FuzzyBeam {
                        angle: a,
                        range: r,
                        hit: r <= radius,
                        k: model.peak(BeamKind::Sonar, r),
                        dr: model.range_error(BeamKind::Sonar, r),
                        dtheta: spacing.max(model.laser_dtheta),
                        lateral: confidence::parabola(a - centre, bound),
                        worth: 1.0,
                        kind: BeamKind::Sonar,
                    });
                }
                i = end + 1;
            }
        }
    }
}

/// `Mo` and `Ms` over a rectangle of cells; the global map grows as the robot explores.
#[derive(Debug, Clone, PartialEq)]
pub struct FuzzyGrid {
    pub resolution: f64,
    /// World position of the lower-left corner of cell (0, 0).
    pub origin: (f64, f64),
    pub width: usize,
    pub height: usize,
    pub mo: Vec<f32>,
    pub ms: Vec<f32>,
    /// Per cell, the sums over every reading of its obstacle and free-space
    /// confidence (the navigation map's evidence, [`Self::to_evidence_grid`]);
    /// `None` on a grid that is never drawn as a map ([`Self::without_sums`]).
    pub sums: Option<Vec<[f32; 2]>>,
}

/// Least `ΣMo + ΣMs` a cell needs to be known in
/// [`FuzzyGrid::to_evidence_grid`]: one sure reading's worth. Below it the
/// cell was only grazed by the tails of a few parabolas, and a cell just
/// behind a wall, which no ray ever reaches to call it free, read as a wall
/// on the strength of a few long returns (its ratio is 1 however little
/// evidence it has): walls came out thick on their far side. At 0.05 (the
/// edge of a parabola's support) the clean-air map error on the dense
/// trial's three twins was 0.041 / 0.044 / 0.041 m, at 1.0 0.038 / 0.041 /
/// 0.037 m, and on MIT CSAIL 0.178 → 0.170 m; higher still helped the
/// simulator's slow, densely sampled route but not CSAIL (2.0: 0.181 m,
/// 4.0: 0.189 m), where a fast robot sees most walls in few scans.
pub const MIN_EVIDENCE: f32 = 1.0;

/// [`FuzzyGrid::to_evidence_grid`]'s walls: at or above nav2's and
/// map_server's occupied threshold (0.65).
const WALL_LEVEL: i8 = 65;

/// [`FuzzyGrid::to_evidence_grid`]: a wall cell with less than this share of
/// the occupied evidence (ΣMo) of its strongest wall neighbour is the flank
/// of that wall's returns and goes to unknown ([`FLANK_LEVEL`]). Mo spreads
/// each return over its range bound (at least a cell) both ways; the cells
/// behind the surface get no free evidence, so their share is 1 however
/// little of Mo reached them, and walls came out two or three cells thick.
/// On the dense trial's four clean twins (`smokenav slam --backend fuzzy`)
/// the map error went from 0.038–0.041 m to 0.031–0.034 m; a share of 0.3,
/// 0.5 or 0.7 made a millimetre's difference.
const FLANK_SHARE: f32 = 0.5;

/// What a flank cell reads as: unknown to every occupied/free threshold.
const FLANK_LEVEL: i8 = 50;

/// Cells the global map grows by at a time (each way), so growth is rare.
const GROW_CELLS: usize = 256;

impl FuzzyGrid {
    /// A square grid of ± `half_extent` around (0, 0).
    pub fn square(resolution: f64, half_extent: f64) -> Self {
        let n = (2.0 * half_extent / resolution).ceil() as usize;
        let h = n as f64 * resolution / 2.0;
        Self {
            resolution,
            origin: (-h, -h),
            width: n,
            height: n,
            mo: vec![0.0; n * n],
            ms: vec![0.0; n * n],
            sums: Some(vec![[0.0; 2]; n * n]),
        }
    }

    /// An empty grid (no cells) that grows on [`Self::ensure`].
    pub fn empty(resolution: f64) -> Self {
        Self {
            resolution,
            origin: (0.0, 0.0),
            width: 0,
            height: 0,
            mo: Vec::new(),
            ms: Vec::new(),
            sums: Some(Vec::new()),
        }
    }

    /// The same grid keeping no sums: a scan's local map, matched and
    /// cropped by `Mo` / `Ms` alone, is never drawn as a navigation map.
    pub fn without_sums(mut self) -> Self {
        self.sums = None;
        self
    }

    pub fn clear(&mut self) {
        self.mo.fill(0.0);
        self.ms.fill(0.0);
        if let Some(s) = &mut self.sums {
            s.fill([0.0; 2]);
        }
    }

    /// Index of the cell holding (x, y), if inside.
    #[inline]
    pub fn index(&self, x: f64, y: f64) -> Option<usize> {
        let cx = ((x - self.origin.0) / self.resolution).floor();
        let cy = ((y - self.origin.1) / self.resolution).floor();
        (cx >= 0.0 && cy >= 0.0 && (cx as usize) < self.width && (cy as usize) < self.height)
            .then(|| cy as usize * self.width + cx as usize)
    }

    #[inline]
    pub fn centre(&self, i: usize) -> (f64, f64) {
        (
            self.origin.0 + ((i % self.width) as f64 + 0.5) * self.resolution,
            self.origin.1 + ((i / self.width) as f64 + 0.5) * self.resolution,
        )
    }

    /// The sensor saw (x, y) at all: some obstacle or free-space confidence.
    pub fn seen(&self, x: f64, y: f64) -> bool {
        self.index(x, y)
            .is_some_and(|i| self.mo[i] > 0.0 || self.ms[i] > 0.0)
    }

    /// Eq. 7 at cell `i`.
    pub fn combined(&self, i: usize, unknown: f64) -> f64 {
        confidence::combined(f64::from(self.mo[i]), f64::from(self.ms[i]), unknown)
    }

    /// Eq. 7 at the world point (x, y); `unknown` outside the grid.
    pub fn combined_at(&self, x: f64, y: f64, unknown: f64) -> f64 {
        self.index(x, y)
            .map_or(unknown, |i| self.combined(i, unknown))
    }

    /// Grows (keeping the content) until the rectangle is inside.
    pub fn ensure(&mut self, min: (f64, f64), max: (f64, f64)) {
        let res = self.resolution;
        let (mut x0, mut y0) = self.origin;
        let (mut x1, mut y1) = (x0 + self.width as f64 * res, y0 + self.height as f64 * res);
        if self.width > 0 && min.0 >= x0 && min.1 >= y0 && max.0 < x1 && max.1 < y1 {
            return;
        }
        let pad = GROW_CELLS as f64 * res;
        if self.width == 0 {
            // Cell edges on multiples of the resolution around the first rectangle.
            x0 = (min.0 / res).floor() * res - pad;
            y0 = (min.1 / res).floor() * res - pad;
            x1 = x0;
            y1 = y0;
        }
        if min.0 < x0 {
            x0 -= ((x0 - min.0) / pad).ceil() * pad;
        }
        if min.1 < y0 {
            y0 -= ((y0 - min.1) / pad).ceil() * pad;
        }
        if max.0 >= x1 {
            x1 += ((max.0 - x1) / pad).floor() * pad + pad;
        }
        if max.1 >= y1 {
            y1 += ((max.1 - y1) / pad).floor() * pad + pad;
        }
        let w = ((x1 - x0) / res).round() as usize;
        let h = ((y1 - y0) / res).round() as usize;
        let (dx, dy) = (
            ((self.origin.0 - x0) / res).round() as usize,
            ((self.origin.1 - y0) / res).round() as usize,
        );
        let mut mo = vec![0.0; w * h];
        let mut ms = vec![0.0; w * h];
        let mut sums = self.sums.as_ref().map(|_| vec![[0.0; 2]; w * h]);
        for row in 0..self.height {
            let src = row * self.width..(row + 1) * self.width;
            let dst = (row + dy) * w + dx;
            mo[dst..dst + self.width].copy_from_slice(&self.mo[src.clone()]);
            ms[dst..dst + self.width].copy_from_slice(&self.ms[src.clone()]);
            if let (Some(to), Some(from)) = (&mut sums, &self.sums) {
                to[dst..dst + self.width].copy_from_slice(&from[src]);
            }
        }
        *self = Self {
            resolution: res,
            origin: (x0, y0),
            width: w,
            height: h,
            mo,
            ms,
            sums,
        };
    }

    /// Eqs. 5–6: unites the readings of a sensor at `sensor` (in this grid's
    /// frame) into `Mo` and `Ms`. Free space is cleared up to `radius`.
    pub fn paint(&mut self, sensor: &Pose2, beams: &[FuzzyBeam], radius: f64) {
        let res = self.resolution;
        let step = 0.5 * res;
        for b in beams {
            let a = sensor.theta + b.angle;
            let (sin, cos) = a.sin_cos();
            let dr = b.dr.max(res);
            // The angle a cell subtends at range r, or the beam's own bound if wider.
            let dth = |r: f64| b.dtheta.max((res / r.max(res)).atan());
            // Free space takes a narrower floor (¾ cell): a ray grazing a wall
            // must not clear the wall's cells, whose centres it passes a cell
            // or less away — with `Ms` united over every scan, one such ray
            // would erase the wall from the combined map for good.
            let dth_free = |r: f64| b.dtheta.max((0.75 * res / r.max(res)).atan());
            // Ms: march along the ray; each cell met takes P at its far side
            // (its centre half a cell on): a cell is free only as far as the
            // ray crossed it, so the cell a return ends in, whose wall may lie
            // anywhere in it, is not called free by its own ray.
            let reach = b.range.min(radius);
            let mut last = usize::MAX;
            let n = (reach / step).ceil() as usize;
            for s in 0..=n {
                let d = (s as f64 * step).min(reach);
                let Some(i) = self.index(sensor.x + cos * d, sensor.y + sin * d) else {
                    continue;
                };
                // Without sums a cell already wholly free gains nothing.
                if i == last || (self.sums.is_none() && self.ms[i] >= 1.0) {
                    last = i;
                    continue;
                }
                last = i;
                let (cx, cy) = self.centre(i);
                let (rx, ry) = (cx - sensor.x, cy - sensor.y);
                let rc = rx.hypot(ry);
                let tc = ry.atan2(rx);
                let p = b.worth
                    * b.lateral
                    * confidence::free(
                        rc + 0.5 * res,
                        a + normalize_angle(tc - a),
                        b.range,
                        a,
                        dr,
                        dth_free(rc),
                    );
                if p as f32 > self.ms[i] {
                    self.ms[i] = p as f32;
                }
                if let Some(s) = &mut self.sums {
                    s[i][1] += p as f32;
                }
            }
            if !b.hit {
                continue;
            }
            // Mo: the cells around the return.
            let (ex, ey) = (sensor.x + cos * b.range, sensor.y + sin * b.range);
            let half = dr + b.range * dth(b.range).tan();
            let cells = (half / res).ceil() as isize;
            let Some(c) = self.index(ex, ey) else {
                continue;
            };
            let (cx0, cy0) = ((c % self.width) as isize, (c / self.width) as isize);
            for gy in (cy0 - cells).max(0)..=(cy0 + cells).min(self.height as isize - 1) {
                for gx in (cx0 - cells).max(0)..=(cx0 + cells).min(self.width as isize - 1) {
                    let i = gy as usize * self.width + gx as usize;
                    let (cx, cy) = self.centre(i);
                    let (rx, ry) = (cx - sensor.x, cy - sensor.y);
                    let rc = rx.hypot(ry);
                    let tc = a + normalize_angle(ry.atan2(rx) - a);
                    let o = b.worth
                        * b.lateral
                        * confidence::occupied(b.k, rc, tc, b.range, a, dr, dth(rc));
                    if o as f32 > self.mo[i] {
                        self.mo[i] = o as f32;
                    }
                    if let Some(s) = &mut self.sums {
                        s[i][0] += o as f32;
                    }
                }
            }
        }
    }

    /// The map for navigation (`slam/map`, saved maps, map error): the share
    /// of a cell's evidence that says "obstacle", ΣMo / (ΣMo + ΣMs) over
    /// every reading (`sums`), scaled 0–100; unknown (-1) with less than
    /// [`MIN_EVIDENCE`] of either. All unknown on a grid
    /// [`Self::without_sums`]. The flanks of a wall (cells with under
    /// [`FLANK_SHARE`] of the occupied evidence of a wall cell beside them)
    /// are unknown, so a wall is as thick as the returns put it.
    ///
    /// Not eq. 7 thresholded: `Mo` is a reading's *confidence*, which the
    /// URG-04LX fit lowers with range (0.5 at 2 m, 0.2 past 3.65 m), and a
    /// fuzzy union keeps the best reading instead of accumulating them, so a
    /// wall seen a hundred times from 3 m stays at 0.2 — at or under eq. 7's
    /// "unknown" 0.3, and far under an occupancy threshold such as nav2's
    /// 0.65. That is why saved fuzzy maps had faint walls. The ratio keeps
    /// what the fuzzy map knows (obstacle evidence against free-space
    /// evidence) without reading a confidence as a probability.
    ///
    /// Summed, not united: by fuzzy union one ray that grazes a wall, or a
    /// pass that saw it 5 cm off, claims its cells free as strongly as the
    /// hundred returns that ended on it claim them occupied, and a thin wall
    /// seen from both sides came out contested (0.25–0.65, "unknown" in a
    /// saved map: R3.2's partitions were missing, clean-air map error 0.20 m
    /// against 0.04 m summed).
    pub fn to_evidence_grid(&self) -> OccupancyGrid {
        let mut g = OccupancyGrid::new(
            self.width,
            self.height,
            self.resolution,
            [self.origin.0, self.origin.1, 0.0],
        );
        let sums = self.sums.as_deref().unwrap_or_default();
        let level = |[mo, ms]: [f32; 2]| {
            let sum = mo + ms;
            (sum >= MIN_EVIDENCE).then(|| (mo / sum * 100.0).round().clamp(0.0, 100.0) as i8)
        };
        for (cell, &e) in g.cells.iter_mut().zip(sums) {
            *cell = level(e).unwrap_or(UNKNOWN);
        }
        // The flanks: a wall cell next to one with over 1 / FLANK_SHARE
        // times its occupied evidence is unknown. Read from `sums`, so the
        // cells already changed do not change their neighbours' outcome.
        if sums.is_empty() {
            return g;
        }
        let is_wall = |e: [f32; 2]| level(e).is_some_and(|v| v >= WALL_LEVEL);
        let w = self.width;
        for y in 1..self.height.saturating_sub(1) {
            for x in 1..w.saturating_sub(1) {
                let i = y * w + x;
                if !is_wall(sums[i]) {
                    continue;
                }
                let strongest = [
                    i - w - 1,
                    i - w,
                    i - w + 1,
                    i - 1,
                    i + 1,
                    i + w - 1,
                    i + w,
                    i + w + 1,
                ]
                .into_iter()
                .filter(|&j| is_wall(sums[j]))
                .map(|j| sums[j][0])
                .fold(0.0f32, f32::max);
                if sums[i][0] < FLANK_SHARE * strongest {
                    g.cells[i] = FLANK_LEVEL;
                }
            }
        }
        g
    }

    /// The combined map (eq. 7) as an occupancy grid, confidence scaled
    /// 0–100; cells no reading touched are unknown (-1).
    pub fn to_occupancy_grid(&self, unknown: f64) -> OccupancyGrid {
        let mut g = OccupancyGrid::new(
            self.width,
            self.height,
            self.resolution,
            [self.origin.0, self.origin.1, 0.0],
        );
        for (i, cell) in g.cells.iter_mut().enumerate() {
            *cell = if self.mo[i] == 0.0 && self.ms[i] == 0.0 {
                UNKNOWN
            } else {
                (self.combined(i, unknown) * 100.0)
                    .round()
                    .clamp(0.0, 100.0) as i8
            };
        }
        g
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_wall_seen_only_from_afar_is_occupied_in_the_evidence_map() {
        let mut g = FuzzyGrid::square(0.05, 0.1);
        // A wall cell seen from 4 m (peak confidence 0.2 × 0.75 off the
        // parabola's centre), free space, a grazed wall cell, a barely
        // touched one; each seen by ten readings alike (the union keeps one
        // reading's value, the sums add all ten).
        let cells = [(0.15f32, 0.0f32), (0.0, 0.9), (0.6, 0.2), (0.002, 0.0)];
        for (i, (mo, ms)) in cells.into_iter().enumerate() {
            (g.mo[i], g.ms[i]) = (mo, ms);
            g.sums.as_mut().unwrap()[i] = [10.0 * mo, 10.0 * ms];
        }
        let eq7 = g.to_occupancy_grid(0.3);
        let nav = g.to_evidence_grid();
        // Eq. 7 puts the far wall at "unknown" (30), under any occupied threshold…
        assert_eq!(eq7.cells[0], 30);
        // …the evidence ratio keeps it an obstacle.
        assert_eq!(nav.cells[0], 100);
        assert_eq!(nav.cells[1], 0);
        assert_eq!(nav.cells[2], 75);
        assert_eq!(nav.cells[3], UNKNOWN);
        assert_eq!(nav.cells[4], UNKNOWN);
    }

    #[test]
    fn a_cell_behind_a_wall_that_a_few_long_returns_touched_stays_unknown() {
        let mut g = FuzzyGrid::square(0.05, 0.1);
        // The wall's cell: 40 returns at 0.5 each. The cell behind it: the
        // far tails of five of them (0.1 each), and no ray ever reaches it
        // to call it free, so its ratio is 1 however little it got.
        g.sums.as_mut().unwrap()[0] = [20.0, 0.0];
        g.sums.as_mut().unwrap()[1] = [0.5, 0.0];
        let nav = g.to_evidence_grid();
        assert_eq!(nav.cells[0], 100);
        // Half a sure reading's worth: not known, not a second layer of wall.
        assert_eq!(nav.cells[1], UNKNOWN);
    }
    #[test]
    fn a_wall_is_as_thick_as_its_returns_not_as_the_parabolas_flanks() {
        // 10 × 10 cells. A wall along row 5 seen from below: 40 returns'
        // worth on each of its cells, free evidence in front (row 4) as rays
        // pass, and behind it (row 6) the parabolas' far side: a quarter of
        // the wall's Mo, no free evidence at all, so a ratio of 1.
        let mut g = FuzzyGrid::square(0.05, 0.25);
        let w = g.width;
        assert_eq!((w, g.height), (10, 10));
        let sums = g.sums.as_mut().unwrap();
        for x in 1..9 {
            sums[4 * w + x] = [2.0, 30.0];
            sums[5 * w + x] = [20.0, 2.0];
            sums[6 * w + x] = [5.0, 0.0];
        }
        // A diagonal wall, every cell as strong as the next, and a lone post.
        for k in 0..3 {
            sums[(1 + k) * w + 1 + k] = [10.0, 1.0];
        }
        sums[8 * w + 8] = [3.0, 0.0];
        let nav = g.to_evidence_grid();
        for x in 1..9 {
            assert!(nav.cells[5 * w + x] >= WALL_LEVEL, "the wall at {x}");
            assert_eq!(nav.cells[6 * w + x], FLANK_LEVEL, "its flank at {x}");
            assert!(nav.cells[4 * w + x] < 20, "free in front at {x}");
        }
        for k in 0..3 {
            assert!(nav.cells[(1 + k) * w + 1 + k] >= WALL_LEVEL, "diagonal {k}");
        }
        assert_eq!(nav.cells[8 * w + 8], 100, "a lone post stays");
    }

    use crate::scan::Beam;

    fn scan(beams: &[(f32, f32, BeamKind)]) -> RangeScan {
        RangeScan {
            beams: beams
                .iter()
                .map(|&(angle, r, kind)| Beam {
                    angle,
                    range: Some(r),
                    kind,
                })
                .collect(),
            laser_noise_factor: 1.0,
            ..Default::default()
        }
    }

    #[test]
    fn a_laser_return_lights_its_cell_with_the_urg_confidence_and_clears_the_way() {
        let m = ConfidenceModel::default();
        let s = scan(&[(0.0, 1.0, BeamKind::Laser)]);
        let mut beams = Vec::new();
        fuzzy_beams(&s, &m, 80.0, 8.0, &mut beams);
        let mut g = FuzzyGrid::square(0.05, 3.0);
        g.paint(&Pose2::default(), &beams, 8.0);
        // The endpoint's cell centre (1.025, 0.025) is 25 mm behind the
        // return, 0.025 rad off the axis: inside the cell-wide bounds.
        let i = g.index(1.0, 0.0).unwrap();
        let expect = confidence::occupied(
            m.peak(BeamKind::Laser, 1.0),
            1.025f64.hypot(0.025),
            0.025f64.atan2(1.025),
            1.0,
            0.0,
            0.05,
            (0.05f64 / 1.025f64.hypot(0.025)).atan(),
        );
        assert!(
            (f64::from(g.mo[i]) - expect).abs() < 1e-6,
            "{} vs {expect}",
            g.mo[i]
        );
        assert!(g.mo[i] > 0.4);
        // Free before the return: the cell centre (0.525, 0.025) lies ⅔ of
        // its angular bound (¾ cell) off the beam, so P ≈ 1 − (⅔)² there.
        let rc = 0.525f64.hypot(0.025);
        let p = 1.0 - (0.025f64.atan2(0.525) / (0.0375 / rc).atan()).powi(2);
        let ms = f64::from(g.ms[g.index(0.5, 0.0).unwrap()]);
        assert!(
            (ms - p).abs() < 1e-6 && (ms - 5.0 / 9.0).abs() < 0.01,
            "free before the return: {ms}"
        );
        assert_eq!(
            g.ms[g.index(1.3, 0.0).unwrap()],
            0.0,
            "nothing known behind it"
        );
        assert_eq!(g.mo[g.index(1.3, 0.0).unwrap()], 0.0);
        let unknown = g.combined_at(1.3, 0.0, 0.3);
        assert_eq!(unknown, 0.3, "behind an obstacle: unknown");
        // One ray leaves free space only partly sure: min(max(0.3, 0), 1 − P).
        assert!(
            (g.combined_at(0.5, 0.0, 0.3) - 0.3f64.min(1.0 - p)).abs() < 1e-6,
            "free space of one ray"
        );
    }

    #[test]
    fn a_sonar_arc_is_weak_and_fades_towards_the_cone_edges() {
        let m = ConfidenceModel {
            sonar_half_cone: 7.5f64.to_radians(),
            ..Default::default()
        };
        // A 15° arc of beams 0.5° apart at 2 m, as the fusion paints it.
        let arc: Vec<_> = (0..=30)
            .map(|k| ((-7.5 + 0.5 * k as f32).to_radians(), 2.0, BeamKind::Sonar))
            .collect();
        let mut beams = Vec::new();
        fuzzy_beams(&scan(&arc), &m, 80.0, 8.0, &mut beams);
        assert_eq!(beams.len(), 31);
        assert!((beams[15].lateral - 1.0).abs() < 1e-9, "on axis");
        assert!(
            beams[0].lateral < 0.2 && beams[30].lateral < 0.2,
            "{}",
            beams[0].lateral
        );
        let mut g = FuzzyGrid::square(0.05, 3.0);
        g.paint(&Pose2::default(), &beams, 8.0);
        let axis = g.mo[g.index(2.0, 0.0).unwrap()];
        let (s, c) = 6.5f64.to_radians().sin_cos();
        let edge = g.mo[g.index(2.0 * c, 2.0 * s).unwrap()];
        assert!(axis <= 0.5 && axis > 0.3, "{axis}");
        assert!(edge < axis / 2.0, "{edge} vs {axis}");
    }

    #[test]
    fn a_laser_return_in_smoke_never_reaches_a_confident_wall_and_keeps_its_evidence_share() {
        // A phantom of smoke 0.3 m ahead: the URG's K there is about 0.75, a
        // confident cell (≥ 0.65) in clear air.
        // The beam ends on the centre of cell (0.325, 0.025).
        let (angle, range) = (0.025f32.atan2(0.325), 0.325f32.hypot(0.025));
        let paint = |model: &ConfidenceModel, factor: f64| {
            let mut s = scan(&[(angle, range, BeamKind::Laser)]);
            s.laser_noise_factor = factor;
            let mut beams = Vec::new();
            fuzzy_beams(&s, model, 80.0, 8.0, &mut beams);
            let mut g = FuzzyGrid::square(0.05, 3.0);
            g.paint(&Pose2::default(), &beams, 8.0);
            let end = g.index(0.325, 0.025).unwrap();
            let before = g.index(0.13, 0.01).unwrap();
            (g.combined(end, 0.3), g.mo[end], g.ms[before], g)
        };
        let m = ConfidenceModel::default();
        let (clear, mo_clear, ms_clear, _) = paint(&m, 1.0);
        assert!(clear >= 0.65, "clear air: {clear}");
        // Fog: σ × 1.658 (Sevcik & Oh's 13.75 vs 5 mm²), the most `[slam]`'s model gives.
        let fog = (13.75f64 / 5.0).sqrt();
        let (smoky, mo_smoke, ms_smoke, g) = paint(&m, fog);
        assert!((0.3..0.65).contains(&smoky), "dense smoke: {smoky}");
        let worth = 1.0 / (fog * fog);
        assert!((f64::from(mo_smoke) - f64::from(mo_clear) * worth).abs() < 1e-6);
        assert!((f64::from(ms_smoke) - f64::from(ms_clear) * worth).abs() < 1e-6);
        // Light smoke (Sevcik & Oh's rain, 8.39 vs 5 mm²) already keeps a
        // return 0.3 m ahead under 0.65.
        let (light, _, _, _) = paint(&m, (8.39f64 / 5.0).sqrt());
        assert!(light < 0.65, "light smoke: {light}");
        // Both halves of the evidence scaled alike: the navigation map is unchanged.
        let (_, _, _, g_clear) = paint(&m, 1.0);
        assert_eq!(g.to_evidence_grid().cells, g_clear.to_evidence_grid().cells);
        // The paper's clear-air model when the discount is off.
        let off = ConfidenceModel {
            laser_smoke_discount: false,
            ..Default::default()
        };
        assert_eq!(paint(&off, fog).0, clear);
        // A factor below 1 or not a number never makes a reading worth more.
        assert_eq!(paint(&m, 0.5).0, clear);
        assert_eq!(paint(&m, f64::NAN).0, clear);
    }

    #[test]
    fn a_return_does_not_call_its_own_cell_free() {
        // The return at 1.04 m ends in the cell centred on (1.025, 0.025):
        // that centre is 15 mm before it, but the ray did not cross the cell.
        let (angle, range) = (0.025f32.atan2(1.04), 1.04f32.hypot(0.025));
        let mut beams = Vec::new();
        fuzzy_beams(
            &scan(&[(angle, range, BeamKind::Laser)]),
            &ConfidenceModel::default(),
            80.0,
            8.0,
            &mut beams,
        );
        let mut g = FuzzyGrid::square(0.05, 3.0);
        g.paint(&Pose2::default(), &beams, 8.0);
        let end = g.index(1.03, 0.03).unwrap();
        assert_eq!(g.ms[end], 0.0);
        assert!(g.mo[end] > 0.4);
        // The cell before it, crossed whole, is mostly free (the ramp of eq.
        // 3 spans δr, widened to a cell), the one before that wholly.
        assert!(g.ms[g.index(0.98, 0.03).unwrap()] > 0.5);
        assert!(g.ms[g.index(0.93, 0.03).unwrap()] > 0.9);
    }

    #[test]
    fn a_thin_wall_seen_from_both_sides_and_grazed_stays_a_wall() {
        // A partition along y = 1.0 (on a cell edge, as a wall may fall),
        // x from -1 to 1, scanned from 0.6 m below and above by 181 beams
        // each, and then grazed: rays from (−2.5, 0.98) along it, ending at
        // its end, which pass the centres of the cells either side of y = 1.
        let m = ConfidenceModel::default();
        let mut g = FuzzyGrid::square(0.05, 3.0);
        let mut beams = Vec::new();
        for (sy, dir) in [(0.4f64, 1.0f64), (1.6, -1.0)] {
            for sx in [-0.6, 0.0, 0.6] {
                let rays: Vec<_> = (0..181)
                    .filter_map(|k| {
                        let a = (k as f64 - 90.0).to_radians() * 0.8;
                        let t = (1.0 - sy) / (dir * a.cos());
                        let x = sx + dir * t * a.sin();
                        (t > 0.0 && x.abs() < 1.0).then_some((a as f32, t as f32, BeamKind::Laser))
                    })
                    .collect();
                fuzzy_beams(&scan(&rays), &m, 80.0, 8.0, &mut beams);
                let sensor = Pose2::new(sx, sy, dir * std::f64::consts::FRAC_PI_2);
                g.paint(&sensor, &beams, 8.0);
            }
        }
        let graze: Vec<_> = [-0.004f32, 0.0, 0.004]
            .iter()
            .map(|&a| (a, 3.5f32, BeamKind::Laser))
            .collect();
        fuzzy_beams(&scan(&graze), &m, 80.0, 8.0, &mut beams);
        g.paint(&Pose2::new(-2.5, 0.98, 0.0), &beams, 8.0);
        let nav = g.to_evidence_grid();
        // Every cell the partition runs along, either side of it.
        let mut walls = 0;
        for k in 0..36 {
            let x = -0.875 + 0.05 * k as f64;
            let below = nav.cells[g.index(x, 0.975).unwrap()];
            let above = nav.cells[g.index(x, 1.025).unwrap()];
            walls += usize::from(below.max(above) >= 65);
        }
        assert_eq!(walls, 36, "the partition is a wall along its whole length");
        // Free space before it stays free.
        assert!(nav.cells[g.index(0.3, 0.7).unwrap()] <= 25);
        assert!(nav.cells[g.index(0.3, 1.3).unwrap()] <= 25);
    }

    #[test]
    fn growing_keeps_what_was_painted() {
        let mut g = FuzzyGrid::empty(0.05);
        g.ensure((-1.0, -1.0), (1.0, 1.0));
        let i = g.index(0.52, 0.33).unwrap();
        g.mo[i] = 0.7;
        g.ensure((-30.0, -2.0), (1.0, 40.0));
        assert!(g.index(-29.9, 39.9).is_some());
        assert_eq!(g.mo[g.index(0.52, 0.33).unwrap()], 0.7);
        assert_eq!(g.mo.iter().filter(|v| **v > 0.0).count(), 1);
    }
}
