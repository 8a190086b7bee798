//! The relations metric of Kümmerle et al. 2009 ("On measuring the accuracy
//! of SLAM algorithms") against a published relations file: the benchmark's
//! ground truth is not a trajectory but a set of relative motions between
//! pairs of scans, each checked by hand against the scans themselves.
//!
//! A relations file holds one relation per line, `t1 t2 x y z roll pitch
//! yaw`: the motion from the robot's pose at stamp `t1` to its pose at
//! stamp `t2`, expressed in the frame of the first (m, rad); the Freiburg
//! benchmark files (Intel, ACES, FR079, MIT CSAIL, Killian Court, …) are
//! written so. The planar `t1 t2 x y theta` is read as well. z, roll and
//! pitch are ignored: the evaluation is planar. Blank lines and lines
//! starting with `#` are skipped.
//!
//! The estimate's poses at `t1` and `t2` are interpolated between the
//! estimate's samples around them (never across a gap longer than
//! `max_gap_s`); a relation outside the estimate's span is counted, not
//! scored. Errors are reported as the benchmark's tables give them: the
//! absolute and the squared translational (m, m²) and rotational (°, °²)
//! errors, each as mean ± standard deviation. No alignment is involved.

use crate::trajectory::{
    FileReadError, LineError, MeanStd, StampedPose, data_lines, finite_numbers, read_bounded,
    relative, relative_error, truth_at,
};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Largest relations file read, bytes (the benchmark's are under 10 MB).
pub const MAX_FILE_BYTES: u64 = 256 * 1024 * 1024;

/// One relation: the motion from the pose at `t1` to the pose at `t2`, in the first one's frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Relation {
    pub t1: f64,
    pub t2: f64,
    pub dx: f64,
    pub dy: f64,
    pub dtheta: f64,
}

#[derive(Debug, thiserror::Error)]
pub enum RelationsError {
    #[error(transparent)]
    Read(#[from] FileReadError),
    #[error(transparent)]
    Parse(#[from] LineError),
    #[error("{}: no relations (expected lines `t1 t2 x y z roll pitch yaw`)", path.display())]
    Empty { path: PathBuf },
}

/// Parses relations text; `path` is only used in messages.
pub fn parse_relations(text: &str, path: &Path) -> Result<Vec<Relation>, RelationsError> {
    const FULL: [&str; 8] = ["t1", "t2", "x", "y", "z", "roll", "pitch", "yaw"];
    const PLANAR: [&str; 5] = ["t1", "t2", "x", "y", "theta"];
    let mut out = Vec::new();
    for (line, fields) in data_lines(text) {
        let err = |reason: String| {
            RelationsError::from(LineError {
                path: path.to_owned(),
                line,
                reason,
            })
        };
        let names: &[&str] = match fields.len() {
            8 => &FULL,
            5 => &PLANAR,
            n => {
                return Err(err(format!(
                    "expected 8 numbers `t1 t2 x y z roll pitch yaw` or 5 `t1 t2 x y theta`, got {n} field(s)"
                )));
            }
        };
        let v = finite_numbers(&fields, names).map_err(err)?;
        let dtheta = if fields.len() == 8 { v[7] } else { v[4] };
        out.push(Relation {
            t1: v[0],
            t2: v[1],
            dx: v[2],
            dy: v[3],
            dtheta,
        });
    }
    if out.is_empty() {
        return Err(RelationsError::Empty {
            path: path.to_owned(),
        });
    }
    Ok(out)
}

/// Reads a relations file.
pub fn load_relations(path: &Path) -> Result<Vec<Relation>, RelationsError> {
    parse_relations(&read_bounded(path, MAX_FILE_BYTES)?, path)
}

/// An estimate scored against a relations file.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RelationsReport {
    /// Relations scored.
    pub relations: usize,
    /// Relations whose stamps fall outside the estimate (or in a gap of it).
    pub unmatched: usize,
    /// Absolute translational error, m.
    pub translation_m: MeanStd,
    /// Squared translational error, m².
    pub translation_sq_m2: MeanStd,
    /// Absolute rotational error, degrees.
    pub rotation_deg: MeanStd,
    /// Squared rotational error, degrees².
    pub rotation_sq_deg2: MeanStd,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RelationsMetricError {
    #[error(
        "none of the {relations} relations has both stamps within the estimate's poses \
         ({first:.6} – {last:.6} s; the relations start at {first_relation:.6} s): \
         is it the same log?"
    )]
    NoneMatched {
        relations: usize,
        first: f64,
        last: f64,
        first_relation: f64,
    },
}

