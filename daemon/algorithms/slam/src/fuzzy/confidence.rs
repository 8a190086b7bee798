//! The fuzzy confidence model of a range reading (Hou et al. 2014, eqs. 1–4).
//!
//! A reading (ρ, φ) says "obstacle near ρ along φ" with a confidence that
//! falls parabolically with the distance to ρ (the range error bound δr,
//! eq. 1) and with the angle to φ (the finite lateral resolution δθ, eq. 2),
//! and "free space before it" with the complementary profile (eq. 3).

use crate::scan::BeamKind;
use smokenav_platform_config::FuzzySection;

/// The paper's parabola: 1 at 0, 0 at and beyond ±`bound` (eq. 1 without K₀).
pub fn parabola(offset: f64, bound: f64) -> f64 {
    if bound <= 0.0 {
        return 0.0;
    }
    let u = offset / bound;
    if u.abs() <= 1.0 { 1.0 - u * u } else { 0.0 }
}

/// Eq. 1: confidence of an obstacle at range `r` given reading `rho`.
pub fn range_confidence(k0: f64, r: f64, rho: f64, dr: f64) -> f64 {
    k0 * parabola(r - rho, dr)
}

/// Eq. 2, B_ρ,φ(r, θ): confidence that an obstacle is at (r, θ).
pub fn occupied(k: f64, r: f64, theta: f64, rho: f64, phi: f64, dr: f64, dtheta: f64) -> f64 {
    k * parabola(r - rho, dr) * parabola(theta - phi, dtheta)
}

/// Eq. 3, P_ρ,φ(r, θ): confidence that (r, θ) is free space. Full before
/// ρ − δr, rising from 0 at ρ to 1 at ρ − δr, nothing behind ρ; times the
/// lateral profile.
pub fn free(r: f64, theta: f64, rho: f64, phi: f64, dr: f64, dtheta: f64) -> f64 {
    let lateral = parabola(theta - phi, dtheta);
    if lateral == 0.0 || r > rho || r < 0.0 {
        return 0.0;
    }
    if r < rho - dr {
        lateral
    } else {
        let u = (r - rho) / dr;
        u * u * lateral
    }
}

/// Eq. 4: the paper's 6th-order fit of the URG-04LX's confidence over range
/// (`r` in mm), as printed. Meaningful over 20–4095 mm only; it goes
/// negative past about 3.65 m.
pub fn urg04lx_k(r_mm: f64) -> f64 {
    const C: [f64; 7] = [
        4.70e-21, -5.96e-17, 2.82e-13, -5.96e-10, 4.56e-7, -1.12e-4, 0.76,
    ];
    C.iter().fold(0.0, |acc, c| acc * r_mm + c)
}

/// Eq. 7: the map for people and path design, min(max(u, Mo), 1 − Ms) with u
/// the "unknown" level (0.3 in the paper).
pub fn combined(mo: f64, ms: f64, unknown: f64) -> f64 {
    mo.max(unknown).min(1.0 - ms)
}

/// The model's parameters per beam kind (`[slam.fuzzy]`).
#[derive(Debug, Clone, PartialEq)]
pub struct ConfidenceModel {
    pub laser_dtheta: f64,
    pub laser_dr_m: f64,
    pub laser_dr_frac: f64,
    pub laser_k_min: f64,
    pub laser_smoke_discount: bool,
    pub sonar_k: f64,
    pub sonar_dr_m: f64,
    pub sonar_dr_frac: f64,
    /// Half the sonar cone, rad.
    pub sonar_half_cone: f64,
    pub unknown: f64,
}

impl Default for ConfidenceModel {
    fn default() -> Self {
        Self::from_config(&FuzzySection::default())
    }
}

impl ConfidenceModel {
    pub fn from_config(c: &FuzzySection) -> Self {
        Self {
            laser_dtheta: c.laser_angular_resolution_deg.to_radians(),
            laser_dr_m: c.laser_range_error_m,
            laser_dr_frac: c.laser_range_error_frac,
            laser_k_min: c.laser_k_min,
            laser_smoke_discount: c.laser_smoke_discount,
            sonar_k: c.sonar_k,
            sonar_dr_m: c.sonar_range_error_m,
            sonar_dr_frac: c.sonar_range_error_frac,
            sonar_half_cone: (c.sonar_cone() / 2.0).to_radians(),
            unknown: c.unknown_level,
        }
    }

    /// What a laser return is worth at the scan's smoke noise factor `f` (the
    /// σ multiplier of `[slam]`'s smoke model, ≥ 1): 1 ÷ f², the reading's
    /// information relative to clear air (the inverse of its variance ratio:
    /// 0.36 in fog), scaling both its obstacle and its free-space
    /// confidence; 1 with the discount off. Both, so the share of one
    /// reading's evidence that says "obstacle" is the same, while the
    /// combined map of eq. 7 is less sure of what a laser saw in smoke: a
    /// phantom there stays weak. (1 ÷ f, the σ ratio, left two confident
    /// cells of light smoke on one of three recordings of the dense trial.)
    pub fn laser_worth(&self, noise_factor: f64) -> f64 {
        if self.laser_smoke_discount && noise_factor.is_finite() {
            1.0 / noise_factor.max(1.0).powi(2)
        } else {
            1.0
        }
    }

