//! The static world: walls and obstacles as segments, indexed by a uniform
//! grid so rays and clearance queries only look at nearby walls.
//!
//! Arenas come from three places: the bundled vector files (mirroring the
//! SmokeNav paper's MRL and R3.2 arenas and a plain corridor), a user's vector
//! file, or a ROS `map_server` map (PGM/PNG + YAML), whose occupied pixels
//! are traced into wall segments.

use crate::SimError;
use crate::geom::{Segment, Vec2};
use serde::Deserialize;
use smokenav_platform_map::{FREE, OCCUPIED, OccupancyGrid, UNKNOWN};
use std::path::{Path, PathBuf};

/// Segments accepted from a file (a 2000×2000-pixel map traced pixel by pixel
/// stays far below this; a crafted file must not exhaust memory).
pub const MAX_SEGMENTS: usize = 500_000;
/// Coordinates beyond this many metres from the origin are rejected.
pub const MAX_COORD_M: f64 = 10_000.0;
/// Bounding box side beyond which an arena is rejected, m.
pub const MAX_EXTENT_M: f64 = 1_000.0;

/// Cell side of the wall index, m: a few walls per cell in a room, and a
/// 5.6 m laser ray crosses ~25 cells.
const INDEX_CELL_M: f64 = 0.25;

/// The bundled arenas.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BuiltinArena {
    /// SmokeNav (Santos et al. 2015) Fig. 1/7a: the MRL arena, 4.57 × 4.04 m, used to tune sonar-only mapping.
    Mrl,
    /// SmokeNav Fig. 10/15: the R3.2 classroom arena, 13.63 × 9.87 m, with obstacles.
    R32,
    /// SmokeNav Fig. 5/6: a plain corridor, where the Pioneer's oblique sonars see nothing.
    Corridor,
    /// A room with table tops and low obstacles out of the laser's plane.
    Heights,
    /// Two 20 m aisles either side of a rack: parallel walls longer than the laser's range.
    Aisles,
    /// A workshop with cables and a cable tray to drive over and a low box, all under the laser's plane.
    Cables,
}

impl BuiltinArena {
    pub const ALL: [BuiltinArena; 6] = [
        BuiltinArena::Mrl,
        BuiltinArena::R32,
        BuiltinArena::Corridor,
        BuiltinArena::Heights,
        BuiltinArena::Aisles,
        BuiltinArena::Cables,
    ];

    pub fn name(self) -> &'static str {
        match self {
            BuiltinArena::Mrl => "mrl",
            BuiltinArena::R32 => "r3.2",
            BuiltinArena::Corridor => "corridor",
            BuiltinArena::Heights => "heights",
            BuiltinArena::Aisles => "aisles",
            BuiltinArena::Cables => "cables",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|a| a.name() == name)
    }

    /// The vector file's text.
    pub fn source(self) -> &'static str {
        match self {
            BuiltinArena::Mrl => include_str!("../../arenas/mrl.toml"),
            BuiltinArena::R32 => include_str!("../../arenas/r3.2.toml"),
            BuiltinArena::Corridor => include_str!("../../arenas/corridor.toml"),
            BuiltinArena::Heights => include_str!("../../arenas/heights.toml"),
            BuiltinArena::Aisles => include_str!("../../arenas/aisles.toml"),
            BuiltinArena::Cables => include_str!("../../arenas/cables.toml"),
        }
    }

    pub fn load(self) -> Result<Arena, SimError> {
        Arena::from_vector_str(
            self.source(),
            Path::new(&format!("<builtin {}>", self.name())),
        )
    }
}

/// A vector arena file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct VectorFile {
    #[serde(default)]
    name: String,
    #[serde(default)]
    #[allow(dead_code)] // documentation for people reading the file
    description: String,
    #[serde(default)]
    wall: Vec<WallSpec>,
    #[serde(default, rename = "box")]
    boxes: Vec<BoxSpec>,
    #[serde(default)]
    circle: Vec<CircleSpec>,
}

/// A polyline of walls.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct WallSpec {
    points: Vec<[f64; 2]>,
    /// `[base, top]` above the floor, m; omitted: floor to ceiling.
    #[serde(default)]
    height_m: Option<[f64; 2]>,
    /// Join the last point back to the first.
    #[serde(default)]
    closed: bool,
}

/// A rectangular obstacle (table, cabinet).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct BoxSpec {
    center: [f64; 2],
    size: [f64; 2],
    #[serde(default)]
    yaw_deg: f64,
    /// `[base, top]` above the floor, m (a table top: `[0.45, 0.55]`; a
    /// low box: `[0.0, 0.2]`); omitted: floor to ceiling.
    #[serde(default)]
    height_m: Option<[f64; 2]>,
}

/// A round obstacle (column, bin), drawn as a 24-gon.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CircleSpec {
    center: [f64; 2],
    radius: f64,
    /// `[base, top]` above the floor, m; omitted: floor to ceiling.
    #[serde(default)]
    height_m: Option<[f64; 2]>,
}

