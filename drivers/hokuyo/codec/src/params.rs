//! Typed VV / PP / II replies and the scan geometry PP defines.
//!
//! These are read once per connection, so they own their strings.

use crate::error::ParamError;
use crate::reply::Reply;
use crate::status::Command;
use std::f64::consts::PI;

fn check_reply(reply: &Reply<'_>, expected: Command) -> Result<(), ParamError> {
    if reply.echo.command != expected {
        return Err(ParamError::WrongCommand {
            expected,
            got: reply.echo.command,
        });
    }
    if !reply.status.is_ok() {
        return Err(ParamError::Status {
            command: expected,
            status: reply.status,
            meaning: reply.status.meaning(expected),
        });
    }
    Ok(())
}

/// All `KEY:VALUE` pairs of a reply, in order, checksums verified.
pub fn collect_params(reply: &Reply<'_>) -> Result<Vec<(String, String)>, ParamError> {
    reply
        .params()
        .map(|p| {
            p.map(|p| (p.key_str().into_owned(), p.value_str().into_owned()))
                .map_err(ParamError::from)
        })
        .collect()
}

fn lookup(pairs: &[(String, String)], key: &str) -> Option<String> {
    pairs.iter().find(|(k, _)| k == key).map(|(_, v)| v.clone())
}

fn number(
    pairs: &[(String, String)],
    command: Command,
    key: &'static str,
) -> Result<u32, ParamError> {
    let v = lookup(pairs, key).ok_or(ParamError::Missing { command, key })?;
    // Some firmware appends units or notes after the digits; the digits come first.
    let digits: &str = v.split(|c: char| !c.is_ascii_digit()).next().unwrap_or("");
    digits.parse().map_err(|_| ParamError::NotNumber {
        key,
        value: v.clone(),
    })
}

/// `VV`: version information. Fields a firmware omits are empty.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct VersionInfo {
    pub vendor: String,
    pub product: String,
    pub firmware: String,
    pub protocol: String,
    pub serial: String,
}

impl VersionInfo {
    pub fn from_reply(reply: &Reply<'_>) -> Result<Self, ParamError> {
        check_reply(reply, Command::Vv)?;
        let p = collect_params(reply)?;
        let get = |k| lookup(&p, k).unwrap_or_default();
        Ok(VersionInfo {
            vendor: get("VEND"),
            product: get("PROD"),
            firmware: get("FIRM"),
            protocol: get("PROT"),
            serial: get("SERI"),
        })
    }
}

/// `PP`: the sensor's specification. Every field is required.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SensorSpec {
    pub model: String,
    pub geometry: Geometry,
}

impl SensorSpec {
    pub fn from_reply(reply: &Reply<'_>) -> Result<Self, ParamError> {
        check_reply(reply, Command::Pp)?;
        let p = collect_params(reply)?;
        let c = Command::Pp;
        let model = lookup(&p, "MODL").ok_or(ParamError::Missing {
            command: c,
            key: "MODL",
        })?;
        let geometry = Geometry {
            dmin_mm: number(&p, c, "DMIN")?,
            dmax_mm: number(&p, c, "DMAX")?,
            ares: number(&p, c, "ARES")?,
            amin: number(&p, c, "AMIN")?,
            amax: number(&p, c, "AMAX")?,
            afrt: number(&p, c, "AFRT")?,
            scan_rpm: number(&p, c, "SCAN")?,
        };
        geometry.validate().map_err(ParamError::Geometry)?;
        Ok(SensorSpec { model, geometry })
    }

    pub fn family(&self) -> ModelFamily {
        ModelFamily::from_model(&self.model)
    }
}

/// `II`: the sensor's state. Fields a firmware omits are empty.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct SensorState {
    pub model: String,
    /// `LASR`: `ON` / `OFF`.
    pub laser: String,
    pub scan_speed: String,
    pub measure_mode: String,
    pub bit_rate: String,
    /// `TIME`: raw; its encoding differs between models.
    pub time: String,
    /// `STAT`: the sensor's own health sentence.
    pub stat: String,
}

impl SensorState {
    pub fn from_reply(reply: &Reply<'_>) -> Result<Self, ParamError> {
        check_reply(reply, Command::Ii)?;
        let p = collect_params(reply)?;
        let get = |k| lookup(&p, k).unwrap_or_default();
        Ok(SensorState {
            model: get("MODL"),
            laser: get("LASR"),
            scan_speed: get("SCSP"),
            measure_mode: get("MESM"),
            bit_rate: get("SBPS"),
            time: get("TIME"),
            stat: get("STAT"),
        })
    }

