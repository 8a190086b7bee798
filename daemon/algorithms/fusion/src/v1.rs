//! SmokeNav v1: the heuristic of Algorithm 2 of SmokeNav (Santos et al.
//! 2015, §5.3), as implemented here.
//!
//! The smoke level picks a state — *clean* (only the laser), *light* (sonar
//! and laser superimposed, the sonar replacing noisy or contradicted laser
//! sections) or *dense* (only the sonar). While the smoke rises, dense starts
//! at SMOKE_MAX_UP (200); while it falls, at SMOKE_MAX_DOWN (240), because the
//! MQ303A recovers slowly and a falling reading overstates the smoke. The
//! direction is the smoke driver's trend; a *steady* trend keeps the last
//! direction, so the thresholds — and the state — hold while the sensor
//! settles.
//!
//! Superimposing: the paper says "sonar superimposed to LRF" while rising and
//! "LRF superimposed to sonar" while falling. Both keep both readings; in a
//! laser-shaped scan that means the nearer of the two per beam
//! (`SectionSource::Both`), so the direction only changes the threshold.
//!
//! Its numbers are keys under `[fusion.v1]` (keys, defaults and ranges in
//! `smokenav_platform_config::fusion`):
//!
//! | paper                 | key                           | default |
//! |-----------------------|-------------------------------|---------|
//! | SMOKE_MIN             | `v1.smoke_min`                | 130     |
//! | SMOKE_MAX_UP          | `v1.smoke_max_up`             | 200     |
//! | SMOKE_MAX_DOWN        | `v1.smoke_max_down`           | 240     |
//! | (Ns−1)/3 crossings    | `v1.zero_crossing_fraction`   | 1/3     |
//! | MAX_DIFF = α_step·r̄  | (computed per section)        |         |
//!
//! Choices where the paper gives no number: `v1.disagreement_m` (a "high
//! difference" between the laser and the sonar of one section, 0.3 m) and
//! `v1.noise_floor_m` (differences smaller than this carry no sign in the
//! zero-crossing test; 0 = the paper, every non-zero difference counts).

use crate::geometry::SonarEcho;
use smokenav_platform_config::fusion::V1Params;
use smokenav_shared_types::{LaserScan, SectionSource, SmokeReading, SmokeTrend};

/// What the smoke sensor says about visibility.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SmokeState {
    /// No usable reading (absent, warming up, disconnected, saturated ADC).
    #[default]
    Unknown,
    /// Below SMOKE_MIN: only the laser.
    Clean,
    /// Between SMOKE_MIN and the dense threshold: laser and sonar superimposed.
    Light,
    /// At or above SMOKE_MAX_UP (rising) / SMOKE_MAX_DOWN (falling): only the sonar.
    Dense,
}

impl SmokeState {
    pub fn as_str(self) -> &'static str {
        match self {
            SmokeState::Unknown => "unknown",
            SmokeState::Clean => "clean",
            SmokeState::Light => "light",
            SmokeState::Dense => "dense",
        }
    }

    /// For health metrics: 0 unknown, 1 clean, 2 light, 3 dense.
    pub fn code(self) -> u8 {
        self as u8
    }
}

/// The stateful smoke classifier (the direction memory is the hysteresis).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SmokeClassifier {
    rising: bool,
    state: SmokeState,
}

impl Default for SmokeClassifier {
    fn default() -> Self {
        Self {
            rising: true,
            state: SmokeState::Unknown,
        }
    }
}

impl SmokeClassifier {
    pub fn state(&self) -> SmokeState {
        self.state
    }

    /// True while the last non-steady trend was rising.
    pub fn rising(&self) -> bool {
        self.rising
    }

