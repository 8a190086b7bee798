//! The emulated ADC board, transport-independent and pure: a sensor model,
//! an ADC, noise, a concentration profile and injected faults, stepped by
//! the caller's time. The serial and IIO emulators render its output.

use crate::model::{Mq303a, Profile, SensorParams};
use crate::noise::Noise;
use smokenav_smoke_codec::AdcScale;
use std::str::FromStr;

/// A fault to inject.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Fault {
    /// The next `lines` outputs are corrupt (line noise, a bad checksum, a
    /// truncated or overlong line, junk text in a sysfs file).
    Garbage { lines: u32 },
    /// The next `samples` values are beyond what the ADC can read.
    OutOfRange { samples: u32 },
    /// The sensor's wire is cut for `secs`: the ADC reads the low rail.
    SensorUnplugged { secs: f64 },
    /// The whole board vanishes for `secs` (USB unplug; the IIO device goes
    /// away). The sensor heater loses power too, so it comes back cold.
    BoardUnplugged { secs: f64 },
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FaultParseError {
    #[error(
        "expected `garbage N`, `out-of-range N`, `sensor-off SECS` or `unplug SECS`, found {0:?}"
    )]
    Syntax(String),
}

impl FromStr for Fault {
    type Err = FaultParseError;

    /// `garbage 5`, `out-of-range 3`, `sensor-off 2.5`, `unplug 2` (also
    /// with `:` instead of the space).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let err = || FaultParseError::Syntax(s.to_owned());
        let (kind, arg) = s
            .trim()
            .split_once([' ', ':'])
            .map(|(k, a)| (k.trim(), a.trim()))
            .ok_or_else(err)?;
        let count = || arg.parse::<u32>().map_err(|_| err());
        let secs = || {
            arg.parse::<f64>()
                .ok()
                .filter(|s| s.is_finite() && *s >= 0.0)
                .ok_or_else(err)
        };
        Ok(match kind {
            "garbage" => Fault::Garbage { lines: count()? },
            "out-of-range" => Fault::OutOfRange { samples: count()? },
            "sensor-off" => Fault::SensorUnplugged { secs: secs()? },
            "unplug" | "vanish" => Fault::BoardUnplugged { secs: secs()? },
            _ => return Err(err()),
        })
    }
}

/// A control message for a running emulator.
#[derive(Debug, Clone, PartialEq)]
pub enum Command {
    Fault(Fault),
    /// Start this concentration profile now.
    Profile(Profile),
}

impl Board {
    /// Applies a command at `t_s`.
    pub fn apply(&mut self, t_s: f64, cmd: Command) {
        match cmd {
            Command::Fault(f) => self.inject(t_s, f),
            Command::Profile(p) => self.set_profile(t_s, p),
        }
    }
}

/// What the board produces at one tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Output {
    /// A reading: `counts` at the ADC's resolution and the voltage behind it.
    Sample { counts: u32, mv: f64 },
    /// A corrupt output; `variant` picks which kind, cycling.
    Garbage { variant: u32 },
    /// A value the ADC cannot produce.
    OutOfRange { counts: u64, mv: f64 },
    /// The board is unplugged: nothing at all.
    Offline,
}

#[derive(Debug, Clone)]
pub struct BoardConfig {
    pub adc: AdcScale,
    pub sensor: SensorParams,
    pub profile: Profile,
    /// Gaussian noise on the sensor output, σ in mV.
    pub noise_mv: f64,
    pub seed: u64,
    /// Start with the heater already warm (bench tests), else cold.
    pub warm_start: bool,
}

impl BoardConfig {
    /// A 10-bit, 5 V board in clean air, warm, with 2 mV of noise.
    pub fn bench(profile: Profile) -> Self {
        Self {
            adc: AdcScale::AVR_5V_10BIT,
            sensor: SensorParams {
                warmup_s: 0.0,
                ..SensorParams::default()
            },
            profile,
            noise_mv: 2.0,
            seed: 1,
            warm_start: true,
        }
    }
}