    /// True when STAT reads like the sensor's "all is well" sentence
    /// ("Sensor works well." on the 04LX, "Stable ..." / "normal" on others).
    pub fn is_healthy(&self) -> bool {
        let s = self.stat.to_ascii_lowercase();
        s.contains("works well") || s.contains("normal") || s.contains("stable")
    }
}

/// Sensor families that differ in what they support.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModelFamily {
    /// URG-04LX, URG-04LX-UG01: SCIP 1.1 at boot, no ME (probing it can hang the sensor).
    Urg04lx,
    /// UTM-30LX(-EW): ME supported.
    Utm30lx,
    /// UST-10LX/20LX: ME supported.
    Ust,
    Unknown,
}

impl ModelFamily {
    /// Classifies a PP/II `MODL` string.
    pub fn from_model(model: &str) -> ModelFamily {
        let m = model.trim_start().to_ascii_uppercase();
        if m.starts_with("URG-04LX") {
            ModelFamily::Urg04lx
        } else if m.starts_with("UTM-30LX") {
            ModelFamily::Utm30lx
        } else if m.starts_with("UST-") {
            ModelFamily::Ust
        } else {
            ModelFamily::Unknown
        }
    }

    /// Whether ME (range + intensity) may be sent. Unknown models are never probed.
    pub fn supports_intensity(self) -> bool {
        matches!(self, ModelFamily::Utm30lx | ModelFamily::Ust)
    }

    /// What a sensor error code (a value below DMIN) means on this family.
    pub fn error_meaning(self, code: u32) -> &'static str {
        match (self, code) {
            (ModelFamily::Urg04lx, 0) => "possibly beyond 22 m (nothing in range)",
            (ModelFamily::Urg04lx, 1 | 2) => "low intensity",
            (ModelFamily::Urg04lx, 6) => "other error (possibly 5.7 m)",
            (ModelFamily::Urg04lx, 7) => "neighbouring steps in error",
            (ModelFamily::Urg04lx, 8) => "intensity difference of two waves",
            (ModelFamily::Urg04lx, 9) => "same step failed twice",
            (ModelFamily::Urg04lx, 18) => "strong reflector",
            (ModelFamily::Urg04lx, 19) => "step not measurable",
            (ModelFamily::Urg04lx, _) => "other error",
            (ModelFamily::Utm30lx | ModelFamily::Ust, 1) => "no object",
            (ModelFamily::Utm30lx | ModelFamily::Ust, 2) => "object too near",
            (ModelFamily::Utm30lx | ModelFamily::Ust, 3) => "interference",
            (ModelFamily::Utm30lx | ModelFamily::Ust, 4) => "near-end out of range",
            _ => "other error",
        }
    }
}

/// Scan geometry from PP. Never hard-coded: every model reports its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Geometry {
    /// Values below this are error codes, not ranges.
    pub dmin_mm: u32,
    pub dmax_mm: u32,
    /// Steps per full revolution.
    pub ares: u32,
    /// First measurable step.
    pub amin: u32,
    /// Last measurable step.
    pub amax: u32,
    /// Step pointing straight ahead (angle 0).
    pub afrt: u32,
    /// Motor speed, revolutions per minute.
    pub scan_rpm: u32,
}

/// One value of a scan, classified against DMIN/DMAX.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reading {
    /// A range in mm within DMIN..=DMAX.
    Range(u32),
    /// A range in mm above DMAX.
    BeyondMax(u32),
    /// A sensor error code (the value was below DMIN).
    Code(u32),
}

impl Geometry {
    /// The URG-04LX, as its PP reply states it (firmware 3.1.00): 682 steps of
    /// 2π/1024 from step 44 to 725, step 384 straight ahead, 600 rpm, ranges
    /// 20–5600 mm. The one place this model's geometry is written down.
    pub const URG_04LX: Geometry = Geometry {
        dmin_mm: 20,
        dmax_mm: 5600,
        ares: 1024,
        amin: 44,
        amax: 725,
        afrt: 384,
        scan_rpm: 600,
    };

