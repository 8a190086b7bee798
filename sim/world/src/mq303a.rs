//! The MQ303A alcohol sensor that SmokeNav (Santos et al. 2015) uses as a smoke (glycol vapour)
//! detector, read through an ADC.
//!
//! The sensor itself is the smoke codec's pure model
//! (`smokenav_smoke_codec::mq303a::Mq303a`: datasheet power law, the
//! paper's divider whose output falls as concentration rises, fast rise and
//! slow recovery, cold-heater warm-up), which the board emulator runs too,
//! so the simulator and the emulator cannot disagree about it. This module adds what the world knows: the
//! concentration at the robot, converted from the smoke field's g/m³ to the
//! model's alcohol-equivalent ppm, and the ADC conversion with noise.
//!
//! Concentration scale: `ppm_per_gpm3` = 60 maps the field onto the sensor so
//! that the paper's SmokeNav v1 thresholds land where the laser breaks down:
//! the model drops ~240 mV (SMOKE_MAX_DOWN) at 10 ppm, i.e. at ≈ 0.16 g/m³,
//! an extinction of ≈ 1.4 /m (visibility ≈ 2 m, where Sevcik & Oh 2007 saw the URG
//! fail to penetrate fog).

use smokenav_shared_types::Rng;
use smokenav_smoke_codec::mq303a::{Mq303a, SensorParams};

#[derive(Debug, Clone, PartialEq)]
pub struct Mq303aParams {
    /// The sensor model's parameters (supply, power law, time constants, warm-up).
    pub sensor: SensorParams,
    /// Alcohol-equivalent ppm per g/m³ of smoke.
    pub ppm_per_gpm3: f64,
    /// 1σ electrical noise at the ADC input, mV.
    pub noise_mv: f64,
    /// Start with a cold heater (reads low until warm) instead of a warm sensor.
    pub cold_start: bool,
}

impl Default for Mq303aParams {
    fn default() -> Self {
        Self {
            sensor: SensorParams::default(),
            ppm_per_gpm3: 60.0,
            noise_mv: 2.0,
            cold_start: false,
        }
    }
}

/// The sensor at the robot, plus its ADC.
#[derive(Debug, Clone)]
pub struct SmokeSensor {
    pub params: Mq303aParams,
    model: Mq303a,
    ambient_ppm: f64,
    rng: Rng,
}

impl SmokeSensor {
    pub fn new(params: Mq303aParams, rng: Rng) -> Self {
        let model = if params.cold_start {
            Mq303a::cold(params.sensor)
        } else {
            Mq303a::warm(params.sensor)
        };
        Self {
            params,
            model,
            ambient_ppm: 0.0,
            rng,
        }
    }

    /// Alcohol-equivalent ppm of `density_gpm3` of smoke.
    pub fn ppm_of(&self, density_gpm3: f64) -> f64 {
        density_gpm3.max(0.0) * self.params.ppm_per_gpm3
    }

    /// Advances the sensor by `dt_s` with `density_gpm3` of smoke around it.
    pub fn update(&mut self, density_gpm3: f64, dt_s: f64) {
        self.ambient_ppm = self.ppm_of(density_gpm3);
        self.model.step(dt_s, self.ambient_ppm);
    }

    /// The concentration around the sensor at the last update, ppm.
    pub fn ambient_ppm(&self) -> f64 {
        self.ambient_ppm
    }

    /// Noise-free output, mV.
    pub fn output_mv(&self) -> f64 {
        self.model.output_mv()
    }

    /// Clean-air output of a warm sensor, mV.
    pub fn clean_air_mv(&self) -> f64 {
        self.params.sensor.clean_air_mv()
    }

    /// One ADC conversion: (mV at the pin with noise, counts) for an ADC of
    /// `bits` with reference `vref_mv`; clamps at the rails like a real converter.
    pub fn sample(&mut self, vref_mv: f64, bits: u8) -> (f64, u32) {
        let mv = self.model.output_mv() + self.params.noise_mv * self.rng.normal();
        let full = ((1u64 << bits.min(31)) - 1) as f64;
        let counts = (mv / vref_mv * full).round().clamp(0.0, full) as u32;
        (mv, counts)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quiet() -> Mq303aParams {
        Mq303aParams {
            noise_mv: 0.0,
            ..Default::default()
        }
    }

    #[test]
    fn v1_threshold_falls_where_visibility_is_about_two_metres() {
        let mut s = SmokeSensor::new(quiet(), Rng::new(0, 0));
        let clean = s.output_mv();
        s.update(0.16, 1000.0); // settled in 0.16 g/m³ (σ = 8.7 × 0.16 ≈ 1.4 /m)
        let drop = clean - s.output_mv();
        assert!(
            (200.0..=260.0).contains(&drop),
            "SMOKE_MAX_DOWN is 240 mV: {drop}"
        );
        assert!((s.ambient_ppm() - 9.6).abs() < 1e-9);
    }

    #[test]
    fn smoke_reading_rises_fast_and_recovers_slowly() {
        let mut s = SmokeSensor::new(quiet(), Rng::new(0, 0));
        let clean = s.output_mv();
        let dt = 0.05;
        let mut low = clean;
        let mut t_half_down = None;
        for k in 1..=600 {
            s.update(0.3, dt);
            low = low.min(s.output_mv());
            if t_half_down.is_none()
                && clean - s.output_mv() > 0.5 * (clean - s.params.sensor.steady_state_mv(18.0))
            {
                t_half_down = Some(k as f64 * dt);
            }
        }
        let swing = clean - low;
        let mut t_half_up = None;
        for k in 1..=6000 {
            s.update(0.0, dt);
            if t_half_up.is_none() && clean - s.output_mv() < 0.5 * swing {
                t_half_up = Some(k as f64 * dt);
            }
        }
        let (down, up) = (t_half_down.unwrap(), t_half_up.unwrap());
        assert!(
            down < 3.0 && up > 4.0 * down,
            "half response {down} s, half recovery {up} s"
        );
    }

    #[test]
    fn adc_counts_follow_the_voltage_and_clamp() {
        let mut s = SmokeSensor::new(quiet(), Rng::new(0, 0));
        let (mv, counts) = s.sample(5000.0, 10);
        assert_eq!(counts, (mv / 5000.0 * 1023.0).round() as u32);
        let (_, counts) = s.sample(1000.0, 10);
        assert_eq!(counts, 1023, "above the reference pins at full scale");
    }

    #[test]
    fn cold_start_reads_low_until_the_heater_settles() {
        let mut s = SmokeSensor::new(
            Mq303aParams {
                cold_start: true,
                ..quiet()
            },
            Rng::new(0, 0),
        );
        assert!(s.output_mv() < s.clean_air_mv() - 500.0);
        for _ in 0..2400 {
            s.update(0.0, 0.05);
        }
        assert!((s.output_mv() - s.clean_air_mv()).abs() < 10.0);
    }
}
