//! Which directions of the robot pose a scan constrains, and by how much.
//!
//! A scan matcher's objective is flat along a long featureless corridor (or
//! a scan that smoke reduced to the two side walls): the walls say where the
//! robot is across the corridor and how it is turned, not how far along it
//! went. There the optimum is decided by nothing real — where the local map
//! happens to end, a few stray points — and a matcher that follows it
//! slides, typically backwards (points beyond the map's end match better when
//! the scan is pulled back onto it), shrinking the corridor.
//!
//! [`ScanConstraint`] measures this from the scan's own geometry: each
//! endpoint on a locally straight surface constrains the pose only along
//! that surface's normal, so the Gauss-Newton Hessian of the point-to-line
//! objective, `H = Σ Jᵢ Jᵢᵀ` with `Jᵢ = (nₓ, n_y, p × n)`, is the information
//! the scan carries about (x, y, θ) in units of "endpoints". Its eigenvectors
//! with small eigenvalues are the degenerate directions (Zhang, Kaess and
//! Singh, "On degeneracy of optimization-based state estimation problems",
//! ICRA 2016). [`ScanConstraint::remap`] keeps a match's correction only
//! where the scan constrains it and takes the prediction (odometry) elsewhere.
//!
//! Computed in the robot frame, so one per scan serves every particle.

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use smokenav_shared_types::Pose2;

/// Neighbours either side (in scan order) a normal is fitted over.
const NEIGHBOURS: usize = 3;
/// Neighbours further than this from the point are not on its surface, m.
const NEIGHBOUR_RADIUS: f64 = 0.3;
/// A fit whose spread across the line exceeds this share of the spread along
/// it is a corner or clutter: its normal is not used.
const MAX_FLATNESS: f64 = 0.05;
/// Length that makes a rotation comparable with a translation: θ is scaled
/// by it (1 rad at 1 m moves a point 1 m).
pub const ROTATION_SCALE_M: f64 = 1.0;

/// What a scan constrains: the information about the pose in the robot
/// frame, (x, y, θ·[`ROTATION_SCALE_M`]), in endpoints.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanConstraint {
    /// Σ JᵢJᵢᵀ over the endpoints with a normal.
    pub information: Matrix3<f64>,
    /// Eigenvalues (ascending) and eigenvectors (columns, same order).
    pub eigenvalues: Vector3<f64>,
    pub eigenvectors: Matrix3<f64>,
    /// Endpoints that had a usable normal.
    pub normals: usize,
}

/// How strongly a direction must be constrained before a match is followed in it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DegeneracyParams {
    /// Eigenvalue (endpoints' worth of constraint) at which a match's
    /// correction is taken half; twice it almost fully (94 %), half of it
    /// hardly (6 %). A simulated aisle leaves its length direction below 0.5;
    /// the weakest direction of a real office scan is typically 3–10.
    pub min_information: f64,
    /// The same as a share of the endpoints with a normal (each adds 1 to
    /// the translation's trace; the larger of the two applies).
    pub min_share: f64,
    /// σ of a prediction (along a direction) at which the floors apply as
    /// they are; a worse prediction lowers them by (this / its σ)², m.
    pub reference_sigma_m: f64,
}

/// A robot-frame covariance in the scaled coordinates (x, y, θ·[`ROTATION_SCALE_M`]).
fn scaled(c: &Matrix3<f64>) -> Matrix3<f64> {
    let s = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, ROTATION_SCALE_M));
    s * c * s
}

impl Default for DegeneracyParams {
    fn default() -> Self {
        Self {
            min_information: 1.0,
            min_share: 0.01,
            reference_sigma_m: 0.07,
        }
    }
}

impl ScanConstraint {
    /// From endpoints in the robot frame, in scan order (neighbours in the
    /// list are neighbours on the surface).
    pub fn from_points(points: &[(f64, f64)]) -> Self {
        let mut info = Matrix3::zeros();
        let mut normals = 0;
        let r2 = NEIGHBOUR_RADIUS * NEIGHBOUR_RADIUS;
        for (i, &(px, py)) in points.iter().enumerate() {
            let lo = i.saturating_sub(NEIGHBOURS);
            let hi = (i + NEIGHBOURS + 1).min(points.len());
            let (mut n, mut sx, mut sy) = (0.0, 0.0, 0.0);
            for &(qx, qy) in &points[lo..hi] {
                if (qx - px).powi(2) + (qy - py).powi(2) <= r2 {
                    n += 1.0;
                    sx += qx;
                    sy += qy;
                }
            }
            if n < 3.0 {
                continue;
            }
            let (mx, my) = (sx / n, sy / n);
            let (mut cxx, mut cxy, mut cyy) = (0.0, 0.0, 0.0);
            for &(qx, qy) in &points[lo..hi] {
                if (qx - px).powi(2) + (qy - py).powi(2) <= r2 {
                    let (dx, dy) = (qx - mx, qy - my);
                    cxx += dx * dx;
                    cxy += dx * dy;
                    cyy += dy * dy;
                }
            }
            // Eigen-decomposition of the 2×2 scatter, closed form.
            let half_tr = 0.5 * (cxx + cyy);
            let d = (0.25 * (cxx - cyy).powi(2) + cxy * cxy).sqrt();
            let (big, small) = (half_tr + d, half_tr - d);
            if big <= 1e-12 || small > MAX_FLATNESS * big {
                continue;
            }
            // The normal is the eigenvector of the small eigenvalue.
            let (nx, ny) = if cxy.abs() > 1e-12 {
                let (vx, vy) = (small - cyy, cxy);
                let l = vx.hypot(vy);
                (vx / l, vy / l)
            } else if cxx < cyy {
                (1.0, 0.0)
            } else {
                (0.0, 1.0)
            };
            let j = Vector3::new(nx, ny, (px * ny - py * nx) / ROTATION_SCALE_M);
            info += j * j.transpose();
            normals += 1;
        }
        Self::from_information(info, normals)
    }