    /// Checks the relations every sensor satisfies (AMIN ≤ AFRT ≤ AMAX < ARES, …).
    pub fn validate(&self) -> Result<(), String> {
        if self.ares == 0 || self.ares > 1 << 16 {
            return Err(format!(
                "ARES {} is not a usable steps-per-revolution",
                self.ares
            ));
        }
        if !(self.amin <= self.afrt && self.afrt <= self.amax && self.amax < self.ares) {
            return Err(format!(
                "expected AMIN <= AFRT <= AMAX < ARES, got AMIN {} AFRT {} AMAX {} ARES {}",
                self.amin, self.afrt, self.amax, self.ares
            ));
        }
        if self.amax > 9999 {
            return Err(format!(
                "AMAX {} does not fit a 4-digit step field",
                self.amax
            ));
        }
        if self.scan_rpm == 0 {
            return Err("SCAN is 0 rpm".into());
        }
        if self.dmin_mm >= self.dmax_mm {
            return Err(format!(
                "DMIN {} mm is not below DMAX {} mm",
                self.dmin_mm, self.dmax_mm
            ));
        }
        Ok(())
    }

    /// Angle of one step.
    pub fn step_rad(&self) -> f64 {
        2.0 * PI / f64::from(self.ares.max(1))
    }

    /// Angle of step `s`, rad, counter-clockwise, 0 straight ahead: (s − AFRT)·2π/ARES.
    pub fn step_angle(&self, step: u32) -> f64 {
        (f64::from(step) - f64::from(self.afrt)) * self.step_rad()
    }

    /// Measurable steps AMIN..=AMAX.
    pub fn step_count(&self) -> usize {
        (self.amax.saturating_sub(self.amin) + 1) as usize
    }

    /// Seconds per revolution.
    pub fn scan_period_s(&self) -> f64 {
        60.0 / f64::from(self.scan_rpm.max(1))
    }

    /// Seconds between two steps: 60 / (SCAN · ARES) (97.66 µs on the 04LX).
    pub fn step_time_s(&self) -> f64 {
        self.scan_period_s() / f64::from(self.ares.max(1))
    }

    /// Seconds from the scan timestamp (taken at the rear, angle ±π) to step `s`:
    /// (angle(s) + π) / 2π · period.
    pub fn time_from_rear_s(&self, step: u32) -> f64 {
        (self.step_angle(step) + PI) / (2.0 * PI) * self.scan_period_s()
    }

    /// Classifies one raw value.
    pub fn classify(&self, raw: u32) -> Reading {
        if raw < self.dmin_mm {
            Reading::Code(raw)
        } else if raw > self.dmax_mm {
            Reading::BeyondMax(raw)
        } else {
            Reading::Range(raw)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn urg04lx() -> Geometry {
        Geometry::URG_04LX
    }

    #[test]
    fn urg04lx_geometry_spans_682_steps_at_97_66_us() {
        let g = urg04lx();
        assert_eq!(g.step_count(), 682);
        assert!((g.step_time_s() * 1e6 - 97.656_25).abs() < 1e-6);
        assert!((g.scan_period_s() - 0.1).abs() < 1e-12);
        assert_eq!(g.step_angle(384), 0.0);
        // Step 44: (44 − 384)·2π/1024 = −2.0862 rad (−119.5°).
        assert!((g.step_angle(44) - (-340.0 * 2.0 * PI / 1024.0)).abs() < 1e-12);
        // From the rear to step 44: (−2.0862 + π)/2π · 100 ms = 16.80 ms.
        assert!((g.time_from_rear_s(44) - 0.016_796_875).abs() < 1e-9);
    }

    #[test]
    fn values_below_dmin_are_codes_not_ranges() {
        let g = urg04lx();
        assert_eq!(g.classify(0), Reading::Code(0));
        assert_eq!(g.classify(19), Reading::Code(19));
        assert_eq!(g.classify(20), Reading::Range(20));
        assert_eq!(g.classify(5600), Reading::Range(5600));
        assert_eq!(g.classify(5601), Reading::BeyondMax(5601));
    }

    #[test]
    fn geometry_validation_names_the_broken_relation() {
        let g = Geometry {
            afrt: 900,
            ..urg04lx()
        };
        assert!(g.validate().unwrap_err().contains("AFRT 900"));
        assert!(
            Geometry {
                scan_rpm: 0,
                ..urg04lx()
            }
            .validate()
            .is_err()
        );
        assert!(urg04lx().validate().is_ok());
    }

    #[test]
    fn only_utm_and_ust_may_be_asked_for_intensity() {
        assert!(
            !ModelFamily::from_model("URG-04LX(Hokuyo Automatic Co.,Ltd.)").supports_intensity()
        );
        assert!(!ModelFamily::from_model("URG-04LX-UG01").supports_intensity());
        assert!(ModelFamily::from_model("UTM-30LX-EW").supports_intensity());
        assert!(!ModelFamily::from_model("UBG-04LX-F01").supports_intensity());
    }
}
