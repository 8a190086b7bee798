//! The Hokuyo URG-04LX in smoke.
//!
//! Geometry from the sensor's own `PP` reply (SCIP 2.0): ARES
//! 1024 steps per turn, measured steps AMIN 44 … AMAX 725 (682 beams,
//! −119.5° … +119.9°), AFRT 384 straight ahead, 0.3515625° per step, counter-
//! clockwise; DMIN 20 mm, DMAX 5600 mm; SCAN 600 rpm, so 100 ms per turn and
//! 97.66 µs per step. Ranges are produced as the millimetre values the sensor
//! sends, with values below DMIN being its error codes, so the Hokuyo
//! emulator can put them on the wire as they are.
//!
//! Smoke model, per beam:
//! * Beer–Lambert attenuation: the extinction σ(r) of the smoke field is
//!   integrated along the beam, τ(r) = ∫σ, and the light that reaches range r
//!   and comes back is weighted by exp(−2τ(r)) (two-way path).
//! * Backscatter: each slice of smoke returns light in proportion to its
//!   backscatter coefficient β = σ/S (S, the lidar ratio, is a property of
//!   the particles). Integrated over the beam the smoke's return is
//!   W_b = (1/S)·(1 − e^{−2τ_R})/2, growing with optical depth, while the
//!   wall's W_w = (ρ/π)·e^{−2τ_R} fades.
//! * Early backscatter: the beam is caught by the smoke with probability
//!   equal to the smoke's share of the returned power, W_b/(W_b + W_w),
//!   which grows with optical depth from 0 in clean air to 1 in dense smoke.
//!   A caught beam reads the centroid of the smoke's return, just inside the
//!   smoke front; so dense smoke gives short, tightly clustered readings that
//!   look like a wall, as SmokeNav (Santos et al. 2015) reports ("when the smoke density is very
//!   high, from the LRF standpoint, it forms an almost indistinguishable
//!   obstacle"; "the standard deviation of the LRF readings significantly
//!   drops when affected by the smoke", Figs. 4 and 13). In light smoke some
//!   beams read the smoke and most the wall, and the per-beam patchiness of
//!   real smoke varies the odds: noisy readings biased short (Sevcik & Oh 2007,
//!   Fig. 7: fog widens and, when heavy, shifts the range distribution).
//! * Noise: clean air ±10 mm below 1 m and ±1 % beyond (URG-04LX data sheet;
//!   Sevcik & Oh 2007 Fig. 4 confirms ±1 % at 2 m), taken as 2σ; it grows as the
//!   returned power falls. No wall within DMAX reads error code 0 ("possibly
//!   ≥ 22 m, nothing in range"); too weak a return reads code 1 ("low intensity").

use crate::arena::Arena;
use crate::geom::{Pose2, Position, Vec2, normalize_angle};
use crate::smoke::SmokeField;
use smokenav_shared_types::Rng;

/// Angular resolution: steps per full turn (PP ARES).
pub const URG_ARES: u32 = 1024;
/// First measured step (PP AMIN).
pub const URG_AMIN: u32 = 44;
/// Last measured step (PP AMAX).
pub const URG_AMAX: u32 = 725;
/// Step pointing straight ahead (PP AFRT).
pub const URG_AFRT: u32 = 384;
/// Beams per scan, AMIN..=AMAX.
pub const URG_STEPS: usize = (URG_AMAX - URG_AMIN + 1) as usize;
/// Shortest valid range, mm (PP DMIN); smaller values are error codes.
pub const URG_DMIN_MM: u16 = 20;
/// Longest valid range, mm (PP DMAX).
pub const URG_DMAX_MM: u16 = 5600;
/// Scan period: 600 rpm (PP SCAN).
pub const URG_SCAN_PERIOD_NS: u64 = 100_000_000;
/// Time between steps, s: 60 / (SCAN · ARES).
pub const URG_STEP_TIME_S: f64 = 60.0 / (600.0 * 1024.0);

/// Error code: nothing within range.
pub const CODE_NO_OBJECT: u16 = 0;
/// Error code: reflected light too weak.
pub const CODE_LOW_INTENSITY: u16 = 1;

