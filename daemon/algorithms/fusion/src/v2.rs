//! SmokeNav v2: the fuzzy model of Algorithm 3 and Fig. 14 of SmokeNav
//! (Santos et al. 2015, §5.4), as implemented here, and the design choices
//! where the paper is ambiguous or silent.
//!
//! Every breakpoint is a key under `[fusion.v2]`; the keys, defaults and
//! accepted ranges are listed in `smokenav_platform_config::fusion`.
//!
//! ## Inputs and membership functions
//!
//! Inputs: the section's sonar reading s_R\[τ,t\], the smoke level a_R\[t\] and
//! the standard deviation σ(l_R\[t\]) of the scan's valid ranges.
//!
//! The breakpoints of Fig. 14 are not in the text. The paper's rationale is:
//! "the LRF readings can only be trusted when alcohol readings are below 20
//! or the standard deviation of the laser readings is above 0.8. If not, only
//! trust the sonar readings whenever it presents readings inferior to 2.5
//! meters". Each membership function therefore crosses 0.5 at the number the
//! rationale names:
//!
//! | set          | key                   | input             | Π breakpoints a, b, c, d           | μ = 0.5 at |
//! |--------------|-----------------------|-------------------|------------------------------------|------------|
//! | Confident    | `v2.confident`        | sonar range s, m  | 0.05, 0.15, 2.0, 3.0               | 2.5 m      |
//! | Alcoholized  | `v2.alcoholized`      | smoke level a     | 10, 30, inf, inf (rising shoulder) | 20         |
//! | Dense        | `v2.dense`            | laser σ, m        | 0, 0, 0.6, 1.0 (falling shoulder)  | 0.8 m      |
//!
//! A Π function ([`crate::fuzzy::pi`]) is 0 below `a`, rises along an
//! S-curve to 1 at `b`, stays 1 up to `c` and falls along a Z-curve to 0 at
//! `d`; `a = b` or `c = d` makes that side a step, `inf` leaves it open.
//!
//! ## The rule base, and where the paper is ambiguous
//!
//! - **The rule text contradicts the rationale.** Algorithm 3 reads "IF a is
//!   Alcoholized OR σ is Dense THEN ρL is Laser-driven", which would raise
//!   the trust in the laser when there is smoke. We follow the rationale
//!   (and the required behaviour: dense smoke ⇒ sonar, clean air ⇒ laser):
//!   the laser rule fires with
//!   `w_L = max(1 − μ_Alcoholized(a), 1 − μ_Dense(σ))` (the laser is trusted
//!   when the air is clean OR the scan is not uniform), and the ELSE-IF
//!   sonar rule with `w_S = min(1 − w_L, μ_Confident(s))`. With no usable
//!   smoke reading the laser rule uses σ alone.
//! - **One bell per output cannot express low trust.** With a single
//!   consequent term, the centroid of the clipped term stays near the middle
//!   of [0, 1] however weakly the rule fires. Each output therefore has the
//!   same generalised bell twice ("the same bell-shaped membership relation
//!   for softening both outputs", `v2.output_bell`): a *high* term centred at
//!   1 fired with `w` and a *low* term centred at 0 fired with `1 − w`,
//!   Mamdani min implication, max aggregation, centroid over
//!   `v2.defuzz_samples` points of [0, 1] ([`crate::fuzzy::Defuzzifier`]).
//!   ρ > 0.5 exactly when `w` > 0.5.
//! - **Decision.** Sonar when ρS > ρL and ρS > ρT; laser when ρL ≥ ρS and
//!   ρL > ρT; otherwise neither (beams marked beyond max range). The paper's
//!   formula uses a strict `>` against ρT = 1/2 (`v2.rho_threshold`); its
//!   prose says "equal or greater"; we use the formula.
//! - **Uncovered laser sections** (between sonar cones) follow ρL, and are
//!   dropped when a neighbouring section's laser was found contradicted.
//!
//! ## Beyond the paper: the sonar as a witness
//!
//! The smoke sensor sits on the robot, but the laser sees a smoke cloud
//! metres before the robot enters it: for seconds the scan is a phantom wall
//! while the smoke reading has barely risen, and a scan that is part phantom
//! and part real walls keeps a high spread, so the Dense test does not fire
//! either. Ultrasound is not scattered by smoke, and a sonar echoes from the
//! nearest surface in its cone, so laser ranges clearly nearer (by more than
//! `v2.contradiction_margin_m`) than the sonar's arc in that cone are
//! something the sonar cannot see. When the sonar heard nothing within its
//! cap, the arc is the cap's: beyond it a sonar misses weak and glancing
//! echoes, so its silence there proves nothing.
//!
//! Each section's laser rule is therefore
//! `w_L(τ) = min(w_L, max(1 − μ_Alcoholized(a), 1 − μ_Contradicted(c_τ)))`,
//! where c_τ is the share of the section's laser ranges nearer than its
//! sonar's arc (`v2.contradicted`: 0.1, 0.3, inf, inf); the sonar rule uses
//! w_L(τ). In clean air nothing changes (bit-identical output); in
//! alcoholized air a contradicted section goes to a confident sonar, or to
//! neither when the sonar heard nothing — conflicting sensors give
//! "unknown", as Bayesian occupancy fusion (Tran et al. 2021) requires of a
//! fusion rule. Single contradicted beams of a kept section are dropped.
//! `contradicted = { a = 2.0, b = 2.0, c = inf, d = inf }` (a share never
//! reached) turns the witness off.
//!
//! The witness also vouches. Smoke catches a beam short, in front of the
//! surface it was going to; a laser beam that lies no nearer than the
//! sonar's echo arc (within the margin) reached the sonar's nearest surface
//! or passed it, and was not caught. So in a section given to the sonar
//! such beams keep their laser range, marked `Both` per beam, and only the
//! contradicted ones get the arc (`v2.keep_uncontradicted_laser`, on; off,
//! the whole section is the arc, as in the paper). That also removes the
//! arc where the laser shows nothing there. SLAM maps `Both` beams but does
//! not scan-match them: through smoke they are a part view, and matching
//! part views slid the graph front end (seed 3 of the dense-smoke trial:
//! 0.070 → 0.113 m ATE when they were matched as laser).
//!
//! ## A silent smoke sensor
//!
//! Without a smoke reading the witness cannot be gated by the air, and
//! trusting the laser then is exactly the phantom wall the witness exists to
//! catch. The smoke sensor is *silent* when the synchronised set has no smoke
//! reading (the synchroniser heard nothing from it within its timeout,
//! `[fusion.sync]`), or the reading's own state is not `ready` (warming up,
//! disconnected, saturated). Then v2 assumes the worst it can still check:
//! the scan-wide rule uses σ alone, and every section's witness acts as in
//! fully alcoholized air (μ_Alcoholized = 1 in the section rule), so a
//! contradicted section goes to a confident sonar or to neither. A laser the
//! sonar agrees with is kept. The output says so when no reading came
//! (`SyncState::NoSmoke`); the fusion process's health says so in both
//! cases (`smoke_silent`, state degraded).

