//! A pure model of the MQ303A alcohol sensor as SmokeNav (Santos et al. 2015) wired it.
//!
//! Facts it is built on:
//!
//! * The MQ303A is a tin-dioxide sensor whose resistance `Rs` *falls* as the
//!   alcohol concentration rises, following a power law (Hanwei/Seeed
//!   datasheet: `Rs(air)/Rs(125 ppm) ≥ 3`, slope `R300ppm/R100ppm =
//!   0.50 ± 0.15`, range 20–1000 ppm, several minutes of preheating).
//! * The paper reads it so that the output voltage is *inversely*
//!   proportional to the concentration: the voltage across `Rs` in a divider
//!   with a load resistor `RL`, `V = Vc · Rs / (Rs + RL)`.
//! * It "detects the artificial smoke relatively fast, but it is slow to
//!   recover": gas adsorbs quickly and desorbs slowly. The model gives the
//!   sensor an internal *adsorbed* concentration that follows the ambient one
//!   with a short time constant going up and a long one coming down.
//! * A cold heater leaves `Rs` low, so right after power-on the output reads
//!   low (it would look like smoke) and climbs to the clean-air value as the
//!   heater settles: why the driver marks readings not-ready during warm-up.
//!
//! Concentrations are ppm *alcohol-equivalent*: the paper's smoke machine
//! makes glycol vapour, which the sensor sees as a weak alcohol. With the
//! defaults, 10 ppm drops the output by ~240 mV (the paper's SMOKE_MAX_DOWN)
//! below a 3000 mV clean-air level.
//!
//! The time constants and the warm-up curve are modelling choices matching
//! the paper's qualitative description, not datasheet figures.
//!
//! Pure: the caller supplies time steps; no clock, no I/O.

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorParams {
    /// Divider supply `Vc`, mV (a Grove-style module on a 5 V board).
    pub supply_mv: f64,
    /// Clean-air sensor resistance over the load resistance, `R0/RL`.
    pub r0_over_rl: f64,
    /// Power law `Rs/R0 = (1 + c/c0)^(−beta)`: the concentration scale, ppm.
    pub c0_ppm: f64,
    /// Power-law exponent.
    pub beta: f64,
    /// Time constant of the response to rising concentration, s.
    pub tau_rise_s: f64,
    /// Time constant of the recovery when the concentration falls, s.
    pub tau_fall_s: f64,
    /// Heater settling time after power-on, s (0: starts warm).
    pub warmup_s: f64,
    /// `Rs/R0` of a cold sensor at power-on.
    pub cold_ratio: f64,
}

impl Default for SensorParams {
    /// `beta = ln 2 / ln 3 ≈ 0.63` gives the datasheet's 0.50 slope between
    /// 100 and 300 ppm (asymptotically); `c0 = 26.6 ppm` puts `Rs(air)/Rs` at
    /// 3 for 125 ppm. `R0 = 1.5 RL` puts clean air at 3000 mV of 5000.
    fn default() -> Self {
        Self {
            supply_mv: 5000.0,
            r0_over_rl: 1.5,
            c0_ppm: 26.6,
            beta: std::f64::consts::LN_2 / 3f64.ln(),
            tau_rise_s: 2.0,
            tau_fall_s: 25.0,
            warmup_s: 60.0,
            cold_ratio: 0.25,
        }
    }
}

impl SensorParams {
    /// Steady-state `Rs/R0` at `ppm`, for a warm sensor.
    pub fn resistance_ratio(&self, ppm: f64) -> f64 {
        (1.0 + ppm.max(0.0) / self.c0_ppm).powf(-self.beta)
    }

    /// Divider output for a given `Rs/R0`, mV.
    pub fn output_for_ratio(&self, rs_over_r0: f64) -> f64 {
        let r = self.r0_over_rl * rs_over_r0;
        self.supply_mv * r / (r + 1.0)
    }

    /// Output of a warm sensor settled at `ppm`, mV.
    pub fn steady_state_mv(&self, ppm: f64) -> f64 {
        self.output_for_ratio(self.resistance_ratio(ppm))
    }

    /// Output in clean air, mV.
    pub fn clean_air_mv(&self) -> f64 {
        self.output_for_ratio(1.0)
    }

    /// The settled concentration that drops the output `drop_mv` below
    /// clean air (inverse of [`steady_state_mv`](Self::steady_state_mv)),
    /// ppm; `None` if the output cannot drop that far.
    pub fn ppm_for_drop(&self, drop_mv: f64) -> Option<f64> {
        let v = self.clean_air_mv() - drop_mv;
        if !(v > 0.0 && v <= self.clean_air_mv()) {
            return None;
        }
        let r = v / (self.supply_mv - v); // Rs/RL
        let ratio = r / self.r0_over_rl;
        Some(self.c0_ppm * (ratio.powf(-1.0 / self.beta) - 1.0))
    }
}

/// One sensor, stepped in time.
#[derive(Debug, Clone)]
pub struct Mq303a {
    params: SensorParams,
    /// Concentration the sensing bead currently responds to, ppm.
    adsorbed_ppm: f64,
    /// Time the heater has been on, s.
    heated_s: f64,
}

