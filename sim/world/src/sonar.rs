//! Sonar transducers: a cone, the nearest surface inside it, and specular
//! reflection.
//!
//! * Immune to smoke: "since they use acoustic waves, they are immune to
//!   smoke or dust particles" (SmokeNav (Santos et al. 2015), Sec. 4). The model never looks at the
//!   smoke field.
//! * Cone: the beam is sampled by rays across its full width (15° for the
//!   Pioneer's SensComp Series 600 at −6 dB, ~20° for the Scout's Polaroid
//!   6500; SmokeNav Sec. 4, both in the robot profiles). The reading is the
//!   nearest surface that echoes.
//! * Specular reflection: smooth walls mirror ultrasound, so a patch only
//!   echoes back to the transducer when the ray meets it within a critical
//!   incidence angle of its normal; otherwise the sound is deflected away and,
//!   with nothing else in the cone, the sonar reports its maximum range
//!   (saturated). SmokeNav Fig. 5: in a plain corridor only the Pioneer's ±90°
//!   sonars see the walls ("obstacles are only detected when the incident
//!   beam is normal or nearly normal"); Fig. 6: the Scout's side sonars "are
//!   able to detect the walls even when the incident sonar beam is not
//!   normal". Hence a small critical angle for the Pioneer and a larger one
//!   for the Scout, both configurable.
//! * Range noise: both transducer families are specified at ±1 % of range.
//! * "The Pioneer's less stable behaviour" (SmokeNav Sec. 4, 5.3.1) is an
//!   option: echoes randomly lost (max-range reading) and occasional short
//!   crosstalk readings from a neighbour's ping.

use crate::arena::Arena;
use crate::geom::{Pose2, Position, Vec2};
use smokenav_shared_types::Rng;

#[derive(Debug, Clone, PartialEq)]
pub struct SonarParams {
    /// Full beam width, degrees.
    pub cone_deg: f64,
    pub min_range_m: f64,
    /// Reading reported when no echo returns, m (Pioneer 5.0, Scout 255 in = 6.477).
    pub max_range_m: f64,
    /// Largest incidence angle (from the surface normal) that still echoes, degrees.
    pub critical_angle_deg: f64,
    /// 1σ range noise as a fraction of range.
    pub noise_frac: f64,
    /// Rays sampled across the cone.
    pub rays: usize,
    /// Unstable-sonar option: probability an echo is lost.
    pub dropout_prob: f64,
    /// Unstable-sonar option: probability of a spurious short reading.
    pub crosstalk_prob: f64,
    /// Height of the transducers' axes above the floor, m.
    pub height_m: f64,
}

/// A sonar ring around the base's top plate.
pub const DEFAULT_SONAR_HEIGHT_M: f64 = 0.30;

impl SonarParams {
    /// The SmokeNav paper's Pioneer 3-DX ring: 15° cones, near-normal echoes only.
    pub fn pioneer() -> Self {
        Self {
            cone_deg: 15.0,
            min_range_m: 0.1,
            max_range_m: 5.0,
            critical_angle_deg: 12.0,
            noise_frac: 0.005,
            rays: 9,
            dropout_prob: 0.0,
            crosstalk_prob: 0.0,
            height_m: DEFAULT_SONAR_HEIGHT_M,
        }
    }

    /// The SmokeNav paper's Nomad Scout ring: ~20° Polaroid 6500 cones that echo off oblique walls.
    pub fn scout() -> Self {
        Self {
            cone_deg: 20.0,
            min_range_m: 0.15,
            max_range_m: 6.477,
            critical_angle_deg: 40.0,
            noise_frac: 0.005,
            rays: 9,
            dropout_prob: 0.0,
            crosstalk_prob: 0.0,
            height_m: DEFAULT_SONAR_HEIGHT_M,
        }
    }
}

/// One ping's result.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Echo {
    /// Range, m; `max_range_m` when saturated.
    pub range_m: f64,
    /// No echo: free space within range, or walls only at specular angles.
    pub saturated: bool,
}

