//! Pure ADC sample-line codec and MQ303A signal processing (no I/O).
