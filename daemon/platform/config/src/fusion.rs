//! `[fusion]`: the synchroniser and the SmokeNav methods.
//!
//! Every threshold and membership breakpoint of both methods is a key here,
//! with the value of SmokeNav (Santos et al. 2015) as the default where the
//! paper gives one. What the methods do with them — the paper's tables, where
//! its text is ambiguous and what was decided, what goes beyond it — is the
//! design documentation beside the code: `smokenav_algorithms_fusion::v1` and
//! `smokenav_algorithms_fusion::v2` (`daemon/algorithms/fusion/src/v1.rs`,
//! `v2.rs`); the synchroniser follows ROS message_filters' ApproximateTime
//! policy (`smokenav_algorithms_fusion::sync`).
//!
//! | key                         | meaning                                                                   | default              | range                       |
//! |-----------------------------|---------------------------------------------------------------------------|----------------------|-----------------------------|
//! | `method`                    | fusion method: `laser-only`, `v1` or `v2`                                 | `v2`                 | one of the three            |
//! | `sonar_cap_m`               | sonar readings beyond are saturated, m                                    | 2.5                  | [0.2, 20]                   |
//! | `section_range_m`           | range at which a sonar's cone defines its laser section τ, m              | `sonar_cap_m`        | [0.2, 20]                   |
//! | `sync.queue_size`           | messages kept per input topic                                             | 8                    | 2–1000                      |
//! | `sync.max_interval_s`       | widest stamp span of a set, s                                             | 0.15                 | [0.001, 5]                  |
//! | `sync.timeout_s`            | an input silent this long no longer holds up the output, s                | 0.5                  | [0.01, 10]                  |
//! | `sync.age_penalty`          | ROS's age penalty                                                         | 0.1                  | [0, 10]                     |
//! | `sync.laser_min_period_s`   | inter-message lower bound of the laser, s (0 off)                         | 0.05                 | [0, 10], < `sync.timeout_s` |
//! | `sync.sonar_min_period_s`   | … of the sonar ring, s                                                    | 0.05                 | [0, 10], < `sync.timeout_s` |
//! | `sync.smoke_min_period_s`   | … of the smoke sensor, s                                                  | 0.05                 | [0, 10], < `sync.timeout_s` |
//! | `v1.smoke_min`              | SMOKE_MIN: below it, only the laser                                       | 130                  | ≥ 0, < both maxima          |
//! | `v1.smoke_max_up`           | SMOKE_MAX_UP: rising smoke at or above it, only the sonar                 | 200                  | finite                      |
//! | `v1.smoke_max_down`         | SMOKE_MAX_DOWN: the same while the smoke falls                            | 240                  | finite                      |
//! | `v1.zero_crossing_fraction` | share of sign changes that makes a laser section noisy                    | 1/3                  | [0, 1]                      |
//! | `v1.noise_floor_m`          | differences up to this carry no sign, m                                   | 0                    | [0, 1]                      |
//! | `v1.disagreement_m`         | laser–sonar difference at which the sonar replaces the laser, m           | 0.3                  | [0, 20]                     |
//! | `v2.rho_threshold`          | ρT: a source needs more trust than this                                   | 0.5                  | [0, 1]                      |
//! | `v2.confident`              | μ Confident over the sonar range, m                                       | 0.05, 0.15, 2.0, 3.0 | Π shape                     |
//! | `v2.alcoholized`            | μ Alcoholized over the smoke level                                        | 10, 30, inf, inf     | Π shape                     |
//! | `v2.dense`                  | μ Dense over the laser's spread σ, m                                      | 0, 0, 0.6, 1.0       | Π shape                     |
//! | `v2.contradicted`           | μ Contradicted over the share of laser ranges nearer than the sonar's arc | 0.1, 0.3, inf, inf   | Π shape                     |
//! | `v2.contradiction_margin_m` | how much nearer a laser range must be to contradict, m                    | 0.3                  | [0, 5]                      |
//! | `v2.keep_uncontradicted_laser` | in a section given to its sonar, laser beams the sonar does not contradict stay | true          | bool                        |
//! | `v2.speck_max_beams`        | in measured smoke, laser runs this long nearer than both sides drop (0: off) | 2                    | 0–16                        |
//! | `v2.output_bell`            | the consequent bell: `width` at μ = 0.5, `slope`                          | 0.2, 2.0             | [0.01, 1], [0.1, 20]        |
//! | `v2.defuzz_samples`         | points of [0, 1] the centroid is taken over                               | 101                  | 11–10001                    |
//!
//! A Π shape is written `{ a = …, b = …, c = …, d = … }`: 0 below `a`, 1
//! from `b` to `c`, 0 above `d`, with `a <= b <= c <= d`; `c` and `d` may be
//! `inf` (an open shoulder). Every other value must be finite.

