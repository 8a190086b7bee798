//! Trajectory accuracy: absolute trajectory error (ATE) after the best rigid
//! alignment, and relative pose error (RPE) over a fixed time step, as Sturm
//! et al. define them for the TUM RGB-D benchmark (IROS 2012), in 2D.
//!
//! Files hold one pose per line, `timestamp x y theta` (s, m, m, rad), or
//! the TUM RGB-D benchmark's `timestamp x y z qx qy qz qw` (what `evo`
//! reads; planar poses are written with z = 0 and a yaw-only quaternion),
//! separated by spaces or tabs; blank lines and lines starting with `#` are
//! skipped; timestamps must increase. Estimated poses are paired with the
//! ground truth interpolated at their timestamps, or (for a reference that
//! only has poses at some of the estimate's stamps, like GMapping's corrected
//! poses of a CARMEN log) with the truth sample at the same stamp.

use serde::Serialize;
use smokenav_shared_types::Pose2;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Longest trajectory file read, bytes (a day at 100 Hz is ~150 MB; crafted files must not exhaust memory).
pub const MAX_FILE_BYTES: u64 = 512 * 1024 * 1024;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StampedPose {
    pub t: f64,
    pub x: f64,
    pub y: f64,
    pub theta: f64,
}

impl StampedPose {
    /// A pose stamped in nanoseconds (the bus's and the logs' unit).
    pub fn from_ns(stamp_ns: u64, pose: &Pose2) -> Self {
        Self {
            t: stamp_ns as f64 * 1e-9,
            x: pose.x,
            y: pose.y,
            theta: pose.theta,
        }
    }
}

/// Writes poses in the trajectory file format (microsecond stamps).
pub fn format_trajectory(poses: &[StampedPose]) -> String {
    format_trajectory_as(poses, TrajectoryFormat::Plain)
}

/// The line layouts a trajectory file may have.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TrajectoryFormat {
    /// `timestamp x y theta`.
    #[default]
    Plain,
    /// TUM RGB-D: `timestamp x y z qx qy qz qw` (z = 0, rotation about z only).
    Tum,
}

/// Writes poses as `format` lines (microsecond stamps).
pub fn format_trajectory_as(poses: &[StampedPose], format: TrajectoryFormat) -> String {
    let mut s = String::with_capacity(poses.len() * 80);
    for p in poses {
        let _ = match format {
            TrajectoryFormat::Plain => {
                writeln!(s, "{:.6} {:.6} {:.6} {:.6}", p.t, p.x, p.y, p.theta)
            }
            TrajectoryFormat::Tum => {
                let (qz, qw) = (0.5 * p.theta).sin_cos();
                writeln!(
                    s,
                    "{:.6} {:.6} {:.6} 0 0 0 {:.9} {:.9}",
                    p.t, p.x, p.y, qz, qw
                )
            }
        };
    }
    s
}

