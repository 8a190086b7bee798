//! Occupancy grids that particles share copy-on-write.
//!
//! The plane is cut into 32 × 32-cell tiles held through `Arc`. Cloning a grid
//! (what resampling does) copies only the table of tile pointers; a tile is
//! copied the first time a particle writes to it while another particle still
//! holds it (`Arc::make_mut`). So 30 particles that descend from one another
//! keep one copy of everything they have not re-observed since they split.
//!
//! Cells hold log-odds in fixed point (`i16`, 1/256 per unit) with a sentinel
//! for "never observed". Cell `(cx, cy)` covers
//! `[cx·res, (cx+1)·res) × [cy·res, (cy+1)·res)` of the map frame, so the grid
//! grows in any direction without moving what is already there.

use smokenav_platform_map::OccupancyGrid;
use smokenav_shared_types::Pose2;
use std::sync::Arc;

pub const TILE_SHIFT: i32 = 5;
pub const TILE: i32 = 1 << TILE_SHIFT;
const TILE_MASK: i32 = TILE - 1;
pub const TILE_CELLS: usize = (TILE * TILE) as usize;

/// A cell no beam has touched.
pub const UNKNOWN: i16 = i16::MIN;
/// Fixed-point scale of the stored log-odds.
pub const LOGODDS_SCALE: f64 = 256.0;

/// Largest grid side in tiles (32 × 5 cm × 4096 ≈ 6.5 km): a corrupt pose must not
/// make the grid allocate without bound.
pub const MAX_TILES_PER_SIDE: i32 = 4096;

#[derive(Clone)]
pub struct Tile {
    cells: [i16; TILE_CELLS],
    /// Bit `x` of row `y` is set when cell (x, y) is more likely occupied than
    /// not: the scan matcher reads a whole kernel row in one load.
    occupied: [u32; TILE as usize],
    /// Mean position of the endpoints that fell in each cell, in 1/256 of a
    /// cell from its lower-left corner (x in the high byte, y in the low): the
    /// matcher measures distances to it rather than to the cell centre, so a
    /// wall is located to a fraction of a cell whatever its angle to the grid
    /// (GMapping keeps the same statistic).
    mean_hit: [u16; TILE_CELLS],
    /// Endpoints counted into `mean_hit` (saturating).
    hits: [u8; TILE_CELLS],
}

/// The running mean forgets older endpoints beyond this many (so a moved obstacle's mean follows it).
const MEAN_WINDOW: u32 = 32;

impl Tile {
    fn unknown() -> Self {
        Self {
            cells: [UNKNOWN; TILE_CELLS],
            occupied: [0; TILE as usize],
            mean_hit: [0; TILE_CELLS],
            hits: [0; TILE_CELLS],
        }
    }

    #[inline]
    fn add(&mut self, lx: i32, ly: i32, delta: i16, max: i16) {
        let c = &mut self.cells[((ly << TILE_SHIFT) | lx) as usize];
        let base = if *c == UNKNOWN { 0 } else { *c as i32 };
        let v = (base + delta as i32).clamp(-(max as i32), max as i32) as i16;
        *c = v;
        let row = &mut self.occupied[ly as usize];
        if v > 0 {
            *row |= 1 << lx;
        } else {
            *row &= !(1 << lx);
        }
    }

    /// Occupied bits of row `ly`.
    #[inline]
    pub fn occupied_row(&self, ly: i32) -> u32 {
        self.occupied[(ly & TILE_MASK) as usize]
    }

    /// Log-odds of local cell (lx, ly), or [`UNKNOWN`].
    #[inline]
    pub fn cell(&self, lx: i32, ly: i32) -> i16 {
        self.cells[(((ly & TILE_MASK) << TILE_SHIFT) | (lx & TILE_MASK)) as usize]
    }

