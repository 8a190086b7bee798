//! The odometry motion model: the four GMapping noise terms.

use smokenav_platform_config::SlamSection;
use smokenav_shared_types::Pose2;
use smokenav_shared_types::Rng;

/// Samples where a particle went given an odometry delta. The standard
/// deviations grow linearly with the motion, as in GMapping:
/// translation noise `srr·|Δρ| + srt·|Δθ|` per axis (with 0.3·srr
/// cross-coupling from the other axis), rotation noise `str·|Δρ| + stt·|Δθ|`.
#[derive(Debug, Clone, Copy)]
pub struct MotionModel {
    /// Translation error per metre of translation.
    pub srr: f64,
    /// Translation error per radian of rotation.
    pub srt: f64,
    /// Rotation error per metre of translation.
    pub str: f64,
    /// Rotation error per radian of rotation.
    pub stt: f64,
}

impl MotionModel {
    pub fn from_config(c: &SlamSection) -> Self {
        Self {
            srr: c.srr,
            srt: c.srt,
            str: c.str,
            stt: c.stt,
        }
    }

    /// `pose ⊕ (delta + noise)`, `delta` expressed in the frame of the previous odometry pose.
    pub fn sample(&self, pose: &Pose2, delta: &Pose2, rng: &mut Rng) -> Pose2 {
        let (ax, ay, at) = (delta.x.abs(), delta.y.abs(), delta.theta.abs());
        let cross = 0.3 * self.srr;
        let noisy = Pose2::new(
            delta.x + rng.gaussian(self.srr * ax + self.srt * at + cross * ay),
            delta.y + rng.gaussian(self.srr * ay + self.srt * at + cross * ax),
            delta.theta + rng.gaussian(self.stt * at + self.str * ax.hypot(ay)),
        );
        pose.compose(&noisy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn standing_still_adds_no_noise() {
        let m = MotionModel::from_config(&SlamSection::default());
        let mut rng = Rng::new(1, 0);
        let p = Pose2::new(1.0, 2.0, 0.5);
        assert_eq!(m.sample(&p, &Pose2::default(), &mut rng), p);
    }

    #[test]
    fn one_metre_forward_spreads_by_srr_and_str() {
        // srr 0.1 → σx = 0.1 m; str 0.1 → σθ = 0.1 rad for 1 m of travel.
        let m = MotionModel::from_config(&SlamSection::default());
        let mut rng = Rng::new(3, 0);
        let n = 20_000;
        let d = Pose2::new(1.0, 0.0, 0.0);
        let samples: Vec<Pose2> = (0..n)
            .map(|_| m.sample(&Pose2::default(), &d, &mut rng))
            .collect();
        let sd = |f: &dyn Fn(&Pose2) -> f64, mean: f64| {
            (samples.iter().map(|p| (f(p) - mean).powi(2)).sum::<f64>() / n as f64).sqrt()
        };
        let mean_theta = samples.iter().map(|p| p.theta).sum::<f64>() / n as f64;
        assert!((sd(&|p| p.theta, mean_theta) - 0.1).abs() < 0.005);
        // x spread: 0.1 (srr) combined with the cosine of the heading noise, close to 0.1.
        let mean_x = samples.iter().map(|p| p.x).sum::<f64>() / n as f64;
        assert!((mean_x - 1.0).abs() < 0.01, "{mean_x}");
        assert!((sd(&|p| p.x, mean_x) - 0.1).abs() < 0.01);
    }
}