/// Beam angle of `step` in the sensor frame, rad (counter-clockwise positive).
pub fn step_angle(step: u32) -> f64 {
    (step as f64 - URG_AFRT as f64) * std::f64::consts::TAU / URG_ARES as f64
}

#[derive(Debug, Clone, PartialEq)]
pub struct LaserParams {
    /// Lidar ratio S = σ/β, sr: ~20–60 sr for fog droplets and smoke.
    pub lidar_ratio_sr: f64,
    /// Diffuse reflectance of walls (painted walls and plywood: 0.5–0.9).
    pub wall_reflectance: f64,
    /// Weakest return the sensor still ranges, relative units (a clean wall returns ρ/π).
    pub min_return: f64,
    /// Log-normal spread of each beam's smoke column around the field's mean
    /// (smoke is patchy on scales the grid does not resolve).
    pub patchiness: f64,
    /// 1σ range noise below 1 m, m (data sheet ±10 mm as 2σ).
    pub noise_near_m: f64,
    /// 1σ relative noise beyond 1 m (data sheet ±1 % as 2σ).
    pub noise_far_frac: f64,
    /// Height of the scan plane above the floor, m: obstacles that do not
    /// reach it are invisible to the beam.
    pub height_m: f64,
}

/// A URG-04LX on top of a Nomad Scout or a Pioneer's plate.
pub const DEFAULT_LASER_HEIGHT_M: f64 = 0.40;

impl Default for LaserParams {
    fn default() -> Self {
        Self {
            lidar_ratio_sr: 30.0,
            wall_reflectance: 0.7,
            min_return: 0.004,
            patchiness: 0.3,
            noise_near_m: 0.005,
            noise_far_frac: 0.005,
            height_m: DEFAULT_LASER_HEIGHT_M,
        }
    }
}

/// The laser and its random stream.
#[derive(Debug, Clone)]
pub struct LaserModel {
    pub params: LaserParams,
    /// Sensor pose in the robot's base frame.
    mount: Pose2,
    /// Unit direction of each beam in the base frame (mount yaw + step angle).
    beam_dirs: Vec<Vec2>,
    rng: Rng,
    /// Nose-down pitch of the base the laser is bolted to, rad (see [`Self::set_pitch`]).
    pitch: f64,
}

/// What one beam saw, before it is turned into the sensor's millimetres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BeamDetail {
    /// Distance to the wall along the beam, if one lies within DMAX.
    pub wall_m: Option<f64>,
    /// Optical depth up to the wall (or DMAX).
    pub optical_depth: f64,
    /// Share of the returned power that came from the smoke.
    pub smoke_share: f64,
    /// The sensor's value: mm, or an error code below DMIN.
    pub value: u16,
}

impl LaserModel {
    pub fn new(params: LaserParams, mount: Pose2, rng: Rng) -> Self {
        let beam_dirs = (URG_AMIN..=URG_AMAX)
            .map(|step| Vec2::from_angle(mount.theta + step_angle(step)))
            .collect();
        Self {
            params,
            mount,
            beam_dirs,
            rng,
            pitch: 0.0,
        }
    }

    /// Tilts the scan plane with the base (nose-down positive, rad): a base
    /// with one end up on a cable tray points its forward beams at the floor
    /// ahead, or over low obstacles, for as long as it stays tilted. The
    /// laser's height is taken as unchanged (the tilt is about the base's
    /// centre; a few millimetres at a laser mounted near it).
    pub fn set_pitch(&mut self, pitch_rad: f64) {
        self.pitch = if pitch_rad.is_finite() {
            pitch_rad
        } else {
            0.0
        };
    }

    /// Sensor pose in the robot's base frame.
    pub fn mount(&self) -> Pose2 {
        self.mount
    }

    /// One beam from `o` along unit `d`, in the horizontal plane at the laser's height.
    pub fn beam(&mut self, arena: &Arena, smoke: &SmokeField, o: Vec2, d: Vec2) -> BeamDetail {
        self.beam_sloped(arena, smoke, o, d, 0.0)
    }