impl Mq303a {
    /// Just powered on: cold heater, clean bead.
    pub fn cold(params: SensorParams) -> Self {
        Self {
            params,
            adsorbed_ppm: 0.0,
            heated_s: 0.0,
        }
    }

    /// Powered long enough ago to be warm, in clean air.
    pub fn warm(params: SensorParams) -> Self {
        Self {
            heated_s: f64::INFINITY,
            ..Self::cold(params)
        }
    }

    pub fn params(&self) -> &SensorParams {
        &self.params
    }

    /// The heater lost power: cold again.
    pub fn power_cycle(&mut self) {
        self.heated_s = 0.0;
    }

    pub fn adsorbed_ppm(&self) -> f64 {
        self.adsorbed_ppm
    }

    /// `Rs/R0` multiplier of the heater state: `cold_ratio` at power-on,
    /// within 0.7 % of 1 after `warmup_s` (five time constants).
    fn warm_factor(&self) -> f64 {
        let p = &self.params;
        if p.warmup_s <= 0.0 || self.heated_s.is_infinite() {
            return 1.0;
        }
        1.0 - (1.0 - p.cold_ratio) * (-5.0 * self.heated_s / p.warmup_s).exp()
    }

    /// Advances by `dt_s` in air of `ambient_ppm` and returns the output, mV.
    /// The step is integrated exactly for a constant ambient over `dt_s`.
    pub fn step(&mut self, dt_s: f64, ambient_ppm: f64) -> f64 {
        let dt = if dt_s.is_finite() { dt_s.max(0.0) } else { 0.0 };
        let ambient = if ambient_ppm.is_finite() {
            ambient_ppm.max(0.0)
        } else {
            0.0
        };
        let tau = if ambient > self.adsorbed_ppm {
            self.params.tau_rise_s
        } else {
            self.params.tau_fall_s
        };
        self.adsorbed_ppm = if tau > 0.0 {
            ambient + (self.adsorbed_ppm - ambient) * (-dt / tau).exp()
        } else {
            ambient
        };
        self.heated_s += dt;
        self.output_mv()
    }

    /// Current output, mV.
    pub fn output_mv(&self) -> f64 {
        let p = &self.params;
        p.output_for_ratio(p.resistance_ratio(self.adsorbed_ppm) * self.warm_factor())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn datasheet_sensitivity_rs_air_over_rs_125ppm_is_3() {
        let p = SensorParams::default();
        let s = 1.0 / p.resistance_ratio(125.0);
        assert!((s - 3.0).abs() < 0.01, "sensitivity {s}");
    }

    #[test]
    fn datasheet_slope_r300_over_r100_is_within_0_50_plus_minus_0_15() {
        let p = SensorParams::default();
        let slope = p.resistance_ratio(300.0) / p.resistance_ratio(100.0);
        assert!((0.35..=0.65).contains(&slope), "slope {slope}");
    }

    #[test]
    fn output_falls_as_concentration_rises() {
        let p = SensorParams::default();
        assert!((p.clean_air_mv() - 3000.0).abs() < 1e-9);
        let mut prev = p.clean_air_mv();
        for ppm in [1.0, 5.0, 10.0, 50.0, 125.0, 1000.0] {
            let v = p.steady_state_mv(ppm);
            assert!(v < prev, "{ppm} ppm: {v} mV not below {prev} mV");
            prev = v;
        }
    }

    #[test]
    fn ten_ppm_drops_about_the_papers_smoke_max_down() {
        let p = SensorParams::default();
        let drop = p.clean_air_mv() - p.steady_state_mv(10.0);
        assert!((220.0..260.0).contains(&drop), "drop {drop} mV");
        let back = p.ppm_for_drop(drop).unwrap();
        assert!((back - 10.0).abs() < 1e-9);
        assert_eq!(p.ppm_for_drop(4000.0), None);
    }

    #[test]
    fn rise_is_fast_and_recovery_slow() {
        let p = SensorParams::default();
        let mut s = Mq303a::warm(p);
        // 2 s at 10 ppm: one rise time constant, 63 % adsorbed.
        for _ in 0..20 {
            s.step(0.1, 10.0);
        }
        assert!((s.adsorbed_ppm() - 10.0 * (1.0 - (-1f64).exp())).abs() < 1e-9);
        for _ in 0..200 {
            s.step(0.1, 10.0);
        }
        // 2 s of clean air: only 2/25 of a recovery time constant.
        for _ in 0..20 {
            s.step(0.1, 0.0);
        }
        let left = s.adsorbed_ppm() / 10.0;
        assert!((left - (-2.0f64 / 25.0).exp()).abs() < 1e-3, "{left}");
    }

    #[test]
    fn cold_sensor_reads_low_then_settles_to_clean_air_by_warmup() {
        let p = SensorParams {
            warmup_s: 30.0,
            ..SensorParams::default()
        };
        let mut s = Mq303a::cold(p);
        let first = s.output_mv();
        assert!(first < p.clean_air_mv() - 1000.0, "cold output {first}");
        for _ in 0..300 {
            s.step(0.1, 0.0);
        }
        assert!((s.output_mv() - p.clean_air_mv()).abs() < 10.0);
        s.power_cycle();
        assert!(s.output_mv() < p.clean_air_mv() - 1000.0);
    }
}