#[derive(Debug, thiserror::Error)]
pub enum TrajectoryError {
    #[error(transparent)]
    Read(#[from] FileReadError),
    #[error(transparent)]
    Parse(#[from] LineError),
    #[error("{}: no poses (expected lines `timestamp x y theta`)", path.display())]
    Empty { path: PathBuf },
}

/// Parses trajectory text; `path` is only used in messages.
pub fn parse_trajectory(text: &str, path: &Path) -> Result<Vec<StampedPose>, TrajectoryError> {
    let mut out: Vec<StampedPose> = Vec::new();
    for (line, fields) in data_lines(text) {
        let err = |reason: String| {
            TrajectoryError::from(LineError {
                path: path.to_owned(),
                line,
                reason,
            })
        };
        const PLAIN: [&str; 4] = ["timestamp", "x", "y", "theta"];
        const TUM: [&str; 8] = ["timestamp", "x", "y", "z", "qx", "qy", "qz", "qw"];
        let names: &[&str] = match fields.len() {
            4 => &PLAIN,
            8 => &TUM,
            n => {
                return Err(err(format!(
                    "expected 4 numbers `timestamp x y theta` or 8 (TUM) \
                     `timestamp x y z qx qy qz qw`, got {n} field(s)"
                )));
            }
        };
        let mut v = finite_numbers(&fields, names).map_err(err)?;
        if fields.len() == 8 {
            // Yaw of the quaternion; a planar evaluation ignores z, roll and pitch.
            let [qx, qy, qz, qw] = [v[4], v[5], v[6], v[7]];
            if qx * qx + qy * qy + qz * qz + qw * qw < 1e-12 {
                return Err(err("the quaternion is zero".into()));
            }
            v[3] = (2.0 * (qw * qz + qx * qy)).atan2(1.0 - 2.0 * (qy * qy + qz * qz));
        }
        if let Some(prev) = out.last()
            && v[0] <= prev.t
        {
            return Err(err(format!(
                "timestamp {} does not increase (previous {})",
                v[0], prev.t
            )));
        }
        out.push(StampedPose {
            t: v[0],
            x: v[1],
            y: v[2],
            theta: v[3],
        });
    }
    if out.is_empty() {
        return Err(TrajectoryError::Empty {
            path: path.to_owned(),
        });
    }
    Ok(out)
}

/// The lines of a text file of numbers that carry data, as (1-based line
/// number, whitespace-separated fields): blank lines and `#` comments skipped.
pub(crate) fn data_lines(text: &str) -> impl Iterator<Item = (usize, Vec<&str>)> {
    text.lines().enumerate().filter_map(|(i, raw)| {
        let line = raw.trim();
        (!line.is_empty() && !line.starts_with('#'))
            .then(|| (i + 1, line.split_whitespace().collect()))
    })
}

/// The (up to 8) numbers of a line's fields, each named for the message when it is not a finite number.
pub(crate) fn finite_numbers(fields: &[&str], names: &[&str]) -> Result<[f64; 8], String> {
    let mut v = [0.0f64; 8];
    for (k, (f, name)) in fields.iter().zip(names).take(8).enumerate() {
        v[k] = f
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("{name}: expected a finite number, got {f:?}"))?;
    }
    Ok(v)
}

/// Why a text file (a trajectory, a relations file) could not be read whole.
#[derive(Debug, thiserror::Error)]
pub enum FileReadError {
    #[error("cannot read {}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: {len} bytes exceed the limit of {max}", path.display())]
    TooLarge { path: PathBuf, len: u64, max: u64 },
}

/// A line of a text file (a trajectory, a relations file) that could not be read.
#[derive(Debug, thiserror::Error)]
#[error("{}:{line}: {reason}", path.display())]
pub struct LineError {
    pub path: PathBuf,
    pub line: usize,
    pub reason: String,
}

/// Reads a text file of at most `max_bytes` (crafted files must not exhaust memory).
pub(crate) fn read_bounded(path: &Path, max_bytes: u64) -> Result<String, FileReadError> {
    let io = |source| FileReadError::Io {
        path: path.to_owned(),
        source,
    };
    let len = std::fs::metadata(path).map_err(io)?.len();
    if len > max_bytes {
        return Err(FileReadError::TooLarge {
            path: path.to_owned(),
            len,
            max: max_bytes,
        });
    }
    std::fs::read_to_string(path).map_err(io)
}

/// Reads a trajectory file.
pub fn load_trajectory(path: &Path) -> Result<Vec<StampedPose>, TrajectoryError> {
    parse_trajectory(&read_bounded(path, MAX_FILE_BYTES)?, path)
}

/// How estimated poses find their ground truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pairing {
    /// The truth interpolated at the estimate's stamp (a dense truth, e.g. the simulator's).
    Interpolate,
    /// The truth sample nearest the estimate's stamp, if within `tolerance_s`,
    /// as it is (a sparse reference at some of the estimate's own stamps).
    SameStamp { tolerance_s: f64 },
}

#[derive(Debug, Clone, PartialEq)]
pub struct TrajectoryOptions {
    /// Align the estimate to the truth with the best rigid transform before ATE.
    pub align: bool,
    /// Truth samples further apart than this are not interpolated across, s.
    pub max_gap_s: f64,
    /// Time step of the relative pose error, s.
    pub rpe_delta_s: f64,
    pub pairing: Pairing,
}