    /// One beam from `o` along unit `d` (its horizontal projection) that
    /// rises `slope` metres per metre it goes out (a tilted scan plane):
    /// it hits what spans its height where it gets there, or the floor.
    /// Distances are along the beam.
    pub fn beam_sloped(
        &mut self,
        arena: &Arena,
        smoke: &SmokeField,
        o: Vec2,
        d: Vec2,
        slope: f64,
    ) -> BeamDetail {
        let p = &self.params;
        let dmax = URG_DMAX_MM as f64 / 1000.0;
        // Fixed number of draws per beam keeps every later beam's numbers independent of this one's path.
        let (z_patch, noise) = self.rng.normal_pair();
        let caught = self.rng.uniform();
        let patch = (p.patchiness * z_patch - 0.5 * p.patchiness * p.patchiness).exp();
        let wall = if slope == 0.0 {
            arena
                .cast_at_height(o, d, dmax, p.height_m)
                .map(|h| h.distance)
        } else {
            // Horizontal distances, stretched to the beam's own at the end.
            let stretch = (1.0 + slope * slope).sqrt();
            let reach = dmax / stretch;
            let h = p.height_m;
            let floor = (slope < 0.0).then(|| h / -slope).filter(|&f| f <= reach);
            let hit = arena
                .cast_where(o, d, reach, |s, t| s.spans(h + slope * t))
                .map(|x| x.distance);
            match (hit, floor) {
                (Some(a), Some(f)) => Some(a.min(f)),
                (a, f) => a.or(f),
            }
            .map(|t| t * stretch)
        };
        let end = wall.unwrap_or(dmax);
        // Backscatter power W and its first moment M along the beam, cell by cell
        // (σ constant in a cell); `trans` is the two-way transmission e^{−2τ} so far.
        let (mut tau, mut trans, mut w_b, mut m_b) = (0.0f64, 1.0f64, 0.0f64, 0.0f64);
        smoke.walk_ray(o, d, end, |t_a, t_b, sigma| {
            let s = sigma * patch;
            let dt = t_b - t_a;
            let x = 2.0 * s * dt;
            // e^{−x}, 1 − e^{−x} and g(x) = (1 − e^{−x})/x − e^{−x}; by Taylor series
            // for thin cells, where they cancel (and an exp call costs more than the
            // series: error below 3e-9 at x = 0.05).
            let (e_x, one_minus, g) = if x < 0.05 {
                let om = x * (1.0 - x / 2.0 * (1.0 - x / 3.0 * (1.0 - x / 4.0)));
                (
                    1.0 - om,
                    om,
                    x * (0.5 - x * (1.0 / 3.0 - x * (0.125 - x / 30.0))),
                )
            } else {
                let e = (-x).exp();
                (e, 1.0 - e, (1.0 - e) / x - e)
            };
            // ∫ s·e^{−2τ(r)} dr and ∫ r·s·e^{−2τ(r)} dr over the cell.
            w_b += trans * one_minus / 2.0;
            m_b += trans / 2.0 * (t_a * one_minus + dt * g);
            trans *= e_x;
            tau += s * dt;
            // Beyond a two-way transmission of 1e-6 nothing measurable comes back.
            trans > 1e-6
        });
        let (w_b, m_b) = (w_b / p.lidar_ratio_sr, m_b / p.lidar_ratio_sr);
        let clean_return = p.wall_reflectance / std::f64::consts::PI;
        let w_w = if wall.is_some() {
            clean_return * trans
        } else {
            0.0
        };
        let power = w_b + w_w;
        let mut detail = BeamDetail {
            wall_m: wall,
            optical_depth: tau,
            smoke_share: if power > 0.0 { w_b / power } else { 0.0 },
            value: CODE_NO_OBJECT,
        };
        if power < p.min_return {
            detail.value = if wall.is_some() {
                CODE_LOW_INTENSITY
            } else {
                CODE_NO_OBJECT
            };
            return detail;
        }
        // Caught by the smoke: the centroid of its return; otherwise the wall.
        let range = if caught < detail.smoke_share {
            m_b / w_b
        } else {
            end
        };
        let clean_sigma = if range < 1.0 {
            p.noise_near_m
        } else {
            p.noise_far_frac * range
        };
        let sigma = clean_sigma * (clean_return / power).sqrt().min(10.0);
        let mm = ((range + sigma * noise) * 1000.0).round();
        detail.value = if mm > URG_DMAX_MM as f64 {
            CODE_NO_OBJECT
        } else {
            mm.max(URG_DMIN_MM as f64) as u16
        };
        detail
    }