    /// Mean endpoint of local cell (lx, ly) as a fraction of the cell (centre if never hit).
    #[inline]
    pub fn mean_hit_fraction(&self, lx: i32, ly: i32) -> (f64, f64) {
        let i = (((ly & TILE_MASK) << TILE_SHIFT) | (lx & TILE_MASK)) as usize;
        if self.hits[i] == 0 {
            return (0.5, 0.5);
        }
        let m = self.mean_hit[i];
        (
            ((m >> 8) as f64 + 0.5) / 256.0,
            ((m & 0xff) as f64 + 0.5) / 256.0,
        )
    }

    /// Records an endpoint at sub-cell offset (`ox`, `oy`) ∈ [0, 256) and adds the hit log-odds.
    #[inline]
    fn hit(&mut self, lx: i32, ly: i32, ox: u8, oy: u8, delta: i16, max: i16) {
        self.add(lx, ly, delta, max);
        let i = ((ly << TILE_SHIFT) | lx) as usize;
        let n = self.hits[i] as u32;
        let k = (n + 1).min(MEAN_WINDOW) as i32;
        let m = self.mean_hit[i];
        let (mx, my) = ((m >> 8) as i32, (m & 0xff) as i32);
        let nx = if n == 0 {
            ox as i32
        } else {
            mx + (ox as i32 - mx) / k
        };
        let ny = if n == 0 {
            oy as i32
        } else {
            my + (oy as i32 - my) / k
        };
        self.mean_hit[i] = ((nx.clamp(0, 255) as u16) << 8) | ny.clamp(0, 255) as u16;
        self.hits[i] = self.hits[i].saturating_add(1);
    }
}

/// How scans change cells, in fixed point.
#[derive(Debug, Clone, Copy)]
pub struct LogOddsModel {
    pub hit: i16,
    pub miss: i16,
    pub max: i16,
}

impl LogOddsModel {
    pub fn new(hit: f64, miss: f64, max: f64) -> Self {
        let q = |v: f64| (v * LOGODDS_SCALE).round().clamp(1.0, 30_000.0) as i16;
        Self {
            hit: q(hit),
            miss: q(miss),
            max: q(max),
        }
    }
}

/// One beam to integrate: from the sensor to `(ex, ey)` in the map frame; `hit`
/// says whether an obstacle was seen there (false for a beam cropped at the
/// usable range, which only clears space).
#[derive(Debug, Clone, Copy)]
pub struct BeamEnd {
    pub ex: f64,
    pub ey: f64,
    pub hit: bool,
}

#[derive(Clone)]
pub struct TiledGrid {
    resolution: f64,
    inv_resolution: f64,
    /// Tile coordinates of slot (0, 0) and the slot table's size.
    tx0: i32,
    ty0: i32,
    ntx: i32,
    nty: i32,
    slots: Vec<Option<Arc<Tile>>>,
}

impl std::fmt::Debug for TiledGrid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TiledGrid")
            .field("resolution", &self.resolution)
            .field("tiles", &(self.tx0, self.ty0, self.ntx, self.nty))
            .finish()
    }
}

impl TiledGrid {
    pub fn new(resolution: f64) -> Self {
        Self {
            resolution,
            inv_resolution: 1.0 / resolution,
            tx0: 0,
            ty0: 0,
            ntx: 0,
            nty: 0,
            slots: Vec::new(),
        }
    }

    pub fn resolution(&self) -> f64 {
        self.resolution
    }

    pub fn inv_resolution(&self) -> f64 {
        self.inv_resolution
    }

    /// The cell containing a map-frame point.
    #[inline]
    pub fn world_to_cell(&self, x: f64, y: f64) -> (i32, i32) {
        (
            floor_cell(x * self.inv_resolution),
            floor_cell(y * self.inv_resolution),
        )
    }

    /// Centre of a cell in the map frame.
    #[inline]
    pub fn cell_center(&self, cx: i32, cy: i32) -> (f64, f64) {
        (
            (cx as f64 + 0.5) * self.resolution,
            (cy as f64 + 0.5) * self.resolution,
        )
    }

