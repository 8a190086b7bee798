//! `[slam.graph]`: the graph back-end's node spacing, loop-closure search and map.
//!
//! ```toml
//! [slam.graph]
//! closure_search_m = 4.0     # older nodes this close to the estimate are loop candidates
//! closure_window_m = 1.5     # the closure match searches ± this around the estimate …
//! closure_window_rad = 0.35  # … and ± this in heading
//! closure_min_score = 0.45   # below it a closure match is refused
//! sonar_behind_wall_m = 0.15 # sonar echoes further behind a laser-confirmed wall are left out of the map
//! ```
//!
//! The defaults are the ones measured on MIT CSAIL and the dense-smoke
//! trial (README, graph SLAM). A building whose loops come back with more
//! drift than the window leaves them open (slam_toolbox's complaint #692):
//! widen `closure_window_m` / `closure_window_rad` and `closure_search_m`
//! with it, at the price of look-alike places matched by mistake (every
//! closure still passes the score, rival, overlap and consistency checks,
//! and one that would move its node further than `closure_review_m` must
//! reach `closure_wide_min_score`).
//! Where its estimate is uncertain (a blind stretch in smoke, a long loop)
//! the back-end widens the search by itself (`closure_wide_*`).

use crate::validate::{Validate, Validator};
use serde::{Deserialize, Serialize};

/// `[slam.graph]`: every key optional, unknown keys rejected.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GraphSection {
    /// A scan becomes a node once the robot moved this far since the last node, m …
    pub node_distance_m: f64,
    /// … or turned this far, rad.
    pub node_angle_rad: f64,
    /// Older nodes within this distance of a new node's estimate are loop-closure candidates, m.
    pub closure_search_m: f64,
    /// Nodes between a candidate and the new node, at least (the recent chain is not a loop).
    pub closure_min_separation: u32,
    /// Separate stretches of the older trajectory tried per new node, nearest first.
    pub closure_candidates: u32,
    /// Translational window of a closure's match around the estimate, ± m.
    pub closure_window_m: f64,
    /// Rotational window of a closure's match around the estimate, ± rad.
    pub closure_window_rad: f64,
    /// Mean blurred-table value (0–1) a closure match must reach.
    pub closure_min_score: f64,
    /// A node whose scan the fusion withheld more than this share (0–1) of
    /// beams from the laser (smoke) searches for no closure.
    pub closure_max_withheld: f64,
    /// A node whose own search found nothing while its estimate is this many
    /// σ (of its marginal covariance) beyond the window
    /// searches again over ± that many σ; 0 turns it off. A wide match is
    /// only taken once a second node's agrees with it.
    pub closure_wide_sigmas: f64,
    /// Largest wide window, ± m …
    pub closure_wide_max_m: f64,
    /// … and ± rad.
    pub closure_wide_max_rad: f64,
    /// Score (0–1) a wide match must reach; so must any closure that moves
    /// its node further than `closure_review_m` / `closure_review_rad`.
    pub closure_wide_min_score: f64,
    /// A closure that moves its node further than this from its estimate,
    /// m, … stays under review for the next ten nodes: a later far match
    /// that contradicts it takes it out again (one such match can be a
    /// look-alike place, or a wall matched from its far side) …
    pub closure_review_m: f64,
    /// … or turns it further than this, rad.
    pub closure_review_rad: f64,
    /// The map leaves out a sonar echo that lies more than this behind a
    /// wall the laser drew (in the map's direction from the sonar), m; 0
    /// draws every echo. Such an echo was heard along another path (a sonar
    /// meeting a wall obliquely hears nothing from it) or placed by a pose
    /// the laser could not check.
    pub sonar_behind_wall_m: f64,
}

impl Default for GraphSection {
    fn default() -> Self {
        Self {
            node_distance_m: 0.3,
            node_angle_rad: 0.3,
            closure_search_m: 4.0,
            closure_min_separation: 15,
            closure_candidates: 5,
            closure_window_m: 1.5,
            closure_window_rad: 0.35,
            closure_min_score: 0.45,
            closure_max_withheld: 0.3,
            closure_wide_sigmas: 3.0,
            closure_wide_max_m: 4.0,
            closure_wide_max_rad: 0.7,
            closure_wide_min_score: 0.5,
            closure_review_m: 0.3,
            closure_review_rad: 0.1,
            sonar_behind_wall_m: 0.15,
        }
    }
}

