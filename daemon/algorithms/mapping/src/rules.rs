//! The four ways of pooling per-sensor occupancy opinions of one cell that
//! Tran et al. 2021 compare (after Dietrich et al.'s
//! survey of opinion pools and Thrun's *Probabilistic Robotics*):
//! Linear Opinion Pool (eq. 4), Logarithmic Independent Opinion Pool
//! (eq. 6), Independent Opinion Pool (eq. 7) and the Bayes filter in
//! log-odds (eq. 15). Only IOP and Bayes leave a cell seen by one sensor at
//! that sensor's value (eqs. 16–19), which is why the maps use Bayes.

use crate::logodds::{logodds, probability};
use std::fmt;

/// A fusion rule.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FusionRule {
    /// Weighted mean of the probabilities.
    Lop,
    /// Weighted geometric mean, renormalised.
    Liop,
    /// Product, renormalised (weights do not enter: in the paper's eq. 7 they
    /// would cancel in a consistently weighted normaliser).
    Iop,
    /// Sum of log-odds against the prior (0.5 here, so `l = Σ l_i`).
    Bayes,
}

impl FusionRule {
    pub const ALL: [FusionRule; 4] = [
        FusionRule::Lop,
        FusionRule::Liop,
        FusionRule::Iop,
        FusionRule::Bayes,
    ];

    pub fn name(self) -> &'static str {
        match self {
            FusionRule::Lop => "LOP",
            FusionRule::Liop => "LIOP",
            FusionRule::Iop => "IOP",
            FusionRule::Bayes => "Bayes",
        }
    }
}

impl fmt::Display for FusionRule {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// One sensor's opinion of one cell: its occupancy probability and weight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Opinion {
    pub p: f64,
    /// 0 ≤ w ≤ 1; LOP and LIOP normalise the weights to sum to one.
    pub w: f64,
}

impl Opinion {
    pub const fn new(p: f64, w: f64) -> Self {
        Self { p, w }
    }
}

/// Pools the opinions with `rule`. An empty set, or weights summing to zero,
/// gives the prior 0.5. Probabilities are taken as given; 0 and 1 are legal
/// (IOP of a certain and an opposite certain opinion is 0.5).
pub fn fuse(rule: FusionRule, opinions: &[Opinion]) -> f64 {
    let wsum: f64 = opinions.iter().map(|o| o.w).sum();
    match rule {
        FusionRule::Lop => {
            if wsum <= 0.0 {
                return 0.5;
            }
            opinions.iter().map(|o| o.w * o.p).sum::<f64>() / wsum
        }
        FusionRule::Liop => {
            if wsum <= 0.0 {
                return 0.5;
            }
            let (mut a, mut b) = (1.0, 1.0);
            for o in opinions {
                let w = o.w / wsum;
                a *= o.p.powf(w);
                b *= (1.0 - o.p).powf(w);
            }
            if a + b > 0.0 { a / (a + b) } else { 0.5 }
        }
        FusionRule::Iop => {
            let (mut a, mut b) = (1.0, 1.0);
            for o in opinions {
                a *= o.p;
                b *= 1.0 - o.p;
            }
            if a + b > 0.0 { a / (a + b) } else { 0.5 }
        }
        FusionRule::Bayes => probability(opinions.iter().map(|o| logodds(o.p)).sum()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Eqs. 16–19: sensor 1 says `p1`, the other N − 1 sensors know nothing (0.5),
    /// all weighted equally.
    fn single_informative(rule: FusionRule, p1: f64, n: usize) -> f64 {
        let mut o = vec![Opinion::new(0.5, 1.0 / n as f64); n];
        o[0].p = p1;
        fuse(rule, &o)
    }

    #[test]
    fn one_informative_sensor_iop_and_bayes_return_its_probability() {
        for n in 2..=5 {
            for p1 in [0.1, 0.3, 0.7, 0.9] {
                // Eq. 18 and 19: independent of N.
                assert!((single_informative(FusionRule::Iop, p1, n) - p1).abs() < 1e-12);
                assert!((single_informative(FusionRule::Bayes, p1, n) - p1).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn one_informative_sensor_lop_and_liop_depend_on_n() {
        for n in 2..=5usize {
            let nf = n as f64;
            let p1: f64 = 0.9;
            // Eq. 16.
            let lop = p1 / nf + (nf - 1.0) * 0.5 / nf;
            assert!((single_informative(FusionRule::Lop, p1, n) - lop).abs() < 1e-12);
            // Eq. 17.
            let liop = p1.powf(1.0 / nf) / (p1.powf(1.0 / nf) + (1.0 - p1).powf(1.0 / nf));
            assert!((single_informative(FusionRule::Liop, p1, n) - liop).abs() < 1e-12);
            assert!(lop < p1 && liop < p1, "n = {n}: pulled towards 0.5");
        }
        // And they move with N.
        assert!(
            single_informative(FusionRule::Lop, 0.9, 2)
                > single_informative(FusionRule::Lop, 0.9, 3)
        );
        assert!(
            single_informative(FusionRule::Liop, 0.9, 2)
                > single_informative(FusionRule::Liop, 0.9, 3)
        );
    }

    #[test]
    fn two_sensors_at_0_7_give_0_845_after_one_bayes_update() {
        // The paper's Fig. 12 point (3): both ISMs say 0.7. Exactly,
        // l = 2 · ln(0.7/0.3) = 1.695 and p = 0.49/0.58 = 0.845; the paper's
        // 0.83 comes from its log-odds written as 0.35 (log10, rounded) twice.
        let two = [Opinion::new(0.7, 0.5), Opinion::new(0.7, 0.5)];
        let p = fuse(FusionRule::Bayes, &two);
        assert!(
            (p - 0.49 / 0.58).abs() < 1e-12 && (p - 0.845).abs() < 5e-4,
            "{p}"
        );
        assert!(
            (fuse(FusionRule::Iop, &two) - p).abs() < 1e-12,
            "IOP = Bayes at prior 0.5"
        );
        // Supporting evidence raises IOP/Bayes but not the averaging pools.
        assert!((fuse(FusionRule::Lop, &two) - 0.7).abs() < 1e-12);
        assert!((fuse(FusionRule::Liop, &two) - 0.7).abs() < 1e-12);
    }

    #[test]
    fn conflicting_evidence_returns_to_unknown() {
        let c = [Opinion::new(0.7, 0.5), Opinion::new(0.3, 0.5)];
        for rule in FusionRule::ALL {
            assert!((fuse(rule, &c) - 0.5).abs() < 1e-12, "{rule}");
        }
    }

    #[test]
    fn weights_shift_lop_and_liop_towards_the_trusted_sensor() {
        // The paper's second use case: the sonar (first) weighs less than the laser.
        let o = [Opinion::new(0.9, 0.2), Opinion::new(0.2, 0.8)];
        assert!(fuse(FusionRule::Lop, &o) < 0.5);
        assert!(fuse(FusionRule::Liop, &o) < 0.5);
        assert!((fuse(FusionRule::Lop, &o) - (0.18 + 0.16)).abs() < 1e-12);
    }

    #[test]
    fn degenerate_inputs_give_the_prior() {
        for rule in FusionRule::ALL {
            assert_eq!(fuse(rule, &[]), 0.5, "{rule}");
        }
        assert_eq!(fuse(FusionRule::Lop, &[Opinion::new(0.9, 0.0)]), 0.5);
        assert_eq!(
            fuse(
                FusionRule::Iop,
                &[Opinion::new(1.0, 1.0), Opinion::new(0.0, 1.0)]
            ),
            0.5
        );
    }
}
