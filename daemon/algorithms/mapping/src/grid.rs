//! 2D grids: a clamped log-odds grid that sensors update, and a probability
//! grid that fusion rules and the octree projection produce.

use crate::logodds::{ClampLogOdds, probability};
use smokenav_platform_map::{OccupancyGrid, UNKNOWN};

/// Where a 2D grid lies: lower-left corner, cell side, size in cells.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridGeometry {
    pub origin: [f64; 2],
    pub resolution: f64,
    pub width: usize,
    pub height: usize,
}

impl GridGeometry {
    /// The cell index of a point, `None` outside.
    pub fn index(&self, x: f64, y: f64) -> Option<usize> {
        let cx = ((x - self.origin[0]) / self.resolution).floor();
        let cy = ((y - self.origin[1]) / self.resolution).floor();
        (cx >= 0.0 && cy >= 0.0 && (cx as usize) < self.width && (cy as usize) < self.height)
            .then(|| cy as usize * self.width + cx as usize)
    }

    /// Integer cell coordinates of a point (may lie outside).
    pub fn cell(&self, x: f64, y: f64) -> (i64, i64) {
        (
            ((x - self.origin[0]) / self.resolution).floor() as i64,
            ((y - self.origin[1]) / self.resolution).floor() as i64,
        )
    }

    pub fn index_of_cell(&self, cx: i64, cy: i64) -> Option<usize> {
        (cx >= 0 && cy >= 0 && (cx as usize) < self.width && (cy as usize) < self.height)
            .then(|| cy as usize * self.width + cx as usize)
    }

    pub fn center(&self, cx: i64, cy: i64) -> (f64, f64) {
        (
            self.origin[0] + (cx as f64 + 0.5) * self.resolution,
            self.origin[1] + (cy as f64 + 0.5) * self.resolution,
        )
    }

    pub fn len(&self) -> usize {
        self.width * self.height
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A clamped log-odds grid; 0 (p = 0.5) is "never observed".
#[derive(Debug, Clone)]
pub struct LogOddsGrid {
    pub geometry: GridGeometry,
    clamp: ClampLogOdds,
    cells: Vec<f32>,
}

impl LogOddsGrid {
    pub fn new(geometry: GridGeometry, clamp: ClampLogOdds) -> Self {
        Self {
            geometry,
            clamp,
            cells: vec![0.0; geometry.len()],
        }
    }

    pub fn add(&mut self, index: usize, delta: f32) {
        if let Some(c) = self.cells.get_mut(index) {
            *c = self.clamp.add(*c, delta);
        }
    }

    pub fn logodds(&self, index: usize) -> f32 {
        self.cells.get(index).copied().unwrap_or(0.0)
    }

    /// The grid as probabilities (never-observed cells unknown).
    pub fn probabilities(&self) -> ProbGrid {
        ProbGrid {
            geometry: self.geometry,
            p: self
                .cells
                .iter()
                .map(|&l| {
                    if l == 0.0 {
                        f32::NAN
                    } else {
                        probability(l as f64) as f32
                    }
                })
                .collect(),
        }
    }
}

/// Occupancy probabilities per cell, NaN where unknown.
#[derive(Debug, Clone, PartialEq)]
pub struct ProbGrid {
    pub geometry: GridGeometry,
    pub p: Vec<f32>,
}

/// What a cell of a map says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CellClass {
    Unknown,
    Free,
    Occupied,
}

impl ProbGrid {
    pub fn unknown(geometry: GridGeometry) -> Self {
        Self {
            geometry,
            p: vec![f32::NAN; geometry.len()],
        }
    }

    /// OctoMap's threshold: occupied above 0.5, free below, unknown at or
    /// near exactly 0.5 (a conflict) and where never observed.
    pub fn class(&self, index: usize) -> CellClass {
        match self.p.get(index) {
            Some(p) if *p > 0.5 + 1e-6 => CellClass::Occupied,
            Some(p) if *p < 0.5 - 1e-6 => CellClass::Free,
            _ => CellClass::Unknown,
        }
    }

