//! Occupancy grids and the ROS `map_server` map format.
//!
//! A map is a YAML file naming an image (PGM or PNG) plus resolution, origin
//! and thresholds, exactly as nav2's `map_io` reads it, so maps made here open
//! in ROS tools and maps from ROS users load here. Cells follow
//! `nav_msgs/OccupancyGrid`: row-major from the lower-left corner, -1 unknown,
//! 0 free … 100 occupied. Input files are distrusted: sizes are capped and
//! every error names the file.

use serde::{Deserialize, Serialize};
use std::fs;
use std::path::{Path, PathBuf};

/// Largest grid accepted from a file, in cells (a 1 km × 1 km map at 5 cm is 400 M; we cap lower
/// because a robot's map never needs that and a crafted header must not exhaust memory).
pub const MAX_CELLS: usize = 64 * 1024 * 1024;
/// Largest map YAML read, bytes (a real one is a few hundred).
pub const MAX_YAML_BYTES: u64 = 64 * 1024;
/// Largest image file read, bytes (a raw PGM of [`MAX_CELLS`] cells plus its header).
pub const MAX_IMAGE_BYTES: u64 = MAX_CELLS as u64 + 4096;
/// Coarsest cell accepted, m: beyond this a "map" is a typo (`1e300`) whose
/// extent overflows every computation made on it.
pub const MAX_RESOLUTION_M: f64 = 1000.0;
/// Farthest origin accepted, m from the map frame's origin in x and y.
pub const MAX_ORIGIN_M: f64 = 1e7;

pub const UNKNOWN: i8 = -1;
pub const FREE: i8 = 0;
pub const OCCUPIED: i8 = 100;

/// Farthest apart two consecutive positions of a trajectory are taken as
/// driven in a straight line by [`OccupancyGrid::clear_footprint`], m.
pub const MAX_FOOTPRINT_SWEEP_M: f64 = 0.5;

#[derive(Debug, thiserror::Error)]
pub enum MapError {
    #[error("{path}: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("{path}: invalid map YAML: {reason}")]
    Yaml { path: PathBuf, reason: String },
    #[error("{path}: key `{key}`: {reason}")]
    BadValue {
        path: PathBuf,
        key: &'static str,
        reason: String,
    },
    #[error("{path}: cannot read image: {reason}")]
    Image { path: PathBuf, reason: String },
    #[error("{path}: {width}×{height} cells exceeds the limit of {MAX_CELLS}")]
    TooLarge {
        path: PathBuf,
        width: u64,
        height: u64,
    },
    /// A FIFO, device or directory where a map file was expected: reading it could block forever.
    #[error("{path}: not a regular file")]
    NotAFile { path: PathBuf },
    #[error("{path}: {bytes} bytes exceeds the limit of {limit} for this file")]
    FileTooLarge {
        path: PathBuf,
        bytes: u64,
        limit: u64,
    },
    #[error("grid has {cells} cells but width×height is {expected}")]
    Shape { cells: usize, expected: usize },
}

/// An occupancy grid in the map frame.
#[derive(Debug, Clone, PartialEq)]
pub struct OccupancyGrid {
    /// Cell edge, m.
    pub resolution: f64,
    pub width: usize,
    pub height: usize,
    /// Pose (x, y, yaw) of the lower-left corner of cell (0, 0).
    pub origin: [f64; 3],
    /// Row-major from the lower-left corner: `cells[y * width + x]`.
    pub cells: Vec<i8>,
}

impl OccupancyGrid {
    pub fn new(width: usize, height: usize, resolution: f64, origin: [f64; 3]) -> Self {
        Self {
            resolution,
            width,
            height,
            origin,
            cells: vec![UNKNOWN; width * height],
        }
    }

    pub fn get(&self, x: usize, y: usize) -> Option<i8> {
        (x < self.width && y < self.height).then(|| self.cells[y * self.width + x])
    }

    pub fn set(&mut self, x: usize, y: usize, v: i8) {
        if x < self.width && y < self.height {
            self.cells[y * self.width + x] = v;
        }
    }

    /// Centre of cell (x, y) in the map frame (origin yaw ignored, as map_server does for most tools).
    pub fn cell_center(&self, x: usize, y: usize) -> (f64, f64) {
        (
            self.origin[0] + (x as f64 + 0.5) * self.resolution,
            self.origin[1] + (y as f64 + 0.5) * self.resolution,
        )
    }

