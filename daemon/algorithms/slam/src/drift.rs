//! Drifted logs: real scans whose odometry is a corrected trajectory
//! corrupted with seeded noise and systematic drift, for measuring SLAM on
//! large loops with strong drift against a known reference.
//!
//! Each laser record's motion since the previous one (taken from its
//! odometry pose: in a corrected log such as GMapping's CSAIL output that is
//! the corrected pose) is replaced by
//!
//! - translation × (1 + `scale`) plus N(0, (`sigma_t` · step)²) along and across,
//! - rotation × (1 + `turn_scale`) plus `heading_bias` per metre travelled
//!   plus N(0, (`sigma_r` · |turn| + `sigma_r_per_m` · step)²),
//!
//! and the records are written back with the drifted pose as their
//! odometry (and laser) pose. The heading bias is what bends a long loop by
//! metres, as a miscalibrated wheel base does. Same seed, same output.
//! Optionally the stamps are replaced (`stamps`): the corrected CSAIL log
//! keeps only six digits of its timestamps, its reference poses file has them.
//! A stamp that does not come after the one before is moved a second after
//! it, and a line that cannot be read is left out; the report counts both.

use crate::carmen::{CarmenError, CarmenReader, LaserRecord, LaserRecordKind, LineError, Record};
use smokenav_shared_types::{Pose2, Rng};
use std::io::{BufRead, Write};

/// How a log's motion is corrupted.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriftParams {
    pub seed: u64,
    /// Translation scale error (0.02: every step reads 2 % long).
    pub scale: f64,
    /// Rotation scale error.
    pub turn_scale: f64,
    /// Heading error per metre travelled, rad/m.
    pub heading_bias: f64,
    /// σ of the translation noise per metre of step.
    pub sigma_t: f64,
    /// σ of the rotation noise per radian of turn.
    pub sigma_r: f64,
    /// σ of the rotation noise per metre of step, rad/m.
    pub sigma_r_per_m: f64,
}

impl Default for DriftParams {
    fn default() -> Self {
        Self {
            seed: 1,
            scale: 0.02,
            turn_scale: 0.01,
            heading_bias: 0.004,
            sigma_t: 0.02,
            sigma_r: 0.02,
            sigma_r_per_m: 0.003,
        }
    }
}

impl DriftParams {
    /// No drift at all: the log's own poses become the odometry (what is
    /// left of a run's error against them is not drift).
    pub fn none() -> Self {
        Self {
            scale: 0.0,
            turn_scale: 0.0,
            heading_bias: 0.0,
            sigma_t: 0.0,
            sigma_r: 0.0,
            sigma_r_per_m: 0.0,
            ..Self::default()
        }
    }

    /// Refuses parameters that cannot describe odometry: a value that is
    /// not finite, a negative σ, a scale that reverses or stops every step.
    pub fn validate(&self) -> Result<(), InvalidDrift> {
        let fields = [
            ("scale", self.scale),
            ("turn_scale", self.turn_scale),
            ("heading_bias", self.heading_bias),
            ("sigma_t", self.sigma_t),
            ("sigma_r", self.sigma_r),
            ("sigma_r_per_m", self.sigma_r_per_m),
        ];
        if let Some(&(field, value)) = fields.iter().find(|(_, v)| !v.is_finite()) {
            return Err(InvalidDrift::NotFinite { field, value });
        }
        if let Some(&(field, value)) = fields[3..].iter().find(|(_, v)| *v < 0.0) {
            return Err(InvalidDrift::NegativeSigma { field, value });
        }
        if self.scale <= -1.0 {
            return Err(InvalidDrift::ReversingScale { value: self.scale });
        }
        Ok(())
    }
}