/// A ray's first wall.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Distance along the ray, m.
    pub distance: f64,
    /// Unit normal of the wall there (either side).
    pub normal: Vec2,
}

/// Walls plus their spatial index.
#[derive(Debug, Clone)]
pub struct Arena {
    pub name: String,
    segments: Vec<Segment>,
    min: Vec2,
    max: Vec2,
    /// Index grid: `cols × rows` cells of `INDEX_CELL_M`, from `min`.
    cols: usize,
    rows: usize,
    /// CSR layout: segments of cell `c` are `cell_items[cell_start[c]..cell_start[c + 1]]`.
    cell_start: Vec<u32>,
    cell_items: Vec<u32>,
    /// When loaded from a pixel map: that map, returned as the ground truth.
    source_grid: Option<OccupancyGrid>,
    /// Whether any segment spans less than the full height.
    has_heights: bool,
}

impl Arena {
    /// Builds an arena from wall segments. `file` is only used in messages.
    pub fn from_segments(
        name: &str,
        segments: Vec<Segment>,
        file: &Path,
    ) -> Result<Self, SimError> {
        let invalid = |reason: String| SimError::Invalid {
            file: file.to_owned(),
            key: "walls".into(),
            reason,
        };
        if segments.is_empty() {
            return Err(invalid("the arena has no walls".into()));
        }
        if segments.len() > MAX_SEGMENTS {
            return Err(invalid(format!(
                "{} wall segments exceed the limit of {MAX_SEGMENTS}",
                segments.len()
            )));
        }
        let mut min = Vec2::new(f64::INFINITY, f64::INFINITY);
        let mut max = Vec2::new(f64::NEG_INFINITY, f64::NEG_INFINITY);
        for s in &segments {
            for p in [s.a, s.b] {
                if !p.is_finite() || p.x.abs() > MAX_COORD_M || p.y.abs() > MAX_COORD_M {
                    return Err(invalid(format!(
                        "wall point ({}, {}) is not a finite coordinate within ±{MAX_COORD_M} m",
                        p.x, p.y
                    )));
                }
                min = Vec2::new(min.x.min(p.x), min.y.min(p.y));
                max = Vec2::new(max.x.max(p.x), max.y.max(p.y));
            }
        }
        if max.x - min.x > MAX_EXTENT_M || max.y - min.y > MAX_EXTENT_M {
            return Err(invalid(format!(
                "arena spans {:.1} × {:.1} m, more than {MAX_EXTENT_M} m",
                max.x - min.x,
                max.y - min.y
            )));
        }
        // One cell of margin so every segment end lies strictly inside.
        min = min - Vec2::new(INDEX_CELL_M, INDEX_CELL_M);
        max = max + Vec2::new(INDEX_CELL_M, INDEX_CELL_M);
        let cols = ((max.x - min.x) / INDEX_CELL_M).ceil() as usize;
        let rows = ((max.y - min.y) / INDEX_CELL_M).ceil() as usize;
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); cols * rows];
        for (i, s) in segments.iter().enumerate() {
            for_each_cell_on_segment(s.a, s.b, min, INDEX_CELL_M, cols, rows, |cx, cy| {
                let list = &mut lists[cy * cols + cx];
                if list.last() != Some(&(i as u32)) {
                    list.push(i as u32);
                }
            });
        }
        let mut cell_start = Vec::with_capacity(cols * rows + 1);
        let mut cell_items = Vec::new();
        cell_start.push(0);
        for l in &lists {
            cell_items.extend_from_slice(l);
            cell_start.push(cell_items.len() as u32);
        }
        let has_heights = segments.iter().any(|s| !s.is_full_height());
        Ok(Self {
            name: name.to_owned(),
            segments,
            min,
            max,
            cols,
            rows,
            cell_start,
            cell_items,
            source_grid: None,
            has_heights,
        })
    }

    /// Parses the vector format (see `arenas/*.toml`).
    pub fn from_vector_str(text: &str, file: &Path) -> Result<Self, SimError> {
        let spec: VectorFile = smokenav_platform_config::parse_toml(text, file)?;
        let invalid = |key: String, reason: String| SimError::Invalid {
            file: file.to_owned(),
            key,
            reason,
        };
        let height = |key: String, h: Option<[f64; 2]>| -> Result<[f64; 2], SimError> {
            match h {
                None => Ok(crate::geom::FULL_HEIGHT),
                Some([lo, hi])
                    if lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo < hi && hi <= 100.0 =>
                {
                    Ok([lo, hi])
                }
                Some(h) => Err(invalid(
                    key,
                    format!("[base, top] must satisfy 0 ≤ base < top ≤ 100 m, got {h:?}"),
                )),
            }
        };
        let mut segs = Vec::new();
        for (i, w) in spec.wall.iter().enumerate() {
            let z = height(format!("wall[{i}].height_m"), w.height_m)?;
            if w.points.len() < 2 {
                return Err(invalid(
                    format!("wall[{i}].points"),
                    format!("a wall needs at least 2 points, got {}", w.points.len()),
                ));
            }
            if w.points.len() > MAX_SEGMENTS {
                return Err(invalid(
                    format!("wall[{i}].points"),
                    "too many points".into(),
                ));
            }
            let pts: Vec<Vec2> = w.points.iter().map(|p| Vec2::new(p[0], p[1])).collect();
            for pair in pts.windows(2) {
                segs.push(Segment::new(pair[0], pair[1]).with_height(z));
            }
            if w.closed && pts.len() > 2 {
                segs.push(Segment::new(pts[pts.len() - 1], pts[0]).with_height(z));
            }
        }
        for (i, b) in spec.boxes.iter().enumerate() {
            let z = height(format!("box[{i}].height_m"), b.height_m)?;
            if !(b.size[0] > 0.0 && b.size[1] > 0.0) {
                return Err(invalid(
                    format!("box[{i}].size"),
                    format!("sides must be > 0, got {:?}", b.size),
                ));
            }
            let c = Vec2::new(b.center[0], b.center[1]);
            let (hx, hy) = (b.size[0] / 2.0, b.size[1] / 2.0);
            let yaw = b.yaw_deg.to_radians();
            let corners: Vec<Vec2> = [(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)]
                .iter()
                .map(|&(x, y)| c + Vec2::new(x, y).rotated(yaw))
                .collect();
            for k in 0..4 {
                segs.push(Segment::new(corners[k], corners[(k + 1) % 4]).with_height(z));
            }
        }
        for (i, c) in spec.circle.iter().enumerate() {
            if !(c.radius > 0.0 && c.radius < MAX_EXTENT_M) {
                return Err(invalid(
                    format!("circle[{i}].radius"),
                    format!("must be > 0 m, got {}", c.radius),
                ));
            }
            let z = height(format!("circle[{i}].height_m"), c.height_m)?;
            const SIDES: usize = 24;
            let ctr = Vec2::new(c.center[0], c.center[1]);
            for k in 0..SIDES {
                let a0 = k as f64 * std::f64::consts::TAU / SIDES as f64;
                let a1 = (k + 1) as f64 * std::f64::consts::TAU / SIDES as f64;
                let mut s = Segment::new(
                    ctr + Vec2::from_angle(a0) * c.radius,
                    ctr + Vec2::from_angle(a1) * c.radius,
                );
                s.normal = Vec2::from_angle((a0 + a1) / 2.0); // radial, as the real column's
                segs.push(s.with_height(z));
            }
        }
        let name = if spec.name.is_empty() {
            file.display().to_string()
        } else {
            spec.name
        };
        Self::from_segments(&name, segs, file)
    }

    pub fn from_vector_file(path: &Path) -> Result<Self, SimError> {
        let text = std::fs::read_to_string(path).map_err(|e| SimError::Io {
            path: path.to_owned(),
            source: e,
        })?;
        Self::from_vector_str(&text, path)
    }

    /// Loads a map_server map and traces its occupied pixels into walls.
    pub fn from_map_server(yaml: &Path) -> Result<Self, SimError> {
        let grid = smokenav_platform_map::load_map_server(yaml)?;
        Self::from_grid(grid, yaml)
    }

    /// Traces the boundary between occupied and other pixels into segments.
    /// Each pixel edge carries the smoothed occupancy gradient as its normal,
    /// so a diagonal wall drawn as a pixel staircase reflects sound like a
    /// diagonal wall (the sonar's specular model depends on it).
    pub fn from_grid(grid: OccupancyGrid, file: &Path) -> Result<Self, SimError> {
        let (w, h, res) = (grid.width, grid.height, grid.resolution);
        if grid.cells.len() != w * h {
            return Err(SimError::Invalid {
                file: file.to_owned(),
                key: "image".into(),
                reason: format!("{} cells but {w}×{h}", grid.cells.len()),
            });
        }
        let occ = |x: i64, y: i64| -> bool {
            x >= 0
                && y >= 0
                && (x as usize) < w
                && (y as usize) < h
                && grid.cells[y as usize * w + x as usize] >= 65
        };
        let o = Vec2::new(grid.origin[0], grid.origin[1]);
        // Sobel gradient of occupancy; the outward normal is its negative.
        let smoothed_normal = |x: i64, y: i64, fallback: Vec2| -> Vec2 {
            let v = |dx: i64, dy: i64| occ(x + dx, y + dy) as i32 as f64;
            let gx = (v(1, -1) + 2.0 * v(1, 0) + v(1, 1)) - (v(-1, -1) + 2.0 * v(-1, 0) + v(-1, 1));
            let gy = (v(-1, 1) + 2.0 * v(0, 1) + v(1, 1)) - (v(-1, -1) + 2.0 * v(0, -1) + v(1, -1));
            let g = Vec2::new(-gx, -gy);
            if g.norm() > 1e-9 {
                g.normalized()
            } else {
                fallback
            }
        };
        let mut segs: Vec<Segment> = Vec::new();
        let push_run = |segs: &mut Vec<Segment>, a: Vec2, b: Vec2, n: Vec2| {
            // Merge with the previous edge when it continues it with the same normal.
            if let Some(last) = segs.last_mut()
                && (last.b - a).norm() < 1e-9
                && last.normal.dot(n) > 0.999
                && (last.b - last.a).normalized().dot((b - a).normalized()) > 0.999
            {
                last.b = b;
                return;
            }
            segs.push(Segment {
                a,
                b,
                normal: n,
                z: crate::geom::FULL_HEIGHT,
            });
        };
        // Horizontal edges, row by row (bottom edge: free below; top edge: free above).
        for y in 0..h as i64 {
            for side in [-1i64, 1] {
                for x in 0..w as i64 {
                    if occ(x, y) && !occ(x, y + side) {
                        let ey = if side < 0 { y } else { y + 1 } as f64;
                        let a = o + Vec2::new(x as f64 * res, ey * res);
                        let b = o + Vec2::new((x + 1) as f64 * res, ey * res);
                        let n = smoothed_normal(x, y, Vec2::new(0.0, side as f64));
                        push_run(&mut segs, a, b, n);
                    }
                }
            }
        }
        for x in 0..w as i64 {
            for side in [-1i64, 1] {
                for y in 0..h as i64 {
                    if occ(x, y) && !occ(x + side, y) {
                        let ex = if side < 0 { x } else { x + 1 } as f64;
                        let a = o + Vec2::new(ex * res, y as f64 * res);
                        let b = o + Vec2::new(ex * res, (y + 1) as f64 * res);
                        let n = smoothed_normal(x, y, Vec2::new(side as f64, 0.0));
                        push_run(&mut segs, a, b, n);
                    }
                }
            }
        }
        let mut arena = Self::from_segments(&file.display().to_string(), segs, file)?;
        arena.source_grid = Some(grid);
        Ok(arena)
    }

    /// Whether some obstacle spans less than floor to ceiling (otherwise the
    /// world is planar and sensors need not look at heights).
    pub fn has_heights(&self) -> bool {
        self.has_heights
    }

    pub fn segments(&self) -> &[Segment] {
        &self.segments
    }

    /// Bounding box of the walls (with the index margin).
    pub fn bounds(&self) -> (Vec2, Vec2) {
        (self.min, self.max)
    }

    fn cell_items(&self, cx: usize, cy: usize) -> &[u32] {
        let c = cy * self.cols + cx;
        let (s, e) = (self.cell_start[c] as usize, self.cell_start[c + 1] as usize);
        &self.cell_items[s..e]
    }

    /// First wall along the ray from `o` in unit direction `d`, within `max_range`.
    /// Walks the index grid cell by cell (Amanatides & Woo, "A fast voxel
    /// traversal algorithm", 1987), testing only the walls listed in each cell.
    pub fn cast(&self, o: Vec2, d: Vec2, max_range: f64) -> Option<Hit> {
        self.cast_where(o, d, max_range, |_, _| true)
    }

    /// [`Arena::cast`] through the horizontal plane at height `z`: segments
    /// that do not reach `z` (a table top above a laser, a low box below it)
    /// are passed by.
    pub fn cast_at_height(&self, o: Vec2, d: Vec2, max_range: f64, z: f64) -> Option<Hit> {
        self.cast_where(o, d, max_range, |s, _| s.spans(z))
    }

    /// [`Arena::cast`] counting only hits `accept(segment, distance)` keeps
    /// (a climbing or falling sonar ray accepts a segment only where the ray's
    /// height at that distance is within the segment's).
    pub fn cast_where(
        &self,
        o: Vec2,
        d: Vec2,
        max_range: f64,
        accept: impl Fn(&Segment, f64) -> bool,
    ) -> Option<Hit> {
        let cell = INDEX_CELL_M;
        // Clip the ray to the index box.
        let (mut t0, mut t1) = (0.0f64, max_range);
        for (oc, dc, lo, hi) in [
            (o.x, d.x, self.min.x, self.max.x),
            (o.y, d.y, self.min.y, self.max.y),
        ] {
            if dc.abs() < 1e-15 {
                if oc < lo || oc > hi {
                    return None;
                }
            } else {
                let (a, b) = ((lo - oc) / dc, (hi - oc) / dc);
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
        }
        if t0 > t1 {
            return None;
        }
        let p = o + d * t0;
        let mut cx = (((p.x - self.min.x) / cell).floor() as i64).clamp(0, self.cols as i64 - 1);
        let mut cy = (((p.y - self.min.y) / cell).floor() as i64).clamp(0, self.rows as i64 - 1);
        let step_x: i64 = if d.x > 0.0 { 1 } else { -1 };
        let step_y: i64 = if d.y > 0.0 { 1 } else { -1 };
        let next_boundary = |c: i64, step: i64, lo: f64| lo + (c + (step > 0) as i64) as f64 * cell;
        let mut t_max_x = if d.x.abs() < 1e-15 {
            f64::INFINITY
        } else {
            (next_boundary(cx, step_x, self.min.x) - o.x) / d.x
        };
        let mut t_max_y = if d.y.abs() < 1e-15 {
            f64::INFINITY
        } else {
            (next_boundary(cy, step_y, self.min.y) - o.y) / d.y
        };
        let t_delta_x = if d.x.abs() < 1e-15 {
            f64::INFINITY
        } else {
            cell / d.x.abs()
        };
        let t_delta_y = if d.y.abs() < 1e-15 {
            f64::INFINITY
        } else {
            cell / d.y.abs()
        };
        let mut best: Option<Hit> = None;
        loop {
            for &i in self.cell_items(cx as usize, cy as usize) {
                let s = &self.segments[i as usize];
                if let Some(t) = s.ray_hit(o, d)
                    && t <= max_range
                    && best.is_none_or(|b| t < b.distance)
                    && accept(s, t)
                {
                    best = Some(Hit {
                        distance: t,
                        normal: s.normal,
                    });
                }
            }
            let t_exit = t_max_x.min(t_max_y);
            if let Some(b) = best
                && b.distance <= t_exit
            {
                return best;
            }
            if t_exit > t1 {
                return best;
            }
            if t_max_x < t_max_y {
                cx += step_x;
                t_max_x += t_delta_x;
            } else {
                cy += step_y;
                t_max_y += t_delta_y;
            }
            if cx < 0 || cy < 0 || cx >= self.cols as i64 || cy >= self.rows as i64 {
                return best;
            }
        }
    }

    /// Distance from `p` to the nearest wall, looking no further than `radius`
    /// (returns `radius` or more when nothing is that close).
    pub fn clearance(&self, p: Vec2, radius: f64) -> f64 {
        let cell = INDEX_CELL_M;
        let lo_x = (((p.x - radius - self.min.x) / cell).floor() as i64).max(0);
        let hi_x = (((p.x + radius - self.min.x) / cell).floor() as i64).min(self.cols as i64 - 1);
        let lo_y = (((p.y - radius - self.min.y) / cell).floor() as i64).max(0);
        let hi_y = (((p.y + radius - self.min.y) / cell).floor() as i64).min(self.rows as i64 - 1);
        let mut best = f64::INFINITY;
        for cy in lo_y..=hi_y {
            for cx in lo_x..=hi_x {
                for &i in self.cell_items(cx as usize, cy as usize) {
                    best = best.min(self.segments[i as usize].distance_to(p));
                }
            }
        }
        best
    }

    /// Like [`Arena::clearance`], but only to obstacles whose top is above
    /// `climb_m`: what a base that drives over cables and sills bumps into.
    pub fn clearance_above(&self, p: Vec2, radius: f64, climb_m: f64) -> f64 {
        self.nearest_where(p, radius, |s| s.z[1] > climb_m)
    }

    /// True when an obstacle at most `climb_m` high (a cable, a sill; top above
    /// the floor) lies within `radius` of `p`: the base is on it.
    pub fn low_obstacle_within(&self, p: Vec2, radius: f64, climb_m: f64) -> bool {
        climb_m > 0.0 && self.nearest_where(p, radius, |s| s.z[1] <= climb_m) < radius
    }

    /// The top of the highest obstacle at most `climb_m` high within
    /// `radius` of `p` (what a wheel there stands on), if any.
    pub fn low_obstacle_top_within(&self, p: Vec2, radius: f64, climb_m: f64) -> Option<f64> {
        if climb_m <= 0.0 {
            return None;
        }
        let mut top: Option<f64> = None;
        self.for_each_near(p, radius, |s| {
            if s.z[1] <= climb_m && s.distance_to(p) < radius {
                top = Some(top.map_or(s.z[1], |t| t.max(s.z[1])));
            }
        });
        top
    }

    fn nearest_where(&self, p: Vec2, radius: f64, keep: impl Fn(&Segment) -> bool) -> f64 {
        let mut best = f64::INFINITY;
        self.for_each_near(p, radius, |s| {
            if keep(s) {
                best = best.min(s.distance_to(p));
            }
        });
        best
    }

    /// Every segment listed in the index cells within `radius` of `p` (a
    /// superset of those that are; a segment may come more than once).
    fn for_each_near(&self, p: Vec2, radius: f64, mut visit: impl FnMut(&Segment)) {
        let cell = INDEX_CELL_M;
        let lo_x = (((p.x - radius - self.min.x) / cell).floor() as i64).max(0);
        let hi_x = (((p.x + radius - self.min.x) / cell).floor() as i64).min(self.cols as i64 - 1);
        let lo_y = (((p.y - radius - self.min.y) / cell).floor() as i64).max(0);
        let hi_y = (((p.y + radius - self.min.y) / cell).floor() as i64).min(self.rows as i64 - 1);
        for cy in lo_y..=hi_y {
            for cx in lo_x..=hi_x {
                for &i in self.cell_items(cx as usize, cy as usize) {
                    visit(&self.segments[i as usize]);
                }
            }
        }
    }

    /// The true map: walls occupied, the free space reachable from `start`
    /// free, everything else unknown. For an arena loaded from a pixel map at
    /// the same resolution, that map itself.
    pub fn truth_map(&self, resolution: f64, start: Vec2) -> OccupancyGrid {
        if let Some(g) = &self.source_grid
            && (g.resolution - resolution).abs() < 1e-12
        {
            return g.clone();
        }
        self.truth_map_where(resolution, start, |_| true)
    }

    /// The true map of the segments `keep` accepts (e.g. those a laser at
    /// one height sees, or the obstacles out of its plane), on the same
    /// grid as [`Arena::truth_map`]; free space is flood-filled from `start`
    /// around the kept segments only.
    pub fn truth_map_where(
        &self,
        resolution: f64,
        start: Vec2,
        keep: impl Fn(&Segment) -> bool,
    ) -> OccupancyGrid {
        let margin = 2.0 * resolution;
        let (lo, hi) = self.wall_extent();
        let origin = Vec2::new(lo.x - margin, lo.y - margin);
        let w = (((hi.x - lo.x) + 2.0 * margin) / resolution).ceil() as usize + 1;
        let h = (((hi.y - lo.y) + 2.0 * margin) / resolution).ceil() as usize + 1;
        let mut grid = OccupancyGrid::new(w, h, resolution, [origin.x, origin.y, 0.0]);
        for s in self.segments.iter().filter(|s| keep(s)) {
            for_each_cell_on_segment(s.a, s.b, origin, resolution, w, h, |x, y| {
                grid.cells[y * w + x] = OCCUPIED;
            });
        }
        if let Some((sx, sy)) = grid.world_to_cell(start.x, start.y)
            && grid.cells[sy * w + sx] == UNKNOWN
        {
            let mut stack = vec![(sx, sy)];
            grid.cells[sy * w + sx] = FREE;
            while let Some((x, y)) = stack.pop() {
                let nbrs = [
                    (x.wrapping_sub(1), y),
                    (x + 1, y),
                    (x, y.wrapping_sub(1)),
                    (x, y + 1),
                ];
                for (nx, ny) in nbrs {
                    if nx < w && ny < h && grid.cells[ny * w + nx] == UNKNOWN {
                        grid.cells[ny * w + nx] = FREE;
                        stack.push((nx, ny));
                    }
                }
            }
        }
        grid
    }

    /// Bounding box of the wall end points.
    pub fn wall_extent(&self) -> (Vec2, Vec2) {
        (
            self.min + Vec2::new(INDEX_CELL_M, INDEX_CELL_M),
            self.max - Vec2::new(INDEX_CELL_M, INDEX_CELL_M),
        )
    }
}