    /// Log-odds of a cell in fixed point, or [`UNKNOWN`].
    #[inline]
    pub fn get(&self, cx: i32, cy: i32) -> i16 {
        let tx = (cx >> TILE_SHIFT) - self.tx0;
        let ty = (cy >> TILE_SHIFT) - self.ty0;
        if tx < 0 || ty < 0 || tx >= self.ntx || ty >= self.nty {
            return UNKNOWN;
        }
        match &self.slots[(ty * self.ntx + tx) as usize] {
            Some(tile) => {
                tile.cells[(((cy & TILE_MASK) << TILE_SHIFT) | (cx & TILE_MASK)) as usize]
            }
            None => UNKNOWN,
        }
    }

    /// Occupied-bits of the `w` (1..=32) cells `(x0 .. x0+w, y)`: bit `i` is cell `x0 + i`.
    #[inline]
    pub fn occupied_bits(&self, x0: i32, y: i32, w: i32) -> u32 {
        let ty = (y >> TILE_SHIFT) - self.ty0;
        if ty < 0 || ty >= self.nty {
            return 0;
        }
        let ly = (y & TILE_MASK) as usize;
        let row_of = |tx: i32| -> u32 {
            if tx < 0 || tx >= self.ntx {
                return 0;
            }
            match &self.slots[(ty * self.ntx + tx) as usize] {
                Some(t) => t.occupied[ly],
                None => 0,
            }
        };
        let tx = (x0 >> TILE_SHIFT) - self.tx0;
        let off = x0 & TILE_MASK;
        let mut bits = row_of(tx) >> off;
        if off + w > TILE {
            bits |= row_of(tx + 1) << (TILE - off);
        }
        if w >= 32 {
            bits
        } else {
            bits & ((1u32 << w) - 1)
        }
    }

    /// Mean position of the endpoints that hit cell (cx, cy), in the map frame
    /// (the cell centre if none did).
    #[inline]
    pub fn mean_hit(&self, cx: i32, cy: i32) -> (f64, f64) {
        let (fx, fy) = self
            .tile_at(cx, cy)
            .map(|t| t.mean_hit_fraction(cx, cy))
            .unwrap_or((0.5, 0.5));
        (
            (cx as f64 + fx) * self.resolution,
            (cy as f64 + fy) * self.resolution,
        )
    }

    /// The tile holding cell (cx, cy), if it was ever written.
    #[inline]
    pub fn tile_at(&self, cx: i32, cy: i32) -> Option<&Tile> {
        self.slot_of(cx, cy).and_then(|i| self.slots[i].as_deref())
    }

    /// Occupancy probability of a cell, `None` if never observed.
    pub fn probability(&self, cx: i32, cy: i32) -> Option<f64> {
        let l = self.get(cx, cy);
        (l != UNKNOWN).then(|| 1.0 / (1.0 + (-(l as f64) / LOGODDS_SCALE).exp()))
    }

    /// Makes the slot table cover tiles `[tx_lo, tx_hi] × [ty_lo, ty_hi]`. Returns false
    /// (and leaves the grid unchanged) if that would exceed [`MAX_TILES_PER_SIDE`].
    fn ensure_tiles(&mut self, tx_lo: i32, ty_lo: i32, tx_hi: i32, ty_hi: i32) -> bool {
        if self.ntx > 0
            && tx_lo >= self.tx0
            && ty_lo >= self.ty0
            && tx_hi < self.tx0 + self.ntx
            && ty_hi < self.ty0 + self.nty
        {
            return true;
        }
        let (nx0, ny0, nx1, ny1) = if self.ntx == 0 {
            (tx_lo, ty_lo, tx_hi, ty_hi)
        } else {
            // Grow with a margin so a robot driving along an edge does not re-layout every scan.
            let margin = 4;
            (
                if tx_lo < self.tx0 {
                    tx_lo - margin
                } else {
                    self.tx0
                },
                if ty_lo < self.ty0 {
                    ty_lo - margin
                } else {
                    self.ty0
                },
                if tx_hi >= self.tx0 + self.ntx {
                    tx_hi + margin
                } else {
                    self.tx0 + self.ntx - 1
                },
                if ty_hi >= self.ty0 + self.nty {
                    ty_hi + margin
                } else {
                    self.ty0 + self.nty - 1
                },
            )
        };
        let (w, h) = (nx1 - nx0 + 1, ny1 - ny0 + 1);
        if w > MAX_TILES_PER_SIDE || h > MAX_TILES_PER_SIDE {
            return false;
        }
        let mut slots = vec![None; (w * h) as usize];
        for ty in 0..self.nty {
            for tx in 0..self.ntx {
                let old = &mut self.slots[(ty * self.ntx + tx) as usize];
                let (gx, gy) = (self.tx0 + tx - nx0, self.ty0 + ty - ny0);
                slots[(gy * w + gx) as usize] = old.take();
            }
        }
        self.tx0 = nx0;
        self.ty0 = ny0;
        self.ntx = w;
        self.nty = h;
        self.slots = slots;
        true
    }