/// Counters of what the board produced.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BoardStats {
    pub samples: u64,
    pub garbage: u64,
    pub out_of_range: u64,
    pub offline_ticks: u64,
    pub unplugs: u64,
}

#[derive(Debug, Clone)]
pub struct Board {
    cfg: BoardConfig,
    sensor: Mq303a,
    noise: Noise,
    last_t_s: Option<f64>,
    garbage_left: u32,
    garbage_variant: u32,
    out_of_range_left: u32,
    sensor_off_until: f64,
    offline_until: f64,
    /// Emulator time at which the profile's t = 0 falls.
    profile_origin_s: f64,
    stats: BoardStats,
}

impl Board {
    pub fn new(cfg: BoardConfig) -> Self {
        let sensor = if cfg.warm_start {
            Mq303a::warm(cfg.sensor)
        } else {
            Mq303a::cold(cfg.sensor)
        };
        Self {
            noise: Noise::new(cfg.seed),
            sensor,
            cfg,
            last_t_s: None,
            garbage_left: 0,
            garbage_variant: 0,
            out_of_range_left: 0,
            sensor_off_until: f64::NEG_INFINITY,
            offline_until: f64::NEG_INFINITY,
            profile_origin_s: 0.0,
            stats: BoardStats::default(),
        }
    }

    pub fn config(&self) -> &BoardConfig {
        &self.cfg
    }

    pub fn stats(&self) -> BoardStats {
        self.stats
    }

    pub fn sensor(&self) -> &Mq303a {
        &self.sensor
    }

    /// Injects `fault` at `t_s` (the time the next ticks are measured in).
    pub fn inject(&mut self, t_s: f64, fault: Fault) {
        match fault {
            Fault::Garbage { lines } => self.garbage_left = self.garbage_left.saturating_add(lines),
            Fault::OutOfRange { samples } => {
                self.out_of_range_left = self.out_of_range_left.saturating_add(samples)
            }
            Fault::SensorUnplugged { secs } => self.sensor_off_until = t_s + secs,
            Fault::BoardUnplugged { secs } => {
                self.offline_until = t_s + secs;
                self.stats.unplugs += 1;
                self.sensor.power_cycle();
            }
        }
    }

    /// Replaces the concentration profile; its t = 0 is `t_s`.
    pub fn set_profile(&mut self, t_s: f64, profile: Profile) {
        self.cfg.profile = profile;
        self.profile_origin_s = t_s;
    }

    /// True while an injected board unplug lasts.
    pub fn is_offline(&self, t_s: f64) -> bool {
        t_s < self.offline_until
    }