impl Default for TrajectoryOptions {
    fn default() -> Self {
        Self {
            align: true,
            max_gap_s: 0.5,
            rpe_delta_s: 1.0,
            pairing: Pairing::Interpolate,
        }
    }
}

impl TrajectoryOptions {
    /// Pairs at equal stamps (within 1 ms): for a reference made of poses at
    /// some of the estimate's stamps.
    pub fn same_stamp() -> Self {
        Self {
            pairing: Pairing::SameStamp { tolerance_s: 1e-3 },
            ..Self::default()
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct ErrorStats {
    pub rmse: f64,
    pub mean: f64,
    pub median: f64,
    pub max: f64,
}

impl ErrorStats {
    fn from(mut v: Vec<f64>) -> Self {
        if v.is_empty() {
            return Self::default();
        }
        let n = v.len() as f64;
        let rmse = (v.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
        let mean = v.iter().sum::<f64>() / n;
        v.sort_by(f64::total_cmp);
        let median = if v.len() % 2 == 1 {
            v[v.len() / 2]
        } else {
            (v[v.len() / 2 - 1] + v[v.len() / 2]) / 2.0
        };
        Self {
            rmse,
            mean,
            median,
            max: v[v.len() - 1],
        }
    }
}

/// Mean and standard deviation of absolute errors, as the relations tables report them.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct MeanStd {
    pub mean: f64,
    pub std: f64,
}

impl MeanStd {
    pub(crate) fn from(v: &[f64]) -> Self {
        if v.is_empty() {
            return Self::default();
        }
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
        Self {
            mean,
            std: var.sqrt(),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TrajectoryReport {
    /// Estimated poses paired with the truth.
    pub pairs: usize,
    /// Transform applied to the estimate (estimate → truth frame).
    pub align_dx_m: f64,
    pub align_dy_m: f64,
    pub align_dtheta_deg: f64,
    /// Absolute position error after alignment, m.
    pub ate_m: ErrorStats,
    /// Stamp of the estimated pose with the largest position error, s.
    pub ate_max_at_s: f64,
    /// Absolute heading error after alignment, degrees.
    pub ate_heading_deg: ErrorStats,
    pub rpe_delta_s: f64,
    /// Pose pairs the RPE was computed over.
    pub rpe_pairs: usize,
    /// Relative translation error per `rpe_delta_s`, m.
    pub rpe_translation_m: ErrorStats,
    /// Relative rotation error per `rpe_delta_s`, degrees.
    pub rpe_rotation_deg: ErrorStats,
    /// Relations metric (Kümmerle et al. 2009, "On measuring the accuracy of
    /// SLAM algorithms"): the error of the estimated relative motion between
    /// pose pairs against the true one, here each ground-truth sample and the
    /// next inside the estimate's span; no alignment is needed.
    pub relations: usize,
    /// Translational error of the relations, m (mean ± std of absolute errors).
    pub relations_translation_m: MeanStd,
    /// Rotational error of the relations, degrees.
    pub relations_rotation_deg: MeanStd,
}

/// Error of an estimated relative motion `p` against the true one `q`:
/// translation of q⁻¹·p and its rotation.
pub(crate) fn relative_error(p: (f64, f64, f64), q: (f64, f64, f64)) -> (f64, f64) {
    let (s, c) = q.2.sin_cos();
    let (dx, dy) = (p.0 - q.0, p.1 - q.1);
    let ex = c * dx + s * dy;
    let ey = -s * dx + c * dy;
    (
        (ex * ex + ey * ey).sqrt(),
        wrap(p.2 - q.2).abs().to_degrees(),
    )
}

/// The relations metric over consecutive ground-truth samples: (count, translation m, rotation °).
fn relations_metric(
    truth: &[StampedPose],
    est: &[StampedPose],
    max_gap_s: f64,
) -> (usize, MeanStd, MeanStd) {
    let (mut t_err, mut r_err) = (Vec::new(), Vec::new());
    for w in truth.windows(2) {
        let (Some(ea), Some(eb)) = (
            truth_at(est, w[0].t, max_gap_s),
            truth_at(est, w[1].t, max_gap_s),
        ) else {
            continue;
        };
        let (t, r) = relative_error(relative(&ea, &eb), relative(&w[0], &w[1]));
        t_err.push(t);
        r_err.push(r);
    }
    (t_err.len(), MeanStd::from(&t_err), MeanStd::from(&r_err))
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum TrajectoryMetricError {
    #[error(
        "only {pairs} estimated pose(s) fall within the ground truth's time span (need at least 2)"
    )]
    TooFewPairs { pairs: usize },
    /// Same-stamp pairing found too few poses at the reference's stamps: a
    /// reference sampled on its own clock (a simulator's truth) needs
    /// [`Pairing::Interpolate`].
    #[error(
        "only {pairs} estimated pose(s) lie within {tolerance_ms} ms of a reference pose's stamp (need at least 2)"
    )]
    TooFewAtSameStamps { pairs: usize, tolerance_ms: f64 },
}

fn wrap(a: f64) -> f64 {
    let a = (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
    if a <= -std::f64::consts::PI {
        a + std::f64::consts::TAU
    } else {
        a
    }
}

/// Truth at time `t`, interpolated between the samples around it (none
/// across a gap longer than `max_gap` s, or outside the samples' span).
pub fn truth_at(truth: &[StampedPose], t: f64, max_gap: f64) -> Option<StampedPose> {
    let i = truth.partition_point(|p| p.t < t);
    if i < truth.len() && truth[i].t == t {
        return Some(truth[i]);
    }
    if i == 0 || i >= truth.len() {
        return None;
    }
    let (a, b) = (truth[i - 1], truth[i]);
    if b.t - a.t > max_gap {
        return None;
    }
    let s = (t - a.t) / (b.t - a.t);
    Some(StampedPose {
        t,
        x: a.x + (b.x - a.x) * s,
        y: a.y + (b.y - a.y) * s,
        theta: wrap(a.theta + wrap(b.theta - a.theta) * s),
    })
}

/// The truth sample nearest `t`, if within `tolerance`.
fn truth_near(truth: &[StampedPose], t: f64, tolerance: f64) -> Option<StampedPose> {
    let i = truth.partition_point(|p| p.t < t);
    [i.checked_sub(1), Some(i)]
        .into_iter()
        .flatten()
        .filter_map(|j| truth.get(j))
        .min_by(|a, b| (a.t - t).abs().total_cmp(&(b.t - t).abs()))
        .filter(|p| (p.t - t).abs() <= tolerance)
        .copied()
}

/// Relative motion from `a` to `b` in `a`'s frame: (dx, dy, dθ).
pub(crate) fn relative(a: &StampedPose, b: &StampedPose) -> (f64, f64, f64) {
    let (s, c) = a.theta.sin_cos();
    let (dx, dy) = (b.x - a.x, b.y - a.y);
    (c * dx + s * dy, -s * dx + c * dy, wrap(b.theta - a.theta))
}

/// Compares an estimated trajectory with the ground truth.
pub fn evaluate_trajectories(
    truth: &[StampedPose],
    est: &[StampedPose],
    opts: &TrajectoryOptions,
) -> Result<TrajectoryReport, TrajectoryMetricError> {
    let pairs: Vec<(StampedPose, StampedPose)> = est
        .iter()
        .filter_map(|e| {
            match opts.pairing {
                Pairing::Interpolate => truth_at(truth, e.t, opts.max_gap_s),
                Pairing::SameStamp { tolerance_s } => truth_near(truth, e.t, tolerance_s),
            }
            .map(|g| (*e, g))
        })
        .collect();
    if pairs.len() < 2 {
        return Err(match opts.pairing {
            Pairing::Interpolate => TrajectoryMetricError::TooFewPairs { pairs: pairs.len() },
            Pairing::SameStamp { tolerance_s } => TrajectoryMetricError::TooFewAtSameStamps {
                pairs: pairs.len(),
                tolerance_ms: tolerance_s * 1e3,
            },
        });
    }
    // Closed-form least-squares rigid alignment (Horn/Umeyama, no scale).
    let (mut dth, mut tx, mut ty) = (0.0, 0.0, 0.0);
    if opts.align {
        let n = pairs.len() as f64;
        let (ex, ey) = pairs
            .iter()
            .fold((0.0, 0.0), |a, (e, _)| (a.0 + e.x / n, a.1 + e.y / n));
        let (gx, gy) = pairs
            .iter()
            .fold((0.0, 0.0), |a, (_, g)| (a.0 + g.x / n, a.1 + g.y / n));
        let (mut sc, mut ss) = (0.0, 0.0);
        for (e, g) in &pairs {
            let (ax, ay, bx, by) = (e.x - ex, e.y - ey, g.x - gx, g.y - gy);
            sc += ax * bx + ay * by;
            ss += ax * by - ay * bx;
        }
        dth = if sc == 0.0 && ss == 0.0 {
            0.0
        } else {
            ss.atan2(sc)
        };
        let (s, c) = dth.sin_cos();
        tx = gx - (c * ex - s * ey);
        ty = gy - (s * ex + c * ey);
    }
    let (s, c) = f64::sin_cos(dth);
    let mut pos = Vec::with_capacity(pairs.len());
    let mut head = Vec::with_capacity(pairs.len());
    let mut worst = (f64::NEG_INFINITY, 0.0);
    for (e, g) in &pairs {
        let (x, y) = (c * e.x - s * e.y + tx, s * e.x + c * e.y + ty);
        let d = ((x - g.x).powi(2) + (y - g.y).powi(2)).sqrt();
        if d > worst.0 {
            worst = (d, e.t);
        }
        pos.push(d);
        head.push(wrap(e.theta + dth - g.theta).abs().to_degrees());
    }
    // RPE: each pose against the first one at least `rpe_delta_s` later.
    let mut rpe_t = Vec::new();
    let mut rpe_r = Vec::new();
    let mut j = 0;
    for i in 0..pairs.len() {
        j = j.max(i + 1);
        // 1 µs of slack so stamps like 0.1·k that round below Δ still pair at Δ.
        while j < pairs.len() && pairs[j].0.t - pairs[i].0.t < opts.rpe_delta_s - 1e-6 {
            j += 1;
        }
        if j >= pairs.len() {
            break;
        }
        let (ei, gi) = (&pairs[i].0, &pairs[i].1);
        let (ej, gj) = (&pairs[j].0, &pairs[j].1);
        // E = Q⁻¹·P for the relative motions: translation of P expressed in Q's end frame.
        let (t, r) = relative_error(relative(ei, ej), relative(gi, gj));
        rpe_t.push(t);
        rpe_r.push(r);
    }
    let (relations, relations_translation_m, relations_rotation_deg) =
        relations_metric(truth, est, opts.max_gap_s);
    Ok(TrajectoryReport {
        pairs: pairs.len(),
        align_dx_m: tx,
        align_dy_m: ty,
        align_dtheta_deg: dth.to_degrees(),
        ate_m: ErrorStats::from(pos),
        ate_max_at_s: worst.1,
        ate_heading_deg: ErrorStats::from(head),
        rpe_delta_s: opts.rpe_delta_s,
        rpe_pairs: rpe_t.len(),
        rpe_translation_m: ErrorStats::from(rpe_t),
        rpe_rotation_deg: ErrorStats::from(rpe_r),
        relations,
        relations_translation_m,
        relations_rotation_deg,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A loop: 0.3 m/s around a 4 m circle, sampled at `hz`.
    fn circle(hz: f64, secs: f64) -> Vec<StampedPose> {
        let n = (hz * secs) as usize;
        (0..n)
            .map(|i| {
                let t = i as f64 / hz;
                let a = 0.3 * t / 2.0;
                StampedPose {
                    t,
                    x: 2.0 * a.cos(),
                    y: 2.0 * a.sin(),
                    theta: wrap(a + std::f64::consts::FRAC_PI_2),
                }
            })
            .collect()
    }

    fn transform(p: &[StampedPose], dx: f64, dy: f64, dth: f64) -> Vec<StampedPose> {
        let (s, c) = dth.sin_cos();
        p.iter()
            .map(|q| StampedPose {
                t: q.t,
                x: c * q.x - s * q.y + dx,
                y: s * q.x + c * q.y + dy,
                theta: wrap(q.theta + dth),
            })
            .collect()
    }

    #[test]
    fn identical_trajectories_score_zero() {
        let t = circle(10.0, 60.0);
        let r = evaluate_trajectories(&t, &t, &TrajectoryOptions::default()).unwrap();
        assert_eq!(r.pairs, 600);
        assert!(
            r.ate_m.max < 1e-12 && r.rpe_translation_m.max < 1e-12 && r.rpe_rotation_deg.max < 1e-9
        );
    }

    #[test]
    fn rigidly_moved_estimate_aligns_back_to_zero() {
        let truth = circle(50.0, 60.0);
        let est = transform(&circle(10.0, 60.0), 1.5, -0.7, 0.4);
        let r = evaluate_trajectories(&truth, &est, &TrajectoryOptions::default()).unwrap();
        assert!(r.ate_m.rmse < 1e-3, "{r:?}"); // interpolation between 50 Hz samples on a curve
        assert!((r.align_dtheta_deg + 0.4f64.to_degrees()).abs() < 0.01);
        assert!(
            r.rpe_translation_m.rmse < 1e-3,
            "RPE ignores the global transform"
        );
        let unaligned = evaluate_trajectories(
            &truth,
            &est,
            &TrajectoryOptions {
                align: false,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(unaligned.ate_m.rmse > 1.0);
    }

    #[test]
    fn constant_offset_in_one_half_gives_known_ate() {
        let truth = circle(10.0, 20.0);
        let mut est = truth.clone();
        // Without alignment: every pose 0.1 m off in x ⇒ ATE 0.1 m exactly.
        for p in &mut est {
            p.x += 0.1;
        }
        let opts = TrajectoryOptions {
            align: false,
            ..Default::default()
        };
        let r = evaluate_trajectories(&truth, &est, &opts).unwrap();
        assert!((r.ate_m.rmse - 0.1).abs() < 1e-12 && (r.ate_m.max - 0.1).abs() < 1e-12);
        assert!(
            r.rpe_translation_m.max < 1e-12,
            "a constant offset has no relative error"
        );
    }

    #[test]
    fn relations_metric_measures_relative_motion_without_alignment() {
        // Truth sampled at 1 Hz (sparse, like GMapping's corrected poses), the
        // estimate at 10 Hz: a rigidly moved copy scores zero…
        let truth = circle(1.0, 60.0);
        let est = transform(&circle(10.0, 60.0), 3.0, 1.0, -0.8);
        let r = evaluate_trajectories(&truth, &est, &TrajectoryOptions::default()).unwrap();
        assert_eq!(r.relations, 59);
        assert!(r.relations_translation_m.mean < 1e-9, "{r:?}");
        assert!(r.relations_rotation_deg.mean < 1e-6, "{r:?}");
        // …while 0.3 m/s read 10 % long is 3 cm per 1 s relation, every one of them.
        let mut long = circle(10.0, 60.0);
        for p in &mut long {
            let a = 0.3 * p.t / 2.0;
            p.x = 2.2 * a.cos();
            p.y = 2.2 * a.sin();
        }
        let r = evaluate_trajectories(&truth, &long, &TrajectoryOptions::default()).unwrap();
        let step = 2.0 * 2.0 * (0.075f64).sin();
        assert!(
            (r.relations_translation_m.mean - 0.1 * step).abs() < 1e-6,
            "{:?}",
            r.relations_translation_m
        );
        assert!(r.relations_translation_m.std < 1e-6);
    }

    #[test]
    fn heading_drift_shows_in_rpe_rotation() {
        let truth = circle(10.0, 30.0);
        let mut est = truth.clone();
        // 1°/s of extra turning accumulated in heading only.
        for p in &mut est {
            p.theta = wrap(p.theta + (1.0f64).to_radians() * p.t);
        }
        let r = evaluate_trajectories(&truth, &est, &TrajectoryOptions::default()).unwrap();
        assert!(
            (r.rpe_rotation_deg.mean - 1.0).abs() < 1e-6,
            "{:?}",
            r.rpe_rotation_deg
        );
    }

    #[test]
    fn disjoint_time_spans_are_an_error() {
        let truth = circle(10.0, 10.0);
        let mut est = circle(10.0, 10.0);
        for p in &mut est {
            p.t += 100.0;
        }
        assert_eq!(
            evaluate_trajectories(&truth, &est, &TrajectoryOptions::default()),
            Err(TrajectoryMetricError::TooFewPairs { pairs: 0 })
        );
    }

    #[test]
    fn parse_errors_name_file_and_line() {
        let p = Path::new("est.txt");
        let e = parse_trajectory("# t x y th\n0 0 0 0\n0.1 0 0\n", p)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("est.txt:3:") && e.contains("4 numbers"),
            "{e}"
        );
        let e = parse_trajectory("0 0 0 0\n0.1 1 nan 0\n", p)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("est.txt:2:") && e.contains('y'), "{e}");
        let e = parse_trajectory("1 0 0 0\n0.5 0 0 0\n", p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("est.txt:2:") && e.contains("increase"), "{e}");
        let e = parse_trajectory("# nothing\n\n", p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("est.txt") && e.contains("no poses"), "{e}");
        assert_eq!(parse_trajectory("0\t1 2 0.5\n", p).unwrap()[0].y, 2.0);
    }

    #[test]
    fn same_stamp_pairing_reports_rms_and_max_of_the_residual() {
        // A reference at 4 stamps; the estimate is the same line moved far away
        // and turned, stamped 3 ns later, with one point 0.4 m off sideways.
        let reference: Vec<StampedPose> = (0..4)
            .map(|i| StampedPose {
                t: i as f64 * 100e-9,
                x: i as f64,
                y: 0.0,
                theta: 0.0,
            })
            .collect();
        let (s, c) = (-1.0f64).sin_cos();
        let mut estimate = transform(&reference, 10.0, 5.0, -1.0);
        for e in &mut estimate {
            e.t += 3e-9;
        }
        estimate[2].x += -s * 0.4;
        estimate[2].y += c * 0.4;
        let near = |tolerance_s| TrajectoryOptions {
            pairing: Pairing::SameStamp { tolerance_s },
            ..Default::default()
        };
        let r = evaluate_trajectories(&reference, &estimate, &near(10e-9)).unwrap();
        assert_eq!(r.pairs, 4);
        assert!(r.ate_m.max > 0.25 && r.ate_m.max < 0.4, "{r:?}");
        assert!((r.ate_max_at_s - 203e-9).abs() < 1e-15, "{r:?}");
        assert!(r.ate_m.rmse < r.ate_m.max);
        let e = evaluate_trajectories(&reference, &estimate, &near(1e-9));
        assert!(
            matches!(
                e,
                Err(TrajectoryMetricError::TooFewAtSameStamps { pairs: 0, tolerance_ms })
                    if (tolerance_ms - 1e-6).abs() < 1e-12
            ),
            "stamps 3 ns apart do not pair at 1 ns: {e:?}"
        );
    }

    #[test]
    fn same_stamp_pairing_ignores_estimates_between_reference_poses() {
        // A reference at every 5th stamp of the estimate (GMapping's corrected
        // poses of a log): interpolation would pair every estimated pose.
        let est = circle(10.0, 20.0);
        let sparse: Vec<StampedPose> = est.iter().step_by(5).copied().collect();
        let r = evaluate_trajectories(&sparse, &est, &TrajectoryOptions::same_stamp()).unwrap();
        assert_eq!(r.pairs, 40);
        assert!(r.ate_m.max < 1e-12);
        let dense = evaluate_trajectories(&sparse, &est, &TrajectoryOptions::default()).unwrap();
        assert_eq!(dense.pairs, 196);
    }

    #[test]
    fn rotated_and_shifted_copy_aligns_exactly() {
        let truth: Vec<StampedPose> = (0..20)
            .map(|i| StampedPose {
                t: i as f64,
                x: i as f64 * 0.3,
                y: (i as f64 * 0.7).sin(),
                theta: 0.0,
            })
            .collect();
        // The estimate is the truth turned by -0.7 rad: the alignment turns it back.
        let est = transform(&truth, -576.5, 3.2, -0.7);
        let r = evaluate_trajectories(&truth, &est, &TrajectoryOptions::same_stamp()).unwrap();
        assert!(
            (r.align_dtheta_deg - 0.7f64.to_degrees()).abs() < 1e-9,
            "{r:?}"
        );
        assert!(r.ate_m.max < 1e-9, "{r:?}");
    }

    #[test]
    fn tum_lines_round_trip_the_planar_pose() {
        let poses = [
            StampedPose {
                t: 1.5,
                x: 1.0,
                y: -2.0,
                theta: 0.3,
            },
            StampedPose {
                t: 2.25,
                x: 1.5,
                y: -2.5,
                theta: -3.0,
            },
            StampedPose {
                t: 3.0,
                x: 2.0,
                y: -3.0,
                theta: 3.1,
            },
        ];
        let text = format_trajectory_as(&poses, TrajectoryFormat::Tum);
        let first = text.lines().next().unwrap();
        assert_eq!(first.split(' ').count(), 8, "{first}");
        assert!(
            first.starts_with("1.500000 1.000000 -2.000000 0 0 0 "),
            "{first}"
        );
        let back = parse_trajectory(&text, Path::new("t.tum")).unwrap();
        for (a, b) in poses.iter().zip(&back) {
            assert!((a.t - b.t).abs() < 1e-9 && (a.x - b.x).abs() < 1e-6);
            assert!(
                (a.theta - b.theta).abs() < 1e-6,
                "{} vs {}",
                a.theta,
                b.theta
            );
        }
        let err = parse_trajectory("1 2 3 4 5\n", Path::new("bad.txt")).unwrap_err();
        assert!(err.to_string().contains("bad.txt:1"), "{err}");
        let err = parse_trajectory("1 0 0 0 0 0 0 0\n", Path::new("z.tum")).unwrap_err();
        assert!(err.to_string().contains("quaternion"), "{err}");
    }

    #[test]
    fn written_trajectories_read_back_to_the_microsecond() {
        let poses = [
            StampedPose::from_ns(
                1_134_864_642_914_187_000,
                &Pose2::new(0.154, 0.068, 0.562729),
            ),
            StampedPose::from_ns(1_134_864_643_553_180_000, &Pose2::new(-1.5, 2.0, -3.1)),
        ];
        let text = format_trajectory(&poses);
        assert!(
            text.starts_with("1134864642.914187 0.154000 0.068000 0.562729\n"),
            "{text}"
        );
        let back = parse_trajectory(&text, Path::new("t.txt")).unwrap();
        assert_eq!(back.len(), 2);
        for (a, b) in back.iter().zip(&poses) {
            assert!((a.t - b.t).abs() < 1e-6 && (a.theta - b.theta).abs() < 1e-6);
        }
    }

    proptest::proptest! {
        #[test]
        fn arbitrary_text_never_panics(text in "\\PC{0,400}") {
            let _ = parse_trajectory(&text, Path::new("fuzz.txt"));
        }

        #[test]
        fn arbitrary_numbers_never_panic(v in proptest::collection::vec((-1e6f64..1e6, -1e3f64..1e3, -1e3f64..1e3, -10.0f64..10.0), 0..50)) {
            let mut t = 0.0;
            let poses: Vec<StampedPose> = v.iter().map(|&(dt, x, y, th)| { t += dt.abs() + 1e-3; StampedPose { t, x, y, theta: th } }).collect();
            let _ = evaluate_trajectories(&poses, &poses, &TrajectoryOptions::default());
        }
    }
}
