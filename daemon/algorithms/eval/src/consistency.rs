//! How well scans placed at a trajectory's poses agree with each other, with
//! no reference at all: the better the poses, the more the endpoints of
//! different passes over the same wall fall on one line. It is how two
//! trajectories can be compared when the only "reference" is another SLAM
//! system's estimate (MIT CSAIL's corrected poses are GMapping's): the one
//! whose map is crisper is the more self-consistent, whichever is closer to
//! the other.

use crate::map::DistanceStats;
use crate::nn::PointIndex;
use std::collections::HashSet;

/// What the consistency measure compares.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConsistencyOptions {
    /// Cell side for counting the cells the endpoints fall in, m.
    pub cell_m: f64,
    /// Scans closer than this in the sequence are the same pass (their
    /// overlap says nothing about drift) and are not compared.
    pub min_separation: usize,
    /// An endpoint with no other pass's endpoint within this is not seen
    /// twice (a wall seen once) and is left out of the distances, m.
    pub max_distance_m: f64,
}

impl Default for ConsistencyOptions {
    fn default() -> Self {
        Self {
            cell_m: 0.05,
            min_separation: 10,
            max_distance_m: 0.5,
        }
    }
}

/// The consistency of a set of placed scans.
#[derive(Debug, Clone, PartialEq)]
pub struct ScanConsistency {
    pub scans: usize,
    pub endpoints: usize,
    /// Distinct cells of `cell_m` holding an endpoint: fewer is crisper.
    pub cells: usize,
    /// Distance of each endpoint to the nearest endpoint of another pass
    /// (within `max_distance_m`).
    pub nearest: DistanceStats,
    /// Share of the endpoints that had another pass's endpoint within `max_distance_m`.
    pub seen_again: f64,
}

/// The consistency of `scans`, each a scan's endpoints in the map frame, in
/// the order they were taken.
pub fn scan_consistency(scans: &[Vec<(f64, f64)>], o: &ConsistencyOptions) -> ScanConsistency {
    let cell = if o.cell_m.is_finite() && o.cell_m > 0.0 {
        o.cell_m
    } else {
        ConsistencyOptions::default().cell_m
    };
    let mut points = Vec::new();
    let mut scan_of = Vec::new();
    let mut cells = HashSet::new();
    for (i, scan) in scans.iter().enumerate() {
        for &(x, y) in scan.iter().filter(|p| p.0.is_finite() && p.1.is_finite()) {
            points.push((x, y));
            scan_of.push(i);
            cells.insert(((x / cell).floor() as i64, (y / cell).floor() as i64));
        }
    }
    let endpoints = points.len();
    let index = PointIndex::new(points.clone(), o.max_distance_m.max(cell));
    let distances: Vec<f64> = points
        .iter()
        .zip(&scan_of)
        .filter_map(|(&(x, y), &i)| {
            index.nearest_where(x, y, o.max_distance_m, |j| {
                scan_of[j].abs_diff(i) >= o.min_separation.max(1)
            })
        })
        .collect();
    ScanConsistency {
        scans: scans.len(),
        endpoints,
        cells: cells.len(),
        seen_again: distances.len() as f64 / endpoints.max(1) as f64,
        nearest: DistanceStats::from_distances(distances),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A wall along y = 0 seen by `n` passes, pass k shifted across it by `offset(k)`.
    fn passes(n: usize, offset: impl Fn(usize) -> f64) -> Vec<Vec<(f64, f64)>> {
        (0..n)
            .map(|k| {
                (0..100)
                    .map(|i| (i as f64 * 0.05 + 0.025, offset(k) + 0.01))
                    .collect()
            })
            .collect()
    }

    #[test]
    fn passes_that_agree_score_better_than_passes_that_drifted() {
        let o = ConsistencyOptions {
            min_separation: 1,
            ..ConsistencyOptions::default()
        };
        let agree = scan_consistency(&passes(3, |_| 0.0), &o);
        let drifted = scan_consistency(&passes(3, |k| k as f64 * 0.08), &o);
        assert_eq!(agree.endpoints, 300);
        assert_eq!(agree.cells, 100);
        assert!(agree.nearest.mean_m < 1e-9, "{agree:?}");
        assert!((agree.seen_again - 1.0).abs() < 1e-12);
        // Passes 0.08 m apart: each endpoint is 0.08 m from the next pass.
        assert_eq!(drifted.cells, 300);
        assert!(
            (drifted.nearest.median_m - 0.08).abs() < 1e-9,
            "{drifted:?}"
        );
    }

    #[test]
    fn scans_of_one_pass_are_not_compared_with_each_other() {
        // Consecutive scans of the same wall: with a separation of 10, there
        // is no other pass, so nothing is seen again.
        let c = scan_consistency(&passes(5, |_| 0.0), &ConsistencyOptions::default());
        assert_eq!(c.seen_again, 0.0);
        assert_eq!(c.nearest.count, 0);
        // The 11th scan is another pass of the 1st.
        let c = scan_consistency(
            &passes(11, |k| if k == 10 { 0.02 } else { 0.0 }),
            &ConsistencyOptions::default(),
        );
        assert_eq!(c.nearest.count, 200);
        assert!((c.nearest.median_m - 0.02).abs() < 1e-9, "{c:?}");
    }

    #[test]
    fn a_far_pass_and_bad_values_are_left_out() {
        let mut scans = passes(2, |k| k as f64 * 2.0);
        scans[1].push((f64::NAN, 0.0));
        let c = scan_consistency(
            &scans,
            &ConsistencyOptions {
                min_separation: 1,
                ..ConsistencyOptions::default()
            },
        );
        assert_eq!(c.endpoints, 200);
        assert_eq!(c.nearest.count, 0);
        assert_eq!(
            scan_consistency(&[], &ConsistencyOptions::default()).endpoints,
            0
        );
    }
}
