//! The robot profile: one TOML file per robot.
//!
//! Parsing is strict: unknown keys are rejected (a typo must not silently fall
//! back to a default on a robot), and every value is validated. Errors name
//! the file, the line, the key and the reason, every problem at once:
//!
//! ```text
//! config/pioneer-3dx.toml:12: key `laser.stall_timeout_s`: must be within [0.2, 30], got -1
//! ```
//!
//! The shipped profiles are built in ([`RobotConfig::builtin`]).

pub mod base;
pub mod common;
pub mod fusion;
pub mod laser;
pub mod mapping;
pub mod robot;
pub mod slam;
pub mod slam_fuzzy;
pub mod slam_graph;
pub mod slam_vote;
pub mod smoke;
pub mod sonar;
pub mod validate;
pub mod zenoh;

pub use base::{BaseSection, PioneerOptions, ScoutOptions, WheelOrder};
pub use common::MountPose;
pub use fusion::{FusionMethod, FusionSection, SyncParams};
pub use laser::{LaserSection, ScanLayout};
pub use mapping::{MappingRule, MappingSection};
pub use robot::{BusSection, Platform, RobotSection};
pub use slam::{ResumeAt, SlamBackendKind, SlamInput, SlamMode, SlamSection};
pub use slam_fuzzy::{FuzzyReference, FuzzySearch, FuzzySection};
pub use slam_graph::GraphSection;
pub use slam_vote::{VoteRule, VoteSection};
pub use smoke::{AdcBackend, SmokeSection};
pub use sonar::{SonarSection, Transducer};
pub use validate::{Issue, Validate, Validator, key_line};
pub use zenoh::{ZenohMode, ZenohSection};

use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::{Path, PathBuf};

/// The robot profiles shipped in `config/`: (name, text).
pub const BUILTIN_PROFILES: [(&str, &str); 2] = [
    (
        "pioneer-3dx",
        include_str!("../../../../config/pioneer-3dx.toml"),
    ),
    (
        "nomad-scout",
        include_str!("../../../../config/nomad-scout.toml"),
    ),
];

/// Environment variable that overrides `robot.instance`.
pub const INSTANCE_ENV: &str = "SMOKENAV_INSTANCE";
/// Environment variable that overrides `bus.root_path`.
pub const IOX2_ROOT_ENV: &str = "SMOKENAV_IOX2_ROOT";

/// A whole robot profile.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotConfig {
    pub robot: RobotSection,
    #[serde(default)]
    pub bus: BusSection,
    pub laser: LaserSection,
    pub base: BaseSection,
    pub sonar: SonarSection,
    pub smoke: SmokeSection,
    #[serde(default)]
    pub fusion: FusionSection,
    #[serde(default)]
    pub slam: SlamSection,
    #[serde(default)]
    pub mapping: MappingSection,
    #[serde(default)]
    pub zenoh: ZenohSection,
}

impl Validate for RobotConfig {
    fn validate(&self, _key: &str, v: &mut Validator) {
        self.robot.validate("robot", v);
        self.bus.validate("bus", v);
        self.laser.validate("laser", v);
        self.base.validate("base", v);
        self.sonar.validate("sonar", v);
        self.smoke.validate("smoke", v);
        self.fusion.validate("fusion", v);
        self.slam.validate("slam", v);
        self.mapping.validate("mapping", v);
        self.zenoh.validate("zenoh", v);
        match self.robot.platform {
            Platform::Scout if self.base.scout.is_none() => v.fail(
                "base.scout",
                "a Scout profile needs a [base.scout] table (wheel_order, track_m)",
            ),
            Platform::Pioneer if self.base.scout.is_some() => {
                v.fail("base.scout", "only valid when robot.platform = \"scout\"")
            }
            Platform::Scout if self.base.pioneer.is_some() => v.fail(
                "base.pioneer",
                "only valid when robot.platform = \"pioneer\"",
            ),
            _ => {}
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("{file}: cannot read: {error}")]
    Io {
        file: PathBuf,
        error: std::io::Error,
    },
    /// The TOML is malformed, a key is unknown or a value has the wrong type.
    #[error("{}: key `{key}`: {reason}", At(file, *line))]
    Parse {
        file: PathBuf,
        /// 1-based; 0 when neither toml nor the key path locate it.
        line: usize,
        key: String,
        reason: String,
    },
    /// Values are well-formed but not acceptable.
    #[error("{}", InvalidDisplay(file, issues))]
    Invalid { file: PathBuf, issues: Vec<Issue> },
    /// [`RobotConfig::builtin`] was asked for a profile that is not shipped.
    #[error("no shipped robot profile is called {name:?} (have: {known})")]
    UnknownBuiltin { name: String, known: String },
}

/// `file:line`, or `file` when the line is unknown (0).
struct At<'a>(&'a Path, usize);