/// Calls `f(cx, cy)` for every cell of a `cols × rows` grid (cell side
/// `cell`, lower-left corner `origin`) that the segment `a`–`b` passes
/// through, in order. Cells are 4-connected, so a rasterised wall never
/// leaks smoke or flood-fills diagonally.
pub fn for_each_cell_on_segment(
    a: Vec2,
    b: Vec2,
    origin: Vec2,
    cell: f64,
    cols: usize,
    rows: usize,
    mut f: impl FnMut(usize, usize),
) {
    let to_cell = |p: Vec2| {
        (
            ((p.x - origin.x) / cell).floor() as i64,
            ((p.y - origin.y) / cell).floor() as i64,
        )
    };
    let inside =
        |cx: i64, cy: i64| cx >= 0 && cy >= 0 && (cx as usize) < cols && (cy as usize) < rows;
    let (mut cx, mut cy) = to_cell(a);
    let (ex, ey) = to_cell(b);
    let d = b - a;
    let step_x: i64 = if d.x > 0.0 { 1 } else { -1 };
    let step_y: i64 = if d.y > 0.0 { 1 } else { -1 };
    let boundary = |c: i64, step: i64, lo: f64| lo + (c + (step > 0) as i64) as f64 * cell;
    let mut t_max_x = if d.x.abs() < 1e-15 {
        f64::INFINITY
    } else {
        (boundary(cx, step_x, origin.x) - a.x) / d.x
    };
    let mut t_max_y = if d.y.abs() < 1e-15 {
        f64::INFINITY
    } else {
        (boundary(cy, step_y, origin.y) - a.y) / d.y
    };
    let t_dx = if d.x.abs() < 1e-15 {
        f64::INFINITY
    } else {
        cell / d.x.abs()
    };
    let t_dy = if d.y.abs() < 1e-15 {
        f64::INFINITY
    } else {
        cell / d.y.abs()
    };
    // Bounded: a segment crosses at most |Δcx| + |Δcy| boundaries.
    let max_steps = (ex - cx).unsigned_abs() + (ey - cy).unsigned_abs() + 1;
    for _ in 0..max_steps {
        if inside(cx, cy) {
            f(cx as usize, cy as usize);
        }
        if (cx, cy) == (ex, ey) || (t_max_x > 1.0 && t_max_y > 1.0) {
            break;
        }
        if t_max_x < t_max_y {
            cx += step_x;
            t_max_x += t_dx;
        } else {
            cy += step_y;
            t_max_y += t_dy;
        }
    }
}

