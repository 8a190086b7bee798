//! Validation helpers: each section checks its own values and reports every
//! problem with the full key path, so one run of `smokenav config check` lists
//! them all.

use std::fmt;

/// One problem in a config file.
#[derive(Debug, Clone, PartialEq)]
pub struct Issue {
    /// Dotted key path, e.g. `sonar.transducers[3].yaw_deg`.
    pub key: String,
    pub reason: String,
}

impl fmt::Display for Issue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "key `{}`: {}", self.key, self.reason)
    }
}

/// Collects issues under a key prefix.
#[derive(Debug, Default)]
pub struct Validator {
    pub issues: Vec<Issue>,
}

impl Validator {
    pub fn fail(&mut self, key: impl Into<String>, reason: impl Into<String>) {
        self.issues.push(Issue {
            key: key.into(),
            reason: reason.into(),
        });
    }

    /// `value` must be finite and > 0.
    pub fn positive(&mut self, key: &str, value: f64) {
        if !(value.is_finite() && value > 0.0) {
            self.fail(key, format!("must be a positive number, got {value}"));
        }
    }

    /// `value` must be finite and >= 0.
    pub fn non_negative(&mut self, key: &str, value: f64) {
        if !(value.is_finite() && value >= 0.0) {
            self.fail(key, format!("must be zero or positive, got {value}"));
        }
    }

    pub fn finite(&mut self, key: &str, value: f64) {
        if !value.is_finite() {
            self.fail(key, format!("must be a finite number, got {value}"));
        }
    }

    /// `value` must lie within `[lo, hi]`.
    pub fn within(&mut self, key: &str, value: f64, lo: f64, hi: f64) {
        if !(value.is_finite() && value >= lo && value <= hi) {
            self.fail(key, format!("must be within [{lo}, {hi}], got {value}"));
        }
    }

    /// `a` must be strictly less than `b`.
    pub fn ordered(&mut self, key_a: &str, a: f64, key_b: &str, b: f64) {
        if a.is_finite() && b.is_finite() && a >= b {
            self.fail(key_a, format!("must be less than `{key_b}` ({b}), got {a}"));
        }
    }

    pub fn non_empty(&mut self, key: &str, value: &str) {
        if value.trim().is_empty() {
            self.fail(key, "must not be empty");
        }
    }
}

/// Implemented by every config section.
pub trait Validate {
    /// Checks the section, whose key path is `key` (e.g. `laser`).
    fn validate(&self, key: &str, v: &mut Validator);
}