    /// As a ROS-style occupancy grid (0–100, −1 unknown).
    pub fn to_occupancy_grid(&self) -> OccupancyGrid {
        let g = self.geometry;
        let mut out = OccupancyGrid::new(
            g.width,
            g.height,
            g.resolution,
            [g.origin[0], g.origin[1], 0.0],
        );
        for (o, p) in out.cells.iter_mut().zip(&self.p) {
            *o = if p.is_nan() {
                UNKNOWN
            } else {
                (p * 100.0).round().clamp(0.0, 100.0) as i8
            };
        }
        out
    }
}

/// Calls `f(cx, cy)` for the cells a segment from `a` to `b` crosses, in
/// order, except the cell containing `b`, which it returns (Amanatides &
/// Woo's traversal on cells of side `res` from `offset`).
pub fn walk_cells(
    a: [f64; 2],
    b: [f64; 2],
    res: f64,
    offset: [f64; 2],
    mut f: impl FnMut(i64, i64),
) -> (i64, i64) {
    let cell = |p: f64, o: f64| ((p - o) / res).floor() as i64;
    let (mut cx, mut cy) = (cell(a[0], offset[0]), cell(a[1], offset[1]));
    let (ex, ey) = (cell(b[0], offset[0]), cell(b[1], offset[1]));
    let d = [b[0] - a[0], b[1] - a[1]];
    let step = |v: f64| if v > 0.0 { 1i64 } else { -1 };
    let (sx, sy) = (step(d[0]), step(d[1]));
    let first = |c: i64, s: i64, p: f64, o: f64, dv: f64| {
        if dv.abs() < 1e-15 {
            f64::INFINITY
        } else {
            let edge = o + (c + (s > 0) as i64) as f64 * res;
            (edge - p) / dv
        }
    };
    let mut tx = first(cx, sx, a[0], offset[0], d[0]);
    let mut ty = first(cy, sy, a[1], offset[1], d[1]);
    let dtx = if d[0].abs() < 1e-15 {
        f64::INFINITY
    } else {
        res / d[0].abs()
    };
    let dty = if d[1].abs() < 1e-15 {
        f64::INFINITY
    } else {
        res / d[1].abs()
    };
    // Bounded by the cells between the ends, whatever rounding does.
    let max_steps = (ex - cx).unsigned_abs() + (ey - cy).unsigned_abs() + 2;
    for _ in 0..max_steps {
        if cx == ex && cy == ey {
            break;
        }
        f(cx, cy);
        if tx < ty {
            cx += sx;
            tx += dtx;
        } else {
            cy += sy;
            ty += dty;
        }
    }
    (ex, ey)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn walk_visits_the_cells_before_the_end_in_order() {
        let mut v = Vec::new();
        let end = walk_cells([0.05, 0.05], [0.45, 0.05], 0.1, [0.0, 0.0], |x, y| {
            v.push((x, y))
        });
        assert_eq!(end, (4, 0));
        assert_eq!(v, vec![(0, 0), (1, 0), (2, 0), (3, 0)]);
        let mut n = 0;
        walk_cells([0.05, 0.05], [0.95, 0.95], 0.1, [0.0, 0.0], |_, _| n += 1);
        assert_eq!(n, 18, "4-connected: 9 steps in x and 9 in y");
    }

    #[test]
    fn classes_follow_the_threshold() {
        let g = GridGeometry {
            origin: [0.0, 0.0],
            resolution: 1.0,
            width: 3,
            height: 1,
        };
        let p = ProbGrid {
            geometry: g,
            p: vec![0.7, 0.3, f32::NAN],
        };
        assert_eq!(p.class(0), CellClass::Occupied);
        assert_eq!(p.class(1), CellClass::Free);
        assert_eq!(p.class(2), CellClass::Unknown);
        assert_eq!(p.to_occupancy_grid().cells, vec![70, 30, -1]);
    }
}