use crate::validate::{Validate, Validator};
use serde::{Deserialize, Serialize};
pub use smokenav_shared_types::FusionMethod;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FusionSection {
    #[serde(default = "default_method")]
    pub method: FusionMethod,
    /// Sonar readings beyond this are treated as saturated (the paper limited sonar to 2.5 m).
    #[serde(default = "default_cap")]
    pub sonar_cap_m: f64,
    /// Range at which a sonar's cone defines its laser section τ (the beams
    /// whose angle lies within the cone seen from the laser). Unset: `sonar_cap_m`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub section_range_m: Option<f64>,
    #[serde(default)]
    pub sync: SyncParams,
    #[serde(default)]
    pub v1: V1Params,
    #[serde(default)]
    pub v2: V2Params,
}

fn default_method() -> FusionMethod {
    FusionMethod::V2
}
fn default_cap() -> f64 {
    2.5
}

impl Default for FusionSection {
    fn default() -> Self {
        Self {
            method: default_method(),
            sonar_cap_m: default_cap(),
            section_range_m: None,
            sync: SyncParams::default(),
            v1: V1Params::default(),
            v2: V2Params::default(),
        }
    }
}

impl FusionSection {
    /// The range that defines the sections.
    pub fn section_range(&self) -> f64 {
        self.section_range_m.unwrap_or(self.sonar_cap_m)
    }
}

/// Approximate-time synchronisation (ROS message_filters semantics plus a timeout).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SyncParams {
    /// Messages kept per input topic.
    pub queue_size: usize,
    /// A set whose stamps span more than this is never formed, s.
    pub max_interval_s: f64,
    /// An input silent for this long no longer holds up the output, s.
    pub timeout_s: f64,
    /// ROS's age penalty: how much a later set must improve on the span of an
    /// earlier one to replace it (message_filters' code uses 0.1).
    pub age_penalty: f64,
    /// Inter-message lower bounds (ROS `setInterMessageLowerBound`), s: the
    /// shortest time between two messages of one topic. They let a set go out
    /// as soon as its last member arrives instead of one period later; a bound
    /// larger than the true period can pair suboptimally. 0 disables.
    /// Defaults: half the 10 Hz period of all three sensors in the paper.
    pub laser_min_period_s: f64,
    pub sonar_min_period_s: f64,
    pub smoke_min_period_s: f64,
}

impl Default for SyncParams {
    fn default() -> Self {
        Self {
            queue_size: 8,
            max_interval_s: 0.15,
            timeout_s: 0.5,
            age_penalty: 0.1,
            laser_min_period_s: 0.05,
            sonar_min_period_s: 0.05,
            smoke_min_period_s: 0.05,
        }
    }
}

/// SmokeNav v1: the heuristic of Algorithm 2.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct V1Params {
    /// Below this smoke level only the laser is used (SMOKE_MIN, 130 mV).
    pub smoke_min: f64,
    /// While the smoke rises, at or above this only the sonar is used (SMOKE_MAX_UP, 200 mV).
    pub smoke_max_up: f64,
    /// While it falls, at or above this only the sonar is used (SMOKE_MAX_DOWN,
    /// 240 mV: the MQ303A recovers slowly, so a falling reading overstates the smoke).
    pub smoke_max_down: f64,
    /// A laser section is noisy when at least this share of its Ns−1 successive
    /// differences change sign (the paper: a third).
    pub zero_crossing_fraction: f64,
    /// Differences of at most this magnitude carry no sign in the test, m (0 = the paper).
    pub noise_floor_m: f64,
    /// Laser and sonar of one section disagree when the nearest laser range
    /// and the sonar range differ by more than this, m; the sonar then replaces the laser.
    pub disagreement_m: f64,
}