    /// The cell containing the world point, if inside the grid.
    pub fn world_to_cell(&self, wx: f64, wy: f64) -> Option<(usize, usize)> {
        let x = ((wx - self.origin[0]) / self.resolution).floor();
        let y = ((wy - self.origin[1]) / self.resolution).floor();
        (x >= 0.0 && y >= 0.0 && (x as usize) < self.width && (y as usize) < self.height)
            .then_some((x as usize, y as usize))
    }

    /// Marks free every cell whose centre lies within `radius` (m) of the
    /// path through `positions` (map frame, in the order driven): the robot's
    /// body swept it, so nothing stood there. Consecutive positions up to
    /// [`MAX_FOOTPRINT_SWEEP_M`] apart are joined by the straight segment
    /// between them; farther apart (a jump: a reset, a relocalisation) only
    /// the positions themselves are cleared. Returns how many of the cleared
    /// cells read `threshold` (0..100) or more before.
    pub fn clear_footprint(
        &mut self,
        positions: impl IntoIterator<Item = (f64, f64)>,
        radius: f64,
        threshold: i8,
    ) -> usize {
        let usable = radius > 0.0 && radius.is_finite() && self.resolution > 0.0;
        if !usable || self.cells.len() != self.width * self.height {
            return 0;
        }
        let step = 0.5 * self.resolution;
        let mut cleared = 0;
        let mut last: Option<(f64, f64)> = None;
        for (px, py) in positions {
            if !(px.is_finite() && py.is_finite()) {
                continue;
            }
            let Some((lx, ly)) = last else {
                cleared += self.clear_disc(px, py, radius, threshold);
                last = Some((px, py));
                continue;
            };
            let d = (px - lx).hypot(py - ly);
            if d < step {
                // Standing still: nothing new under the robot.
                continue;
            }
            let n = if d <= MAX_FOOTPRINT_SWEEP_M {
                (d / step).ceil() as usize
            } else {
                1
            };
            for i in 1..=n {
                let t = i as f64 / n as f64;
                cleared +=
                    self.clear_disc(lx + t * (px - lx), ly + t * (py - ly), radius, threshold);
            }
            last = Some((px, py));
        }
        cleared
    }

    /// [`Self::clear_footprint`] at one position.
    fn clear_disc(&mut self, px: f64, py: f64, radius: f64, threshold: i8) -> usize {
        let res = self.resolution;
        let cx = ((px - self.origin[0]) / res).floor();
        let cy = ((py - self.origin[1]) / res).floor();
        let reach = (radius / res).ceil() + 1.0;
        let (x0, x1) = (
            (cx - reach).max(0.0),
            (cx + reach).min(self.width as f64 - 1.0),
        );
        let (y0, y1) = (
            (cy - reach).max(0.0),
            (cy + reach).min(self.height as f64 - 1.0),
        );
        if x0 > x1 || y0 > y1 {
            return 0;
        }
        let mut cleared = 0;
        for y in y0 as usize..=y1 as usize {
            for x in x0 as usize..=x1 as usize {
                let (wx, wy) = self.cell_center(x, y);
                if (wx - px).powi(2) + (wy - py).powi(2) <= radius * radius {
                    let c = &mut self.cells[y * self.width + x];
                    cleared += usize::from(*c >= threshold);
                    *c = FREE;
                }
            }
        }
        cleared
    }

    /// Centres of the cells whose occupancy is at least `threshold` (0..100).
    pub fn occupied_points(&self, threshold: i8) -> Vec<(f64, f64)> {
        let mut out = Vec::new();
        for y in 0..self.height {
            for x in 0..self.width {
                if self.cells[y * self.width + x] >= threshold {
                    out.push(self.cell_center(x, y));
                }
            }
        }
        out
    }

    fn check_shape(&self) -> Result<(), MapError> {
        let expected = self.width * self.height;
        if self.cells.len() != expected {
            return Err(MapError::Shape {
                cells: self.cells.len(),
                expected,
            });
        }
        Ok(())
    }

    /// Grey image, top row first: free white, occupied black, unknown grey (map_server trinary colours).
    pub fn to_gray_image(&self) -> image::GrayImage {
        image::GrayImage::from_fn(self.width as u32, self.height as u32, |x, y| {
            let row = self.height - 1 - y as usize;
            image::Luma([cell_to_trinary_pixel(
                self.cells[row * self.width + x as usize],
            )])
        })
    }