use crate::fuzzy::{Defuzzifier, pi};
use crate::geometry::SonarEcho;
use smokenav_platform_config::fusion::V2Params;
use smokenav_shared_types::SectionSource;

#[derive(Debug, Clone)]
pub struct FuzzyModel {
    params: V2Params,
    defuzz: Defuzzifier,
}

/// The scan-wide part of the inference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaserTrust {
    pub mu_alcoholized: f64,
    pub mu_dense: f64,
    /// Firing strength of the laser rule.
    pub w: f64,
    /// ρL.
    pub rho: f64,
}

impl FuzzyModel {
    pub fn new(params: V2Params) -> Self {
        let defuzz = Defuzzifier::new(&params.output_bell, params.defuzz_samples);
        Self { params, defuzz }
    }

    pub fn params(&self) -> &V2Params {
        &self.params
    }

    /// ρL from the smoke level (if the sensor is usable) and the scan's spread.
    pub fn laser_trust(&self, smoke_level: Option<f64>, spread: f64) -> LaserTrust {
        let mu_dense = pi(spread, &self.params.dense);
        let mu_alcoholized = smoke_level.map_or(0.0, |a| pi(a, &self.params.alcoholized));
        let w = match smoke_level {
            Some(_) => (1.0 - mu_alcoholized).max(1.0 - mu_dense),
            None => 1.0 - mu_dense,
        };
        LaserTrust {
            mu_alcoholized,
            mu_dense,
            w,
            rho: self.defuzz.rho(w),
        }
    }