    /// The range error bound δr of a reading of `rho` m.
    pub fn range_error(&self, kind: BeamKind, rho: f64) -> f64 {
        match kind {
            BeamKind::Laser => self.laser_dr_m.max(self.laser_dr_frac * rho),
            BeamKind::Sonar => self.sonar_dr_m.max(self.sonar_dr_frac * rho),
        }
    }

    /// The peak confidence K of a reading of `rho` m: the URG-04LX fit for a
    /// laser (held at `laser_k_min` where the fit falls below it), a
    /// constant for a sonar.
    pub fn peak(&self, kind: BeamKind, rho: f64) -> f64 {
        match kind {
            BeamKind::Laser => urg04lx_k(rho * 1000.0).clamp(self.laser_k_min, 1.0),
            BeamKind::Sonar => self.sonar_k,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-9
    }

    #[test]
    fn range_confidence_is_k0_at_the_reading_and_zero_at_the_error_bound() {
        // Eq. 1 with the URG-04LX's ±10 mm at 0.5 m.
        let (k0, rho, dr) = (0.76, 0.5, 0.01);
        assert!(close(range_confidence(k0, rho, rho, dr), 0.76));
        assert!(close(
            range_confidence(k0, rho + 0.005, rho, dr),
            0.76 * 0.75
        ));
        assert!(close(
            range_confidence(k0, rho - 0.005, rho, dr),
            0.76 * 0.75
        ));
        assert!(close(range_confidence(k0, rho + 0.01, rho, dr), 0.0));
        assert_eq!(range_confidence(k0, rho + 0.02, rho, dr), 0.0);
    }

    #[test]
    fn occupied_is_the_product_of_the_range_and_lateral_parabolas() {
        // Eq. 2 with δθ = 0.36°.
        let dth = 0.36f64.to_radians();
        let (rho, phi, dr) = (2.0, 0.3, 0.02);
        assert!(close(occupied(0.5, rho, phi, rho, phi, dr, dth), 0.5));
        let half = occupied(0.5, rho + 0.01, phi + dth / 2.0, rho, phi, dr, dth);
        assert!(close(half, 0.5 * 0.75 * 0.75), "{half}");
        assert!(occupied(0.5, rho, phi + dth, rho, phi, dr, dth).abs() < 1e-12);
        assert_eq!(occupied(0.5, rho, phi + 2.0 * dth, rho, phi, dr, dth), 0.0);
    }

    #[test]
    fn free_space_is_full_before_the_error_band_and_zero_behind_the_reading() {
        // Eq. 3.
        let (rho, phi, dr, dth) = (3.0, 0.0, 0.03, 0.01);
        assert!(close(free(1.0, phi, rho, phi, dr, dth), 1.0));
        assert!(close(free(rho - dr, phi, rho, phi, dr, dth), 1.0));
        assert!(close(free(rho - dr / 2.0, phi, rho, phi, dr, dth), 0.25));
        assert!(close(free(rho, phi, rho, phi, dr, dth), 0.0));
        assert_eq!(free(rho + 0.001, phi, rho, phi, dr, dth), 0.0);
        assert!(close(free(1.0, phi + dth / 2.0, rho, phi, dr, dth), 0.75));
        assert_eq!(free(1.0, phi + dth, rho, phi, dr, dth), 0.0);
    }

    #[test]
    fn urg04lx_confidence_follows_the_papers_polynomial() {
        // Eq. 4 at its key points: 0.76 at 0, ~0.735 at 1 m, falling past 1 m.
        assert!(close(urg04lx_k(0.0), 0.76));
        assert!((urg04lx_k(1000.0) - 0.7351).abs() < 1e-4);
        assert!((urg04lx_k(2000.0) - 0.4976).abs() < 1e-4);
        assert!((urg04lx_k(3000.0) - 0.2215).abs() < 1e-4);
        assert!(urg04lx_k(4000.0) < 0.0, "the printed fit leaves its range");
        let m = ConfidenceModel::default();
        assert_eq!(m.peak(BeamKind::Laser, 4.0), 0.2, "held at laser_k_min");
        assert!((m.peak(BeamKind::Laser, 1.0) - 0.7351).abs() < 1e-4);
    }

    #[test]
    fn urg04lx_range_error_is_10_mm_then_1_percent() {
        let m = ConfidenceModel::default();
        assert!(close(m.range_error(BeamKind::Laser, 0.3), 0.01));
        assert!(close(m.range_error(BeamKind::Laser, 1.0), 0.01));
        assert!(close(m.range_error(BeamKind::Laser, 3.0), 0.03));
        assert!(close(m.laser_dtheta, 0.36f64.to_radians()));
        // The Pioneer's 15° cone when no robot profile says otherwise.
        assert!(close(m.sonar_half_cone, 7.5f64.to_radians()));
        assert_eq!(m.peak(BeamKind::Sonar, 1.0), 0.5);
    }

    #[test]
    fn combined_map_follows_eq_7() {
        // Free space: darkest; unseen: 0.3; obstacle: its confidence.
        assert!(close(combined(0.0, 1.0, 0.3), 0.0));
        assert!(close(combined(0.0, 0.0, 0.3), 0.3));
        assert!(close(combined(0.76, 0.0, 0.3), 0.76));
        assert!(
            close(combined(0.1, 0.0, 0.3), 0.3),
            "weak evidence stays unknown"
        );
        assert!(
            close(combined(0.76, 0.5, 0.3), 0.5),
            "space caps the obstacle"
        );
        assert!(close(combined(0.0, 0.9, 0.3), 0.1));
    }
}