impl Validate for GraphSection {
    fn validate(&self, key: &str, v: &mut Validator) {
        let k = |name: &str| format!("{key}.{name}");
        v.within(&k("node_distance_m"), self.node_distance_m, 0.01, 10.0);
        v.within(&k("node_angle_rad"), self.node_angle_rad, 0.01, 3.2);
        // 0 turns loop closure off.
        v.within(&k("closure_search_m"), self.closure_search_m, 0.0, 100.0);
        if !(1..=100_000).contains(&self.closure_min_separation) {
            v.fail(
                k("closure_min_separation"),
                format!("must be 1–100000, got {}", self.closure_min_separation),
            );
        }
        if !(1..=100).contains(&self.closure_candidates) {
            v.fail(
                k("closure_candidates"),
                format!("must be 1–100, got {}", self.closure_candidates),
            );
        }
        // The branch and bound's work grows with the window's area.
        v.within(&k("closure_window_m"), self.closure_window_m, 0.0, 10.0);
        v.within(&k("closure_window_rad"), self.closure_window_rad, 0.0, 3.2);
        v.within(&k("closure_min_score"), self.closure_min_score, 0.0, 1.0);
        v.within(
            &k("closure_wide_sigmas"),
            self.closure_wide_sigmas,
            0.0,
            10.0,
        );
        v.within(&k("closure_wide_max_m"), self.closure_wide_max_m, 0.0, 10.0);
        v.within(
            &k("closure_wide_max_rad"),
            self.closure_wide_max_rad,
            0.0,
            3.2,
        );
        v.within(
            &k("closure_wide_min_score"),
            self.closure_wide_min_score,
            0.0,
            1.0,
        );
        // 100 m and 3.2 rad: no closure is ever reviewed (before 2026-12-06).
        v.within(&k("closure_review_m"), self.closure_review_m, 0.0, 100.0);
        v.within(&k("closure_review_rad"), self.closure_review_rad, 0.0, 3.2);
        v.within(
            &k("sonar_behind_wall_m"),
            self.sonar_behind_wall_m,
            0.0,
            10.0,
        );
        v.within(
            &k("closure_max_withheld"),
            self.closure_max_withheld,
            0.0,
            1.0,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::parse_toml;
    use crate::slam::SlamSection;
    use std::path::Path;

    #[test]
    fn keys_override_the_defaults_and_the_rest_stay() {
        let s = parse_toml::<SlamSection>(
            "backend = \"graph\"\n[graph]\nclosure_window_m = 3.0\nclosure_search_m = 8.0\n",
            Path::new("slam.toml"),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(s.graph.closure_window_m, 3.0);
        assert_eq!(s.graph.closure_search_m, 8.0);
        assert_eq!(
            s.graph.closure_min_score,
            GraphSection::default().closure_min_score
        );
        let mut v = Validator::default();
        s.validate("slam", &mut v);
        assert!(v.issues.is_empty(), "{:?}", v.issues);
    }

    #[test]
    fn an_unknown_key_and_a_value_out_of_range_are_named() {
        let err =
            parse_toml::<SlamSection>("[graph]\nclosure_radius_m = 3.0\n", Path::new("slam.toml"))
                .unwrap_err()
                .to_string();
        assert!(err.contains("closure_radius_m"), "{err}");
        assert!(err.contains("slam.toml"), "{err}");
        let s = parse_toml::<SlamSection>(
            "[graph]\nclosure_window_m = 40.0\nclosure_min_score = 1.5\n",
            Path::new("slam.toml"),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let mut v = Validator::default();
        s.validate("slam", &mut v);
        let issues = format!("{:?}", v.issues);
        assert!(issues.contains("slam.graph.closure_window_m"), "{issues}");
        assert!(issues.contains("slam.graph.closure_min_score"), "{issues}");
    }
}
