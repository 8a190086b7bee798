//! Membership functions and Mamdani defuzzification for SmokeNav v2.

use smokenav_platform_config::fusion::{BellShape, PiShape};

/// μ of a Π-shaped set (see [`PiShape`]); NaN inputs belong to nothing.
pub fn pi(x: f64, s: &PiShape) -> f64 {
    if x.is_nan() {
        return 0.0;
    }
    rise(x, s.a, s.b).min(fall(x, s.c, s.d))
}

/// S-curve: 0 at `a`, 1 at `b` (a step when `a == b`).
fn rise(x: f64, a: f64, b: f64) -> f64 {
    if x >= b {
        1.0
    } else if x <= a {
        0.0
    } else {
        let u = (x - a) / (b - a);
        if u <= 0.5 {
            2.0 * u * u
        } else {
            1.0 - 2.0 * (1.0 - u) * (1.0 - u)
        }
    }
}

/// Z-curve: 1 at `c`, 0 at `d` (a step when `c == d`, never falling when `c = inf`).
fn fall(x: f64, c: f64, d: f64) -> f64 {
    1.0 - if x <= c { 0.0 } else { rise(x, c, d) }
}

/// Generalised bell centred at `centre`.
pub fn bell(x: f64, centre: f64, b: &BellShape) -> f64 {
    1.0 / (1.0 + ((x - centre) / b.width).abs().powf(2.0 * b.slope))
}

/// Centre-of-gravity defuzzifier for one output with a *high* term (bell at 1)
/// fired with strength `w` and a *low* term (bell at 0) fired with `1 − w`,
/// Mamdani min implication and max aggregation. The terms are sampled once.
#[derive(Debug, Clone)]
pub struct Defuzzifier {
    xs: Vec<f64>,
    low: Vec<f64>,
    high: Vec<f64>,
}

impl Defuzzifier {
    pub fn new(shape: &BellShape, samples: usize) -> Self {
        let n = samples.max(2);
        let xs: Vec<f64> = (0..n).map(|k| k as f64 / (n - 1) as f64).collect();
        let low = xs.iter().map(|&x| bell(x, 0.0, shape)).collect();
        let high = xs.iter().map(|&x| bell(x, 1.0, shape)).collect();
        Self { xs, low, high }
    }

    /// ρ for a rule fired with strength `w` ∈ [0, 1].
    pub fn rho(&self, w: f64) -> f64 {
        let w = if w.is_nan() { 0.0 } else { w.clamp(0.0, 1.0) };
        let nw = 1.0 - w;
        let (mut num, mut den) = (0.0, 0.0);
        for ((&x, &lo), &hi) in self.xs.iter().zip(&self.low).zip(&self.high) {
            let m = hi.min(w).max(lo.min(nw));
            num += x * m;
            den += m;
        }
        if den > 0.0 { num / den } else { 0.0 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_platform_config::fusion::V2Params;

    #[test]
    fn confident_crosses_one_half_at_the_papers_2_5_m() {
        let p = V2Params::default();
        assert_eq!(pi(1.0, &p.confident), 1.0);
        assert!((pi(2.5, &p.confident) - 0.5).abs() < 1e-12);
        assert_eq!(pi(3.0, &p.confident), 0.0);
        assert_eq!(
            pi(0.01, &p.confident),
            0.0,
            "below the transducer's blind zone"
        );
    }

    #[test]
    fn alcoholized_crosses_one_half_at_20_and_never_falls() {
        let p = V2Params::default();
        assert_eq!(pi(0.0, &p.alcoholized), 0.0);
        assert!((pi(20.0, &p.alcoholized) - 0.5).abs() < 1e-12);
        assert_eq!(pi(300.0, &p.alcoholized), 1.0);
        assert_eq!(pi(1e12, &p.alcoholized), 1.0);
    }

    #[test]
    fn dense_crosses_one_half_at_0_8_m_spread() {
        let p = V2Params::default();
        assert_eq!(pi(0.0, &p.dense), 1.0);
        assert!((pi(0.8, &p.dense) - 0.5).abs() < 1e-12);
        assert_eq!(pi(1.5, &p.dense), 0.0);
        assert_eq!(pi(f64::NAN, &p.dense), 0.0);
    }

    #[test]
    fn defuzzified_trust_is_monotone_and_centred() {
        let p = V2Params::default();
        let d = Defuzzifier::new(&p.output_bell, p.defuzz_samples);
        assert!((d.rho(0.5) - 0.5).abs() < 1e-9);
        let mut last = -1.0;
        for k in 0..=100 {
            let r = d.rho(k as f64 / 100.0);
            assert!(r > last, "ρ must grow with the firing strength");
            last = r;
        }
        assert!(
            d.rho(0.0) < 0.2 && d.rho(1.0) > 0.8,
            "{} {}",
            d.rho(0.0),
            d.rho(1.0)
        );
        assert!(
            (d.rho(0.0) + d.rho(1.0) - 1.0).abs() < 1e-9,
            "low and high terms mirror"
        );
    }
}
