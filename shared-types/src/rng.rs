//! The one seeded random number generator of the simulator and the
//! algorithms.
//!
//! "Same seed ⇒ same run" must survive dependency upgrades, so the generator
//! is ours and its algorithm never changes: xoshiro256++ (Blackman & Vigna,
//! "Scrambled linear pseudorandom number generators", 2021) seeded through
//! SplitMix64, as its authors recommend. A `(seed, stream)` pair names a
//! stream: each simulated sensor owns one, so switching one model on or off
//! never changes another's numbers.
//!
//! Two ways to draw normals, kept on purpose: [`Rng::normal`] draws two
//! uniforms every call (a fixed number of draws per simulated event keeps
//! streams aligned), while [`Rng::gaussian`] keeps the second value of each
//! Box–Muller pair for the next call (half the draws, for the particle
//! filter's motion noise). Changing either would change every seeded result.

/// xoshiro256++ with its SplitMix64 seeding.
#[derive(Debug, Clone)]
pub struct Rng {
    s: [u64; 4],
    /// The unused half of the last Box–Muller pair [`Rng::gaussian`] drew.
    spare_normal: Option<f64>,
}

fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Rng {
    /// The stream `stream` of `seed`: distinct streams of one seed are
    /// independent; stream 0 is seeded from `seed` alone.
    pub fn new(seed: u64, stream: u64) -> Self {
        let mut st = seed ^ stream.wrapping_mul(0xD1B5_4A32_D192_ED03);
        let s = [
            splitmix64(&mut st),
            splitmix64(&mut st),
            splitmix64(&mut st),
            splitmix64(&mut st),
        ];
        Self {
            s,
            spare_normal: None,
        }
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        let s = &mut self.s;
        let result = s[0].wrapping_add(s[3]).rotate_left(23).wrapping_add(s[0]);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        result
    }

    /// Uniform in [0, 1) with 53 random bits.
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Standard normal (Box–Muller; always two uniforms per call so the
    /// number of draws per event is fixed).
    pub fn normal(&mut self) -> f64 {
        let u1 = 1.0 - self.uniform(); // (0, 1]: ln is finite
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// Two independent standard normals from one Box–Muller draw.
    pub fn normal_pair(&mut self) -> (f64, f64) {
        let u1 = 1.0 - self.uniform();
        let u2 = self.uniform();
        let r = (-2.0 * u1.ln()).sqrt();
        let (s, c) = (std::f64::consts::TAU * u2).sin_cos();
        (r * c, r * s)
    }

    /// Normal with standard deviation `sigma` (0 when `sigma` is not
    /// positive), using both halves of each Box–Muller pair in turn.
    pub fn gaussian(&mut self, sigma: f64) -> f64 {
        if sigma.is_nan() || sigma <= 0.0 {
            return 0.0;
        }
        let z = match self.spare_normal.take() {
            Some(z) => z,
            None => {
                let (c, s) = self.normal_pair();
                self.spare_normal = Some(s);
                c
            }
        };
        sigma * z
    }

    /// Bernoulli trial with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        self.uniform() < p
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_stream_repeats_exactly() {
        let mut a = Rng::new(42, 1);
        let mut b = Rng::new(42, 1);
        for _ in 0..1000 {
            assert_eq!(a.next_u64(), b.next_u64());
        }
        let mut c = Rng::new(42, 2);
        assert_ne!(Rng::new(42, 1).next_u64(), c.next_u64());
    }

    #[test]
    fn the_first_output_of_seed_42_never_changes() {
        // Pinned: every seeded simulator run and filter depends on it.
        // (computed independently from the published xoshiro256++ and
        // SplitMix64 definitions).
        assert_eq!(Rng::new(42, 0).next_u64(), 0xD076_4D4F_4476_689F);
    }

    #[test]
    fn normals_have_unit_variance() {
        let mut r = Rng::new(7, 0);
        let n = 200_000;
        let (mut s, mut s2, mut g, mut g2) = (0.0, 0.0, 0.0, 0.0);
        for _ in 0..n {
            let x = r.normal();
            s += x;
            s2 += x * x;
            let y = r.gaussian(2.0);
            g += y;
            g2 += y * y;
        }
        let (mean, var) = (s / n as f64, s2 / n as f64 - (s / n as f64).powi(2));
        assert!(mean.abs() < 0.01, "{mean}");
        assert!((var - 1.0).abs() < 0.02, "{var}");
        let (gm, gv) = (g / n as f64, g2 / n as f64 - (g / n as f64).powi(2));
        assert!(gm.abs() < 0.02, "{gm}");
        assert!((gv - 4.0).abs() < 0.08, "{gv}");
        assert_eq!(r.gaussian(0.0), 0.0);
        assert_eq!(r.gaussian(f64::NAN), 0.0);
    }
}
