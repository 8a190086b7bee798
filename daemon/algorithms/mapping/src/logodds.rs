//! Log-odds arithmetic and OctoMap's clamped update policy.
//!
//! The Bayes filter in log-odds form (Moravec & Elfes; Thrun, Burgard & Fox,
//! *Probabilistic Robotics*, ch. 9) adds `l(p) = ln(p / (1 − p))` per
//! measurement. Yguel et al.'s clamping bounds the sum so a cell seen free
//! many times can still turn occupied after a few hits; OctoMap (Hornung et
//! al., "OctoMap: an efficient probabilistic 3D mapping framework based on
//! octrees", 2013) uses it with the defaults below.

/// `ln(p / (1 − p))`.
pub fn logodds(p: f64) -> f64 {
    (p / (1.0 - p)).ln()
}

/// The inverse of [`logodds`].
pub fn probability(l: f64) -> f64 {
    1.0 - 1.0 / (1.0 + l.exp())
}

/// Hit and miss probabilities of an update and the clamping bounds, as
/// probabilities.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Clamping {
    /// Probability an "occupied" update carries.
    pub hit: f64,
    /// Probability a "free" update carries.
    pub miss: f64,
    /// Lower clamping bound.
    pub min: f64,
    /// Upper clamping bound.
    pub max: f64,
}

impl Default for Clamping {
    /// OctoMap's defaults: hit 0.7 (+0.85 in log-odds), miss 0.4 (−0.41),
    /// clamped to 0.1192–0.971 (−2.0 … +3.5). The "0.12–0.97" are these
    /// rounded.
    fn default() -> Self {
        Self {
            hit: 0.7,
            miss: 0.4,
            min: 0.1192,
            max: 0.971,
        }
    }
}

/// [`Clamping`] in log-odds, as the maps store it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClampLogOdds {
    pub hit: f32,
    pub miss: f32,
    pub min: f32,
    pub max: f32,
}

impl From<Clamping> for ClampLogOdds {
    fn from(c: Clamping) -> Self {
        Self {
            hit: logodds(c.hit) as f32,
            miss: logodds(c.miss) as f32,
            min: logodds(c.min) as f32,
            max: logodds(c.max) as f32,
        }
    }
}

impl ClampLogOdds {
    /// `l + delta`, clamped (the paper's eq. 22).
    pub fn add(&self, l: f32, delta: f32) -> f32 {
        (l + delta).clamp(self.min, self.max)
    }

    /// Whether a further update of this sign cannot change `l`.
    pub fn saturated(&self, l: f32, occupied: bool) -> bool {
        if occupied {
            l >= self.max
        } else {
            l <= self.min
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn octomap_defaults_in_log_odds() {
        let c = ClampLogOdds::from(Clamping::default());
        assert!((c.hit - 0.847).abs() < 1e-3, "{}", c.hit);
        assert!((c.miss + 0.405).abs() < 1e-3, "{}", c.miss);
        assert!((c.min + 2.0).abs() < 1e-3, "{}", c.min);
        assert!((c.max - 3.5).abs() < 0.02, "{}", c.max);
    }

    #[test]
    fn clamping_bounds_the_sum_both_ways() {
        let c = ClampLogOdds::from(Clamping::default());
        let mut l = 0.0;
        for _ in 0..50 {
            l = c.add(l, c.miss);
        }
        assert_eq!(l, c.min);
        // Eq. 22: from the lower bound, three hits already make the cell occupied.
        for _ in 0..3 {
            l = c.add(l, c.hit);
        }
        assert!(l > 0.0, "{l}");
        assert!(c.saturated(c.max, true) && !c.saturated(c.max, false));
    }

    #[test]
    fn probability_inverts_log_odds() {
        for p in [0.01, 0.3, 0.5, 0.7, 0.97] {
            assert!((probability(logodds(p)) - p).abs() < 1e-12);
        }
    }
}
