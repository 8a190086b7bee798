//! Accuracy of maps and trajectories against ground truth (the simulator's,
//! or a surveyed one): the k-nearest-neighbour map error of SmokeNav (Santos et
//! al. 2015) in both directions, the pixel error of SLAMfusion (Fernandes &
//! Alexandre), ATE/RPE for trajectories, and, with no reference at all, how
//! well scans placed at a trajectory's poses agree with each other; and the
//! relations metric against a published relations file (Kümmerle et al. 2009).
//! Pure functions over loaded data plus loaders whose errors name the file;
//! `smokenav eval` is the command-line front end.

pub mod consistency;
pub mod map;
pub mod nn;
pub mod relations;
pub mod trajectory;

pub use consistency::{ConsistencyOptions, ScanConsistency, scan_consistency};
pub use map::{
    Alignment, Band, DistanceStats, ErrorBands, ErrorClass, ErrorPicture, FarGroup, MapMetricError,
    MapOptions, MapReport, error_picture, evaluate_maps,
};
pub use relations::{
    Relation, RelationsError, RelationsMetricError, RelationsReport, evaluate_relations,
    load_relations, parse_relations,
};
pub use trajectory::{
    ErrorStats, FileReadError, LineError, MeanStd, Pairing, StampedPose, TrajectoryError,
    TrajectoryFormat, TrajectoryMetricError, TrajectoryOptions, TrajectoryReport,
    evaluate_trajectories, format_trajectory, format_trajectory_as, load_trajectory,
    parse_trajectory, truth_at,
};

use std::path::{Path, PathBuf};

/// Anything that can go wrong evaluating files; every variant names the file(s).
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error(transparent)]
    Map(#[from] smokenav_platform_map::MapError),
    #[error(transparent)]
    Trajectory(#[from] TrajectoryError),
    #[error("{}: {source}", path.display())]
    MapMetric {
        path: PathBuf,
        source: MapMetricError,
    },
    #[error("{} vs {}: {source}", estimate.display(), truth.display())]
    TrajectoryMetric {
        truth: PathBuf,
        estimate: PathBuf,
        source: TrajectoryMetricError,
    },
}

/// Loads two map_server maps and compares them.
pub fn evaluate_map_files(
    truth: &Path,
    estimate: &Path,
    opts: &MapOptions,
) -> Result<MapReport, EvalError> {
    let t = smokenav_platform_map::load_map_server(truth)?;
    let e = smokenav_platform_map::load_map_server(estimate)?;
    evaluate_maps(&t, &e, opts).map_err(|source| {
        // Name the file the problem is in.
        let path = match &source {
            MapMetricError::NoWalls { which, .. }
            | MapMetricError::Geometry { which, .. }
            | MapMetricError::TooManyWalls { which, .. }
                if *which == "estimated" =>
            {
                estimate.to_owned()
            }
            MapMetricError::Incomparable { .. } => estimate.to_owned(),
            _ => truth.to_owned(),
        };
        EvalError::MapMetric { path, source }
    })
}

/// Loads two trajectory files and compares them.
pub fn evaluate_trajectory_files(
    truth: &Path,
    estimate: &Path,
    opts: &TrajectoryOptions,
) -> Result<TrajectoryReport, EvalError> {
    let t = load_trajectory(truth)?;
    let e = load_trajectory(estimate)?;
    evaluate_trajectories(&t, &e, opts).map_err(|source| EvalError::TrajectoryMetric {
        truth: truth.to_owned(),
        estimate: estimate.to_owned(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_platform_map::{OCCUPIED, OccupancyGrid, save_map_server};

    fn walls() -> OccupancyGrid {
        let mut g = OccupancyGrid::new(40, 30, 0.05, [0.0, 0.0, 0.0]);
        for x in 0..40 {
            g.set(x, 0, OCCUPIED);
            g.set(x, 29, OCCUPIED);
        }
        for y in 0..30 {
            g.set(0, y, OCCUPIED);
            g.set(39, y, OCCUPIED);
        }
        g
    }

    #[test]
    fn map_files_round_trip_to_zero_error() {
        let dir = tempfile::tempdir().unwrap();
        let gt = save_map_server(&walls(), dir.path(), "gt").unwrap();
        let est = save_map_server(&walls(), dir.path(), "est").unwrap();
        let r = evaluate_map_files(&gt, &est, &MapOptions::default()).unwrap();
        assert_eq!(r.knn_error_m, 0.0);
    }

    #[test]
    fn bad_files_give_errors_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let gt = save_map_server(&walls(), dir.path(), "gt").unwrap();
        // Missing estimate.
        let missing = dir.path().join("nope.yaml");
        let e = evaluate_map_files(&gt, &missing, &MapOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("nope.yaml"), "{e}");
        // YAML that is not a map.
        let junk = dir.path().join("junk.yaml");
        std::fs::write(&junk, "hello: [").unwrap();
        let e = evaluate_map_files(&junk, &gt, &MapOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("junk.yaml"), "{e}");
        // Image that is not a PGM.
        let est = save_map_server(&walls(), dir.path(), "broken").unwrap();
        std::fs::write(dir.path().join("broken.pgm"), b"P5\n40 30\n255\n\x00").unwrap();
        let e = evaluate_map_files(&gt, &est, &MapOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("broken.pgm"), "{e}");
        // A map without walls.
        let empty = save_map_server(
            &OccupancyGrid::new(5, 5, 0.05, [0.0; 3]),
            dir.path(),
            "empty",
        )
        .unwrap();
        let e = evaluate_map_files(&gt, &empty, &MapOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("empty.yaml") && e.contains("no occupied cells"),
            "{e}"
        );
        // Trajectories.
        let t = dir.path().join("t.txt");
        std::fs::write(&t, "0 0 0 0\n1 1 0 0\n").unwrap();
        let bad = dir.path().join("e.txt");
        std::fs::write(&bad, "0 0 0 0\nzero 1 0 0\n").unwrap();
        let e = evaluate_trajectory_files(&t, &bad, &TrajectoryOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("e.txt:2"), "{e}");
        let far = dir.path().join("far.txt");
        std::fs::write(&far, "50 0 0 0\n51 1 0 0\n").unwrap();
        let e = evaluate_trajectory_files(&t, &far, &TrajectoryOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("far.txt") && e.contains("t.txt"), "{e}");
        let e = evaluate_trajectory_files(
            &dir.path().join("none.txt"),
            &t,
            &TrajectoryOptions::default(),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("none.txt"), "{e}");
    }
}