    /// The laser rule of one section: the scan-wide strength, lowered where
    /// the smoke is in the air and the section's sonar contradicts the laser
    /// (`contradicted_share`: the share of the section's laser ranges nearer
    /// than the sonar's arc; `None` when the sonar gave nothing to compare).
    pub fn section_laser_trust(
        &self,
        scan: &LaserTrust,
        contradicted_share: Option<f64>,
    ) -> LaserTrust {
        self.section_laser_trust_in(scan, contradicted_share, scan.mu_alcoholized)
    }

    /// [`Self::section_laser_trust`] with the smoke the witness assumes:
    /// μ_Alcoholized of the reading, or 1 when the smoke sensor is silent.
    pub fn section_laser_trust_in(
        &self,
        scan: &LaserTrust,
        contradicted_share: Option<f64>,
        mu_alcoholized: f64,
    ) -> LaserTrust {
        let mu_c = contradicted_share.map_or(0.0, |c| pi(c, &self.params.contradicted));
        let w = scan.w.min((1.0 - mu_alcoholized).max(1.0 - mu_c));
        if w == scan.w {
            return *scan;
        }
        LaserTrust {
            w,
            rho: self.defuzz.rho(w),
            ..*scan
        }
    }

    /// ρS of one section, given the (section's) laser rule.
    pub fn sonar_trust(&self, laser: &LaserTrust, echo: SonarEcho, raw_range: f64) -> f64 {
        let s = match echo {
            SonarEcho::Echo(r) => r,
            // Saturated: its raw range (at or beyond the cap) is what the sonar said.
            SonarEcho::Saturated if raw_range.is_finite() => raw_range,
            SonarEcho::Saturated => f64::INFINITY,
            SonarEcho::Missing => return self.defuzz.rho(0.0),
        };
        let w = (1.0 - laser.w).min(pi(s, &self.params.confident));
        self.defuzz.rho(w)
    }

    /// Sonar if ρS > ρL and ρS > ρT; laser if ρL ≥ ρS and ρL > ρT; else neither.
    pub fn decide(&self, rho_sonar: f64, rho_laser: f64) -> SectionSource {
        let t = self.params.rho_threshold;
        if rho_sonar > rho_laser && rho_sonar > t {
            SectionSource::Sonar
        } else if rho_laser >= rho_sonar && rho_laser > t {
            SectionSource::Laser
        } else {
            SectionSource::Neither
        }
    }