    /// Writes a PNG picture of the grid.
    pub fn save_png(&self, path: &Path) -> Result<(), MapError> {
        self.check_shape()?;
        self.to_gray_image()
            .save(path)
            .map_err(|e| MapError::Image {
                path: path.to_owned(),
                reason: e.to_string(),
            })
    }
}

fn cell_to_trinary_pixel(c: i8) -> u8 {
    match c {
        c if c < 0 => 205,
        c if c >= 65 => 0,
        c if c <= 19 => 254,
        // In between: a proportional grey, as map_saver writes in scale mode.
        c => (254.0 - c as f64 * 2.54).round() as u8,
    }
}

/// The YAML side of a map_server map.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapYaml {
    pub image: String,
    pub resolution: f64,
    pub origin: Vec<f64>,
    #[serde(default)]
    pub negate: Negate,
    pub occupied_thresh: f64,
    pub free_thresh: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mode: Option<String>,
}

/// `negate`: read as a bool or 0/1 (nav2 takes both), written as 0 or 1,
/// because ROS 1's `map_server` reads it as an integer and rejects `false`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Negate(pub bool);

impl Serialize for Negate {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_u8(self.0 as u8)
    }
}

impl<'de> Deserialize<'de> for Negate {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum B {
            Bool(bool),
            Int(i64),
        }
        Ok(Negate(match B::deserialize(d)? {
            B::Bool(b) => b,
            B::Int(i) => i != 0,
        }))
    }
}

/// The `mode` of a map_server map: how image pixels become cells.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum MapMode {
    /// Free, occupied or unknown (PGM; what nav2's `map_saver` writes by default).
    #[default]
    Trinary,
    /// Occupancy as a grey level, unknown transparent (PNG with alpha).
    Scale,
    /// The cell value itself as the pixel, 255 unknown (PGM).
    Raw,
}

impl MapMode {
    pub fn as_str(self) -> &'static str {
        match self {
            MapMode::Trinary => "trinary",
            MapMode::Scale => "scale",
            MapMode::Raw => "raw",
        }
    }
}

/// `occupied_thresh` written into saved maps (nav2's and ROS 1's default).
pub const OCCUPIED_THRESH: f64 = 0.65;
/// `free_thresh` written into saved maps (ROS 1's default; nav2's is 0.25). With
/// 0.196 the trinary grey 205 reads back as unknown, 254 as free.
pub const FREE_THRESH: f64 = 0.196;

/// A probability cell (0..100, -1 unknown) as nav2 would read it back from a
/// trinary map saved with [`OCCUPIED_THRESH`] and [`FREE_THRESH`]: 100, 0 or -1.
pub fn trinary_cell(c: i8) -> i8 {
    match c {
        c if !(0..=OCCUPIED).contains(&c) => UNKNOWN,
        c if c >= 65 => OCCUPIED,
        c if c <= 19 => FREE,
        _ => UNKNOWN,
    }
}

/// Writes the cells of `grid` thresholded by [`trinary_cell`] into `out`
/// (reusing its allocation): what nav2's static layer expects on a map topic.
pub fn trinary_cells_into(grid: &OccupancyGrid, out: &mut Vec<i8>) {
    out.clear();
    out.extend(grid.cells.iter().map(|&c| trinary_cell(c)));
}

fn trinary_save_pixel(c: i8) -> u8 {
    match trinary_cell(c) {
        OCCUPIED => 0,
        FREE => 254,
        _ => 205,
    }
}

/// Writes `<dir>/<name>.pgm` and `<dir>/<name>.yaml` (trinary mode, as `map_saver` does)
/// and returns the YAML path.
pub fn save_map_server(grid: &OccupancyGrid, dir: &Path, name: &str) -> Result<PathBuf, MapError> {
    save_map_server_mode(grid, dir, name, MapMode::Trinary)
}

/// File stem of a saved fuzzy confidence map (`fuzzy.pgm`, `fuzzy.yaml`, `fuzzy.png`).
pub const FUZZY_NAME: &str = "fuzzy";

/// Writes a fuzzy back-end's combined confidence map (0–100, -1 unknown) as
/// `fuzzy.pgm` + `fuzzy.yaml` in raw mode — the pixel is the confidence, so
/// nothing is thresholded away — and `fuzzy.png` to look at; returns the YAML path.
pub fn save_fuzzy(grid: &OccupancyGrid, dir: &Path) -> Result<PathBuf, MapError> {
    let yaml = save_map_server_mode(grid, dir, FUZZY_NAME, MapMode::Raw)?;
    grid.save_png(&dir.join(format!("{FUZZY_NAME}.png")))?;
    Ok(yaml)
}

