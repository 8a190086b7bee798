//! Counts to millivolts, with range checks.

use crate::line::SampleValue;

/// A sensor output as read by the ADC.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measurement {
    /// Raw ADC counts (for a board that reports millivolts, the count the
    /// configured ADC would have read for them).
    pub raw_counts: u32,
    /// Sensor output, mV.
    pub raw_mv: f64,
}

/// A value the ADC cannot have produced: counted and dropped by the driver,
/// never fed to the signal chain.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum RangeError {
    #[error("expected at most {max} counts from a {bits}-bit ADC, got {counts}")]
    CountsAboveMax { counts: i64, max: u32, bits: u8 },
    #[error("expected a non-negative count, got {counts}")]
    NegativeCounts { counts: i64 },
    #[error("expected 0–{vref_mv} mV (the ADC reference), got {mv} mV")]
    MillivoltsOutOfRange { mv: f64, vref_mv: f64 },
}

/// Invalid ADC parameters.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum AdcConfigError {
    #[error("ADC resolution must be 1–31 bits, got {0}")]
    Bits(u8),
    #[error("ADC reference must be a positive number of mV, got {0}")]
    Vref(f64),
}

/// A successive-approximation ADC of `bits` resolution against `vref_mv`.
///
/// Conversion follows the AVR datasheet's `ADC = Vin · 2^bits / Vref`, so
/// `Vin = counts · Vref / 2^bits` and full scale (`2^bits − 1`) reads one LSB
/// below Vref: on the default 10-bit, 5000 mV board one count is 4.883 mV and
/// 1023 counts is 4995.1 mV.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdcScale {
    vref_mv: f64,
    bits: u8,
}

impl AdcScale {
    /// An ATmega328 board (Arduino Uno/Nano): 10 bits against its 5 V supply.
    pub const AVR_5V_10BIT: AdcScale = AdcScale {
        vref_mv: 5000.0,
        bits: 10,
    };

    pub fn new(vref_mv: f64, bits: u8) -> Result<Self, AdcConfigError> {
        if !(1..=31).contains(&bits) {
            return Err(AdcConfigError::Bits(bits));
        }
        if !(vref_mv.is_finite() && vref_mv > 0.0) {
            return Err(AdcConfigError::Vref(vref_mv));
        }
        Ok(Self { vref_mv, bits })
    }

    pub fn vref_mv(&self) -> f64 {
        self.vref_mv
    }

    pub fn bits(&self) -> u8 {
        self.bits
    }

    /// Highest count the ADC can report.
    pub fn max_counts(&self) -> u32 {
        (1u32 << self.bits) - 1
    }

    /// One count, mV.
    pub fn lsb_mv(&self) -> f64 {
        self.vref_mv / f64::from(1u32 << self.bits)
    }

    pub fn counts_to_mv(&self, counts: u32) -> f64 {
        f64::from(counts) * self.lsb_mv()
    }

    /// The count the ADC reads for `mv` (truncating, as the converter does),
    /// clamped to the ADC's range.
    pub fn mv_to_counts(&self, mv: f64) -> u32 {
        let c = (mv / self.lsb_mv()).floor();
        if c.is_nan() || c <= 0.0 {
            0
        } else {
            (c as u32).min(self.max_counts())
        }
    }

    /// A raw count from the wire, range-checked.
    pub fn measure_counts(&self, counts: i64) -> Result<Measurement, RangeError> {
        if counts < 0 {
            return Err(RangeError::NegativeCounts { counts });
        }
        let max = self.max_counts();
        match u32::try_from(counts) {
            Ok(c) if c <= max => Ok(Measurement {
                raw_counts: c,
                raw_mv: self.counts_to_mv(c),
            }),
            _ => Err(RangeError::CountsAboveMax {
                counts,
                max,
                bits: self.bits,
            }),
        }
    }

    /// A millivolt value from the wire, range-checked against the reference.
    pub fn measure_mv(&self, mv: f64) -> Result<Measurement, RangeError> {
        if !(mv.is_finite() && (0.0..=self.vref_mv).contains(&mv)) {
            return Err(RangeError::MillivoltsOutOfRange {
                mv,
                vref_mv: self.vref_mv,
            });
        }
        Ok(Measurement {
            raw_counts: self.mv_to_counts(mv),
            raw_mv: mv,
        })
    }

    /// A decoded serial sample, range-checked.
    pub fn measure(&self, value: SampleValue) -> Result<Measurement, RangeError> {
        match value {
            SampleValue::Counts(c) => self.measure_counts(i64::from(c)),
            SampleValue::Millivolts(mv) => self.measure_mv(f64::from(mv)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn arduino() -> AdcScale {
        let adc = AdcScale::new(5000.0, 10).unwrap();
        assert_eq!(adc, AdcScale::AVR_5V_10BIT);
        adc
    }

    #[test]
    fn ten_bit_5v_board_reads_4_883_mv_per_count() {
        let adc = arduino();
        assert_eq!(adc.max_counts(), 1023);
        assert!((adc.lsb_mv() - 4.8828125).abs() < 1e-12);
        assert!((adc.counts_to_mv(512) - 2500.0).abs() < 1e-9);
        assert!((adc.counts_to_mv(1023) - 4995.1171875).abs() < 1e-9);
    }

    #[test]
    fn counts_above_the_resolution_are_out_of_range() {
        let adc = arduino();
        assert!(adc.measure_counts(1023).is_ok());
        assert_eq!(
            adc.measure_counts(1024),
            Err(RangeError::CountsAboveMax {
                counts: 1024,
                max: 1023,
                bits: 10
            })
        );
        assert_eq!(
            adc.measure_counts(-1),
            Err(RangeError::NegativeCounts { counts: -1 })
        );
    }

    #[test]
    fn millivolts_above_vref_are_out_of_range_and_map_back_to_counts() {
        let adc = arduino();
        let m = adc.measure_mv(2500.0).unwrap();
        assert_eq!(m.raw_counts, 512);
        assert!(adc.measure_mv(5000.1).is_err());
        assert!(adc.measure_mv(f64::NAN).is_err());
    }

    #[test]
    fn bad_adc_parameters_are_refused() {
        assert_eq!(AdcScale::new(5000.0, 0), Err(AdcConfigError::Bits(0)));
        assert_eq!(AdcScale::new(5000.0, 32), Err(AdcConfigError::Bits(32)));
        assert!(AdcScale::new(0.0, 10).is_err());
        assert!(AdcScale::new(f64::INFINITY, 10).is_err());
    }
}