/// Where an arena comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum ArenaSource {
    Builtin(BuiltinArena),
    MapServer(PathBuf),
    Vector(PathBuf),
}

impl ArenaSource {
    pub fn load(&self) -> Result<Arena, SimError> {
        match self {
            ArenaSource::Builtin(b) => b.load(),
            ArenaSource::MapServer(p) => Arena::from_map_server(p),
            ArenaSource::Vector(p) => Arena::from_vector_file(p),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(side: f64) -> Arena {
        let text = format!(
            "[[wall]]\npoints = [[0, 0], [{side}, 0], [{side}, {side}], [0, {side}]]\nclosed = true\n"
        );
        Arena::from_vector_str(&text, Path::new("square.toml")).unwrap()
    }

    #[test]
    fn ray_from_inside_square_hits_the_facing_wall() {
        let a = square(4.0);
        let hit = a
            .cast(Vec2::new(1.0, 2.0), Vec2::new(1.0, 0.0), 10.0)
            .unwrap();
        assert!((hit.distance - 3.0).abs() < 1e-9, "{hit:?}");
        assert!(hit.normal.x.abs() > 0.999);
        let d = Vec2::from_angle(45f64.to_radians());
        let hit = a.cast(Vec2::new(1.0, 1.0), d, 10.0).unwrap();
        assert!((hit.distance - 3.0 * 2f64.sqrt()).abs() < 1e-9, "{hit:?}");
        assert_eq!(a.cast(Vec2::new(1.0, 2.0), Vec2::new(1.0, 0.0), 2.5), None);
    }

    #[test]
    fn grid_cast_matches_brute_force_on_every_direction() {
        let a = BuiltinArena::R32.load().unwrap();
        let o = Vec2::new(1.0, 1.0);
        for k in 0..3600 {
            let d = Vec2::from_angle(k as f64 * 0.1f64.to_radians());
            let brute = a
                .segments()
                .iter()
                .filter_map(|s| s.ray_hit(o, d))
                .fold(f64::INFINITY, f64::min);
            let got = a.cast(o, d, 100.0).map_or(f64::INFINITY, |h| h.distance);
            assert!(
                (brute - got).abs() < 1e-9,
                "beam {k}: brute {brute} grid {got}"
            );
        }
    }

    #[test]
    fn a_ray_at_one_height_passes_over_low_boxes_and_under_table_tops() {
        let text = r#"
            [[wall]]
            points = [[0.0, 0.0], [10.0, 0.0], [10.0, 4.0], [0.0, 4.0]]
            closed = true
            [[box]]
            center = [3.0, 2.0]
            size = [1.0, 1.0]
            height_m = [0.0, 0.2]
            [[box]]
            center = [6.0, 2.0]
            size = [1.0, 1.0]
            height_m = [0.45, 0.55]
        "#;
        let a = Arena::from_vector_str(text, Path::new("t.toml")).unwrap();
        let (o, d) = (Vec2::new(1.0, 2.0), Vec2::new(1.0, 0.0));
        let at = |z: f64| a.cast_at_height(o, d, 20.0, z).unwrap().distance;
        assert!((at(0.40) - 9.0).abs() < 1e-9, "laser plane: both passed");
        assert!((at(0.10) - 1.5).abs() < 1e-9, "crate height");
        assert!((at(0.50) - 4.5).abs() < 1e-9, "table-top height");
        // Without a height, every segment counts (the robot's collisions).
        assert!((a.cast(o, d, 20.0).unwrap().distance - 1.5).abs() < 1e-9);
        // The truth of one plane leaves the other obstacles out.
        let all = a.truth_map(0.1, o);
        let plane = a.truth_map_where(0.1, o, |s| s.spans(0.40));
        let (cx, cy) = all.world_to_cell(2.5, 2.0).unwrap();
        assert_eq!(all.get(cx, cy), Some(OCCUPIED));
        assert_eq!(plane.get(cx, cy), Some(FREE));
    }

    #[test]
    fn heights_must_be_ordered_and_non_negative() {
        let text = "[[box]]\ncenter = [1.0, 1.0]\nsize = [1.0, 1.0]\nheight_m = [0.5, 0.2]\n";
        let e = Arena::from_vector_str(text, Path::new("h.toml")).unwrap_err();
        assert!(e.to_string().contains("box[0].height_m"), "{e}");
    }

    #[test]
    fn clearance_is_the_distance_to_the_nearest_wall() {
        let a = square(4.0);
        assert!((a.clearance(Vec2::new(1.0, 2.0), 1.5) - 1.0).abs() < 1e-12);
        assert!(a.clearance(Vec2::new(2.0, 2.0), 0.5) >= 0.5);
    }

    #[test]
    fn builtin_arenas_have_the_seed_paper_dimensions() {
        for (arena, w, h) in [
            (BuiltinArena::Mrl, 4.57, 4.04),
            (BuiltinArena::R32, 13.63, 9.87),
        ] {
            let a = arena.load().unwrap();
            let (lo, hi) = a.wall_extent();
            assert!(
                (hi.x - lo.x - w).abs() < 1e-9 && (hi.y - lo.y - h).abs() < 1e-9,
                "{}",
                arena.name()
            );
        }
    }

    #[test]
    fn truth_map_marks_walls_and_reachable_free_space() {
        let a = square(2.0);
        let g = a.truth_map(0.1, Vec2::new(1.0, 1.0));
        let (x, y) = g.world_to_cell(1.0, 1.0).unwrap();
        assert_eq!(g.get(x, y), Some(FREE));
        let (x, y) = g.world_to_cell(0.0, 1.0).unwrap();
        assert_eq!(g.get(x, y), Some(OCCUPIED));
        let (x, y) = g.world_to_cell(-0.15, 1.0).unwrap();
        assert_eq!(
            g.get(x, y),
            Some(UNKNOWN),
            "outside the walls is not reachable"
        );
    }

    #[test]
    fn pixel_map_round_trips_into_walls_at_the_same_place() {
        let dir = tempfile::tempdir().unwrap();
        let truth = square(3.0).truth_map(0.05, Vec2::new(1.5, 1.5));
        let yaml = smokenav_platform_map::save_map_server(&truth, dir.path(), "sq").unwrap();
        let a = Arena::from_map_server(&yaml).unwrap();
        // The wall pixel column at x≈0 spans [-0.05, 0] or [0, 0.05]; from (1.5, 1.5) the
        // nearest face is within one pixel of 1.5 m.
        let hit = a
            .cast(Vec2::new(1.5, 1.5), Vec2::new(-1.0, 0.0), 10.0)
            .unwrap();
        assert!((hit.distance - 1.5).abs() <= 0.05 + 1e-9, "{hit:?}");
        assert!(
            hit.normal.x.abs() > 0.99,
            "straight wall keeps an axis normal: {hit:?}"
        );
        assert_eq!(a.truth_map(0.05, Vec2::new(1.5, 1.5)), truth);
    }

    #[test]
    fn traced_diagonal_wall_has_a_diagonal_normal() {
        let mut g = OccupancyGrid::new(40, 40, 0.05, [0.0, 0.0, 0.0]);
        for i in 0..40 {
            g.set(i, i, OCCUPIED);
            if i + 1 < 40 {
                g.set(i + 1, i, OCCUPIED);
            }
        }
        let a = Arena::from_grid(g, Path::new("diag")).unwrap();
        let d = Vec2::new(1.0, -1.0).normalized();
        let hit = a.cast(Vec2::new(0.5, 1.5), d, 5.0).unwrap();
        let cos = hit.normal.dot(d).abs();
        assert!(
            cos > 0.95,
            "incidence on a 45° staircase should be near normal, cos {cos}"
        );
    }

    #[test]
    fn vector_errors_name_file_and_key() {
        let e = Arena::from_vector_str("[[wall]]\npoints = [[0, 0]]\n", Path::new("bad.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("bad.toml") && e.contains("wall[0].points"),
            "{e}"
        );
        let e = Arena::from_vector_str("[[wal]]\n", Path::new("typo.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("typo.toml") && e.contains("wal"), "{e}");
        let e = Arena::from_vector_str(
            "[[wall]]\npoints = [[0, 0], [1e300, 0]]\n",
            Path::new("far.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("far.toml"), "{e}");
    }

    proptest::proptest! {
        #[test]
        fn arbitrary_vector_text_never_panics(text in "\\PC{0,300}") {
            let _ = Arena::from_vector_str(&text, Path::new("fuzz.toml"));
        }

        #[test]
        fn arbitrary_walls_never_panic(pts in proptest::collection::vec((-50.0f64..50.0, -50.0f64..50.0), 2..20)) {
            let body: Vec<String> = pts.iter().map(|(x, y)| format!("[{x}, {y}]")).collect();
            let text = format!("[[wall]]\npoints = [{}]\n", body.join(", "));
            if let Ok(a) = Arena::from_vector_str(&text, Path::new("fuzz.toml")) {
                for k in 0..36 {
                    let _ = a.cast(Vec2::new(0.0, 0.0), Vec2::from_angle(k as f64 * 0.17), 30.0);
                }
                let _ = a.truth_map(0.2, Vec2::new(0.0, 0.0));
            }
        }
    }
}