    /// From an information matrix already summed (e.g. over several scans'
    /// points, rescaled), and the number of endpoints with a normal it counts.
    pub fn from_information(info: Matrix3<f64>, normals: usize) -> Self {
        let eig = SymmetricEigen::new(info);
        // Ascending order.
        let mut order = [0usize, 1, 2];
        order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
        let eigenvalues = Vector3::from_fn(|i, _| eig.eigenvalues[order[i]].max(0.0));
        let eigenvectors = Matrix3::from_fn(|r, c| eig.eigenvectors[(r, order[c])]);
        Self {
            information: info,
            eigenvalues,
            eigenvectors,
            normals,
        }
    }

    /// Per eigen-direction, the share (0–1) of a match's correction to keep.
    /// With the prediction's covariance (robot frame), the floor scales with
    /// how good the prediction is: a direction weakly constrained by the scan
    /// is still the match's when the prediction is worse (odometry that
    /// repeated, a reset), and the prediction's when odometry is good.
    pub fn weights(&self, p: &DegeneracyParams, prediction: Option<&Matrix3<f64>>) -> Vector3<f64> {
        let floor = p
            .min_information
            .max(p.min_share * self.normals as f64)
            .max(1e-9);
        let pred = prediction.map(scaled);
        Vector3::from_fn(|i, _| {
            let floor = match &pred {
                Some(c) => {
                    let e = self.eigenvectors.column(i);
                    let var = (e.transpose() * c * e)[0].max(1e-12);
                    floor * (p.reference_sigma_m * p.reference_sigma_m / var).min(1.0)
                }
                None => floor,
            };
            // Sharp around the floor: the weakly constrained directions of a
            // real scan (door frames along a corridor) are still followed.
            let r = (self.eigenvalues[i] / floor.max(1e-9)).powi(4);
            r / (1.0 + r)
        })
    }

    /// Eigen-directions with less than half of a match's correction kept.
    pub fn degenerate_directions(
        &self,
        p: &DegeneracyParams,
        prediction: Option<&Matrix3<f64>>,
    ) -> usize {
        self.weights(p, prediction)
            .iter()
            .filter(|&&w| w < 0.5)
            .count()
    }

    /// `matched` with its correction from `predicted` kept only in the
    /// directions the scan constrains: the prediction's value elsewhere.
    pub fn remap(
        &self,
        predicted: &Pose2,
        matched: &Pose2,
        p: &DegeneracyParams,
        prediction: Option<&Matrix3<f64>>,
    ) -> Pose2 {
        let d = predicted.between(matched);
        let d = Vector3::new(d.x, d.y, d.theta * ROTATION_SCALE_M);
        let w = self.weights(p, prediction);
        if w.iter().all(|&w| w > 1.0 - 1e-9) {
            return *matched;
        }
        let v = &self.eigenvectors;
        let mut kept = Vector3::zeros();
        for i in 0..3 {
            let e = v.column(i);
            kept += e * (w[i] * e.dot(&d));
        }
        predicted.compose(&Pose2::new(kept[0], kept[1], kept[2] / ROTATION_SCALE_M))
    }