impl fmt::Display for At<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.1 {
            0 => write!(f, "{}", self.0.display()),
            line => write!(f, "{}:{line}", self.0.display()),
        }
    }
}

struct InvalidDisplay<'a>(&'a PathBuf, &'a [Issue]);

impl fmt::Display for InvalidDisplay<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, issue) in self.1.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            write!(f, "{}: {}", At(self.0, issue.line.unwrap_or(0)), issue)?;
        }
        Ok(())
    }
}

impl ConfigError {
    /// The keys this error is about (for tests and tools).
    pub fn keys(&self) -> Vec<&str> {
        match self {
            ConfigError::Io { .. } | ConfigError::UnknownBuiltin { .. } => vec![],
            ConfigError::Parse { key, .. } => vec![key.as_str()],
            ConfigError::Invalid { issues, .. } => issues.iter().map(|i| i.key.as_str()).collect(),
        }
    }
}

impl RobotConfig {
    /// Reads, parses and validates a profile, then applies the environment overrides.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError::Io {
            file: path.to_owned(),
            error: e,
        })?;
        let mut cfg = Self::parse(&text, path)?;
        cfg.apply_env();
        Ok(cfg)
    }

    /// A profile shipped in `config/` by name (see [`BUILTIN_PROFILES`]),
    /// parsed and validated. The environment overrides are not applied: the
    /// caller decides (see [`Self::apply_env`]).
    pub fn builtin(name: &str) -> Result<Self, ConfigError> {
        let (name, text) = BUILTIN_PROFILES
            .iter()
            .find(|(n, _)| *n == name)
            .ok_or_else(|| ConfigError::UnknownBuiltin {
                name: name.to_owned(),
                known: BUILTIN_PROFILES.map(|(n, _)| n).join(", "),
            })?;
        Self::parse(text, Path::new(&format!("config/{name}.toml")))
    }

    /// Parses and validates `text`; `file` is only used in messages.
    pub fn parse(text: &str, file: &Path) -> Result<Self, ConfigError> {
        let mut cfg: RobotConfig = parse_toml(text, file)?;
        check(&cfg, text, file)?;
        // The fuzzy model's sonar cone is the robot's unless `[slam.fuzzy]` says otherwise.
        cfg.slam
            .fuzzy
            .sonar_cone_deg
            .get_or_insert(cfg.sonar.cone_deg);
        Ok(cfg)
    }

    /// `SMOKENAV_INSTANCE` and `SMOKENAV_IOX2_ROOT` override the file.
    pub fn apply_env(&mut self) {
        if let Ok(inst) = std::env::var(INSTANCE_ENV)
            && !inst.is_empty()
        {
            self.robot.instance = inst;
        }
        if let Ok(root) = std::env::var(IOX2_ROOT_ENV)
            && !root.is_empty()
        {
            self.bus.root_path = Some(root);
        }
    }

    /// The effective configuration as TOML (what `smokenav config check` prints).
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_else(|e| format!("# cannot render: {e}\n"))
    }
}

/// Validates `value` (read from the TOML `text` of `file`): every issue, each
/// with its key path and line.
pub fn check(value: &impl Validate, text: &str, file: &Path) -> Result<(), ConfigError> {
    let mut v = Validator::default();
    value.validate("", &mut v);
    if v.issues.is_empty() {
        return Ok(());
    }
    v.locate(text);
    Err(ConfigError::Invalid {
        file: file.to_owned(),
        issues: v.issues,
    })
}

/// Deserialises any config-like TOML strictly, reporting the key path and line.
pub fn parse_toml<T: serde::de::DeserializeOwned>(
    text: &str,
    file: &Path,
) -> Result<T, ConfigError> {
    let de = toml::de::Deserializer::parse(text)
        .map_err(|e| toml_error(text, file, String::new(), &e))?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        let key = e.path().to_string();
        toml_error(text, file, key, e.inner())
    })
}

fn toml_error(text: &str, file: &Path, key: String, e: &toml::de::Error) -> ConfigError {
    let line = e
        .span()
        .map(|s| validate::line_of(text, s.start))
        .or_else(|| validate::key_line(text, &key))
        .unwrap_or(0);
    let key = if key.is_empty() || key == "." {
        "(document)".to_owned()
    } else {
        key
    };
    ConfigError::Parse {
        file: file.to_owned(),
        line,
        key,
        reason: e.message().trim().to_owned(),
    }
}

#[cfg(test)]
mod tests;