impl Default for V1Params {
    fn default() -> Self {
        Self {
            smoke_min: 130.0,
            smoke_max_up: 200.0,
            smoke_max_down: 240.0,
            zero_crossing_fraction: 1.0 / 3.0,
            noise_floor_m: 0.0,
            disagreement_m: 0.3,
        }
    }
}

/// A Π-shaped membership function: 0 below `a`, S-curve up to 1 at `b`, 1 up
/// to `c`, Z-curve down to 0 at `d`. `c` and `d` may be `inf`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PiShape {
    pub a: f64,
    pub b: f64,
    pub c: f64,
    pub d: f64,
}

impl PiShape {
    pub const fn new(a: f64, b: f64, c: f64, d: f64) -> Self {
        Self { a, b, c, d }
    }

    fn validate(&self, key: &str, v: &mut Validator) {
        v.finite(&format!("{key}.a"), self.a);
        v.finite(&format!("{key}.b"), self.b);
        for (k, x) in [("c", self.c), ("d", self.d)] {
            if x.is_nan() || x == f64::NEG_INFINITY {
                v.fail(
                    format!("{key}.{k}"),
                    format!("must be a number or inf, got {x}"),
                );
            }
        }
        let ok = self.a <= self.b && self.b <= self.c && self.c <= self.d;
        if !ok {
            v.fail(
                key.to_owned(),
                format!(
                    "breakpoints must satisfy a <= b <= c <= d, got a={} b={} c={} d={}",
                    self.a, self.b, self.c, self.d
                ),
            );
        }
    }
}

/// A generalised bell `1 / (1 + |(x − centre) / width|^(2·slope))`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BellShape {
    /// Half-width at μ = 0.5.
    pub width: f64,
    /// Steepness of the flanks.
    pub slope: f64,
}

/// SmokeNav v2: the fuzzy model of Algorithm 3 and Fig. 14.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct V2Params {
    /// ρT: a source is chosen only if its trust exceeds this (the paper: 1/2).
    pub rho_threshold: f64,
    /// μ Confident over the section's sonar range, m.
    pub confident: PiShape,
    /// μ Alcoholized over the smoke level (the SmokeNav paper's mV scale, see `SmokeReading::level`).
    pub alcoholized: PiShape,
    /// μ Dense over the standard deviation of the scan's valid ranges, m.
    pub dense: PiShape,
    /// Beyond the paper: μ Contradicted over the share of a section's laser
    /// ranges that lie nearer than the section's sonar says anything is (its
    /// echo arc, or its cap when it heard nothing within it) by more than
    /// `contradiction_margin_m`. Ultrasound passes through smoke, so in
    /// alcoholized air such a section is a phantom wall (see the module docs).
    pub contradicted: PiShape,
    /// How much nearer than the sonar's arc a laser range must be to count as contradicting it, m.
    pub contradiction_margin_m: f64,
    /// Beyond the paper: in a section given to its sonar, laser beams the
    /// sonar does not contradict (no nearer than its echo's arc by more than
    /// `contradiction_margin_m`) stay the laser's; only the others get the
    /// arc. Smoke catches a beam short, in front of the surface; a beam that
    /// reached the sonar's nearest surface, or passed it, was not caught.
    /// Off, the whole section is the sonar's arc, as in the paper.
    pub keep_uncontradicted_laser: bool,
    /// Beyond the paper: where the smoke sensor measures smoke (μ
    /// Alcoholized > 0), a run of at most this many laser beams that lies
    /// nearer than the beams on both sides by more than
    /// `contradiction_margin_m` is dropped. Patchy smoke catches single
    /// beams early; below the witness's threshold and between the sonar
    /// cones nothing else removes them, and each became a speck of wall in
    /// the map. 0 turns it off; it also drops objects that narrow (at 2 m
    /// 2 beams are 2.5 cm), so only while smoke is measured.
    pub speck_max_beams: u32,
    /// The consequent bell, used centred at 1 (trust) and at 0 (distrust) for both outputs.
    pub output_bell: BellShape,
    /// Points of [0, 1] the centroid is taken over.
    pub defuzz_samples: usize,
}