/// Stamps this close are one: files write them to the microsecond, and a
/// stamp read back lands a fraction of that off the one it was printed from.
const SAME_STAMP_S: f64 = 1e-6;

/// The estimate's pose at `t`: its sample there, else interpolated.
fn pose_at(estimate: &[StampedPose], t: f64, max_gap_s: f64) -> Option<StampedPose> {
    let i = estimate.partition_point(|p| p.t < t);
    let near = [i.checked_sub(1), Some(i)]
        .into_iter()
        .flatten()
        .filter_map(|j| estimate.get(j))
        .find(|p| (p.t - t).abs() <= SAME_STAMP_S);
    near.copied().or_else(|| truth_at(estimate, t, max_gap_s))
}

/// Scores `estimate` against `relations`.
pub fn evaluate_relations(
    estimate: &[StampedPose],
    relations: &[Relation],
    max_gap_s: f64,
) -> Result<RelationsReport, RelationsMetricError> {
    let (mut t_err, mut r_err) = (Vec::new(), Vec::new());
    for r in relations {
        let (Some(a), Some(b)) = (
            pose_at(estimate, r.t1, max_gap_s),
            pose_at(estimate, r.t2, max_gap_s),
        ) else {
            continue;
        };
        let (t, rot) = relative_error(relative(&a, &b), (r.dx, r.dy, r.dtheta));
        t_err.push(t);
        r_err.push(rot);
    }
    if t_err.is_empty() {
        return Err(RelationsMetricError::NoneMatched {
            relations: relations.len(),
            first: estimate.first().map_or(f64::NAN, |p| p.t),
            last: estimate.last().map_or(f64::NAN, |p| p.t),
            first_relation: relations.first().map_or(f64::NAN, |r| r.t1),
        });
    }
    let sq = |v: &[f64]| v.iter().map(|x| x * x).collect::<Vec<_>>();
    Ok(RelationsReport {
        relations: t_err.len(),
        unmatched: relations.len() - t_err.len(),
        translation_m: MeanStd::from(&t_err),
        translation_sq_m2: MeanStd::from(&sq(&t_err)),
        rotation_deg: MeanStd::from(&r_err),
        rotation_sq_deg2: MeanStd::from(&sq(&r_err)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A robot driving a 2 m circle, one pose per 0.2 s.
    fn circle(n: usize) -> Vec<StampedPose> {
        (0..n)
            .map(|i| {
                let a = i as f64 * 0.05;
                StampedPose {
                    t: 100.0 + 0.2 * i as f64,
                    x: 2.0 * a.sin(),
                    y: 2.0 - 2.0 * a.cos(),
                    theta: a,
                }
            })
            .collect()
    }

    /// The relations of a trajectory between sample `i` and `i + step`, as a benchmark file writes them.
    fn file_of(t: &[StampedPose], step: usize) -> String {
        let mut s = String::from("# t1 t2 x y z roll pitch yaw\n");
        for i in 0..t.len() - step {
            let (x, y, th) = relative(&t[i], &t[i + step]);
            s.push_str(&format!(
                "{:.6} {:.6} {x} {y} 0 0 0 {th}\n",
                t[i].t,
                t[i + step].t
            ));
        }
        s
    }

    #[test]
    fn a_trajectory_scores_zero_against_its_own_relations_in_any_frame() {
        let truth = circle(80);
        let rel = parse_relations(&file_of(&truth, 3), Path::new("r")).unwrap();
        assert_eq!(rel.len(), 77);
        // The same motion, started elsewhere and turned: relations need no alignment.
        let moved: Vec<StampedPose> = truth
            .iter()
            .map(|p| {
                let (s, c) = 1.1f64.sin_cos();
                StampedPose {
                    t: p.t,
                    x: 5.0 + c * p.x - s * p.y,
                    y: -3.0 + s * p.x + c * p.y,
                    theta: p.theta + 1.1,
                }
            })
            .collect();
        let r = evaluate_relations(&moved, &rel, 0.5).unwrap();
        assert_eq!((r.relations, r.unmatched), (77, 0));
        assert!(r.translation_m.mean < 1e-6, "{r:?}");
        assert!(r.rotation_deg.mean < 1e-4, "{r:?}");
    }

    #[test]
    fn a_scale_error_shows_in_translation_and_its_square() {
        let truth = circle(80);
        let rel = parse_relations(&file_of(&truth, 1), Path::new("r")).unwrap();
        // 10 % long: every 0.1 m step is off by 0.01 m, turned right.
        let long: Vec<StampedPose> = truth
            .iter()
            .map(|p| StampedPose {
                x: 1.1 * p.x,
                y: 1.1 * p.y,
                ..*p
            })
            .collect();
        let r = evaluate_relations(&long, &rel, 0.5).unwrap();
        let step = 2.0 * 2.0 * (0.05f64 / 2.0).sin();
        assert!((r.translation_m.mean - 0.1 * step).abs() < 1e-6, "{r:?}");
        assert!(r.translation_m.std < 1e-6, "{r:?}");
        assert!((r.translation_sq_m2.mean - (0.1 * step).powi(2)).abs() < 1e-9);
        assert!(r.rotation_deg.mean < 1e-6, "{r:?}");
    }

    #[test]
    fn stamps_between_samples_are_interpolated_and_outside_ones_counted() {
        let truth = circle(40);
        let mut text = String::new();
        // Half-way between samples 10 and 11, to sample 20; then one past the end.
        let mid = StampedPose {
            t: 102.1,
            x: 2.0 * 0.525f64.sin(),
            y: 2.0 - 2.0 * 0.525f64.cos(),
            theta: 0.525,
        };
        let (x, y, th) = relative(&mid, &truth[20]);
        text.push_str(&format!("102.1 {} {x} {y} {th}\n", truth[20].t));
        text.push_str(&format!("{} 250.0 1 0 0 0 0 0\n", truth[5].t));
        let rel = parse_relations(&text, Path::new("r")).unwrap();
        let r = evaluate_relations(&truth, &rel, 0.5).unwrap();
        assert_eq!((r.relations, r.unmatched), (1, 1));
        // Linear interpolation of a 2 m circle over 0.05 rad: sub-millimetre.
        assert!(r.translation_m.mean < 1e-3, "{r:?}");
    }

    /// The first pose's stamp, printed to the microsecond and read back, lands
    /// just before it: once counted as outside the trajectory.
    #[test]
    fn a_stamp_printed_to_the_microsecond_finds_its_pose() {
        let mut t = circle(10);
        // CSAIL's first stamp, 1134864629.895182, as the ns the log reader makes of it.
        t.iter_mut().for_each(|p| p.t += 1_134_864_529.895_182_1);
        let text = format!("{:.6} {:.6} 0 0 0 0 0 0\n", t[0].t, t[0].t);
        let rel = parse_relations(&text, Path::new("r")).unwrap();
        assert!(rel[0].t1 < t[0].t);
        let r = evaluate_relations(&t, &rel, 0.5).unwrap();
        assert_eq!((r.relations, r.unmatched), (1, 0));
    }

    #[test]
    fn another_logs_relations_are_an_error_that_says_so() {
        let rel = parse_relations("5.0 6.0 1 0 0 0 0 0\n", Path::new("r")).unwrap();
        let e = evaluate_relations(&circle(10), &rel, 0.5).unwrap_err();
        assert!(e.to_string().contains("same log"), "{e}");
    }

    proptest::proptest! {
        #[test]
        fn arbitrary_text_never_panics(text in "\\PC{0,400}") {
            let _ = parse_relations(&text, Path::new("fuzz.relations"));
        }

        #[test]
        fn arbitrary_relations_never_panic(
            v in proptest::collection::vec((-1e3f64..1e3, -1e3f64..1e3, -1e3f64..1e3, -10.0f64..10.0), 1..30),
        ) {
            let rel: Vec<Relation> = v.iter().map(|&(t1, t2, x, th)| Relation { t1, t2, dx: x, dy: -x, dtheta: th }).collect();
            let _ = evaluate_relations(&circle(20), &rel, 0.5);
            let _ = evaluate_relations(&[], &rel, 0.5);
        }
    }

    #[test]
    fn bad_lines_are_named_with_their_number() {
        let p = Path::new("csail.relations");
        for (text, says) in [
            ("1 2 3 4 5 6 7\n", "csail.relations:1: expected 8 numbers"),
            (
                "# c\n\n1 2 x 4 5 6 7 8\n",
                "csail.relations:3: x: expected a finite number",
            ),
            (
                "1 2 3 4 nan\n",
                "csail.relations:1: theta: expected a finite number",
            ),
            ("# only a comment\n", "no relations"),
        ] {
            let e = parse_relations(text, p).unwrap_err().to_string();
            assert!(e.contains(says), "{text:?}: {e}");
        }
    }
}
