//! Inverse sensor models (ISMs): the occupancy probability a reading implies
//! for a point, or `None` where it says nothing (the prior).
//!
//! * Laser: Thrun's three-part model along the beam (*Probabilistic
//!   Robotics*, Table 9.2): free before the hit, occupied within half an
//!   obstacle thickness of it, prior beyond.
//! * Sonar: Tran et al. 2021's ultrasonic model, with the Polaroid /
//!   SensComp transducer's beam taken as a circular cone around its axis:
//!   free inside the cone up to the echo, occupied on the echo's cap (the
//!   spherical shell at the echo range within the cone), prior beyond and
//!   outside the cone. A saturated reading (no echo) says nothing: smooth
//!   walls mirror sound away, so "no echo" is not "free".
//!
//! Both papers' probabilities are OctoMap's hit/miss, 0.7 and 0.4.

use crate::logodds::{Clamping, logodds, probability};

/// Thrun's three-part laser model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaserIsm {
    pub p_free: f64,
    pub p_occupied: f64,
    /// Obstacle thickness α, m: `|d − range| ≤ α/2` is occupied. The maps use
    /// one cell: the cells a beam crosses before its end cell are free, the end
    /// cell occupied.
    pub thickness_m: f64,
}

impl Default for LaserIsm {
    fn default() -> Self {
        let c = Clamping::default();
        Self {
            p_free: c.miss,
            p_occupied: c.hit,
            thickness_m: 0.05,
        }
    }
}

impl LaserIsm {
    /// Probability at distance `d` along a beam that measured `range`.
    pub fn at(&self, d: f64, range: f64) -> Option<f64> {
        let half = self.thickness_m / 2.0;
        if d < range - half {
            Some(self.p_free)
        } else if d <= range + half {
            Some(self.p_occupied)
        } else {
            None
        }
    }
}

/// The 3D sonar-cone model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SonarIsm {
    pub p_free: f64,
    pub p_occupied: f64,
    /// Half the full beam width, rad.
    pub half_cone_rad: f64,
    /// Thickness of the occupied cap, m (the maps use at least one cell).
    pub thickness_m: f64,
}

impl SonarIsm {
    pub fn new(cone_deg: f64) -> Self {
        let c = Clamping::default();
        Self {
            p_free: c.miss,
            p_occupied: c.hit,
            half_cone_rad: cone_deg.to_radians() / 2.0,
            thickness_m: 0.08,
        }
    }

    /// Probability at `v`, in the transducer's frame (x along the axis, m),
    /// for an echo at `range`.
    pub fn at(&self, v: [f64; 3], range: f64) -> Option<f64> {
        let d = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if d <= 0.0 || v[0] < d * self.half_cone_rad.cos() {
            return None;
        }
        let half = self.thickness_m / 2.0;
        if d < range - half {
            Some(self.p_free)
        } else if d <= range + half {
            Some(self.p_occupied)
        } else {
            None
        }
    }

    /// The occupied probability of the cap in a map of one horizontal slice
    /// of `cell` thickness (the fused 2D grid in the laser plane). The echo
    /// came from somewhere on the cap, whose vertical extent at `range` is
    /// `2 · range · sin θ`; a slice holds its share of that evidence, so a cap
    /// spanning ten slices moves each by a tenth of the log-odds a voxel of
    /// the 3D cap gets. Free space is free at every height and keeps `p_free`.
    pub fn slice_p_occupied(&self, range: f64, cell: f64) -> f64 {
        let extent = 2.0 * range * self.half_cone_rad.sin();
        let share = (cell / extent).min(1.0);
        probability(share * logodds(self.p_occupied))
    }

    /// Largest vertical offset from the axis height still inside the cone at
    /// forward distance `a` and lateral offset `b` (both horizontal, m):
    /// `dz² ≤ a² tan² θ − b²`. `None` outside the cone's horizontal sector.
    pub fn vertical_extent(&self, a: f64, b: f64) -> Option<f64> {
        if a <= 0.0 {
            return None;
        }
        let t = self.half_cone_rad.tan();
        let q = a * a * t * t - b * b;
        (q >= 0.0).then(|| q.sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn laser_model_has_three_parts() {
        let m = LaserIsm::default();
        assert_eq!(m.at(1.0, 2.0), Some(0.4));
        assert_eq!(m.at(2.01, 2.0), Some(0.7));
        assert_eq!(m.at(1.99, 2.0), Some(0.7));
        assert_eq!(m.at(2.1, 2.0), None);
    }

    #[test]
    fn sonar_cone_is_free_to_the_echo_occupied_on_its_cap_prior_beyond_and_outside() {
        let m = SonarIsm::new(20.0);
        // On the axis.
        assert_eq!(m.at([1.0, 0.0, 0.0], 2.0), Some(0.4));
        assert_eq!(m.at([2.0, 0.0, 0.0], 2.0), Some(0.7));
        assert_eq!(m.at([2.5, 0.0, 0.0], 2.0), None);
        // 9° above the axis is inside a 20° cone, 11° is not: the cone is 3D.
        let at = |deg: f64, r: f64| {
            let (s, c) = deg.to_radians().sin_cos();
            [r * c, 0.0, r * s]
        };
        assert_eq!(m.at(at(9.0, 2.0), 2.0), Some(0.7));
        assert_eq!(m.at(at(11.0, 2.0), 2.0), None);
        assert_eq!(m.at([-1.0, 0.0, 0.0], 2.0), None);
    }

    #[test]
    fn a_slice_of_the_cap_holds_its_share_of_the_evidence() {
        let m = SonarIsm::new(20.0);
        // At 1.5 m the cap spans 2 · 1.5 · sin 10° = 0.52 m: ten 5 cm slices.
        let p = m.slice_p_occupied(1.5, 0.05);
        let share = 0.05 / (3.0 * 10f64.to_radians().sin());
        assert!((logodds(p) - share * logodds(0.7)).abs() < 1e-12);
        assert!(p > 0.5 && p < 0.55, "{p}");
        // A slice as thick as the cap keeps the full value.
        assert!((m.slice_p_occupied(0.1, 1.0) - 0.7).abs() < 1e-12);
    }

    #[test]
    fn vertical_extent_matches_the_cone() {
        let m = SonarIsm::new(20.0);
        let dz = m.vertical_extent(2.0, 0.0).unwrap();
        assert!((dz - 2.0 * 10f64.to_radians().tan()).abs() < 1e-12);
        // A point at that height is on the cone's surface.
        let d = (4.0 + dz * dz).sqrt();
        assert!(((2.0 / d).acos() - 10f64.to_radians()).abs() < 1e-9);
        assert_eq!(m.vertical_extent(2.0, 0.5), None);
        assert_eq!(m.vertical_extent(-1.0, 0.0), None);
    }
}
