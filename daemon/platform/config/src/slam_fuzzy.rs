//! `[slam.fuzzy]`: the fuzzy confidence model and the fuzzy-map registration
//! back-end (Hou et al. 2014, "Construction of Fuzzy Map for Autonomous Mobile
//! Robots Based on Fuzzy Confidence Model": a parabolic confidence along each beam for the range error, one
//! across it for the finite lateral resolution, local maps registered by
//! Cuckoo search).
//!
//! The defaults are the paper's preset: the Hokuyo URG-04LX's 0.36° angular
//! resolution and its ±10 mm (below 1 m) / ±1 % range error as the error
//! bound δr, and the paper's 6th-order polynomial fit of its confidence
//! K(r) as the peak confidence of a laser return. The polynomial is a fit over
//! the URG-04LX's 20–4095 mm and its printed coefficients go negative past
//! about 3.65 m, so beyond that the laser confidence holds at `laser_k_min`.
//! A sonar return's lateral bound is half its cone (the robot profile's
//! `[sonar] cone_deg` unless `sonar_cone_deg` is given). The search
//! parameters are smokenav's: the paper states none.

use crate::validate::{Validate, Validator};
use serde::{Deserialize, Serialize};

/// How a registration searches the motion between two local maps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum FuzzySearch {
    /// Cuckoo search (Yang & Deb 2009): Lévy flights, nest abandonment, seeded.
    #[default]
    #[serde(rename = "cuckoo")]
    Cuckoo,
    /// Exhaustive coarse-to-fine grid over the window (deterministic).
    #[serde(rename = "correlative")]
    Correlative,
}

/// What a new local map is registered to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum FuzzyReference {
    /// The previous local map (the paper's section 3: scan to scan).
    #[serde(rename = "previous")]
    Previous,
    /// The part of the global fuzzy map around the predicted pose (the
    /// paper's abstract: "selected parts of a developing global fuzzy map").
    #[default]
    #[serde(rename = "global")]
    Global,
}

/// `[slam.fuzzy]`: every key optional, unknown keys rejected.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FuzzySection {
    /// Lateral resolution bound δθ of a laser beam, degrees (URG-04LX: 0.36).
    pub laser_angular_resolution_deg: f64,
    /// Laser range error bound δr at short range, m (URG-04LX: ±10 mm below 1 m).
    pub laser_range_error_m: f64,
    /// … and as a share of the range beyond (URG-04LX: ±1 %): δr = max(m, share·r).
    pub laser_range_error_frac: f64,
    /// Peak laser confidence where the paper's K(r) fit falls below it (past ~3.65 m).
    pub laser_k_min: f64,
    /// A laser return in smoke is worth less: what it says of the obstacle
    /// and of the free space before it is divided by the smoke's variance
    /// ratio (the square of the σ multiplier of `[slam]`'s
    /// `laser_variance_*` / `smoke_level_*` model: 2.75 in fog), so nothing
    /// the laser saw in smoke reaches the combined map's 0.65. Off: the
    /// paper's clear-air model.
    pub laser_smoke_discount: bool,
    /// Peak confidence K of a sonar return.
    pub sonar_k: f64,
    /// Sonar range error bound δr, m …
    pub sonar_range_error_m: f64,
    /// … and as a share of the range: δr = max(m, share·r).
    pub sonar_range_error_frac: f64,
    /// Full sonar cone, degrees; unset: the robot profile's `[sonar] cone_deg`
    /// (15° when only a `[slam]` file is given).
    pub sonar_cone_deg: Option<f64>,
    /// The combined map's "unknown" level (the paper: 0.3).
    pub unknown_level: f64,
    /// Radius of a local map around the robot, m; longer readings only clear space up to it.
    pub local_radius_m: f64,
    /// Registration search: `cuckoo` or `correlative`.
    pub search: FuzzySearch,
    /// What a new local map is registered to: `global` or `previous`.
    pub reference: FuzzyReference,
    /// Translational search window around the predicted motion, ± m.
    pub window_m: f64,
    /// Rotational search window around the predicted motion, ± rad.
    pub window_rad: f64,
    /// Radius of the parabolic dilation of the reference map the overlap is measured on, m.
    pub match_radius_m: f64,
    /// At most this many occupied cells of the new local map are matched (evenly thinned).
    pub max_points: u32,
    /// Below this overlap (0–1) the registration is refused and the prediction kept.
    pub min_overlap: f64,
    /// Cuckoo search: nests (candidate motions).
    pub cuckoo_nests: u32,
    /// Cuckoo search: generations.
    pub cuckoo_generations: u32,
    /// Cuckoo search: share of nests abandoned per generation (p_a).
    pub cuckoo_abandon: f64,
    /// Cuckoo search: Lévy exponent β (Mantegna's algorithm), in (1, 2].
    pub cuckoo_levy_beta: f64,
    /// Cuckoo search: Lévy step scale α as a share of the window.
    pub cuckoo_alpha: f64,
    /// Correlative search: coarse translational step, m (the fine pass uses a quarter).
    pub correlative_step_m: f64,
    /// Correlative search: coarse rotational step, rad (the fine pass uses a quarter).
    pub correlative_step_rad: f64,
}