    /// Slot index of the tile holding a cell, if the slot table covers it.
    #[inline]
    fn slot_of(&self, cx: i32, cy: i32) -> Option<usize> {
        let tx = (cx >> TILE_SHIFT) - self.tx0;
        let ty = (cy >> TILE_SHIFT) - self.ty0;
        (tx >= 0 && ty >= 0 && tx < self.ntx && ty < self.nty)
            .then(|| (ty * self.ntx + tx) as usize)
    }

    /// Integrates one scan taken from `sensor` (map frame): cells along each beam
    /// become freer, the cell a beam ends in more occupied.
    pub fn integrate(&mut self, sensor: &Pose2, beams: &[BeamEnd], model: &LogOddsModel) {
        if beams.is_empty() || !sensor.is_finite() {
            return;
        }
        let (sx, sy) = self.world_to_cell(sensor.x, sensor.y);
        let (mut lo_x, mut lo_y, mut hi_x, mut hi_y) = (sx, sy, sx, sy);
        for b in beams {
            let (cx, cy) = self.world_to_cell(b.ex, b.ey);
            lo_x = lo_x.min(cx);
            lo_y = lo_y.min(cy);
            hi_x = hi_x.max(cx);
            hi_y = hi_y.max(cy);
        }
        if !self.ensure_tiles(
            lo_x >> TILE_SHIFT,
            lo_y >> TILE_SHIFT,
            hi_x >> TILE_SHIFT,
            hi_y >> TILE_SHIFT,
        ) {
            tracing::warn!(sensor = ?sensor, "scan footprint exceeds the largest grid; scan not mapped");
            return;
        }
        for b in beams {
            let (ex, ey) = self.world_to_cell(b.ex, b.ey);
            self.trace_free(sx, sy, ex, ey, model);
            if b.hit {
                // The miss applied by an earlier beam of this scan is outweighed by the hit.
                let ox = sub_cell(b.ex * self.inv_resolution);
                let oy = sub_cell(b.ey * self.inv_resolution);
                if let Some(i) = self.slot_of(ex, ey) {
                    let tile = Arc::make_mut(
                        self.slots[i].get_or_insert_with(|| Arc::new(Tile::unknown())),
                    );
                    tile.hit(ex & TILE_MASK, ey & TILE_MASK, ox, oy, model.hit, model.max);
                }
            }
        }
    }

    /// The first cell on the line from `from` to `to` (map frame) whose
    /// log-odds (fixed point) is at least `wall`, if it lies more than
    /// `margin_m` before `to`: `to` is then behind an obstacle already in
    /// the grid. Returned as the distance from `from` to that cell's centre, m.
    pub fn wall_before(
        &self,
        from: (f64, f64),
        to: (f64, f64),
        wall: i16,
        margin_m: f64,
    ) -> Option<f64> {
        let (x0, y0) = self.world_to_cell(from.0, from.1);
        let (x1, y1) = self.world_to_cell(to.0, to.1);
        let margin = margin_m * self.inv_resolution;
        let margin2 = (margin * margin) as i64;
        for (x, y) in CellLine::new(x0, y0, x1, y1) {
            let (ex, ey) = (i64::from(x1 - x), i64::from(y1 - y));
            if ex * ex + ey * ey <= margin2 {
                return None;
            }
            let c = self.get(x, y);
            if c != UNKNOWN && c >= wall {
                let (wx, wy) = self.cell_center(x, y);
                return Some((wx - from.0).hypot(wy - from.1));
            }
        }
        None
    }