/// Drift parameters [`DriftParams::validate`] refuses; each message starts
/// with the field's name ([`InvalidDrift::field`]).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum InvalidDrift {
    #[error("{field} must be a finite number, not {value}")]
    NotFinite { field: &'static str, value: f64 },
    #[error("{field} is a standard deviation: not below 0 ({value})")]
    NegativeSigma { field: &'static str, value: f64 },
    #[error("scale {value} would reverse or stop every step (it must be above -1)")]
    ReversingScale { value: f64 },
}

impl InvalidDrift {
    /// The [`DriftParams`] field refused.
    pub fn field(&self) -> &'static str {
        match self {
            Self::NotFinite { field, .. } | Self::NegativeSigma { field, .. } => field,
            Self::ReversingScale { .. } => "scale",
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum DriftError {
    #[error("drift parameters: {0}")]
    Params(#[from] InvalidDrift),
    #[error("line {}: {}", .0.line, .0.error)]
    Line(LineError),
    #[error(
        "line {line}: laser record {index} has no stamp to replace it with ({given} stamps given)"
    )]
    TooFewStamps {
        line: usize,
        index: usize,
        given: usize,
    },
    #[error("writing the drifted log or its reference: {0}")]
    Write(#[from] std::io::Error),
}

/// A record stamped at or before the one before it is restamped this much
/// after it: the corrected logs hold a scan per metre or so, and a robot
/// covers that in about a second.
pub const RESTAMP_STEP_NS: u64 = 1_000_000_000;

/// What [`drift_log`] wrote.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DriftReport {
    pub laser_records: usize,
    /// Distance travelled along the input's poses, m.
    pub path_m: f64,
    /// Distance between the last input pose and the last drifted one, m.
    pub end_offset_m: f64,
    /// Lines that could not be read and were left out (the corrected Radish
    /// logs end with `ODOM` records stamped before zero), and the first of them.
    pub skipped_lines: usize,
    pub first_skipped: Option<LineError>,
    /// Records whose stamp did not come after the one before (CSAIL's keep
    /// six digits of a Unix time; four of Intel's go back), restamped
    /// [`RESTAMP_STEP_NS`] after it so that every scan pairs with one
    /// reference pose; and the first such record's index.
    pub restamped: usize,
    pub first_restamped: Option<usize>,
}

/// Writes `input`'s laser records to `out` with drifted odometry (see the
/// module). Records other than laser records are left out (they carry no
/// motion the scans use), and so are lines that cannot be read (counted in
/// the report, the first kept); an input that cannot be read on stops with
/// its line number, and parameters [`DriftParams::validate`] refuses stop
/// before anything is written. With
/// `reference`, the input's own robot poses are written there as
/// `timestamp x y theta` lines, one per record at its output stamp: the
/// trajectory the drifted log is scored against (`smokenav slam
/// --reference`).
pub fn drift_log<R: BufRead, W: Write>(
    input: R,
    mut out: W,
    p: &DriftParams,
    stamps: Option<&[u64]>,
    mut reference: Option<&mut dyn Write>,
) -> Result<DriftReport, DriftError> {
    p.validate()?;
    if let Some(r) = reference.as_deref_mut() {
        writeln!(r, "# timestamp x y theta")?;
    }
    let mut reader = CarmenReader::new(input);
    let mut rng = Rng::new(p.seed, 0);
    let mut report = DriftReport::default();
    let mut last: Option<(Pose2, Pose2)> = None;
    let mut last_stamp: Option<u64> = None;
    while let Some(record) = reader.next() {
        let mut l = match record {
            Ok(Record::Laser(l)) => l,
            Ok(Record::Odom(_)) => continue,
            // The input cannot be read on: nothing after it would be either.
            Err(
                e @ LineError {
                    error: CarmenError::Io(_),
                    ..
                },
            ) => return Err(DriftError::Line(e)),
            // A line that says nothing usable is left out, as the SLAM's
            // reader leaves it out; the next record's motion is taken from
            // the last one read.
            Err(e) => {
                report.skipped_lines += 1;
                report.first_skipped.get_or_insert(e);
                continue;
            }
        };
        let index = report.laser_records;
        if let Some(stamps) = stamps {
            l.ipc_timestamp_ns = *stamps.get(index).ok_or(DriftError::TooFewStamps {
                line: reader.line(),
                index,
                given: stamps.len(),
            })?;
        }
        if let Some(prev) = last_stamp
            && l.ipc_timestamp_ns <= prev
        {
            l.ipc_timestamp_ns = prev + RESTAMP_STEP_NS;
            report.restamped += 1;
            report.first_restamped.get_or_insert(index);
        }
        last_stamp = Some(l.ipc_timestamp_ns);
        let truth = l.robot_pose;
        if let Some(r) = reference.as_deref_mut() {
            writeln!(
                r,
                "{} {:.6} {:.6} {:.6}",
                crate::carmen::format_stamp(l.ipc_timestamp_ns),
                truth.x,
                truth.y,
                truth.theta
            )?;
        }
        let mount = truth.between(&l.laser_pose);
        let drifted = match last {
            None => truth,
            Some((prev_truth, prev_drifted)) => {
                let d = prev_truth.between(&truth);
                let step = d.translation_norm();
                report.path_m += step;
                let noisy = Pose2::new(
                    d.x * (1.0 + p.scale) + rng.gaussian(p.sigma_t * step),
                    d.y * (1.0 + p.scale) + rng.gaussian(p.sigma_t * step),
                    d.theta * (1.0 + p.turn_scale)
                        + p.heading_bias * step
                        + rng.gaussian(p.sigma_r * d.theta.abs() + p.sigma_r_per_m * step),
                );
                prev_drifted.compose(&noisy)
            }
        };
        last = Some((truth, drifted));
        report.end_offset_m = (truth.x - drifted.x).hypot(truth.y - drifted.y);
        l.robot_pose = drifted;
        l.laser_pose = drifted.compose(&mount);
        write_record(&mut out, &l)?;
        report.laser_records += 1;
    }
    out.flush()?;
    if let Some(r) = reference {
        r.flush()?;
    }
    Ok(report)
}

fn write_record<W: Write>(out: &mut W, l: &LaserRecord) -> std::io::Result<()> {
    let stamp = crate::carmen::format_stamp(l.ipc_timestamp_ns);
    let pose = |p: &Pose2| format!("{:.6} {:.6} {:.6}", p.x, p.y, p.theta);
    let mut line = String::with_capacity(16 * l.ranges.len() + 200);
    match l.kind {
        LaserRecordKind::Flaser => line.push_str(&format!("FLASER {}", l.ranges.len())),
        LaserRecordKind::RobotLaser1 => line.push_str(&format!(
            "ROBOTLASER1 0 {} {} {} {} 0.01 0 {}",
            l.start_angle,
            l.angular_resolution * l.ranges.len().saturating_sub(1) as f64,
            l.angular_resolution,
            l.max_range,
            l.ranges.len()
        )),
    }
    for r in &l.ranges {
        line.push_str(&format!(" {r}"));
    }
    match l.kind {
        LaserRecordKind::Flaser => line.push_str(&format!(
            " {} {} {stamp} drift {stamp}",
            pose(&l.laser_pose),
            pose(&l.robot_pose)
        )),
        LaserRecordKind::RobotLaser1 => line.push_str(&format!(
            " 0 {} {} 0 0 0 0 0 {stamp} drift {stamp}",
            pose(&l.laser_pose),
            pose(&l.robot_pose)
        )),
    }
    writeln!(out, "{line}")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 20 m × 10 m rectangle driven at 0.5 m per record, every record a 5-beam FLASER.
    fn square_log() -> String {
        let mut s = String::new();
        let mut pose = Pose2::default();
        let mut k = 0u64;
        for (len, _) in [(20.0, 0), (10.0, 1), (20.0, 2), (10.0, 3)] {
            let steps = (len / 0.5) as usize;
            for i in 0..steps {
                let turn = if i + 1 == steps {
                    std::f64::consts::FRAC_PI_2
                } else {
                    0.0
                };
                pose = pose.compose(&Pose2::new(0.5, 0.0, turn));
                s.push_str(&format!(
                    "FLASER 5 1 2 3 4 5 {x} {y} {t} {x} {y} {t} {k}.5 host {k}.5\n",
                    x = pose.x,
                    y = pose.y,
                    t = pose.theta
                ));
                k += 1;
            }
        }
        s
    }

    fn drifted(p: &DriftParams) -> (String, DriftReport) {
        let mut out = Vec::new();
        let r = drift_log(square_log().as_bytes(), &mut out, p, None, None).unwrap();
        (String::from_utf8(out).unwrap(), r)
    }

    #[test]
    fn a_loop_drifts_by_metres_and_the_same_seed_repeats() {
        let (a, ra) = drifted(&DriftParams::default());
        let (b, _) = drifted(&DriftParams::default());
        assert_eq!(a, b);
        let (c, _) = drifted(&DriftParams {
            seed: 2,
            ..DriftParams::default()
        });
        assert_ne!(a, c);
        assert_eq!(ra.laser_records, 120);
        assert!((ra.path_m - 59.5).abs() < 1e-6, "{ra:?}");
        // 60 m at 4 mrad/m bends the heading ~0.24 rad: metres off at the end.
        assert!(ra.end_offset_m > 2.0, "{ra:?}");
        // The scans themselves are untouched, and the output reads back.
        let mut reader = CarmenReader::new(a.as_bytes());
        let Some(Ok(Record::Laser(first))) = reader.next() else {
            panic!("no laser record");
        };
        assert_eq!(first.ranges, vec![1.0, 2.0, 3.0, 4.0, 5.0]);
        assert_eq!(first.ipc_timestamp_ns, 500_000_000);
        assert_eq!(reader.filter(|r| r.is_ok()).count(), 119);
    }

    #[test]
    fn without_drift_the_poses_are_kept() {
        let (_, r) = drifted(&DriftParams::none());
        assert!(r.end_offset_m < 1e-6, "{r:?}");
    }

    #[test]
    fn parameters_that_cannot_describe_odometry_are_refused_by_name() {
        let bad = |p: DriftParams| {
            let mut out = Vec::new();
            let e = drift_log(square_log().as_bytes(), &mut out, &p, None, None).unwrap_err();
            assert!(out.is_empty(), "{e}");
            match e {
                DriftError::Params(e) => e,
                other => panic!("{other}"),
            }
        };
        let d = DriftParams::default();
        let e = bad(DriftParams { sigma_r: -0.1, ..d });
        assert_eq!(e.field(), "sigma_r");
        assert!(
            e.to_string().starts_with("sigma_r is a standard deviation"),
            "{e}"
        );
        let e = bad(DriftParams {
            heading_bias: f64::NAN,
            ..d
        });
        assert_eq!(e.field(), "heading_bias");
        let e = bad(DriftParams { scale: -1.0, ..d });
        assert!(e.to_string().starts_with("scale -1 would reverse"), "{e}");
        // Negative scales and biases above -1 are drift, not errors.
        let ok = DriftParams {
            scale: -0.5,
            turn_scale: -0.1,
            heading_bias: -0.01,
            ..d
        };
        assert!(drift_log(square_log().as_bytes(), Vec::new(), &ok, None, None).is_ok());
    }

    #[test]
    fn stamps_are_replaced_and_too_few_are_an_error_with_the_line() {
        let stamps: Vec<u64> = (0..120).map(|i| 1_000_000_000 + i * 200_000_000).collect();
        let mut out = Vec::new();
        drift_log(
            square_log().as_bytes(),
            &mut out,
            &DriftParams::default(),
            Some(&stamps),
            None,
        )
        .unwrap();
        let mut reader = CarmenReader::new(out.as_slice());
        let Some(Ok(Record::Laser(l))) = reader.nth(1) else {
            panic!("no second record");
        };
        assert_eq!(l.ipc_timestamp_ns, 1_200_000_000);
        let err = drift_log(
            square_log().as_bytes(),
            Vec::new(),
            &DriftParams::default(),
            Some(&stamps[..10]),
            None,
        )
        .unwrap_err();
        assert!(err.to_string().starts_with("line 11: "), "{err}");
    }

    #[test]
    fn a_bad_line_is_left_out_and_reported_with_its_number() {
        // A bad scan and, as the corrected Radish logs end, an ODOM record stamped before zero.
        let log = square_log().replacen("FLASER 5 1 2 3 4 5", "FLASER 5 1 2 x 4 5", 1)
            + "ODOM 0 0 0 0 0 0 -14.4854 host -14.4854\n";
        let mut out = Vec::new();
        let r = drift_log(
            log.as_bytes(),
            &mut out,
            &DriftParams::default(),
            None,
            None,
        )
        .unwrap();
        assert_eq!(r.laser_records, 119);
        assert_eq!(r.skipped_lines, 2);
        let first = r.first_skipped.expect("the first bad line");
        assert_eq!(first.line, 1);
        assert!(first.to_string().contains("FLASER"), "{first}");
        assert_eq!(
            CarmenReader::new(out.as_slice())
                .filter(|r| r.is_ok())
                .count(),
            119
        );
    }

    #[test]
    fn stamps_that_do_not_increase_are_restamped_a_second_on_and_the_reference_follows() {
        // Records 2 s apart, except 10..20 all stamped 10's 20.5 s (a coarse
        // clock) and record 30 back at 1.5 s.
        let log: String = square_log()
            .lines()
            .enumerate()
            .map(|(k, line)| {
                let stamp = match k {
                    10..20 => "20.5".to_string(),
                    30 => "1.5".to_string(),
                    _ => format!("{}.5", 2 * k),
                };
                let mut f: Vec<&str> = line.split(' ').collect();
                let n = f.len();
                f[n - 3] = &stamp;
                f[n - 1] = &stamp;
                f.join(" ") + "\n"
            })
            .collect();
        let (mut out, mut reference) = (Vec::new(), Vec::new());
        let r = drift_log(
            log.as_bytes(),
            &mut out,
            &DriftParams::default(),
            None,
            Some(&mut reference),
        )
        .unwrap();
        // 11..19 follow 10 a second apart; 20 keeps its own 40.5 s; 30
        // follows 29 (58.5 s) by a second, and 31 keeps its 62.5 s.
        let stamps: Vec<u64> = CarmenReader::new(out.as_slice())
            .filter_map(|r| match r {
                Ok(Record::Laser(l)) => Some(l.ipc_timestamp_ns),
                _ => None,
            })
            .collect();
        assert_eq!(stamps.len(), 120);
        assert!(stamps.windows(2).all(|w| w[0] < w[1]), "{stamps:?}");
        assert_eq!(stamps[10], 20_500_000_000);
        assert_eq!(stamps[19], 29_500_000_000);
        assert_eq!(stamps[20], 40_500_000_000);
        assert_eq!(stamps[30], 59_500_000_000);
        assert_eq!(stamps[31], 62_500_000_000);
        assert_eq!(r.restamped, 10, "{r:?}");
        assert_eq!(r.first_restamped, Some(11));
        // The reference carries the same stamps, one line per record, and the input's poses.
        let text = String::from_utf8(reference).unwrap();
        let lines: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
        assert_eq!(lines.len(), 120);
        assert!(lines[19].starts_with("29.500000 "), "{}", lines[19]);
        let first: Vec<f64> = lines[0]
            .split(' ')
            .skip(1)
            .map(|v| v.parse().unwrap())
            .collect();
        assert_eq!(first, vec![0.5, 0.0, 0.0]);
    }
}
