//! Trajectory evaluation: absolute trajectory error after the best rigid 2D
//! alignment (rotation + translation, no scale), and the `timestamp x y theta`
//! pose file format.

use crate::StampedPose;
use crate::pose::Pose2;

/// A rigid transform of the plane: rotate by `theta`, then shift.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Rigid2 {
    pub theta: f64,
    pub tx: f64,
    pub ty: f64,
}

impl Rigid2 {
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        let (s, c) = self.theta.sin_cos();
        (c * x - s * y + self.tx, s * x + c * y + self.ty)
    }
}

/// The rigid transform that maps `from` onto `to` with the least squared error
/// (closed form: centroids, then the rotation from the cross-covariance).
/// `None` with fewer than two pairs or mismatched lengths.
pub fn align_rigid_2d(from: &[(f64, f64)], to: &[(f64, f64)]) -> Option<Rigid2> {
    if from.len() != to.len() || from.len() < 2 {
        return None;
    }
    let n = from.len() as f64;
    let (fx, fy) = from.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
    let (tx, ty) = to.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
    let (fx, fy, tx, ty) = (fx / n, fy / n, tx / n, ty / n);
    let (mut sxx, mut sxy) = (0.0, 0.0);
    for (f, t) in from.iter().zip(to) {
        let (ax, ay) = (f.0 - fx, f.1 - fy);
        let (bx, by) = (t.0 - tx, t.1 - ty);
        sxx += ax * bx + ay * by;
        sxy += ax * by - ay * bx;
    }
    let theta = sxy.atan2(sxx);
    let (s, c) = theta.sin_cos();
    Some(Rigid2 {
        theta,
        tx: tx - (c * fx - s * fy),
        ty: ty - (s * fx + c * fy),
    })
}

/// Absolute trajectory error of an estimate against a reference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AteReport {
    /// Poses present in both (same stamp within the tolerance).
    pub matched: usize,
    pub rms_m: f64,
    pub mean_m: f64,
    pub max_m: f64,
    /// Stamp of the reference pose with the largest error.
    pub max_at_ns: u64,
    /// Maps the estimate onto the reference.
    pub alignment: Rigid2,
}

/// Pairs estimate and reference poses by stamp (within `tolerance_ns`), aligns
/// the estimate onto the reference rigidly and reports the position errors.
pub fn absolute_trajectory_error(
    estimate: &[StampedPose],
    reference: &[StampedPose],
    tolerance_ns: u64,
) -> Option<AteReport> {
    let mut est: Vec<&StampedPose> = estimate.iter().collect();
    est.sort_by_key(|p| p.stamp_ns);
    let mut pairs = Vec::new();
    let mut stamps = Vec::new();
    for r in reference {
        let i = est.partition_point(|p| p.stamp_ns < r.stamp_ns);
        let near = [i.checked_sub(1), Some(i)]
            .into_iter()
            .flatten()
            .filter_map(|j| est.get(j))
            .min_by_key(|p| p.stamp_ns.abs_diff(r.stamp_ns));
        if let Some(e) = near
            && e.stamp_ns.abs_diff(r.stamp_ns) <= tolerance_ns
        {
            pairs.push(((e.pose.x, e.pose.y), (r.pose.x, r.pose.y)));
            stamps.push(r.stamp_ns);
        }
    }
    let (from, to): (Vec<_>, Vec<_>) = pairs.into_iter().unzip();
    let alignment = align_rigid_2d(&from, &to)?;
    let (mut sum2, mut sum, mut max, mut max_at) = (0.0, 0.0, 0.0f64, 0);
    for ((f, t), stamp) in from.iter().zip(&to).zip(&stamps) {
        let (x, y) = alignment.apply(f.0, f.1);
        let e = (x - t.0).hypot(y - t.1);
        sum2 += e * e;
        sum += e;
        if e > max {
            max = e;
            max_at = *stamp;
        }
    }
    let n = from.len() as f64;
    Some(AteReport {
        matched: from.len(),
        rms_m: (sum2 / n).sqrt(),
        mean_m: sum / n,
        max_m: max,
        max_at_ns: max_at,
        alignment,
    })
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PoseFileError {
    #[error("line {line}: expected `timestamp x y theta`, got {fields} fields")]
    Fields { line: usize, fields: usize },
    #[error("line {line}: {what} is not a number: {text:?}")]
    Number {
        line: usize,
        what: &'static str,
        text: String,
    },
}

/// Parses a decimal timestamp in seconds (`1134864629.895182`, or `1.13486e+09`)
/// into nanoseconds without going through floating point when it is plain decimal.
pub fn parse_stamp_ns(text: &str) -> Option<u64> {
    let t = text.trim();
    if t.is_empty() || t.starts_with('-') || t.starts_with('+') {
        return None;
    }
    if t.bytes().all(|b| b.is_ascii_digit() || b == b'.') {
        let (int, frac) = t.split_once('.').unwrap_or((t, ""));
        if int.is_empty() && frac.is_empty() || frac.contains('.') {
            return None;
        }
        let secs: u64 = if int.is_empty() { 0 } else { int.parse().ok()? };
        let mut ns = 0u64;
        for (i, b) in frac.bytes().take(9).enumerate() {
            ns += (b - b'0') as u64 * 10u64.pow(8 - i as u32);
        }
        return secs.checked_mul(1_000_000_000)?.checked_add(ns);
    }
    let v: f64 = t.parse().ok()?;
    (0.0..1.8e10).contains(&v).then(|| (v * 1e9).round() as u64)
}

/// Formats nanoseconds as seconds with microseconds, the way CARMEN logs write stamps.
pub fn format_stamp(stamp_ns: u64) -> String {
    format!(
        "{}.{:06}",
        stamp_ns / 1_000_000_000,
        (stamp_ns % 1_000_000_000) / 1000
    )
}

/// Reads `timestamp x y theta` lines; `#` starts a comment line.
pub fn parse_pose_file(text: &str) -> Result<Vec<StampedPose>, PoseFileError> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line_no = i + 1;
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let f: Vec<&str> = line.split_whitespace().collect();
        if f.len() != 4 {
            return Err(PoseFileError::Fields {
                line: line_no,
                fields: f.len(),
            });
        }
        let num = |idx: usize, what: &'static str| -> Result<f64, PoseFileError> {
            f[idx]
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| PoseFileError::Number {
                    line: line_no,
                    what,
                    text: f[idx].to_owned(),
                })
        };
        let stamp_ns = parse_stamp_ns(f[0]).ok_or_else(|| PoseFileError::Number {
            line: line_no,
            what: "timestamp",
            text: f[0].to_owned(),
        })?;
        out.push(StampedPose {
            stamp_ns,
            pose: Pose2::new(num(1, "x")?, num(2, "y")?, num(3, "theta")?),
        });
    }
    Ok(out)
}