impl Default for V2Params {
    fn default() -> Self {
        Self {
            rho_threshold: 0.5,
            confident: PiShape::new(0.05, 0.15, 2.0, 3.0),
            alcoholized: PiShape::new(10.0, 30.0, f64::INFINITY, f64::INFINITY),
            dense: PiShape::new(0.0, 0.0, 0.6, 1.0),
            contradicted: PiShape::new(0.1, 0.3, f64::INFINITY, f64::INFINITY),
            contradiction_margin_m: 0.3,
            keep_uncontradicted_laser: true,
            speck_max_beams: 2,
            output_bell: BellShape {
                width: 0.2,
                slope: 2.0,
            },
            defuzz_samples: 101,
        }
    }
}

impl Validate for FusionSection {
    fn validate(&self, key: &str, v: &mut Validator) {
        v.within(&format!("{key}.sonar_cap_m"), self.sonar_cap_m, 0.2, 20.0);
        if let Some(r) = self.section_range_m {
            v.within(&format!("{key}.section_range_m"), r, 0.2, 20.0);
        }
        self.sync.validate(&format!("{key}.sync"), v);
        self.v1.validate(&format!("{key}.v1"), v);
        self.v2.validate(&format!("{key}.v2"), v);
    }
}

impl Validate for SyncParams {
    fn validate(&self, key: &str, v: &mut Validator) {
        if !(2..=1000).contains(&self.queue_size) {
            v.fail(
                format!("{key}.queue_size"),
                format!("must be 2–1000, got {}", self.queue_size),
            );
        }
        v.within(
            &format!("{key}.max_interval_s"),
            self.max_interval_s,
            0.001,
            5.0,
        );
        v.within(&format!("{key}.timeout_s"), self.timeout_s, 0.01, 10.0);
        v.within(&format!("{key}.age_penalty"), self.age_penalty, 0.0, 10.0);
        for (k, p) in [
            ("laser_min_period_s", self.laser_min_period_s),
            ("sonar_min_period_s", self.sonar_min_period_s),
            ("smoke_min_period_s", self.smoke_min_period_s),
        ] {
            v.within(&format!("{key}.{k}"), p, 0.0, 10.0);
            v.ordered(
                &format!("{key}.{k}"),
                p,
                &format!("{key}.timeout_s"),
                self.timeout_s,
            );
        }
    }
}

impl Validate for V1Params {
    fn validate(&self, key: &str, v: &mut Validator) {
        v.non_negative(&format!("{key}.smoke_min"), self.smoke_min);
        v.finite(&format!("{key}.smoke_max_up"), self.smoke_max_up);
        v.finite(&format!("{key}.smoke_max_down"), self.smoke_max_down);
        v.ordered(
            &format!("{key}.smoke_min"),
            self.smoke_min,
            &format!("{key}.smoke_max_up"),
            self.smoke_max_up,
        );
        v.ordered(
            &format!("{key}.smoke_min"),
            self.smoke_min,
            &format!("{key}.smoke_max_down"),
            self.smoke_max_down,
        );
        v.within(
            &format!("{key}.zero_crossing_fraction"),
            self.zero_crossing_fraction,
            0.0,
            1.0,
        );
        v.within(
            &format!("{key}.noise_floor_m"),
            self.noise_floor_m,
            0.0,
            1.0,
        );
        v.within(
            &format!("{key}.disagreement_m"),
            self.disagreement_m,
            0.0,
            20.0,
        );
    }
}