    /// Lowers the log-odds of the cells from `(x0, y0)` up to but excluding `(x1, y1)`
    /// (Bresenham's line).
    fn trace_free(&mut self, x0: i32, y0: i32, x1: i32, y1: i32, model: &LogOddsModel) {
        let miss = -model.miss;
        // The tile being written stays borrowed until the line leaves it:
        // one copy-on-write check per tile instead of per cell.
        let (tx0, ty0, ntx, nty) = (self.tx0, self.ty0, self.ntx, self.nty);
        let slots = &mut self.slots;
        let mut current = usize::MAX;
        let mut tile: Option<&mut Tile> = None;
        for (x, y) in CellLine::new(x0, y0, x1, y1) {
            let (tx, ty) = ((x >> TILE_SHIFT) - tx0, (y >> TILE_SHIFT) - ty0);
            let slot =
                (tx >= 0 && ty >= 0 && tx < ntx && ty < nty).then(|| (ty * ntx + tx) as usize);
            match slot {
                Some(i) if i == current => {}
                Some(i) => {
                    current = i;
                    tile = Some(Arc::make_mut(
                        slots[i].get_or_insert_with(|| Arc::new(Tile::unknown())),
                    ));
                }
                None => {
                    current = usize::MAX;
                    tile = None;
                }
            }
            if let Some(t) = tile.as_deref_mut() {
                t.add(x & TILE_MASK, y & TILE_MASK, miss, model.max);
            }
        }
    }

    /// Tiles that hold at least one observed cell.
    pub fn tile_count(&self) -> usize {
        self.slots.iter().filter(|s| s.is_some()).count()
    }

    /// Addresses of this grid's tiles, to count the distinct tiles of many grids.
    pub fn tile_ptrs(&self) -> impl Iterator<Item = *const Tile> + '_ {
        self.slots.iter().flatten().map(Arc::as_ptr)
    }

    /// Bytes of one tile.
    pub const TILE_BYTES: usize = std::mem::size_of::<Tile>();

    /// The observed part of the grid as a map_server-style grid (probabilities
    /// 0…100, -1 unknown), cropped to the observed cells plus one cell of border.
    pub fn to_occupancy_grid(&self) -> OccupancyGrid {
        let mut bounds: Option<(i32, i32, i32, i32)> = None;
        for ty in 0..self.nty {
            for tx in 0..self.ntx {
                let Some(tile) = &self.slots[(ty * self.ntx + tx) as usize] else {
                    continue;
                };
                let (bx, by) = ((self.tx0 + tx) << TILE_SHIFT, (self.ty0 + ty) << TILE_SHIFT);
                // Skip tiles wholly inside the bounds found so far.
                if let Some((a, b, c, d)) = bounds
                    && bx >= a
                    && by >= b
                    && bx + TILE - 1 <= c
                    && by + TILE - 1 <= d
                {
                    continue;
                }
                for (i, &c) in tile.cells.iter().enumerate() {
                    if c == UNKNOWN {
                        continue;
                    }
                    let cx = bx + (i as i32 & TILE_MASK);
                    let cy = by + (i as i32 >> TILE_SHIFT);
                    bounds = Some(match bounds {
                        None => (cx, cy, cx, cy),
                        Some((a, b, c2, d)) => (a.min(cx), b.min(cy), c2.max(cx), d.max(cy)),
                    });
                }
            }
        }
        let Some((x0, y0, x1, y1)) = bounds else {
            return OccupancyGrid::new(1, 1, self.resolution, [0.0, 0.0, 0.0]);
        };
        let (x0, y0, x1, y1) = (x0 - 1, y0 - 1, x1 + 1, y1 + 1);
        let (w, h) = ((x1 - x0 + 1) as usize, (y1 - y0 + 1) as usize);
        let origin = [
            x0 as f64 * self.resolution,
            y0 as f64 * self.resolution,
            0.0,
        ];
        let mut grid = OccupancyGrid::new(w, h, self.resolution, origin);
        let lut = percent_table();
        for ty in 0..self.nty {
            for tx in 0..self.ntx {
                let Some(tile) = &self.slots[(ty * self.ntx + tx) as usize] else {
                    continue;
                };
                let (bx, by) = ((self.tx0 + tx) << TILE_SHIFT, (self.ty0 + ty) << TILE_SHIFT);
                for (i, &c) in tile.cells.iter().enumerate() {
                    if c == UNKNOWN {
                        continue;
                    }
                    let gx = (bx + (i as i32 & TILE_MASK) - x0) as usize;
                    let gy = (by + (i as i32 >> TILE_SHIFT) - y0) as usize;
                    grid.cells[gy * w + gx] = lut[(c as i32 - i16::MIN as i32) as usize];
                }
            }
        }
        grid
    }
}