impl Default for FuzzySection {
    fn default() -> Self {
        Self {
            laser_angular_resolution_deg: 0.36,
            laser_range_error_m: 0.01,
            laser_range_error_frac: 0.01,
            laser_k_min: 0.2,
            laser_smoke_discount: true,
            sonar_k: 0.5,
            sonar_range_error_m: 0.02,
            sonar_range_error_frac: 0.01,
            sonar_cone_deg: None,
            unknown_level: 0.3,
            local_radius_m: 10.0,
            search: FuzzySearch::Cuckoo,
            reference: FuzzyReference::Global,
            window_m: 0.25,
            window_rad: 0.15,
            match_radius_m: 0.1,
            max_points: 500,
            min_overlap: 0.15,
            cuckoo_nests: 15,
            cuckoo_generations: 40,
            cuckoo_abandon: 0.25,
            cuckoo_levy_beta: 1.5,
            cuckoo_alpha: 0.05,
            correlative_step_m: 0.05,
            correlative_step_rad: 0.025,
        }
    }
}

impl FuzzySection {
    /// The sonar cone used, degrees.
    pub fn sonar_cone(&self) -> f64 {
        self.sonar_cone_deg.unwrap_or(15.0)
    }
}

impl Validate for FuzzySection {
    fn validate(&self, key: &str, v: &mut Validator) {
        let k = |name: &str| format!("{key}.{name}");
        v.within(
            &k("laser_angular_resolution_deg"),
            self.laser_angular_resolution_deg,
            0.01,
            10.0,
        );
        v.within(
            &k("laser_range_error_m"),
            self.laser_range_error_m,
            0.0001,
            1.0,
        );
        v.within(
            &k("laser_range_error_frac"),
            self.laser_range_error_frac,
            0.0,
            0.5,
        );
        v.within(&k("laser_k_min"), self.laser_k_min, 0.0, 1.0);
        v.within(&k("sonar_k"), self.sonar_k, 0.0, 1.0);
        v.within(
            &k("sonar_range_error_m"),
            self.sonar_range_error_m,
            0.0001,
            1.0,
        );
        v.within(
            &k("sonar_range_error_frac"),
            self.sonar_range_error_frac,
            0.0,
            0.5,
        );
        if let Some(c) = self.sonar_cone_deg {
            v.within(&k("sonar_cone_deg"), c, 1.0, 90.0);
        }
        v.within(&k("unknown_level"), self.unknown_level, 0.0, 1.0);
        v.within(&k("local_radius_m"), self.local_radius_m, 1.0, 50.0);
        v.within(&k("window_m"), self.window_m, 0.0, 5.0);
        v.within(&k("window_rad"), self.window_rad, 0.0, 1.6);
        v.within(&k("match_radius_m"), self.match_radius_m, 0.0, 1.0);
        if !(10..=100_000).contains(&self.max_points) {
            v.fail(
                k("max_points"),
                format!("must be 10–100000, got {}", self.max_points),
            );
        }
        v.within(&k("min_overlap"), self.min_overlap, 0.0, 1.0);
        if !(2..=1000).contains(&self.cuckoo_nests) {
            v.fail(
                k("cuckoo_nests"),
                format!("must be 2–1000, got {}", self.cuckoo_nests),
            );
        }
        if !(1..=10_000).contains(&self.cuckoo_generations) {
            v.fail(
                k("cuckoo_generations"),
                format!("must be 1–10000, got {}", self.cuckoo_generations),
            );
        }
        v.within(&k("cuckoo_abandon"), self.cuckoo_abandon, 0.0, 1.0);
        if !(self.cuckoo_levy_beta > 1.0 && self.cuckoo_levy_beta <= 2.0) {
            v.fail(
                k("cuckoo_levy_beta"),
                format!("must be within (1, 2], got {}", self.cuckoo_levy_beta),
            );
        }
        v.within(&k("cuckoo_alpha"), self.cuckoo_alpha, 0.0001, 1.0);
        v.within(
            &k("correlative_step_m"),
            self.correlative_step_m,
            0.001,
            1.0,
        );
        v.within(
            &k("correlative_step_rad"),
            self.correlative_step_rad,
            0.0005,
            0.5,
        );
    }
}
