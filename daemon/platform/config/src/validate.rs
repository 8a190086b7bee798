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
    /// 1-based line of the key in the file (or of the nearest table that
    /// holds it, when the value came from a default), once [`Validator::locate`] ran.
    pub line: Option<usize>,
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
            line: None,
        });
    }

    /// Fills in each issue's line from the TOML `text` the values came from.
    pub fn locate(&mut self, text: &str) {
        if self.issues.is_empty() {
            return;
        }
        let Ok(doc) = toml::de::DeTable::parse(text) else {
            return;
        };
        for issue in &mut self.issues {
            issue.line = key_offset(doc.get_ref(), &issue.key).map(|at| line_of(text, at));
        }
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

/// 1-based line of byte offset `at` in `text`.
pub fn line_of(text: &str, at: usize) -> usize {
    let at = at.min(text.len());
    text.as_bytes()[..at]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

/// 1-based line of `key` (a path as [`Issue::key`] writes it) in the TOML
/// `text`: the key itself, or the deepest table or array element on its path
/// that the file spells out. `None` when the text is not TOML or names
/// nothing on the path.
pub fn key_line(text: &str, key: &str) -> Option<usize> {
    let doc = toml::de::DeTable::parse(text).ok()?;
    key_offset(doc.get_ref(), key).map(|at| line_of(text, at))
}

/// Byte offset of the deepest part of `path` found in `table`.
fn key_offset(table: &toml::de::DeTable<'_>, path: &str) -> Option<usize> {
    use toml::de::DeValue;
    let mut found = None;
    let mut here: Option<&DeValue<'_>> = None;
    for part in path_parts(path) {
        let next = match (part, here) {
            (Part::Key(k), None) => table.get_key_value(k),
            (Part::Key(k), Some(DeValue::Table(t))) => t.get_key_value(k),
            (Part::Index(i), Some(DeValue::Array(a))) => {
                let Some(v) = a.get(i) else { break };
                found = Some(v.span().start);
                here = Some(v.get_ref());
                continue;
            }
            _ => None,
        };
        let Some((k, v)) = next else { break };
        found = Some(k.span().start);
        here = Some(v.get_ref());
    }
    found
}

enum Part<'a> {
    Key(&'a str),
    Index(usize),
}

/// `a.b[3].c` → `a`, `b`, `3`, `c`.
fn path_parts(path: &str) -> impl Iterator<Item = Part<'_>> {
    path.split('.').flat_map(|seg| {
        let (name, rest) = seg.split_once('[').unwrap_or((seg, ""));
        let indices = rest
            .split('[')
            .filter_map(|i| i.trim_end_matches(']').parse().ok())
            .map(Part::Index);
        (!name.is_empty())
            .then_some(Part::Key(name))
            .into_iter()
            .chain(indices)
    })
}

/// Implemented by every config section.
pub trait Validate {
    /// Checks the section, whose key path is `key` (e.g. `laser`).
    fn validate(&self, key: &str, v: &mut Validator);
}