/// The cells of Bresenham's line from `(x0, y0)` up to but excluding `(x1, y1)`.
struct CellLine {
    x: i32,
    y: i32,
    x1: i32,
    y1: i32,
    dx: i32,
    dy: i32,
    sx: i32,
    sy: i32,
    err: i32,
}

impl CellLine {
    #[inline]
    fn new(x0: i32, y0: i32, x1: i32, y1: i32) -> Self {
        let (dx, dy) = ((x1 - x0).abs(), -(y1 - y0).abs());
        Self {
            x: x0,
            y: y0,
            x1,
            y1,
            dx,
            dy,
            sx: if x0 < x1 { 1 } else { -1 },
            sy: if y0 < y1 { 1 } else { -1 },
            err: dx + dy,
        }
    }
}

impl Iterator for CellLine {
    type Item = (i32, i32);

    #[inline]
    fn next(&mut self) -> Option<(i32, i32)> {
        if self.x == self.x1 && self.y == self.y1 {
            return None;
        }
        let cell = (self.x, self.y);
        let e2 = 2 * self.err;
        if e2 >= self.dy {
            self.err += self.dy;
            self.x += self.sx;
        }
        if e2 <= self.dx {
            self.err += self.dx;
            self.y += self.sy;
        }
        Some(cell)
    }
}

/// Occupancy in percent for every fixed-point log-odds value.
fn percent_table() -> &'static [i8] {
    static TABLE: std::sync::OnceLock<Vec<i8>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        (i16::MIN as i32..=i16::MAX as i32)
            .map(|l| {
                let p = 1.0 / (1.0 + (-(l as f64) / LOGODDS_SCALE).exp());
                (p * 100.0).round() as i8
            })
            .collect()
    })
}

/// Position within its cell of a coordinate given in cells, in 1/256 of a cell.
#[inline]
fn sub_cell(v: f64) -> u8 {
    let f = v - floor_cell(v) as f64;
    (f * 256.0).clamp(0.0, 255.0) as u8
}