/// Writes `timestamp x y theta` lines.
pub fn format_pose_file(poses: &[StampedPose]) -> String {
    let mut s = String::with_capacity(poses.len() * 48);
    for p in poses {
        s.push_str(&format!(
            "{} {:.6} {:.6} {:.6}\n",
            format_stamp(p.stamp_ns),
            p.pose.x,
            p.pose.y,
            p.pose.theta
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotated_and_shifted_copy_aligns_exactly() {
        let a: Vec<(f64, f64)> = (0..20)
            .map(|i| (i as f64 * 0.3, (i as f64 * 0.7).sin()))
            .collect();
        let t = Rigid2 {
            theta: 0.7,
            tx: 576.5,
            ty: -3.2,
        };
        let b: Vec<(f64, f64)> = a.iter().map(|p| t.apply(p.0, p.1)).collect();
        let found = align_rigid_2d(&a, &b).unwrap();
        assert!((found.theta - 0.7).abs() < 1e-12);
        assert!((found.tx - 576.5).abs() < 1e-9 && (found.ty + 3.2).abs() < 1e-9);
    }

    #[test]
    fn ate_reports_rms_and_max_of_the_residual() {
        let reference: Vec<StampedPose> = (0..4)
            .map(|i| StampedPose {
                stamp_ns: i * 100,
                pose: Pose2::new(i as f64, 0.0, 0.0),
            })
            .collect();
        // Same line moved far away and turned, with one point 0.4 m off sideways.
        let t = Rigid2 {
            theta: -1.0,
            tx: 10.0,
            ty: 5.0,
        };
        let mut estimate: Vec<StampedPose> = reference
            .iter()
            .map(|r| {
                let (x, y) = t.apply(r.pose.x, r.pose.y);
                StampedPose {
                    stamp_ns: r.stamp_ns + 3,
                    pose: Pose2::new(x, y, 0.0),
                }
            })
            .collect();
        let (s, c) = (-1.0f64).sin_cos();
        estimate[2].pose.x += -s * 0.4;
        estimate[2].pose.y += c * 0.4;
        let r = absolute_trajectory_error(&estimate, &reference, 10).unwrap();
        assert_eq!(r.matched, 4);
        assert!(r.max_m > 0.25 && r.max_m < 0.4, "{r:?}");
        assert_eq!(r.max_at_ns, 200);
        assert!(r.rms_m < r.max_m);
        assert!(
            absolute_trajectory_error(&estimate, &reference, 1).is_none(),
            "stamps 3 ns apart do not pair at 1 ns"
        );
    }

    #[test]
    fn stamps_keep_microseconds_exactly() {
        assert_eq!(
            parse_stamp_ns("1134864629.895182"),
            Some(1_134_864_629_895_182_000)
        );
        assert_eq!(format_stamp(1_134_864_629_895_182_000), "1134864629.895182");
        assert_eq!(
            parse_stamp_ns("1.13486e+09"),
            Some(1_134_860_000_000_000_000)
        );
        assert_eq!(parse_stamp_ns("-1"), None);
        assert_eq!(parse_stamp_ns("1.2.3"), None);
        assert_eq!(parse_stamp_ns("."), None);
        assert_eq!(parse_stamp_ns("99999999999999999999"), None);
    }

    #[test]
    fn pose_file_round_trips_and_names_bad_lines() {
        let text = "# header\n1134864642.914187 0.154 0.068 0.562729\n";
        let poses = parse_pose_file(text).unwrap();
        assert_eq!(poses[0].stamp_ns, 1_134_864_642_914_187_000);
        assert_eq!(parse_pose_file(&format_pose_file(&poses)).unwrap(), poses);
        assert_eq!(
            parse_pose_file("1 2 3\n"),
            Err(PoseFileError::Fields { line: 1, fields: 3 })
        );
        assert!(matches!(
            parse_pose_file("\n1 2 x 3\n"),
            Err(PoseFileError::Number { line: 2, .. })
        ));
    }
}