    /// Produces the output at `t_s` (seconds since the emulator started).
    pub fn tick(&mut self, t_s: f64) -> Output {
        let dt = self.last_t_s.map_or(0.0, |last| (t_s - last).max(0.0));
        self.last_t_s = Some(t_s);
        // The sensor keeps living (heating, adsorbing) whatever the board does.
        let ambient = self.cfg.profile.at(t_s - self.profile_origin_s);
        let sensor_mv = self.sensor.step(dt, ambient);

        if self.is_offline(t_s) {
            self.stats.offline_ticks += 1;
            return Output::Offline;
        }
        if self.garbage_left > 0 {
            self.garbage_left -= 1;
            self.stats.garbage += 1;
            let variant = self.garbage_variant;
            self.garbage_variant = self.garbage_variant.wrapping_add(1);
            return Output::Garbage { variant };
        }
        let adc = self.cfg.adc;
        if self.out_of_range_left > 0 {
            self.out_of_range_left -= 1;
            self.stats.out_of_range += 1;
            // One to four times full scale: what a misconfigured or
            // glitching board prints.
            let k = 1 + self.noise.next_u64() % 3;
            let counts = (u64::from(adc.max_counts()) + 1) * k;
            return Output::OutOfRange {
                counts,
                mv: adc.vref_mv() * (1.0 + k as f64 * 0.05),
            };
        }
        let mv = if t_s < self.sensor_off_until {
            // Input pulled to ground: a count or two of noise.
            self.noise.gaussian(self.cfg.noise_mv).abs()
        } else {
            sensor_mv + self.noise.gaussian(self.cfg.noise_mv)
        };
        let mv = mv.clamp(0.0, adc.vref_mv());
        self.stats.samples += 1;
        Output::Sample {
            counts: adc.mv_to_counts(mv),
            mv,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn board() -> Board {
        Board::new(BoardConfig::bench(Profile::clean()))
    }

    #[test]
    fn clean_air_reads_3000_mv_as_614_counts() {
        let mut b = board();
        let Output::Sample { counts, mv } = b.tick(0.0) else {
            panic!("expected a sample")
        };
        assert!((mv - 3000.0).abs() < 10.0, "{mv}");
        // 3000 mV / 4.883 mV per count = 614.4.
        assert!((612..=616).contains(&counts), "{counts}");
    }

    #[test]
    fn faults_take_their_turn_then_samples_resume() {
        let mut b = board();
        b.inject(0.0, Fault::Garbage { lines: 2 });
        b.inject(0.0, Fault::OutOfRange { samples: 1 });
        assert_eq!(b.tick(0.1), Output::Garbage { variant: 0 });
        assert_eq!(b.tick(0.2), Output::Garbage { variant: 1 });
        let Output::OutOfRange { counts, mv } = b.tick(0.3) else {
            panic!("expected out of range")
        };
        assert!(counts > 1023 && mv > 5000.0);
        assert!(matches!(b.tick(0.4), Output::Sample { .. }));
        assert_eq!(b.stats().garbage, 2);
        assert_eq!(b.stats().out_of_range, 1);
    }

    #[test]
    fn sensor_unplugged_reads_the_low_rail_for_its_duration() {
        let mut b = board();
        b.inject(1.0, Fault::SensorUnplugged { secs: 0.5 });
        let Output::Sample { mv, .. } = b.tick(1.2) else {
            panic!()
        };
        assert!(mv < 20.0, "{mv}");
        let Output::Sample { mv, .. } = b.tick(1.6) else {
            panic!()
        };
        assert!(mv > 2900.0, "{mv}");
    }

    #[test]
    fn board_unplug_is_offline_then_back_with_a_cold_sensor() {
        let cfg = BoardConfig {
            sensor: SensorParams {
                warmup_s: 10.0,
                ..SensorParams::default()
            },
            ..BoardConfig::bench(Profile::clean())
        };
        let mut b = Board::new(cfg);
        b.inject(0.0, Fault::BoardUnplugged { secs: 1.0 });
        assert_eq!(b.tick(0.5), Output::Offline);
        let Output::Sample { mv, .. } = b.tick(1.0) else {
            panic!()
        };
        assert!(mv < 2500.0, "heater re-warming, got {mv}");
        assert_eq!(b.stats().unplugs, 1);
    }

    #[test]
    fn new_profile_starts_at_the_time_it_is_set() {
        let mut b = board();
        b.tick(0.0);
        b.set_profile(100.0, Profile::constant(0.0));
        b.set_profile(100.0, Profile::puff(1.0, 12.0, 0.0, 100.0, 0.0));
        b.tick(100.5);
        assert_eq!(b.sensor().adsorbed_ppm(), 0.0);
        b.tick(102.0);
        assert!(b.sensor().adsorbed_ppm() > 0.0);
    }

    #[test]
    fn fault_commands_parse() {
        assert_eq!("garbage 5".parse(), Ok(Fault::Garbage { lines: 5 }));
        assert_eq!(
            "out-of-range:3".parse(),
            Ok(Fault::OutOfRange { samples: 3 })
        );
        assert_eq!(
            "sensor-off 2.5".parse(),
            Ok(Fault::SensorUnplugged { secs: 2.5 })
        );
        assert_eq!("vanish 2".parse(), Ok(Fault::BoardUnplugged { secs: 2.0 }));
        assert!("unplug -1".parse::<Fault>().is_err());
        assert!("explode 1".parse::<Fault>().is_err());
    }
}
