//! Ground truth: the true pose over time and the true map, in the formats
//! `smokenav eval` reads (trajectories as `timestamp x y theta` lines, maps as
//! map_server YAML + PGM).

use crate::SimError;
use crate::geom::Pose2;
use smokenav_platform_map::OccupancyGrid;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The robot's true pose at `t_ns`, and the smoke it stood in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthSample {
    pub t_ns: u64,
    pub pose: Pose2,
    /// Smoke concentration at the robot, g/m³.
    pub smoke_gpm3: f64,
}

/// `timestamp x y theta` lines (s, m, m, rad), one per pose, with a header comment.
pub fn format_trajectory<'a>(poses: impl IntoIterator<Item = (u64, &'a Pose2)>) -> String {
    let mut s = String::from("# timestamp x y theta\n");
    for (t_ns, p) in poses {
        let _ = writeln!(
            s,
            "{:.6} {:.6} {:.6} {:.6}",
            t_ns as f64 * 1e-9,
            p.x,
            p.y,
            p.theta
        );
    }
    s
}

/// Writes a trajectory file (see [`format_trajectory`]).
pub fn write_trajectory<'a>(
    path: &Path,
    poses: impl IntoIterator<Item = (u64, &'a Pose2)>,
) -> Result<(), SimError> {
    std::fs::write(path, format_trajectory(poses)).map_err(|e| SimError::Io {
        path: path.to_owned(),
        source: e,
    })
}

/// Writes the map as `<dir>/<name>.yaml` + `.pgm` and returns the YAML path.
pub fn write_map(grid: &OccupancyGrid, dir: &Path, name: &str) -> Result<PathBuf, SimError> {
    Ok(smokenav_platform_map::save_map_server(grid, dir, name)?)
}
