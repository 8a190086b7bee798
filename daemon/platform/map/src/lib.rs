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
    #[serde(default, deserialize_with = "bool_or_int")]
    pub negate: bool,
    pub occupied_thresh: f64,
    pub free_thresh: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mode: Option<String>,
}

fn bool_or_int<'de, D: serde::Deserializer<'de>>(d: D) -> Result<bool, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum B {
        Bool(bool),
        Int(i64),
    }
    Ok(match B::deserialize(d)? {
        B::Bool(b) => b,
        B::Int(i) => i != 0,
    })
}

/// Writes `<dir>/<name>.pgm` and `<dir>/<name>.yaml` (trinary mode, as `map_saver` does)
/// and returns the YAML path.
pub fn save_map_server(grid: &OccupancyGrid, dir: &Path, name: &str) -> Result<PathBuf, MapError> {
    grid.check_shape()?;
    fs::create_dir_all(dir).map_err(|e| MapError::Io {
        path: dir.to_owned(),
        error: e,
    })?;
    let pgm = dir.join(format!("{name}.pgm"));
    let yaml = dir.join(format!("{name}.yaml"));
    let mut bytes =
        format!("P5\n# smokenav map\n{} {}\n255\n", grid.width, grid.height).into_bytes();
    bytes.extend_from_slice(grid.to_gray_image().as_raw());
    fs::write(&pgm, bytes).map_err(|e| MapError::Io {
        path: pgm.clone(),
        error: e,
    })?;
    let meta = MapYaml {
        image: format!("{name}.pgm"),
        resolution: grid.resolution,
        origin: grid.origin.to_vec(),
        negate: false,
        occupied_thresh: 0.65,
        free_thresh: 0.196,
        mode: Some("trinary".into()),
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
        })?
        .to_luma_alpha8();
    let (w, h) = (w as usize, h as usize);
    let mut grid = OccupancyGrid::new(
        w,
        h,
        meta.resolution,
        [meta.origin[0], meta.origin[1], meta.origin[2]],
    );
    for y in 0..h {
        for x in 0..w {
            let p = img.get_pixel(x as u32, y as u32);
            let (lum, alpha) = (p.0[0] as f64, p.0[1] as f64);
            let cell = &mut grid.cells[(h - 1 - y) * w + x];
            if mode == "raw" {
                *cell = lum.min(100.0) as i8;
                continue;
            }
            // nav2: trinary averages alpha in; shade in [0,1]; occ = 1 - shade unless negated.
            let shade = if mode == "trinary" && alpha < 255.0 {
                (lum + alpha) / 2.0 / 255.0
            } else {
                lum / 255.0
            };
            let occ = if meta.negate { shade } else { 1.0 - shade };
            *cell = if occ > meta.occupied_thresh {
                OCCUPIED
            } else if occ < meta.free_thresh {
                FREE
            } else if mode == "trinary" || alpha < 1.0 {
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