    /// A full turn: beams AMIN..=AMAX into `out`, each from the robot pose
    /// interpolated at its own step time between `start` (step 0) and `end`
    /// (one scan period later), so motion skews the scan as on the real sensor.
    pub fn scan(
        &mut self,
        arena: &Arena,
        smoke: &SmokeField,
        start: &Pose2,
        end: &Pose2,
        out: &mut [u16; URG_STEPS],
    ) {
        let dth = normalize_angle(end.theta - start.theta);
        // The heading advances by dth/ARES per step: rotate incrementally
        // instead of calling sin/cos per beam.
        let per_step = Vec2::from_angle(dth / URG_ARES as f64);
        let first = URG_AMIN as f64 / URG_ARES as f64;
        let mut rot = Vec2::from_angle(start.theta + dth * first);
        let mount_pos = self.mount.position();
        let (sp, cp) = self.pitch.sin_cos();
        for (i, slot) in out.iter_mut().enumerate() {
            let s = (URG_AMIN as f64 + i as f64) / URG_ARES as f64;
            let base = start.position() + (end.position() - start.position()) * s;
            let o = base + complex_mul(rot, mount_pos);
            let d = complex_mul(rot, self.beam_dirs[i]);
            // The beam (cos b, sin b, 0) in the base frame, pitched nose-down
            // by p: (cos b cos p, sin b, −cos b sin p); its rise per metre out.
            let slope = if self.pitch == 0.0 {
                0.0
            } else {
                let (bx, by) = (self.beam_dirs[i].x, self.beam_dirs[i].y);
                -bx * sp / (bx * bx * cp * cp + by * by).sqrt()
            };
            *slot = self.beam_sloped(arena, smoke, o, d, slope).value;
            rot = complex_mul(rot, per_step);
        }
    }
}