    /// Beams no sonar covers follow the laser's trust.
    pub fn decide_gap(&self, laser: &LaserTrust) -> SectionSource {
        if laser.rho > self.params.rho_threshold {
            SectionSource::Laser
        } else {
            SectionSource::Neither
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> FuzzyModel {
        FuzzyModel::new(V2Params::default())
    }

    #[test]
    fn clean_air_trusts_the_laser() {
        // a = 0 (below 20): the laser rule fires fully whatever σ says.
        let m = model();
        let l = m.laser_trust(Some(0.0), 0.1);
        assert_eq!(l.w, 1.0);
        let s = m.sonar_trust(&l, SonarEcho::Echo(1.0), 1.0);
        assert_eq!(m.decide(s, l.rho), SectionSource::Laser);
    }

    #[test]
    fn dense_smoke_with_short_uniform_laser_prefers_a_confident_sonar() {
        // a = 250 (alcoholized), σ = 0.05 m (dense), sonar 1.2 m (< 2.5 m).
        let m = model();
        let l = m.laser_trust(Some(250.0), 0.05);
        assert!(l.w < 1e-12 && l.rho < 0.2);
        let s = m.sonar_trust(&l, SonarEcho::Echo(1.2), 1.2);
        assert!(s > 0.8);
        assert_eq!(m.decide(s, l.rho), SectionSource::Sonar);
    }

    #[test]
    fn smoke_with_a_far_sonar_trusts_neither() {
        // a = 250, σ = 0.05: laser out; sonar saturated at 5 m → not confident.
        let m = model();
        let l = m.laser_trust(Some(250.0), 0.05);
        let s = m.sonar_trust(&l, SonarEcho::Saturated, 5.0);
        assert!(s < 0.5 && l.rho < 0.5);
        assert_eq!(m.decide(s, l.rho), SectionSource::Neither);
        assert_eq!(m.decide_gap(&l), SectionSource::Neither);
    }

    #[test]
    fn high_alcohol_but_structured_scan_keeps_the_laser() {
        // The slow alcohol sensor still reads 250 but σ = 1.5 m: the laser sees
        // real structure again (σ > 0.8 in the paper's rationale).
        let m = model();
        let l = m.laser_trust(Some(250.0), 1.5);
        assert_eq!(l.w, 1.0);
        let s = m.sonar_trust(&l, SonarEcho::Echo(1.0), 1.0);
        assert_eq!(m.decide(s, l.rho), SectionSource::Laser);
    }

    #[test]
    fn without_a_smoke_reading_the_spread_alone_decides() {
        let m = model();
        let l = m.laser_trust(None, 0.05);
        let s = m.sonar_trust(&l, SonarEcho::Echo(1.0), 1.0);
        assert_eq!(m.decide(s, l.rho), SectionSource::Sonar);
        let l = m.laser_trust(None, 1.2);
        assert_eq!(m.decide_gap(&l), SectionSource::Laser);
    }

    #[test]
    fn a_contradicted_section_in_smoky_air_goes_to_the_sonar() {
        // Smoke 60 (alcoholized) but a structured scan (σ 1.2): the scan-wide
        // rule trusts the laser; the section whose laser ranges all lie well
        // inside the sonar's echo is the smoke front, not a wall.
        let m = model();
        let scan = m.laser_trust(Some(60.0), 1.2);
        assert_eq!(scan.w, 1.0);
        let sec = m.section_laser_trust(&scan, Some(0.9));
        assert!(sec.w < 1e-9 && sec.rho < 0.5);
        let s = m.sonar_trust(&sec, SonarEcho::Echo(2.0), 2.0);
        assert_eq!(m.decide(s, sec.rho), SectionSource::Sonar);
        // The sonar heard nothing within its cap: conflicting sensors, neither.
        let s = m.sonar_trust(&sec, SonarEcho::Saturated, 2.5);
        assert_eq!(m.decide(s, sec.rho), SectionSource::Neither);
        // A section the sonar agrees with keeps the laser.
        let ok = m.section_laser_trust(&scan, Some(0.05));
        assert_eq!(ok, scan);
    }

    #[test]
    fn in_clean_air_a_contradicting_sonar_changes_nothing() {
        // Sonars miss walls by specular reflection: without smoke the laser wins.
        let m = model();
        let scan = m.laser_trust(Some(2.0), 1.2);
        assert_eq!(m.section_laser_trust(&scan, Some(1.0)), scan);
        let scan = m.laser_trust(None, 1.2);
        assert_eq!(m.section_laser_trust(&scan, Some(1.0)), scan);
    }

    #[test]
    fn with_a_silent_smoke_sensor_the_witness_assumes_smoke() {
        // No reading: σ alone says the structured scan is fine, but a section
        // the sonar contradicts still goes to it.
        let m = model();
        let scan = m.laser_trust(None, 1.2);
        assert_eq!(scan.w, 1.0);
        let sec = m.section_laser_trust_in(&scan, Some(0.9), 1.0);
        assert!(sec.w < 1e-9 && sec.rho < 0.5);
        let s = m.sonar_trust(&sec, SonarEcho::Echo(2.0), 2.0);
        assert_eq!(m.decide(s, sec.rho), SectionSource::Sonar);
        // A section the sonar agrees with keeps the laser.
        assert_eq!(m.section_laser_trust_in(&scan, Some(0.05), 1.0), scan);
    }

    #[test]
    fn trust_changes_smoothly_around_the_breakpoints() {
        // σ crossing 0.8 m with dense smoke: ρL passes ρT = 0.5 there.
        let m = model();
        let below = m.laser_trust(Some(250.0), 0.79).rho;
        let above = m.laser_trust(Some(250.0), 0.81).rho;
        assert!(below < 0.5 && above > 0.5, "{below} {above}");
        assert!(above - below < 0.1);
    }
}
