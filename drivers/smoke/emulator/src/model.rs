//! Concentration over time for the emulated board, and the MQ303A it drives.
//!
//! The sensor's physical model lives in the codec
//! ([`smokenav_smoke_codec::mq303a`]) so the simulated world and this
//! emulator share one model without the world depending on an emulator.

pub use smokenav_smoke_codec::mq303a::{Mq303a, SensorParams};

use std::fmt;
use std::str::FromStr;

/// Ambient concentration over time: straight lines between `(t_s, ppm)`
/// points, flat before the first and after the last.
#[derive(Debug, Clone, PartialEq)]
pub struct Profile {
    points: Vec<(f64, f64)>,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProfileError {
    #[error("expected at least one t:ppm point, found none")]
    Empty,
    #[error("point {index}: expected `t:ppm` with two numbers, found {found:?}")]
    Syntax { index: usize, found: String },
    #[error("point {index}: expected finite t ≥ 0 and ppm ≥ 0, found t = {t}, ppm = {ppm}")]
    Range { index: usize, t: f64, ppm: f64 },
    #[error("point {index}: time {t} s goes back from {previous} s")]
    NotSorted { index: usize, t: f64, previous: f64 },
}

impl Profile {
    pub fn new(points: Vec<(f64, f64)>) -> Result<Self, ProfileError> {
        if points.is_empty() {
            return Err(ProfileError::Empty);
        }
        let mut previous = 0.0;
        for (index, &(t, ppm)) in points.iter().enumerate() {
            if !(t.is_finite() && t >= 0.0 && ppm.is_finite() && ppm >= 0.0) {
                return Err(ProfileError::Range { index, t, ppm });
            }
            if t < previous {
                return Err(ProfileError::NotSorted { index, t, previous });
            }
            previous = t;
        }
        Ok(Self { points })
    }

    /// The same concentration forever.
    pub fn constant(ppm: f64) -> Self {
        Self {
            points: vec![(0.0, ppm.max(0.0))],
        }
    }

    pub fn clean() -> Self {
        Self::constant(0.0)
    }

    /// Clean air, then smoke reaching `peak_ppm` over `rise_s` at `start_s`,
    /// held for `hold_s`, cleared over `clear_s`. This is the *air*; the
    /// sensor adds its own fast-rise / slow-recovery lag.
    pub fn puff(start_s: f64, peak_ppm: f64, rise_s: f64, hold_s: f64, clear_s: f64) -> Self {
        let t1 = start_s.max(0.0);
        let t2 = t1 + rise_s.max(0.0);
        let t3 = t2 + hold_s.max(0.0);
        let t4 = t3 + clear_s.max(0.0);
        let peak = peak_ppm.max(0.0);
        Self {
            points: vec![(0.0, 0.0), (t1, 0.0), (t2, peak), (t3, peak), (t4, 0.0)],
        }
    }

    pub fn points(&self) -> &[(f64, f64)] {
        &self.points
    }

    /// Time of the last point, s.
    pub fn end_s(&self) -> f64 {
        self.points.last().map_or(0.0, |p| p.0)
    }

    /// Concentration at `t_s`, ppm.
    pub fn at(&self, t_s: f64) -> f64 {
        let Some(&(t_first, c_first)) = self.points.first() else {
            return 0.0;
        };
        if t_s <= t_first {
            return c_first;
        }
        for pair in self.points.windows(2) {
            if let [(t0, c0), (t1, c1)] = *pair
                && t_s <= t1
            {
                return if t1 > t0 {
                    c0 + (c1 - c0) * (t_s - t0) / (t1 - t0)
                } else {
                    c1
                };
            }
        }
        self.points.last().map_or(0.0, |p| p.1)
    }
}

impl FromStr for Profile {
    type Err = ProfileError;

    /// `t:ppm,t:ppm,…`, e.g. `0:0,10:0,11:12,16:12,17:0`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let mut points = Vec::new();
        for (index, item) in s
            .split(',')
            .map(str::trim)
            .filter(|i| !i.is_empty())
            .enumerate()
        {
            let parsed = item.split_once(':').and_then(|(t, c)| {
                Some((t.trim().parse::<f64>().ok()?, c.trim().parse::<f64>().ok()?))
            });
            match parsed {
                Some(p) => points.push(p),
                None => {
                    return Err(ProfileError::Syntax {
                        index,
                        found: item.to_owned(),
                    });
                }
            }
        }
        Self::new(points)
    }
}

impl fmt::Display for Profile {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, (t, c)) in self.points.iter().enumerate() {
            if i > 0 {
                f.write_str(",")?;
            }
            write!(f, "{t}:{c}")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn profile_interpolates_and_holds_its_ends() {
        let prof: Profile = "0:0, 10:0, 12:20, 16:20, 20:0".parse().unwrap();
        assert_eq!(prof.at(-1.0), 0.0);
        assert_eq!(prof.at(11.0), 10.0);
        assert_eq!(prof.at(14.0), 20.0);
        assert_eq!(prof.at(19.0), 5.0);
        assert_eq!(prof.at(100.0), 0.0);
        assert_eq!(prof.end_s(), 20.0);
        assert_eq!(prof.to_string().parse::<Profile>().unwrap(), prof);
        assert_eq!(Profile::puff(10.0, 20.0, 2.0, 4.0, 4.0), prof);
    }

    #[test]
    fn bad_profiles_say_which_point() {
        assert_eq!("".parse::<Profile>(), Err(ProfileError::Empty));
        assert!(matches!(
            "0:0,5".parse::<Profile>(),
            Err(ProfileError::Syntax { index: 1, .. })
        ));
        assert!(matches!(
            "0:-1".parse::<Profile>(),
            Err(ProfileError::Range { index: 0, .. })
        ));
        assert!(matches!(
            "5:0,4:1".parse::<Profile>(),
            Err(ProfileError::NotSorted { index: 1, .. })
        ));
    }
}