    pub fn update(&mut self, reading: Option<&SmokeReading>, p: &V1Params) -> SmokeState {
        let Some(r) = reading.filter(|r| r.is_ready() && r.level.is_finite()) else {
            self.state = SmokeState::Unknown;
            return self.state;
        };
        match r.trend() {
            SmokeTrend::Rising => self.rising = true,
            SmokeTrend::Falling => self.rising = false,
            SmokeTrend::Steady => {}
        }
        let level = f64::from(r.level);
        let dense_at = if self.rising {
            p.smoke_max_up
        } else {
            p.smoke_max_down
        };
        self.state = if level < p.smoke_min {
            SmokeState::Clean
        } else if level < dense_at {
            SmokeState::Light
        } else {
            SmokeState::Dense
        };
        self.state
    }
}

/// The laser readings of one section.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LaserSectionStats {
    /// Ns: valid ranges in the section.
    pub count: usize,
    /// r̄, m.
    pub mean: f64,
    /// The nearest valid range, m.
    pub min: f64,
    /// MAX_DIFF = α_step · r̄ was exceeded and at least a third of the Ns−1
    /// successive differences changed sign.
    pub noisy: bool,
}

/// Eq. (1), (2) and the zero-crossing test over beams `[first, end)` of `scan`.
pub fn section_stats(
    scan: &LaserScan,
    first: usize,
    end: usize,
    p: &V1Params,
) -> LaserSectionStats {
    let end = end.min(scan.len());
    let valid = |i: usize| {
        scan.beam(i)
            .range()
            .filter(|r| r.is_finite())
            .map(f64::from)
    };
    let (mut n, mut sum, mut min) = (0usize, 0.0f64, f64::INFINITY);
    for r in (first..end).filter_map(valid) {
        n += 1;
        sum += r;
        min = min.min(r);
    }
    if n == 0 {
        return LaserSectionStats::default();
    }
    let mean = sum / n as f64;
    let max_diff = f64::from(scan.angle_increment).abs() * mean;
    let (mut exceeded, mut changes) = (false, 0usize);
    let (mut prev, mut last_sign) = (None::<f64>, 0i8);
    for r in (first..end).filter_map(valid) {
        if let Some(q) = prev {
            let d = r - q;
            exceeded |= d.abs() > max_diff;
            if d.abs() > p.noise_floor_m && d != 0.0 {
                let sign = if d > 0.0 { 1 } else { -1 };
                if last_sign != 0 && sign != last_sign {
                    changes += 1;
                }
                last_sign = sign;
            }
        }
        prev = Some(r);
    }
    let noisy = n >= 3 && exceeded && changes as f64 >= p.zero_crossing_fraction * (n - 1) as f64;
    LaserSectionStats {
        count: n,
        mean,
        min,
        noisy,
    }
}

/// Algorithm 2 for one sonar section.
pub fn decide_section(
    state: SmokeState,
    laser: &LaserSectionStats,
    echo: SonarEcho,
    p: &V1Params,
) -> SectionSource {
    let sonar_or_nothing = || match echo {
        SonarEcho::Echo(_) => SectionSource::Sonar,
        _ => SectionSource::Neither,
    };
    match state {
        SmokeState::Unknown | SmokeState::Clean => SectionSource::Laser,
        SmokeState::Dense => sonar_or_nothing(),
        SmokeState::Light if laser.noisy => sonar_or_nothing(),
        SmokeState::Light => match echo {
            SonarEcho::Echo(s) if laser.count > 0 && (s - laser.min).abs() > p.disagreement_m => {
                SectionSource::Sonar
            }
            SonarEcho::Echo(_) => SectionSource::Both,
            _ => SectionSource::Laser,
        },
    }
}