/// `floor` to a cell index without a libm call. NaN becomes 0; the clamp keeps
/// later shifts and sums far from overflow.
#[inline]
pub fn floor_cell(v: f64) -> i32 {
    let v = v.clamp(-(1 << 28) as f64, (1 << 28) as f64);
    let t = v as i32;
    if (t as f64) > v { t - 1 } else { t }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> LogOddsModel {
        LogOddsModel::new(0.9, 0.4, 4.0)
    }

    #[test]
    fn beam_marks_free_cells_and_an_occupied_end() {
        let mut g = TiledGrid::new(0.05);
        let sensor = Pose2::new(0.01, 0.01, 0.0);
        g.integrate(
            &sensor,
            &[BeamEnd {
                ex: 1.01,
                ey: 0.01,
                hit: true,
            }],
            &model(),
        );
        // 1 m at 5 cm: cells 0..19 free, cell 20 hit.
        for cx in 0..20 {
            assert!(g.probability(cx, 0).unwrap() < 0.5, "cell {cx}");
        }
        assert!(g.probability(20, 0).unwrap() > 0.5);
        assert_eq!(g.probability(21, 0), None);
        assert_eq!(g.probability(5, 1), None);
    }

    #[test]
    fn wall_before_finds_a_wall_only_well_before_the_end() {
        let mut g = TiledGrid::new(0.05);
        let sensor = Pose2::new(0.01, 0.01, 0.0);
        let wall = BeamEnd {
            ex: 1.01,
            ey: 0.01,
            hit: true,
        };
        g.integrate(&sensor, &[wall], &model());
        let one_hit = g.get(20, 0);
        let from = (0.01, 0.01);
        // 0.5 m behind the wall: the wall is 1 m away, at cell 20's centre.
        let d = g.wall_before(from, (1.51, 0.01), one_hit, 0.15);
        assert!(d.is_some_and(|d| (d - 1.015).abs() < 1e-3), "{d:?}");
        // Within the margin of the end, or a weaker wall than asked: none.
        assert_eq!(g.wall_before(from, (1.11, 0.01), one_hit, 0.15), None);
        assert_eq!(g.wall_before(from, (1.51, 0.01), one_hit + 1, 0.15), None);
        // Never observed cells are no wall.
        assert_eq!(g.wall_before(from, (0.01, 2.0), one_hit, 0.15), None);
    }

    #[test]
    fn grid_grows_in_negative_directions_without_moving_cells() {
        let mut g = TiledGrid::new(0.05);
        let m = model();
        g.integrate(
            &Pose2::default(),
            &[BeamEnd {
                ex: 0.5,
                ey: 0.5,
                hit: true,
            }],
            &m,
        );
        let before = g.get(10, 10);
        g.integrate(
            &Pose2::new(-20.0, -30.0, 0.0),
            &[BeamEnd {
                ex: -21.0,
                ey: -31.0,
                hit: true,
            }],
            &m,
        );
        assert_eq!(g.get(10, 10), before);
        let (cx, cy) = g.world_to_cell(-21.0, -31.0);
        assert!(g.probability(cx, cy).unwrap() > 0.5);
    }

    #[test]
    fn clone_shares_tiles_until_one_side_writes() {
        let m = model();
        let mut a = TiledGrid::new(0.05);
        a.integrate(
            &Pose2::default(),
            &[BeamEnd {
                ex: 3.0,
                ey: 0.0,
                hit: true,
            }],
            &m,
        );
        let mut b = a.clone();
        let shared = |a: &TiledGrid, b: &TiledGrid| {
            let pa: std::collections::HashSet<_> = a.tile_ptrs().collect();
            b.tile_ptrs().filter(|p| pa.contains(p)).count()
        };
        let n = a.tile_count();
        assert_eq!(shared(&a, &b), n);
        // A beam along y from the origin touches only the origin's tile (0, 0).
        b.integrate(
            &Pose2::new(0.1, 0.1, 0.0),
            &[BeamEnd {
                ex: 0.1,
                ey: 1.0,
                hit: true,
            }],
            &m,
        );
        assert_eq!(shared(&a, &b), n - 1, "only the written tile was copied");
        assert_eq!(
            a.get(2, 19),
            UNKNOWN,
            "the other grid did not see the write"
        );
        assert!(b.probability(2, 20).unwrap() > 0.5);
    }

    #[test]
    fn occupied_bits_read_across_a_tile_border() {
        let mut g = TiledGrid::new(0.05);
        let m = model();
        // Hits at cells (31, 0) and (32, 0): either side of the tile border x = 32.
        g.integrate(
            &Pose2::new(1.6, 1.0, 0.0),
            &[BeamEnd {
                ex: 1.575,
                ey: 0.02,
                hit: true,
            }],
            &m,
        );
        g.integrate(
            &Pose2::new(1.6, 1.0, 0.0),
            &[BeamEnd {
                ex: 1.625,
                ey: 0.02,
                hit: true,
            }],
            &m,
        );
        assert_eq!(g.occupied_bits(30, 0, 3), 0b110);
        assert_eq!(g.occupied_bits(31, 0, 2), 0b11);
        assert_eq!(g.occupied_bits(-100, 0, 3), 0);
        assert_eq!(g.occupied_bits(31, 5000, 3), 0);
        assert_eq!(floor_cell(-0.5), -1);
        assert_eq!(floor_cell(2.0), 2);
        assert_eq!(floor_cell(f64::NAN), 0);
    }

    #[test]
    fn mean_hit_locates_the_wall_within_its_cell() {
        let mut g = TiledGrid::new(0.05);
        let m = model();
        // Endpoints at x = 1.012 and 1.018 fall in cell 20 ([1.00, 1.05)); their mean is 1.015.
        g.integrate(
            &Pose2::new(0.0, 0.02, 0.0),
            &[BeamEnd {
                ex: 1.012,
                ey: 0.02,
                hit: true,
            }],
            &m,
        );
        g.integrate(
            &Pose2::new(0.0, 0.02, 0.0),
            &[BeamEnd {
                ex: 1.018,
                ey: 0.02,
                hit: true,
            }],
            &m,
        );
        let (x, y) = g.mean_hit(20, 0);
        assert!((x - 1.015).abs() < 0.001, "{x}");
        assert!((y - 0.02).abs() < 0.001, "{y}");
        // A cell never hit reports its centre.
        let (x, y) = g.mean_hit(3, 0);
        assert!((x - 0.175).abs() < 1e-9 && (y - 0.025).abs() < 1e-9);
    }

    #[test]
    fn log_odds_saturate_at_max() {
        let m = model();
        let mut g = TiledGrid::new(0.05);
        for _ in 0..100 {
            g.integrate(
                &Pose2::default(),
                &[BeamEnd {
                    ex: 0.52,
                    ey: 0.02,
                    hit: true,
                }],
                &m,
            );
        }
        assert_eq!(g.get(10, 0), m.max);
        assert_eq!(g.get(3, 0), -m.max);
    }

    #[test]
    fn absurd_pose_does_not_allocate_a_huge_grid() {
        let mut g = TiledGrid::new(0.05);
        g.integrate(
            &Pose2::new(0.0, 0.0, 0.0),
            &[BeamEnd {
                ex: 1e9,
                ey: 0.0,
                hit: true,
            }],
            &model(),
        );
        assert_eq!(g.tile_count(), 0);
        g.integrate(
            &Pose2::new(f64::NAN, 0.0, 0.0),
            &[BeamEnd {
                ex: 1.0,
                ey: 0.0,
                hit: true,
            }],
            &model(),
        );
        assert_eq!(g.tile_count(), 0);
    }

    #[test]
    fn occupancy_export_is_cropped_and_placed() {
        let mut g = TiledGrid::new(0.05);
        g.integrate(
            &Pose2::new(0.01, 0.01, 0.0),
            &[BeamEnd {
                ex: 1.01,
                ey: 0.01,
                hit: true,
            }],
            &model(),
        );
        let occ = g.to_occupancy_grid();
        // Cells 0..=20 observed along y = 0, plus one border cell each side.
        assert_eq!((occ.width, occ.height), (23, 3));
        let (hx, hy) = occ.world_to_cell(1.01, 0.01).unwrap();
        assert!(occ.get(hx, hy).unwrap() > 50);
        let (fx, fy) = occ.world_to_cell(0.5, 0.01).unwrap();
        assert!(occ.get(fx, fy).unwrap() < 50);
        assert_eq!(occ.get(0, 0), Some(-1));
    }
}