#[derive(Debug, Clone)]
pub struct SonarModel {
    pub params: SonarParams,
    rng: Rng,
}

impl SonarModel {
    pub fn new(params: SonarParams, rng: Rng) -> Self {
        Self { params, rng }
    }

    /// Fires the transducer at `mount` (base frame) with the robot at `pose`.
    pub fn ping(&mut self, arena: &Arena, pose: &Pose2, mount: &Pose2) -> Echo {
        let p = &self.params;
        // Fixed draws per ping: noise, dropout, crosstalk trigger, crosstalk range.
        let noise = self.rng.normal();
        let drop = self.rng.uniform();
        let ghost = self.rng.uniform();
        let ghost_at = self.rng.uniform();
        let s = pose.compose(mount);
        let o = s.position();
        let half = p.cone_deg.to_radians() / 2.0;
        let cos_crit = p.critical_angle_deg.to_radians().cos();
        let mut nearest = f64::INFINITY;
        let n = p.rays.max(1);
        let spread = |k: usize, half: f64| {
            if n == 1 {
                0.0
            } else {
                -half + 2.0 * half * k as f64 / (n - 1) as f64
            }
        };
        // The cone is round: `n` rows of elevation, each `n` rays across the
        // cone's width at that elevation. The level row is the planar model's
        // fan, so full-height walls echo exactly as in 2D (a tilted ray meets
        // them farther away).
        // A planar world: the level row alone gives the same nearest echo.
        let rows = if arena.has_heights() { 0..n } else { 0..1 };
        for row in rows {
            let elev = if arena.has_heights() {
                spread(row, half)
            } else {
                0.0
            };
            let width = (half * half - elev * elev).max(0.0).sqrt();
            let (tan_e, cos_e) = (elev.tan(), elev.cos());
            // A falling ray meets the floor (which mirrors sound away) here.
            let reach = if tan_e < 0.0 {
                (p.height_m / -tan_e).min(p.max_range_m * cos_e)
            } else {
                p.max_range_m * cos_e
            };
            for k in 0..n {
                let d = Vec2::from_angle(s.theta + spread(k, width));
                let hit = arena.cast_where(o, d, reach, |seg, t| {
                    seg.is_full_height() || seg.spans(p.height_m + t * tan_e)
                });
                if let Some(hit) = hit
                    && hit.normal.dot(d).abs() * cos_e >= cos_crit
                {
                    nearest = nearest.min(hit.distance / cos_e);
                }
            }
        }
        let saturated = Echo {
            range_m: p.max_range_m,
            saturated: true,
        };
        if ghost < p.crosstalk_prob {
            let hi = nearest.min(p.max_range_m);
            return Echo {
                range_m: p.min_range_m + ghost_at * (hi - p.min_range_m).max(0.0),
                saturated: false,
            };
        }
        if !nearest.is_finite() || drop < p.dropout_prob {
            return saturated;
        }
        let r = nearest * (1.0 + p.noise_frac * noise);
        if r < p.min_range_m || r >= p.max_range_m {
            // Inside the blanking interval, or beyond the last listening moment.
            return saturated;
        }
        Echo {
            range_m: r,
            saturated: false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::arena::BuiltinArena;

    fn corridor() -> Arena {
        BuiltinArena::Corridor.load().unwrap()
    }

    fn ping(params: SonarParams, yaw_deg: f64, heading_deg: f64) -> Echo {
        let mut m = SonarModel::new(params, Rng::new(1, 2));
        let pose = Pose2::new(8.0, 1.0, heading_deg.to_radians());
        m.ping(
            &corridor(),
            &pose,
            &Pose2::new(0.0, 0.0, yaw_deg.to_radians()),
        )
    }

    #[test]
    fn side_sonar_at_90_degrees_sees_corridor_wall_at_one_metre() {
        let e = ping(SonarParams::pioneer(), 90.0, 0.0);
        assert!(!e.saturated && (e.range_m - 1.0).abs() < 0.03, "{e:?}");
    }

    #[test]
    fn pioneer_oblique_sonars_saturate_in_a_plain_corridor() {
        // SmokeNav Fig. 5b: only ±90° see the walls; ±50° and ±30° meet them at 40°/60° incidence.
        for yaw in [50.0, 30.0, -30.0, -50.0] {
            let e = ping(SonarParams::pioneer(), yaw, 0.0);
            assert!(e.saturated && e.range_m == 5.0, "yaw {yaw}: {e:?}");
        }
    }

    #[test]
    fn scout_oblique_sonars_see_corridor_walls() {
        // SmokeNav Fig. 6: the Scout's side sonars detect the walls off normal incidence.
        for yaw in [67.5, 45.0, -45.0, -67.5] {
            let e = ping(SonarParams::scout(), yaw, 0.0);
            assert!(!e.saturated, "yaw {yaw}: {e:?}");
            // Nearest echoing ray is the cone edge closest to the normal: 1/cos(incidence − 10°).
            let expect = 1.0 / ((90.0 - yaw.abs() - 10.0f64).max(0.0)).to_radians().cos();
            assert!(
                (e.range_m - expect).abs() < 0.05,
                "yaw {yaw}: {e:?} vs {expect}"
            );
        }
    }

    #[test]
    fn sonar_reads_the_nearest_wall_at_normal_incidence_within_one_percent() {
        let mut m = SonarModel::new(SonarParams::pioneer(), Rng::new(3, 3));
        let pose = Pose2::new(14.0, 1.0, 0.0); // 2 m from the end wall
        let vals: Vec<f64> = (0..500)
            .map(|_| m.ping(&corridor(), &pose, &Pose2::default()).range_m)
            .collect();
        assert!(
            vals.iter().all(|v| (v - 2.0).abs() < 0.04),
            "{:?}",
            vals.iter().fold(0.0f64, |a, v| a.max((v - 2.0).abs()))
        );
    }

    #[test]
    fn the_cone_sees_a_low_crate_and_a_table_top_the_laser_plane_misses() {
        let arena = |h: [f64; 2]| {
            let text = format!(
                "[[wall]]\npoints = [[0.0, 0.0], [10.0, 0.0], [10.0, 4.0], [0.0, 4.0]]\nclosed = true\n\
                 [[box]]\ncenter = [3.0, 2.0]\nsize = [1.0, 1.0]\nheight_m = [{}, {}]\n",
                h[0], h[1]
            );
            Arena::from_vector_str(&text, std::path::Path::new("t.toml")).unwrap()
        };
        let mut m = SonarModel::new(SonarParams::scout(), Rng::new(1, 2));
        let pose = Pose2::new(1.3, 2.0, 0.0);
        // The box's face is 1.2 m ahead; the sonar axis is at 0.30 m, its cone ±10°.
        for h in [[0.0, 0.2], [0.45, 0.55]] {
            let e = m.ping(&arena(h), &pose, &Pose2::default());
            assert!(!e.saturated, "{h:?}: {e:?}");
            assert!(e.range_m > 1.17 && e.range_m < 1.25, "{h:?}: {e:?}");
        }
        // Above the cone's reach at 1.2 m (0.30 + 1.2 · tan 10° = 0.51 m): the
        // front face is unseen. (A rising ray passing under the box meets its
        // far face at 2.2 m, 0.69 m up: the model has vertical faces only, no
        // undersides.)
        let e = m.ping(&arena([0.6, 0.8]), &pose, &Pose2::default());
        assert!(e.range_m > 2.1, "{e:?}");
    }

    #[test]
    fn unstable_option_loses_echoes_at_its_rate() {
        let params = SonarParams {
            dropout_prob: 0.3,
            ..SonarParams::pioneer()
        };
        let mut m = SonarModel::new(params, Rng::new(5, 5));
        let pose = Pose2::new(14.0, 1.0, 0.0);
        let lost = (0..4000)
            .filter(|_| m.ping(&corridor(), &pose, &Pose2::default()).saturated)
            .count();
        assert!((lost as f64 / 4000.0 - 0.3).abs() < 0.03, "{lost}");
    }
}