/// A run of beams no sonar covers: accepted only when the bordering sections are clean.
pub fn decide_gap(
    state: SmokeState,
    left: Option<SectionSource>,
    right: Option<SectionSource>,
) -> SectionSource {
    let clean = |s: Option<SectionSource>| {
        matches!(s, None | Some(SectionSource::Laser | SectionSource::Both))
    };
    match state {
        SmokeState::Unknown | SmokeState::Clean => SectionSource::Laser,
        SmokeState::Dense => SectionSource::Neither,
        SmokeState::Light if clean(left) && clean(right) => SectionSource::Laser,
        SmokeState::Light => SectionSource::Neither,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_shared_types::{BeamReading, Header, SmokeSensorState};

    fn reading(level: f32, trend: SmokeTrend) -> SmokeReading {
        SmokeReading {
            header: Header::new(0, 0, "smoke"),
            level,
            trend: trend as u8,
            state: SmokeSensorState::Ready as u8,
            ..Default::default()
        }
    }

    fn scan(ranges: &[f32], inc: f32) -> LaserScan {
        let mut s = LaserScan {
            angle_min: -1.0,
            angle_increment: inc,
            count: ranges.len() as u32,
            range_max: 5.6,
            ..Default::default()
        };
        for (i, &r) in ranges.iter().enumerate() {
            s.set_beam(i, BeamReading::Range(r));
        }
        s
    }

    #[test]
    fn below_smoke_min_130_is_clean() {
        let p = V1Params::default();
        let mut c = SmokeClassifier::default();
        assert_eq!(
            c.update(Some(&reading(129.9, SmokeTrend::Rising)), &p),
            SmokeState::Clean
        );
        assert_eq!(
            c.update(Some(&reading(130.0, SmokeTrend::Rising)), &p),
            SmokeState::Light
        );
    }

    #[test]
    fn rising_smoke_is_dense_from_200_falling_from_240() {
        let p = V1Params::default();
        let mut c = SmokeClassifier::default();
        assert_eq!(
            c.update(Some(&reading(199.0, SmokeTrend::Rising)), &p),
            SmokeState::Light
        );
        assert_eq!(
            c.update(Some(&reading(220.0, SmokeTrend::Rising)), &p),
            SmokeState::Dense
        );
        assert_eq!(
            c.update(Some(&reading(220.0, SmokeTrend::Falling)), &p),
            SmokeState::Light
        );
        assert_eq!(
            c.update(Some(&reading(240.0, SmokeTrend::Falling)), &p),
            SmokeState::Dense
        );
    }

    #[test]
    fn steady_trend_holds_the_last_direction_while_the_sensor_settles() {
        let p = V1Params::default();
        let mut c = SmokeClassifier::default();
        c.update(Some(&reading(260.0, SmokeTrend::Rising)), &p);
        // Plateau at 220 after rising: still dense (rising threshold 200 holds).
        assert_eq!(
            c.update(Some(&reading(220.0, SmokeTrend::Steady)), &p),
            SmokeState::Dense
        );
        assert!(c.rising());
        // Once falling, the same 220 is light, and stays light on a plateau.
        assert_eq!(
            c.update(Some(&reading(225.0, SmokeTrend::Falling)), &p),
            SmokeState::Light
        );
        assert_eq!(
            c.update(Some(&reading(220.0, SmokeTrend::Steady)), &p),
            SmokeState::Light
        );
        assert!(!c.rising());
    }

    #[test]
    fn slow_recovery_keeps_the_sonar_in_use_until_smoke_min() {
        // The MQ303A decays slowly: 260 → 245 → 238 → 180 → 131 → 129.
        let p = V1Params::default();
        let mut c = SmokeClassifier::default();
        c.update(Some(&reading(260.0, SmokeTrend::Rising)), &p);
        let states: Vec<SmokeState> = [245.0, 238.0, 180.0, 131.0, 129.0]
            .iter()
            .map(|&l| c.update(Some(&reading(l, SmokeTrend::Falling)), &p))
            .collect();
        use SmokeState::*;
        assert_eq!(states, vec![Dense, Light, Light, Light, Clean]);
    }

    #[test]
    fn warming_up_sensor_is_unknown_and_means_laser() {
        let p = V1Params::default();
        let mut c = SmokeClassifier::default();
        let mut r = reading(300.0, SmokeTrend::Rising);
        r.state = SmokeSensorState::WarmingUp as u8;
        assert_eq!(c.update(Some(&r), &p), SmokeState::Unknown);
        assert_eq!(
            decide_section(
                SmokeState::Unknown,
                &LaserSectionStats::default(),
                SonarEcho::Echo(1.0),
                &p
            ),
            SectionSource::Laser
        );
    }

    #[test]
    fn smooth_wall_section_is_not_noisy() {
        // A wall at 2 m seen at 0.00614 rad steps: ranges grow smoothly.
        let ranges: Vec<f32> = (0..20).map(|i| 2.0 + 0.01 * i as f32).collect();
        let s = section_stats(&scan(&ranges, 0.006_135_9), 0, 20, &V1Params::default());
        assert_eq!(s.count, 20);
        assert!(!s.noisy);
        assert!((s.min - 2.0).abs() < 1e-6);
    }

    #[test]
    fn alternating_ranges_beyond_max_diff_are_noisy() {
        // Smoke speckle: 0.8, 1.1, 0.7, 1.2, …: MAX_DIFF = 0.0061·0.95 ≈ 6 mm is
        // exceeded and every difference changes sign (18 of 19 ≥ 19/3).
        let ranges: Vec<f32> = (0..20)
            .map(|i| if i % 2 == 0 { 0.8 } else { 1.1 })
            .collect();
        let s = section_stats(&scan(&ranges, 0.006_135_9), 0, 20, &V1Params::default());
        assert!(s.noisy);
    }

    #[test]
    fn few_sign_changes_are_below_a_third() {
        // 19 differences, 3 dips = 6 sign changes < 19/3 = 6.33: not noisy.
        let mut ranges = vec![1.0f32; 20];
        for (i, r) in ranges.iter_mut().enumerate() {
            *r = 1.0 + 0.05 * i as f32;
        }
        for i in [3, 7, 11] {
            ranges[i] = ranges[i - 1] - 0.02;
        }
        let s = section_stats(&scan(&ranges, 0.006_135_9), 0, 20, &V1Params::default());
        assert!(!s.noisy);
    }

    #[test]
    fn light_smoke_decisions_follow_algorithm_2() {
        let p = V1Params::default();
        let clean = LaserSectionStats {
            count: 10,
            mean: 2.0,
            min: 1.9,
            noisy: false,
        };
        let noisy = LaserSectionStats {
            noisy: true,
            ..clean
        };
        use SectionSource::*;
        let l = SmokeState::Light;
        assert_eq!(decide_section(l, &clean, SonarEcho::Echo(2.0), &p), Both);
        assert_eq!(
            decide_section(l, &clean, SonarEcho::Echo(1.0), &p),
            Sonar,
            "0.9 m apart > 0.3 m"
        );
        assert_eq!(decide_section(l, &clean, SonarEcho::Saturated, &p), Laser);
        assert_eq!(decide_section(l, &noisy, SonarEcho::Echo(2.0), &p), Sonar);
        assert_eq!(decide_section(l, &noisy, SonarEcho::Missing, &p), Neither);
        assert_eq!(
            decide_section(SmokeState::Dense, &clean, SonarEcho::Echo(2.0), &p),
            Sonar
        );
        assert_eq!(
            decide_section(SmokeState::Dense, &clean, SonarEcho::Saturated, &p),
            Neither
        );
        assert_eq!(
            decide_section(SmokeState::Clean, &noisy, SonarEcho::Echo(1.0), &p),
            Laser
        );
    }

    #[test]
    fn uncovered_beams_need_both_neighbours_clean() {
        use SectionSource::*;
        let l = SmokeState::Light;
        assert_eq!(decide_gap(l, Some(Laser), Some(Both)), Laser);
        assert_eq!(decide_gap(l, Some(Laser), Some(Sonar)), Neither);
        assert_eq!(decide_gap(l, Some(Neither), Some(Laser)), Neither);
        assert_eq!(decide_gap(l, None, Some(Laser)), Laser);
        assert_eq!(
            decide_gap(SmokeState::Dense, Some(Laser), Some(Laser)),
            Neither
        );
        assert_eq!(
            decide_gap(SmokeState::Clean, Some(Sonar), Some(Sonar)),
            Laser
        );
    }
}