    /// Covariance of a match in the robot frame, given the variance of one
    /// endpoint's distance to its surface (m²) and the prediction's
    /// covariance (robot frame) times `prediction_share`, used where the scan
    /// does not constrain: information blended per eigen-direction by
    /// [`Self::weights`] (of the unscaled prediction, as [`Self::remap`] has them).
    pub fn covariance(
        &self,
        point_variance: f64,
        prediction: &Matrix3<f64>,
        prediction_share: f64,
        p: &DegeneracyParams,
    ) -> Matrix3<f64> {
        let pred = scaled(prediction) * prediction_share;
        let w = self.weights(p, Some(prediction));
        let v = &self.eigenvectors;
        let mut cov = Matrix3::zeros();
        for i in 0..3 {
            let e = v.column(i);
            let along_pred = (e.transpose() * pred * e)[0];
            let matched = point_variance / self.eigenvalues[i].max(1e-9);
            // Information: share w from the match, (1 − w) from the prediction.
            let var = 1.0 / (w[i] / matched.min(along_pred) + (1.0 - w[i]) / along_pred);
            cov += e * e.transpose() * var;
        }
        let si = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 1.0 / ROTATION_SCALE_M));
        si * cov * si
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points every 3 cm along the segment from a to b.
    fn segment(a: (f64, f64), b: (f64, f64)) -> Vec<(f64, f64)> {
        let n = ((b.0 - a.0).hypot(b.1 - a.1) / 0.03).ceil() as usize;
        (0..=n)
            .map(|i| {
                let t = i as f64 / n as f64;
                (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1))
            })
            .collect()
    }

    fn corridor() -> Vec<(f64, f64)> {
        let mut p = segment((-5.0, -1.2), (5.0, -1.2));
        p.extend(segment((5.0, 1.4), (-5.0, 1.4)));
        p
    }

    #[test]
    fn a_corridor_leaves_only_the_direction_along_it_free() {
        let c = ScanConstraint::from_points(&corridor());
        let p = DegeneracyParams::default();
        assert_eq!(c.degenerate_directions(&p, None), 1, "{c:?}");
        let free = c.eigenvectors.column(0);
        assert!(free[0].abs() > 0.99, "free direction {free:?}");
        // A match that slid 0.4 m along and corrected 5 cm across and 0.02 rad
        // keeps the correction across and the turn, not the slide.
        let pred = Pose2::new(2.0, 1.0, 0.0);
        let matched = Pose2::new(1.6, 1.05, 0.02);
        let r = c.remap(&pred, &matched, &p, None);
        assert!((r.x - 2.0).abs() < 0.01, "{r:?}");
        assert!((r.y - 1.05).abs() < 0.005, "{r:?}");
        assert!((r.theta - 0.02).abs() < 0.002, "{r:?}");
    }

    #[test]
    fn a_corner_constrains_everything() {
        let mut pts = segment((3.0, -3.0), (3.0, 2.0));
        pts.extend(segment((3.0, 2.0), (-3.0, 2.0)));
        let c = ScanConstraint::from_points(&pts);
        let p = DegeneracyParams::default();
        assert_eq!(c.degenerate_directions(&p, None), 0, "{c:?}");
        let pred = Pose2::new(0.0, 0.0, 0.0);
        let matched = Pose2::new(0.3, -0.2, 0.05);
        let r = c.remap(&pred, &matched, &p, None);
        assert!(
            (r.x - 0.3).abs() < 0.01 && (r.y + 0.2).abs() < 0.01,
            "{r:?}"
        );
    }

    #[test]
    fn the_corridor_frame_does_not_matter() {
        // The same corridor seen by a robot turned 30°: still one free direction, along the walls.
        let (s, c) = (-0.5f64).sin_cos();
        let turned: Vec<_> = corridor()
            .into_iter()
            .map(|(x, y)| (c * x - s * y, s * x + c * y))
            .collect();
        let k = ScanConstraint::from_points(&turned);
        assert_eq!(
            k.degenerate_directions(&DegeneracyParams::default(), None),
            1
        );
        let free = k.eigenvectors.column(0);
        assert!(
            (free[0] - c).abs() < 0.02 || (free[0] + c).abs() < 0.02,
            "{free:?}"
        );
    }

    #[test]
    fn covariance_is_wide_only_along_the_corridor() {
        let c = ScanConstraint::from_points(&corridor());
        let p = DegeneracyParams::default();
        let pred = Matrix3::from_diagonal(&Vector3::new(0.04, 0.04, 0.01));
        let cov = c.covariance(0.03f64.powi(2), &pred, 1.0, &p);
        assert!(cov[(0, 0)] > 0.03, "{cov}");
        assert!(cov[(1, 1)] < 1e-4, "{cov}");
        assert!(cov[(2, 2)] < 1e-4, "{cov}");
        assert!(cov.cholesky().is_some());
    }

    #[test]
    fn too_few_points_constrain_nothing() {
        let c = ScanConstraint::from_points(&[(1.0, 0.0), (1.0, 0.1)]);
        assert_eq!(c.normals, 0);
        let p = DegeneracyParams::default();
        assert_eq!(c.degenerate_directions(&p, None), 3);
        let pred = Pose2::new(1.0, 2.0, 0.3);
        assert_eq!(c.remap(&pred, &Pose2::new(0.0, 0.0, 0.0), &p, None), pred);
    }
}