impl Validate for V2Params {
    fn validate(&self, key: &str, v: &mut Validator) {
        v.within(
            &format!("{key}.rho_threshold"),
            self.rho_threshold,
            0.0,
            1.0,
        );
        self.confident.validate(&format!("{key}.confident"), v);
        self.alcoholized.validate(&format!("{key}.alcoholized"), v);
        self.dense.validate(&format!("{key}.dense"), v);
        self.contradicted
            .validate(&format!("{key}.contradicted"), v);
        v.within(
            &format!("{key}.contradiction_margin_m"),
            self.contradiction_margin_m,
            0.0,
            5.0,
        );
        v.within(
            &format!("{key}.speck_max_beams"),
            f64::from(self.speck_max_beams),
            0.0,
            16.0,
        );
        v.within(
            &format!("{key}.output_bell.width"),
            self.output_bell.width,
            0.01,
            1.0,
        );
        v.within(
            &format!("{key}.output_bell.slope"),
            self.output_bell.slope,
            0.1,
            20.0,
        );
        if !(11..=10_001).contains(&self.defuzz_samples) {
            v.fail(
                format!("{key}.defuzz_samples"),
                format!("must be 11–10001, got {}", self.defuzz_samples),
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::parse_toml;
    use std::path::Path;

    fn parse(text: &str) -> Result<FusionSection, String> {
        let s: FusionSection =
            parse_toml(text, Path::new("fusion.toml")).map_err(|e| e.to_string())?;
        let mut v = Validator::default();
        s.validate("fusion", &mut v);
        if v.issues.is_empty() {
            Ok(s)
        } else {
            Err(v
                .issues
                .iter()
                .map(|i| i.to_string())
                .collect::<Vec<_>>()
                .join("\n"))
        }
    }

    #[test]
    fn empty_section_has_the_papers_values() {
        let s = parse("").unwrap();
        assert_eq!(s.method, FusionMethod::V2);
        assert_eq!(s.sonar_cap_m, 2.5);
        assert_eq!(s.section_range(), 2.5);
        assert_eq!(
            (s.v1.smoke_min, s.v1.smoke_max_up, s.v1.smoke_max_down),
            (130.0, 200.0, 240.0)
        );
        assert_eq!(s.v2.rho_threshold, 0.5);
        assert_eq!(s.sync.age_penalty, 0.1);
    }

    #[test]
    fn open_shoulder_round_trips_as_inf() {
        let s = FusionSection::default();
        let text = toml::to_string(&s).unwrap();
        assert!(text.contains("inf"), "{text}");
        let back = parse(&text).unwrap();
        assert_eq!(back, s);
    }

    #[test]
    fn breakpoints_out_of_order_are_rejected_with_key() {
        let err = parse("[v2]\nconfident = { a = 0.1, b = 0.05, c = 2.0, d = 3.0 }\n").unwrap_err();
        assert!(err.contains("fusion.v2.confident"), "{err}");
        assert!(err.contains("a <= b"), "{err}");
    }

    #[test]
    fn smoke_thresholds_must_exceed_smoke_min() {
        let err = parse("[v1]\nsmoke_min = 250.0\n").unwrap_err();
        assert!(err.contains("fusion.v1.smoke_min"), "{err}");
    }

    #[test]
    fn unknown_v2_key_is_rejected() {
        let err = parse("[v2]\nrho_t = 0.4\n").unwrap_err();
        assert!(err.contains("rho_t"), "{err}");
    }

    /// The key table of the module docs lists every key of the section, and nothing else.
    #[test]
    fn module_docs_list_every_key() {
        let documented: std::collections::BTreeSet<String> = include_str!("fusion.rs")
            .lines()
            .take_while(|l| l.starts_with("//!"))
            .filter_map(|l| l.strip_prefix("//! | `"))
            .filter_map(|l| l.split('`').next())
            .map(str::to_owned)
            .collect();
        let section = FusionSection {
            section_range_m: Some(2.5),
            ..FusionSection::default()
        };
        let table: toml::Table = toml::from_str(&toml::to_string(&section).unwrap()).unwrap();
        let mut keys = std::collections::BTreeSet::new();
        for (k, v) in &table {
            match v.as_table() {
                // Π shapes and the bell are one row each.
                Some(t) if k == "sync" || k == "v1" || k == "v2" => {
                    keys.extend(t.keys().map(|sub| format!("{k}.{sub}")))
                }
                _ => {
                    keys.insert(k.clone());
                }
            }
        }
        assert_eq!(documented, keys);
    }

    #[test]
    fn lower_bound_must_be_below_timeout() {
        let err = parse("[sync]\ntimeout_s = 0.04\n").unwrap_err();
        assert!(err.contains("fusion.sync.laser_min_period_s"), "{err}");
    }
}