/// Rotates `v` by the unit vector `r` (complex multiplication).
fn complex_mul(r: Vec2, v: Vec2) -> Vec2 {
    Vec2::new(r.x * v.x - r.y * v.y, r.x * v.y + r.y * v.x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::smoke::SmokeParams;
    use std::path::Path;

    fn box_room() -> Arena {
        let t = "[[wall]]\npoints = [[-1, -3], [3, -3], [3, 3], [-1, 3]]\nclosed = true\n";
        Arena::from_vector_str(t, Path::new("room.toml")).unwrap()
    }

    fn model(seed: u64) -> LaserModel {
        LaserModel::new(LaserParams::default(), Pose2::default(), Rng::new(seed, 1))
    }

    #[test]
    fn a_scan_plane_tilted_nose_down_sees_the_floor_ahead_and_the_walls_beside() {
        // A 6 m hall, the laser 5 m from its far wall: level, the forward beam reaches it.
        let t = "[[wall]]\npoints = [[-1, -3], [5, -3], [5, 3], [-1, 3]]\nclosed = true\n";
        let arena = Arena::from_vector_str(t, Path::new("hall.toml")).unwrap();
        let smoke = SmokeField::new(&arena, SmokeParams::default(), vec![]).unwrap();
        let range = |m: &mut LaserModel, pitch_deg: f64| {
            let mut out = [0u16; URG_STEPS];
            m.set_pitch(pitch_deg.to_radians());
            m.scan(
                &arena,
                &smoke,
                &Pose2::default(),
                &Pose2::default(),
                &mut out,
            );
            let at = |deg: f64| {
                let i = (URG_AFRT as f64 + deg / 360.0 * URG_ARES as f64).round() as u32 - URG_AMIN;
                out[i as usize] as f64 / 1000.0
            };
            (at(0.0), at(90.0))
        };
        let mut m = model(1);
        let (ahead, side) = range(&mut m, 0.0);
        assert!(
            (ahead - 5.0).abs() < 0.15 && (side - 3.0).abs() < 0.1,
            "{ahead} {side}"
        );
        // Pitched 10° nose down at 0.40 m: the floor 0.40 / sin 10° = 2.30 m along the beam.
        let (ahead, side) = range(&mut m, 10.0);
        let floor = 0.40 / 10f64.to_radians().sin();
        assert!((ahead - floor).abs() < 0.05, "{ahead} against {floor}");
        // The beam square to the pitch axis stays level.
        assert!((side - 3.0).abs() < 0.05, "{side}");
        // Nose up, the forward beam rises and still meets the full-height
        // wall (5.08 m along it; the URG's noise is 1 % of the range, 1σ).
        let (ahead, _) = range(&mut m, -10.0);
        assert!(
            (ahead - 5.0 / 10f64.to_radians().cos()).abs() < 0.15,
            "{ahead}"
        );
    }

    #[test]
    fn pp_geometry_gives_682_beams_over_240_degrees() {
        assert_eq!(URG_STEPS, 682);
        assert!((step_angle(URG_AMIN).to_degrees() + 119.53125).abs() < 1e-9);
        assert!((step_angle(URG_AMAX).to_degrees() - 119.8828125).abs() < 1e-9);
        assert!((step_angle(URG_AFRT + 1).to_degrees() - 0.3515625).abs() < 1e-12);
        assert!((URG_STEP_TIME_S * 1e6 - 97.65625).abs() < 1e-9);
    }

    #[test]
    fn clean_wall_at_2m_reads_within_one_percent() {
        let (arena, smoke) = (
            box_room(),
            SmokeField::new(&box_room(), SmokeParams::default(), vec![]).unwrap(),
        );
        let mut m = model(3);
        let n = 2000;
        let vals: Vec<f64> = (0..n)
            .map(|_| {
                m.beam(&arena, &smoke, Vec2::new(1.0, 0.0), Vec2::new(1.0, 0.0))
                    .value as f64
            })
            .collect();
        let mean = vals.iter().sum::<f64>() / n as f64;
        let within = vals.iter().filter(|v| (*v - 2000.0).abs() <= 20.0).count();
        assert!((mean - 2000.0).abs() < 1.0, "{mean}");
        assert!(
            within as f64 > 0.9 * n as f64,
            "Sevcik & Oh 2007 Fig. 4: most within ±1 %: {within}/{n}"
        );
    }

    #[test]
    fn near_wall_noise_is_about_ten_millimetres() {
        let (arena, smoke) = (
            box_room(),
            SmokeField::new(&box_room(), SmokeParams::default(), vec![]).unwrap(),
        );
        let mut m = model(4);
        let vals: Vec<f64> = (0..2000)
            .map(|_| {
                m.beam(&arena, &smoke, Vec2::new(2.5, 0.0), Vec2::new(1.0, 0.0))
                    .value as f64
            })
            .collect();
        let max_dev = vals.iter().map(|v| (v - 500.0).abs()).fold(0.0, f64::max);
        assert!((8.0..=25.0).contains(&max_dev), "{max_dev}");
    }

    #[test]
    fn nothing_within_5600_mm_is_error_code_0() {
        let t = "[[wall]]\npoints = [[0, -3], [10, -3], [10, 3], [0, 3]]\nclosed = true\n";
        let arena = Arena::from_vector_str(t, Path::new("long.toml")).unwrap();
        let smoke = SmokeField::new(&arena, SmokeParams::default(), vec![]).unwrap();
        let b = model(1).beam(&arena, &smoke, Vec2::new(1.0, 0.0), Vec2::new(1.0, 0.0));
        assert_eq!(b.value, CODE_NO_OBJECT);
        assert_eq!(b.wall_m, None);
    }

    #[test]
    fn dense_smoke_reads_just_inside_its_front() {
        let arena = box_room();
        let mut smoke = SmokeField::new(&arena, SmokeParams::default(), vec![]).unwrap();
        // 0.6 g/m³ ⇒ σ ≈ 5.2 /m from x = 1.0 to 2.0; wall at x = 3, sensor at x = 0.
        smoke.add_rect(Vec2::new(1.0, -3.0), Vec2::new(2.0, 3.0), 0.6);
        let mut m = model(5);
        let vals: Vec<f64> = (0..500)
            .map(|_| {
                m.beam(&arena, &smoke, Vec2::new(0.0, 0.05), Vec2::new(1.0, 0.0))
                    .value as f64
                    / 1000.0
            })
            .collect();
        let mean = vals.iter().sum::<f64>() / vals.len() as f64;
        // Centroid of the smoke's own return: front + 1/(2σ) ≈ 1.0 + 0.1 m (patchiness moves it a little).
        assert!(mean > 1.0 && mean < 1.3, "{mean}");
        let sd = (vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / vals.len() as f64).sqrt();
        assert!(sd < 0.1, "tightly clustered: sd {sd}");
    }

    #[test]
    fn light_smoke_makes_readings_noisy_and_short_biased() {
        let arena = box_room();
        let mut smoke = SmokeField::new(&arena, SmokeParams::default(), vec![]).unwrap();
        smoke.add_rect(Vec2::new(1.0, -3.0), Vec2::new(2.0, 3.0), 0.06); // σ ≈ 0.5 /m
        let mut m = model(6);
        let vals: Vec<f64> = (0..2000)
            .map(|_| {
                m.beam(&arena, &smoke, Vec2::new(0.0, 0.05), Vec2::new(1.0, 0.0))
                    .value as f64
                    / 1000.0
            })
            .collect();
        let mean = vals.iter().sum::<f64>() / vals.len() as f64;
        let sd = (vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / vals.len() as f64).sqrt();
        assert!(
            mean < 2.97 && mean > 2.0,
            "biased short but still near the wall: {mean}"
        );
        assert!(sd > 0.05, "noisier than clean air (≈0.015 m at 3 m): {sd}");
    }

    #[test]
    fn share_of_beams_caught_early_grows_with_optical_depth() {
        let arena = box_room();
        let mut last = -1.0;
        for density in [0.0, 0.02, 0.06, 0.15, 0.4] {
            let mut smoke = SmokeField::new(&arena, SmokeParams::default(), vec![]).unwrap();
            smoke.add_rect(Vec2::new(1.0, -3.0), Vec2::new(2.0, 3.0), density);
            let mut m = model(8);
            let short = (0..2000)
                .filter(|_| {
                    m.beam(&arena, &smoke, Vec2::new(0.0, 0.05), Vec2::new(1.0, 0.0))
                        .value
                        < 2500
                })
                .count() as f64
                / 2000.0;
            assert!(
                short > last,
                "density {density}: {short} caught, not above {last}"
            );
            last = short;
        }
        assert!(last > 0.95, "dense smoke catches nearly every beam: {last}");
    }

    #[test]
    fn scan_of_a_square_room_sees_walls_on_every_beam() {
        let arena = box_room();
        let smoke = SmokeField::new(&arena, SmokeParams::default(), vec![]).unwrap();
        let mut out = [0u16; URG_STEPS];
        let pose = Pose2::new(1.0, 0.0, 0.0);
        model(9).scan(&arena, &smoke, &pose, &pose, &mut out);
        let ahead = out[(URG_AFRT - URG_AMIN) as usize];
        assert!((ahead as i32 - 2000).abs() < 40, "{ahead}");
        // Step 128 after AFRT points at +45°: corner at (3, 3) is ~2.83 m away along it (exact hit at x=3 → 2√2).
        let left45 = out[(URG_AFRT + 128 - URG_AMIN) as usize];
        assert!((left45 as f64 - 2828.4).abs() < 60.0, "{left45}");
        assert!(out.iter().all(|&v| v >= URG_DMIN_MM));
    }
}