/// Writes `<dir>/<name>.{pgm|png}` and `<dir>/<name>.yaml` in `mode` the way nav2's
/// `map_saver` does (`negate: 0`, thresholds [`OCCUPIED_THRESH`]/[`FREE_THRESH`]) and
/// returns the YAML path. Scale mode needs transparency for unknown cells, so it
/// writes a PNG; the others write a binary PGM.
pub fn save_map_server_mode(
    grid: &OccupancyGrid,
    dir: &Path,
    name: &str,
    mode: MapMode,
) -> Result<PathBuf, MapError> {
    grid.check_shape()?;
    fs::create_dir_all(dir).map_err(|e| MapError::Io {
        path: dir.to_owned(),
        error: e,
    })?;
    let image_name = match mode {
        MapMode::Scale => format!("{name}.png"),
        MapMode::Trinary | MapMode::Raw => format!("{name}.pgm"),
    };
    let image_path = dir.join(&image_name);
    let yaml = dir.join(format!("{name}.yaml"));
    // Image rows run top to bottom; grid rows bottom to top.
    let top_down =
        |x: u32, y: u32| grid.cells[(grid.height - 1 - y as usize) * grid.width + x as usize];
    match mode {
        MapMode::Trinary | MapMode::Raw => {
            let mut bytes =
                format!("P5\n# smokenav map\n{} {}\n255\n", grid.width, grid.height).into_bytes();
            bytes.reserve(grid.cells.len());
            for y in 0..grid.height as u32 {
                for x in 0..grid.width as u32 {
                    let c = top_down(x, y);
                    bytes.push(match mode {
                        MapMode::Raw if (0..=OCCUPIED).contains(&c) => c as u8,
                        MapMode::Raw => 255,
                        _ => trinary_save_pixel(c),
                    });
                }
            }
            fs::write(&image_path, bytes).map_err(|e| MapError::Io {
                path: image_path.clone(),
                error: e,
            })?;
        }
        MapMode::Scale => {
            let img =
                image::GrayAlphaImage::from_fn(grid.width as u32, grid.height as u32, |x, y| {
                    match top_down(x, y) {
                        c if (0..=OCCUPIED).contains(&c) => {
                            image::LumaA([((100 - c as i32) as f64 * 2.55).round() as u8, 255])
                        }
                        _ => image::LumaA([128, 0]),
                    }
                });
            img.save(&image_path).map_err(|e| MapError::Image {
                path: image_path.clone(),
                reason: e.to_string(),
            })?;
        }
    }
    let meta = MapYaml {
        image: image_name,
        resolution: grid.resolution,
        origin: grid.origin.to_vec(),
        negate: Negate(false),
        occupied_thresh: OCCUPIED_THRESH,
        free_thresh: FREE_THRESH,
        mode: Some(mode.as_str().into()),
    };
    let text = serde_yaml_ng::to_string(&meta).map_err(|e| MapError::Yaml {
        path: yaml.clone(),
        reason: e.to_string(),
    })?;
    fs::write(&yaml, text).map_err(|e| MapError::Io {
        path: yaml.clone(),
        error: e,
    })?;
    Ok(yaml)
}

/// Checks that `path` is a regular file of at most `limit` bytes before it is
/// opened: opening a FIFO blocks until a writer comes, and a device never ends.
fn check_file(path: &Path, limit: u64) -> Result<(), MapError> {
    let meta = fs::metadata(path).map_err(|e| MapError::Io {
        path: path.to_owned(),
        error: e,
    })?;
    if !meta.is_file() {
        return Err(MapError::NotAFile {
            path: path.to_owned(),
        });
    }
    if meta.len() > limit {
        return Err(MapError::FileTooLarge {
            path: path.to_owned(),
            bytes: meta.len(),
            limit,
        });
    }
    Ok(())
}

