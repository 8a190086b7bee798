//! Putting the simulated MQ303A's ADC counts on the smoke board emulator's wire.
//!
//! The board emulator (`smokenav-smoke-emulator`) has no "print these counts"
//! input: it runs its own MQ303A model on a concentration profile. The world
//! already modelled the sensor (its dynamics, noise and ADC), so the board is
//! made transparent: a sensor with no lag, no warm-up and no noise, whose
//! divider puts clean air at 99 % of Vref, and a constant concentration chosen
//! with the model's own inverse (`SensorParams::ppm_for_drop`) so its steady
//! output lands in the middle of the count the world produced. The board then
//! prints exactly that count (its ADC truncates), and the driver reads it as
//! it would from a real board.

use smokenav_smoke_emulator::{AdcScale, Profile, SensorParams};

/// Clean-air output of the transparent sensor as a share of Vref: every count
/// below it can be reproduced.
const TRANSPARENT_CLEAN_SHARE: f64 = 0.99;

/// Concentration that drives the transparent sensor to (almost) 0 mV.
const FLOOR_PPM: f64 = 1e12;

/// A board that reproduces given ADC counts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TransparentAdc {
    pub adc: AdcScale,
    pub sensor: SensorParams,
}

impl TransparentAdc {
    pub fn new(adc: AdcScale) -> Self {
        let sensor = SensorParams {
            supply_mv: adc.vref_mv(),
            r0_over_rl: TRANSPARENT_CLEAN_SHARE / (1.0 - TRANSPARENT_CLEAN_SHARE),
            tau_rise_s: 0.0,
            tau_fall_s: 0.0,
            warmup_s: 0.0,
            cold_ratio: 1.0,
            ..SensorParams::default()
        };
        Self { adc, sensor }
    }

    /// Highest count the transparent sensor can produce.
    pub fn max_counts(&self) -> u32 {
        self.adc
            .mv_to_counts(self.sensor.clean_air_mv())
            .saturating_sub(1)
    }

    /// The concentration at which the board prints `counts`.
    pub fn ppm_for_counts(&self, counts: u32) -> f64 {
        let counts = counts.min(self.max_counts());
        if counts == 0 {
            return FLOOR_PPM;
        }
        // Aim at the middle of the count: the board's ADC truncates.
        let mv = (f64::from(counts) + 0.5) * self.adc.lsb_mv();
        let drop = (self.sensor.clean_air_mv() - mv).max(0.0);
        self.sensor.ppm_for_drop(drop).unwrap_or(FLOOR_PPM)
    }

    /// The profile to hand the board for `counts`.
    pub fn profile_for_counts(&self, counts: u32) -> Profile {
        Profile::constant(self.ppm_for_counts(counts))
    }

    /// What the board prints at `ppm` (its output through its ADC).
    pub fn counts_at(&self, ppm: f64) -> u32 {
        self.adc.mv_to_counts(self.sensor.steady_state_mv(ppm))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_count_of_a_10_bit_5_v_board_round_trips() {
        let t = TransparentAdc::new(AdcScale::new(5000.0, 10).unwrap());
        // Clean air at 99 % of 5000 mV = 4950 mV, count 1013 (4.883 mV per count).
        assert_eq!(t.max_counts(), 1012);
        for counts in 0..=t.max_counts() {
            assert_eq!(
                t.counts_at(t.ppm_for_counts(counts)),
                counts,
                "count {counts}"
            );
        }
    }

    #[test]
    fn the_mq303a_clean_air_level_is_reproduced_on_a_12_bit_board() {
        // The world's MQ303A reads 3000 mV in clean air: 2457 counts of 4096 at 5 V.
        let t = TransparentAdc::new(AdcScale::new(5000.0, 12).unwrap());
        let counts = (3000.0f64 / 5000.0 * 4096.0) as u32;
        assert_eq!(t.counts_at(t.ppm_for_counts(counts)), counts);
    }

    #[test]
    fn counts_beyond_the_transparent_range_clamp_to_its_top() {
        let t = TransparentAdc::new(AdcScale::new(5000.0, 10).unwrap());
        assert_eq!(t.counts_at(t.ppm_for_counts(1023)), t.max_counts());
    }

    #[test]
    fn the_board_model_has_no_lag_so_a_step_shows_at_the_next_sample() {
        let t = TransparentAdc::new(AdcScale::new(5000.0, 10).unwrap());
        let mut m = smokenav_smoke_emulator::Mq303a::warm(t.sensor);
        let ppm = t.ppm_for_counts(400);
        let mv = m.step(0.1, ppm);
        assert_eq!(t.adc.mv_to_counts(mv), 400);
    }
}