/// Loads a map_server map the way nav2's `map_io` interprets it.
pub fn load_map_server(yaml_path: &Path) -> Result<OccupancyGrid, MapError> {
    check_file(yaml_path, MAX_YAML_BYTES)?;
    let text = fs::read_to_string(yaml_path).map_err(|e| MapError::Io {
        path: yaml_path.to_owned(),
        error: e,
    })?;
    let meta: MapYaml = serde_yaml_ng::from_str(&text).map_err(|e| MapError::Yaml {
        path: yaml_path.to_owned(),
        reason: e.to_string(),
    })?;
    let bad = |key: &'static str, reason: String| MapError::BadValue {
        path: yaml_path.to_owned(),
        key,
        reason,
    };
    if !(meta.resolution.is_finite()
        && meta.resolution > 0.0
        && meta.resolution <= MAX_RESOLUTION_M)
    {
        return Err(bad(
            "resolution",
            format!(
                "must be > 0 and at most {MAX_RESOLUTION_M} m, got {:?}",
                meta.resolution
            ),
        ));
    }
    if meta.origin.len() != 3
        || meta.origin.iter().any(|v| !v.is_finite())
        || meta.origin[..2].iter().any(|v| v.abs() > MAX_ORIGIN_M)
    {
        return Err(bad(
            "origin",
            format!(
                "must be [x, y, yaw] with finite numbers, |x| and |y| at most {MAX_ORIGIN_M} m"
            ),
        ));
    }
    for (key, v) in [
        ("occupied_thresh", meta.occupied_thresh),
        ("free_thresh", meta.free_thresh),
    ] {
        if !(0.0..=1.0).contains(&v) {
            return Err(bad(key, format!("must be within [0, 1], got {v}")));
        }
    }
    let mode = meta.mode.as_deref().unwrap_or("trinary");
    if !matches!(mode, "trinary" | "scale" | "raw") {
        return Err(bad(
            "mode",
            format!("expected trinary, scale or raw, got {mode:?}"),
        ));
    }
    let image_path = yaml_path
        .parent()
        .unwrap_or_else(|| Path::new("."))
        .join(&meta.image);
    check_file(&image_path, MAX_IMAGE_BYTES)?;
    let reader = image::ImageReader::open(&image_path)
        .and_then(|r| r.with_guessed_format())
        .map_err(|e| MapError::Io {
            path: image_path.clone(),
            error: e,
        })?;
    let (w, h) = reader.into_dimensions().map_err(|e| MapError::Image {
        path: image_path.clone(),
        reason: e.to_string(),
    })?;
    if (w as u64) * (h as u64) > MAX_CELLS as u64 {
        return Err(MapError::TooLarge {
            path: image_path,
            width: w as u64,
            height: h as u64,
        });
    }
    let img = image::ImageReader::open(&image_path)
        .and_then(|r| r.with_guessed_format())
        .map_err(|e| MapError::Io {
            path: image_path.clone(),
            error: e,
        })?
        .decode()
        .map_err(|e| MapError::Image {
            path: image_path.clone(),
            reason: e.to_string(),
        })?;
    // nav2 averages alpha in (trinary) only when the image has an alpha channel.
    let has_alpha = img.color().has_alpha();
    let img = img.to_rgba8();
    let (w, h) = (w as usize, h as usize);
    let mut grid = OccupancyGrid::new(
        w,
        h,
        meta.resolution,
        [meta.origin[0], meta.origin[1], meta.origin[2]],
    );
    for y in 0..h {
        for x in 0..w {
            let [r, g, b, a] = img.get_pixel(x as u32, y as u32).0;
            let rgb = r as f64 + g as f64 + b as f64;
            let cell = &mut grid.cells[(h - 1 - y) * w + x];
            // nav2: shade in [0, 1] is the mean of the channels; occ = 1 - shade unless negated.
            let shade = if mode == "trinary" && has_alpha {
                (rgb + a as f64) / 4.0 / 255.0
            } else {
                rgb / 3.0 / 255.0
            };
            if mode == "raw" {
                // The pixel is the value: 0..100 kept, anything else (255) unknown.
                let v = (shade * 255.0).round();
                *cell = if (0.0..=100.0).contains(&v) {
                    v as i8
                } else {
                    UNKNOWN
                };
                continue;
            }
            let occ = if meta.negate.0 { shade } else { 1.0 - shade };
            *cell = if mode == "scale" && a < 255 {
                UNKNOWN
            } else if occ > meta.occupied_thresh {
                OCCUPIED
            } else if occ < meta.free_thresh {
                FREE
            } else if mode == "trinary" {
                UNKNOWN
            } else {
                let ratio = (occ - meta.free_thresh) / (meta.occupied_thresh - meta.free_thresh);
                (1.0 + 98.0 * ratio).round() as i8
            };
        }
    }
    Ok(grid)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> OccupancyGrid {
        let mut g = OccupancyGrid::new(7, 5, 0.05, [-1.0, -0.5, 0.0]);
        for x in 0..7 {
            g.set(x, 0, OCCUPIED);
            g.set(x, 1, FREE);
        }
        g.set(3, 4, OCCUPIED);
        g
    }

    #[test]
    fn map_server_round_trip_keeps_cells_and_origin() {
        let dir = tempfile::tempdir().unwrap();
        let g = sample();
        let yaml = save_map_server(&g, dir.path(), "map").unwrap();
        let back = load_map_server(&yaml).unwrap();
        assert_eq!(back, g);
        assert_eq!(back.world_to_cell(-1.0 + 0.16, -0.5 + 0.01), Some((3, 0)));
    }

    /// A 4 m × 2 m grid at 5 cm, every cell a wall, origin (0, 0).
    fn walls() -> OccupancyGrid {
        let mut g = OccupancyGrid::new(80, 40, 0.05, [0.0, 0.0, 0.0]);
        g.cells.fill(OCCUPIED);
        g
    }

    #[test]
    fn the_footprint_clears_the_cells_the_robot_swept_and_nothing_else() {
        let mut g = walls();
        // Driven along y = 1 from x = 0.5 to 3.5 in 0.1 m steps, with a pause.
        let mut path: Vec<(f64, f64)> = (5..=35).map(|i| (0.1 * f64::from(i), 1.0)).collect();
        path.insert(10, path[9]);
        let cleared = g.clear_footprint(path.iter().copied(), 0.2, 65);
        for y in 0..g.height {
            for x in 0..g.width {
                let (wx, wy) = g.cell_center(x, y);
                // Distance from the cell centre to the segment driven.
                let d = (wy - 1.0).abs().hypot((0.5 - wx).max(wx - 3.5).max(0.0));
                let v = g.get(x, y).unwrap();
                if d <= 0.2 - 1e-9 {
                    assert_eq!(v, FREE, "({wx}, {wy}) lies under the robot");
                } else if d > 0.2 + 1e-9 {
                    assert_eq!(v, OCCUPIED, "({wx}, {wy}) lies {d} m off the path");
                }
            }
        }
        let free = g.cells.iter().filter(|&&v| v == FREE).count();
        assert_eq!(cleared, free, "every cleared cell was a wall");
        // A second pass finds nothing left to clear.
        assert_eq!(g.clear_footprint(path.iter().copied(), 0.2, 65), 0);
    }

    #[test]
    fn the_footprint_does_not_sweep_across_a_jump() {
        let mut g = walls();
        // A relocalisation from (0.5, 0.5) to (3.5, 1.5): two discs, no corridor between.
        g.clear_footprint([(0.5, 0.5), (3.5, 1.5)], 0.15, 65);
        assert_eq!(g.get(40, 20), Some(OCCUPIED), "the middle was never driven");
        assert_eq!(g.get(10, 10), Some(FREE));
        assert_eq!(g.get(70, 30), Some(FREE));
        // 0.4 m apart is a step: swept.
        let mut g = walls();
        g.clear_footprint([(1.0, 1.0), (1.4, 1.0)], 0.1, 65);
        assert_eq!(g.get(24, 20), Some(FREE));
    }

    #[test]
    fn the_footprint_ignores_bad_input() {
        let mut g = walls();
        let path = [
            (f64::NAN, 1.0),
            (1.0, f64::INFINITY),
            (-50.0, -50.0),
            (90.0, 1.0),
        ];
        assert_eq!(g.clear_footprint(path, 0.2, 65), 0);
        assert_eq!(g.clear_footprint([(1.0, 1.0)], 0.0, 65), 0);
        assert_eq!(g.clear_footprint([(1.0, 1.0)], f64::NAN, 65), 0);
        assert!(g.cells.iter().all(|&v| v == OCCUPIED));
        // Unknown and faint cells under the robot become free but are not counted as walls.
        g.cells.fill(UNKNOWN);
        g.set(20, 20, 40);
        assert_eq!(g.clear_footprint([(1.0, 1.0)], 0.1, 65), 0);
        assert_eq!(g.get(20, 20), Some(FREE));
    }

    /// A grid with every value: unknown, free, occupied and probabilities in between.
    fn graded() -> OccupancyGrid {
        let mut g = OccupancyGrid::new(17, 7, 0.05, [-1.0, -0.5, 0.0]);
        for (i, c) in g.cells.iter_mut().enumerate() {
            *c = (i as i32 % 102 - 1) as i8;
        }
        g
    }

    #[test]
    fn raw_mode_keeps_every_value_and_reads_255_as_unknown() {
        let dir = tempfile::tempdir().unwrap();
        let g = graded();
        let yaml = save_map_server_mode(&g, dir.path(), "m", MapMode::Raw).unwrap();
        let back = load_map_server(&yaml).unwrap();
        assert_eq!(back, g);
        assert!(back.cells.contains(&UNKNOWN));
        assert!(back.cells.iter().all(|&c| (-1..=100).contains(&c)));
    }

    #[test]
    fn trinary_mode_reads_back_as_the_published_thresholding() {
        let dir = tempfile::tempdir().unwrap();
        let g = graded();
        let yaml = save_map_server(&g, dir.path(), "m").unwrap();
        let back = load_map_server(&yaml).unwrap();
        let mut expected = Vec::new();
        trinary_cells_into(&g, &mut expected);
        assert_eq!(back.cells, expected);
        assert!(back.cells.iter().all(|c| [-1, 0, 100].contains(c)));
    }

    #[test]
    fn scale_mode_keeps_unknown_free_and_occupied() {
        let dir = tempfile::tempdir().unwrap();
        let g = graded();
        let yaml = save_map_server_mode(&g, dir.path(), "m", MapMode::Scale).unwrap();
        assert!(dir.path().join("m.png").exists());
        let back = load_map_server(&yaml).unwrap();
        for (&c, &b) in g.cells.iter().zip(&back.cells) {
            match c {
                -1 => assert_eq!(b, UNKNOWN),
                // 8-bit grey quantises the threshold: 65 may land either side of 0.65.
                65 => assert!(
                    b == OCCUPIED || (1..=99).contains(&b),
                    "65 read back as {b}"
                ),
                c if c >= 66 => assert_eq!(b, OCCUPIED, "{c}"),
                c if c <= 19 => assert_eq!(b, FREE, "{c}"),
                c => assert!((1..=99).contains(&b), "{c} read back as {b}"),
            }
        }
    }

    #[test]
    fn negate_is_written_as_zero_and_read_as_bool_or_int() {
        let dir = tempfile::tempdir().unwrap();
        let yaml = save_map_server(&sample(), dir.path(), "m").unwrap();
        let text = fs::read_to_string(&yaml).unwrap();
        assert!(text.contains("negate: 0\n"), "{text}");
        for negate in ["false", "1", "true"] {
            fs::write(
                &yaml,
                text.replace("negate: 0", &format!("negate: {negate}")),
            )
            .unwrap();
            let g = load_map_server(&yaml).unwrap();
            let inverted = negate != "false";
            assert_eq!(g.get(0, 0), Some(if inverted { FREE } else { OCCUPIED }));
        }
    }

    #[test]
    fn unknown_yaml_key_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let yaml = save_map_server(&sample(), dir.path(), "m").unwrap();
        let text = fs::read_to_string(&yaml).unwrap() + "bogus: 1\n";
        fs::write(&yaml, text).unwrap();
        let err = load_map_server(&yaml).unwrap_err().to_string();
        assert!(err.contains("bogus") && err.contains("m.yaml"), "{err}");
    }

    #[test]
    fn negative_resolution_is_rejected_with_key() {
        let dir = tempfile::tempdir().unwrap();
        let yaml = save_map_server(&sample(), dir.path(), "m").unwrap();
        let text = fs::read_to_string(&yaml)
            .unwrap()
            .replace("resolution: 0.05", "resolution: -1");
        fs::write(&yaml, text).unwrap();
        let err = load_map_server(&yaml).unwrap_err().to_string();
        assert!(err.contains("resolution"), "{err}");
    }

    #[test]
    fn absurd_resolution_and_origin_are_rejected_with_key() {
        let dir = tempfile::tempdir().unwrap();
        let yaml = save_map_server(&sample(), dir.path(), "m").unwrap();
        let good = fs::read_to_string(&yaml).unwrap();
        fs::write(&yaml, good.replace("resolution: 0.05", "resolution: 1e300")).unwrap();
        let err = load_map_server(&yaml).unwrap_err().to_string();
        assert!(
            err.contains("`resolution`") && err.contains("1e300"),
            "{err}"
        );
        let far = good.replace("- -1.0\n", "- -1.0e12\n");
        assert_ne!(far, good);
        fs::write(&yaml, far).unwrap();
        let err = load_map_server(&yaml).unwrap_err().to_string();
        assert!(err.contains("`origin`"), "{err}");
    }

    #[test]
    fn a_fifo_as_image_or_yaml_is_refused_without_blocking() {
        let dir = tempfile::tempdir().unwrap();
        let yaml = save_map_server(&sample(), dir.path(), "m").unwrap();
        let pgm = dir.path().join("m.pgm");
        fs::remove_file(&pgm).unwrap();
        nix::unistd::mkfifo(&pgm, nix::sys::stat::Mode::S_IRWXU).unwrap();
        // Opening a FIFO for reading blocks until a writer comes: this test
        // would hang, not fail, if the loader opened it.
        let err = load_map_server(&yaml).unwrap_err();
        assert!(matches!(err, MapError::NotAFile { .. }), "{err}");
        assert!(err.to_string().contains("m.pgm"), "{err}");
        let fifo_yaml = dir.path().join("fifo.yaml");
        nix::unistd::mkfifo(&fifo_yaml, nix::sys::stat::Mode::S_IRWXU).unwrap();
        let err = load_map_server(&fifo_yaml).unwrap_err();
        assert!(matches!(err, MapError::NotAFile { .. }), "{err}");
    }

    #[test]
    fn an_oversized_yaml_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let yaml = save_map_server(&sample(), dir.path(), "m").unwrap();
        let mut text = fs::read_to_string(&yaml).unwrap();
        text.push_str(&"#".repeat(MAX_YAML_BYTES as usize));
        fs::write(&yaml, text).unwrap();
        let err = load_map_server(&yaml).unwrap_err();
        assert!(matches!(err, MapError::FileTooLarge { .. }), "{err}");
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(400))]

        /// Any YAML text next to a valid image: a grid or a typed error, never a panic.
        #[test]
        fn mutated_yaml_gives_a_grid_or_an_error(
            cut in 0usize..200,
            insert in "\\PC{0,12}",
            at in 0usize..200,
        ) {
            let dir = tempfile::tempdir().unwrap();
            let yaml = save_map_server(&sample(), dir.path(), "m").unwrap();
            let good = fs::read_to_string(&yaml).unwrap();
            let mut chars: Vec<char> = good.chars().collect();
            let at = at.min(chars.len());
            let cut = cut.min(chars.len() - at).min(8);
            chars.splice(at..at + cut, insert.chars());
            fs::write(&yaml, chars.into_iter().collect::<String>()).unwrap();
            if let Ok(g) = load_map_server(&yaml) {
                proptest::prop_assert_eq!(g.cells.len(), g.width * g.height);
                proptest::prop_assert!(g.resolution > 0.0 && g.resolution <= MAX_RESOLUTION_M);
            }
        }

        /// Any bytes changed in the image: a grid of the header's size or an error.
        #[test]
        fn mutated_image_gives_a_grid_or_an_error(
            edits in proptest::collection::vec((0usize..64, proptest::num::u8::ANY), 1..8),
            truncate in proptest::option::of(0usize..64),
        ) {
            let dir = tempfile::tempdir().unwrap();
            let yaml = save_map_server(&sample(), dir.path(), "m").unwrap();
            let pgm = dir.path().join("m.pgm");
            let mut bytes = fs::read(&pgm).unwrap();
            for (i, b) in edits {
                let i = i % bytes.len();
                bytes[i] = b;
            }
            if let Some(n) = truncate {
                bytes.truncate(n);
            }
            fs::write(&pgm, &bytes).unwrap();
            if let Ok(g) = load_map_server(&yaml) {
                proptest::prop_assert_eq!(g.cells.len(), g.width * g.height);
                proptest::prop_assert!(g.width * g.height <= MAX_CELLS);
            }
        }
    }

    #[test]
    fn truncated_image_is_an_error_not_a_panic() {
        let dir = tempfile::tempdir().unwrap();
        let yaml = save_map_server(&sample(), dir.path(), "m").unwrap();
        fs::write(dir.path().join("m.pgm"), b"P5\n7 5\n255\n\x00\x01").unwrap();
        assert!(load_map_server(&yaml).is_err());
    }
}
