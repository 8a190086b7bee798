//! Scenario files: one TOML file says which arena, which robot, where it
//! starts and goes, where smoke comes from and when, how long, and the seed.
//! Everything not written takes the defaults of the models (see each model's
//! `Default`); the same file and seed always give the same sensor data.
//!
//! ```toml
//! name = "r32-dense-crossing"
//! seed = 3
//! duration_s = 200.0
//! robot = "nomad-scout"            # a bundled profile, or a path to a robot profile TOML
//!
//! [arena]
//! builtin = "r3.2"                 # or: map = "maps/lab.yaml" (map_server), vector = "lab.toml"
//!
//! [start]
//! x = 1.0
//! y = 1.0
//! heading_deg = 90.0
//!
//! [route]                          # omit to drive by velocity commands only
//! speed_mps = 0.3
//! lookahead_m = 0.5
//! loop = false
//! waypoints = [[1.0, 8.8], [3.4, 8.8]]
//!
//! [[smoke.source]]
//! position = [7.0, 7.0]
//! radius_m = 0.4
//! schedule = [{ start_s = 5.0, duration_s = 60.0, rate_gps = 0.5 }]
//! ```
//!
//! Optional tables: `[motion]` (track_m, accel_mps2, angular_accel_dps2),
//! `[odometry]` (scale_left, scale_right, track_error, heading_drift_deg_per_m,
//! slip_per_sqrt_m), `[smoke]` (cell_m, diffusion_m2ps, decay_per_s, wind_mps,
//! layer_height_m, mass_extinction_m2pg, `[[smoke.source]]`, `[[smoke.patch]]`
//! with center/radius_m/density_gpm3), `[laser]` (lidar_ratio_sr,
//! wall_reflectance, min_return, patchiness), `[sonar]` (critical_angle_deg,
//! rays, noise_frac, dropout_prob, crosstalk_prob, interval_s),
//! `[smoke_sensor]` (rise_tau_s, fall_tau_s, ppm_per_gpm3, noise_mv, cold_start),
//! `[truth]` (rate_hz, map_resolution_m). Paths are relative to the scenario file.

use crate::SimError;
use crate::arena::{Arena, ArenaSource, BuiltinArena};
use crate::geom::{Pose2, Position, Vec2};
use crate::laser::LaserParams;
use crate::mq303a::Mq303aParams;
use crate::robot::{DriveParams, OdometryErrors};
use crate::smoke::{Pulse, SmokeParams, SmokeSource};
use crate::sonar::SonarParams;
use serde::Deserialize;
use smokenav_platform_config::{Platform, RobotConfig};
use smokenav_smoke_codec::mq303a::SensorParams;
use std::path::{Path, PathBuf};

/// Scenarios shipped with the simulator: (name, text).
pub const BUILTIN_SCENARIOS: [(&str, &str); 4] = [
    ("mrl-clean", include_str!("../../scenarios/mrl-clean.toml")),
    (
        "r32-light-puff",
        include_str!("../../scenarios/r32-light-puff.toml"),
    ),
    (
        "r32-dense-crossing",
        include_str!("../../scenarios/r32-dense-crossing.toml"),
    ),
    ("corridor", include_str!("../../scenarios/corridor.toml")),
];

/// Robot profiles shipped in `config/`: (name, text).
pub const BUILTIN_PROFILES: [(&str, &str); 2] = [
    (
        "pioneer-3dx",
        include_str!("../../../config/pioneer-3dx.toml"),
    ),
    (
        "nomad-scout",
        include_str!("../../../config/nomad-scout.toml"),
    ),
];

/// Most smoke sources, patches, waypoints or pulses a file may list.
const MAX_ITEMS: usize = 10_000;
/// Longest scenario, s (a day).
const MAX_DURATION_S: f64 = 86_400.0;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ScenarioFile {
    name: String,
    #[serde(default)]
    description: String,
    seed: u64,
    duration_s: f64,
    robot: String,
    arena: ArenaFile,
    start: StartFile,
    #[serde(default)]
    route: Option<RouteFile>,
    #[serde(default)]
    motion: MotionFile,
    #[serde(default)]
    odometry: OdometryFile,
    #[serde(default)]
    smoke: SmokeFile,
    #[serde(default)]
    laser: LaserFile,
    #[serde(default)]
    sonar: SonarFile,
    #[serde(default)]
    smoke_sensor: SmokeSensorFile,
    #[serde(default)]
    truth: TruthFile,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, rename_all = "snake_case")]
enum ArenaFile {
    Builtin(String),
    Map(PathBuf),
    Vector(PathBuf),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct StartFile {
    x: f64,
    y: f64,
    #[serde(default)]
    heading_deg: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RouteFile {
    waypoints: Vec<[f64; 2]>,
    #[serde(default = "default_speed")]
    speed_mps: f64,
    #[serde(default = "default_lookahead")]
    lookahead_m: f64,
    #[serde(default, rename = "loop")]
    looped: bool,
}

fn default_speed() -> f64 {
    0.3
}
fn default_lookahead() -> f64 {
    0.5
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct MotionFile {
    track_m: Option<f64>,
    accel_mps2: Option<f64>,
    angular_accel_dps2: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct OdometryFile {
    #[serde(default)]
    scale_left: f64,
    #[serde(default)]
    scale_right: f64,
    #[serde(default)]
    track_error: f64,
    #[serde(default)]
    heading_drift_deg_per_m: f64,
    #[serde(default)]
    slip_per_sqrt_m: f64,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct SmokeFile {
    cell_m: Option<f64>,
    diffusion_m2ps: Option<f64>,
    decay_per_s: Option<f64>,
    wind_mps: Option<[f64; 2]>,
    layer_height_m: Option<f64>,
    mass_extinction_m2pg: Option<f64>,
    #[serde(default)]
    source: Vec<SourceFile>,
    #[serde(default)]
    patch: Vec<PatchFile>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SourceFile {
    position: [f64; 2],
    #[serde(default = "default_source_radius")]
    radius_m: f64,
    schedule: Vec<PulseFile>,
}

fn default_source_radius() -> f64 {
    0.3
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PulseFile {
    start_s: f64,
    duration_s: f64,
    rate_gps: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PatchFile {
    center: [f64; 2],
    radius_m: f64,
    density_gpm3: f64,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct LaserFile {
    lidar_ratio_sr: Option<f64>,
    wall_reflectance: Option<f64>,
    min_return: Option<f64>,
    patchiness: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct SonarFile {
    critical_angle_deg: Option<f64>,
    rays: Option<usize>,
    noise_frac: Option<f64>,
    dropout_prob: Option<f64>,
    crosstalk_prob: Option<f64>,
    interval_s: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct SmokeSensorFile {
    rise_tau_s: Option<f64>,
    fall_tau_s: Option<f64>,
    ppm_per_gpm3: Option<f64>,
    noise_mv: Option<f64>,
    #[serde(default)]
    cold_start: bool,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct TruthFile {
    rate_hz: Option<f64>,
    map_resolution_m: Option<f64>,
}

/// A scripted route.
#[derive(Debug, Clone, PartialEq)]
pub struct Route {
    pub waypoints: Vec<Vec2>,
    pub speed_mps: f64,
    pub lookahead_m: f64,
    pub looped: bool,
}

/// An initial disc of smoke.
#[derive(Debug, Clone, PartialEq)]
pub struct Patch {
    pub center: Vec2,
    pub radius_m: f64,
    pub density_gpm3: f64,
}

/// A sonar ring transducer: index and pose on the base.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SonarMount {
    pub index: u8,
    pub pose: Pose2,
}

/// A checked, fully resolved scenario.
#[derive(Debug, Clone)]
pub struct Scenario {
    pub name: String,
    pub description: String,
    pub seed: u64,
    pub duration_s: f64,
    /// The file it came from (for messages).
    pub file: PathBuf,
    pub arena: Arena,
    pub arena_source: ArenaSource,
    pub profile: RobotConfig,
    pub start: Pose2,
    pub route: Option<Route>,
    pub drive: DriveParams,
    pub odometry: OdometryErrors,
    pub smoke: SmokeParams,
    pub sources: Vec<SmokeSource>,
    pub patches: Vec<Patch>,
    pub laser: LaserParams,
    pub laser_mount: Pose2,
    pub sonar: SonarParams,
    pub sonar_mounts: Vec<SonarMount>,
    /// Time between two pings of the ring, s (one transducer per ping).
    pub sonar_interval_s: f64,
    /// Firing order, transducer indices.
    pub sonar_order: Vec<u8>,
    pub smoke_sensor: Mq303aParams,
    /// Odometry (and route controller) rate, Hz.
    pub base_rate_hz: f64,
    /// Smoke ADC sampling rate, Hz.
    pub smoke_rate_hz: f64,
    pub adc_vref_mv: f64,
    pub adc_bits: u8,
    pub truth_rate_hz: f64,
    pub truth_map_resolution_m: f64,
}

impl Scenario {
    /// Reads and checks a scenario file.
    pub fn load(path: &Path) -> Result<Self, SimError> {
        let text = std::fs::read_to_string(path).map_err(|e| SimError::Io {
            path: path.to_owned(),
            source: e,
        })?;
        Self::parse(&text, path)
    }

    /// A bundled scenario by name (see [`BUILTIN_SCENARIOS`]).
    pub fn builtin(name: &str) -> Result<Self, SimError> {
        let (n, text) = BUILTIN_SCENARIOS
            .iter()
            .find(|(n, _)| *n == name)
            .ok_or_else(|| SimError::Invalid {
                file: PathBuf::from(name),
                key: "scenario".into(),
                reason: format!(
                    "no bundled scenario of that name (have: {})",
                    BUILTIN_SCENARIOS.map(|(n, _)| n).join(", ")
                ),
            })?;
        Self::parse(text, Path::new(&format!("sim/scenarios/{n}.toml")))
    }

    /// A bundled scenario name, or else a path.
    pub fn builtin_or_file(spec: &str) -> Result<Self, SimError> {
        if BUILTIN_SCENARIOS.iter().any(|(n, _)| *n == spec) {
            Self::builtin(spec)
        } else {
            Self::load(Path::new(spec))
        }
    }

    /// Parses and checks `text`; relative paths resolve against `file`'s directory.
    pub fn parse(text: &str, file: &Path) -> Result<Self, SimError> {
        let f: ScenarioFile = smokenav_platform_config::parse_toml(text, file)?;
        let dir = file.parent().unwrap_or_else(|| Path::new("."));
        let invalid = |key: &str, reason: String| SimError::Invalid {
            file: file.to_owned(),
            key: key.to_owned(),
            reason,
        };
        let check = |key: &str, v: f64, lo: f64, hi: f64| -> Result<f64, SimError> {
            if v.is_finite() && v >= lo && v <= hi {
                Ok(v)
            } else {
                Err(invalid(
                    key,
                    format!("must be within [{lo}, {hi}], got {v}"),
                ))
            }
        };
        let opt =
            |key: &str, v: Option<f64>, default: f64, lo: f64, hi: f64| -> Result<f64, SimError> {
                match v {
                    Some(v) => check(key, v, lo, hi),
                    None => Ok(default),
                }
            };
        if f.name.trim().is_empty() {
            return Err(invalid("name", "must not be empty".into()));
        }
        let duration_s = check("duration_s", f.duration_s, 0.001, MAX_DURATION_S)?;

        // Robot profile: bundled name or a path.
        let profile = match BUILTIN_PROFILES.iter().find(|(n, _)| *n == f.robot) {
            Some((n, text)) => RobotConfig::parse(text, Path::new(&format!("config/{n}.toml")))?,
            None => RobotConfig::load(&dir.join(&f.robot))?,
        };
        let platform = profile.robot.platform;

        let arena_source = match &f.arena {
            ArenaFile::Builtin(name) => {
                ArenaSource::Builtin(BuiltinArena::from_name(name).ok_or_else(|| {
                    invalid(
                        "arena.builtin",
                        format!(
                            "unknown arena {name:?} (have: {})",
                            BuiltinArena::ALL.map(|a| a.name()).join(", ")
                        ),
                    )
                })?)
            }
            ArenaFile::Map(p) => ArenaSource::MapServer(dir.join(p)),
            ArenaFile::Vector(p) => ArenaSource::Vector(dir.join(p)),
        };
        let arena = arena_source.load()?;

        // Motion.
        // The Scout's track is in its profile; the P3-DX's drive wheels are about 33 cm apart (measure yours).
        let track_default = profile.base.scout.as_ref().map_or(0.33, |s| s.track_m);
        let drive = DriveParams {
            track_m: opt("motion.track_m", f.motion.track_m, track_default, 0.05, 2.0)?,
            radius_m: profile.robot.radius_m,
            max_linear_mps: profile.base.max_linear_mps,
            max_angular_rps: profile.base.max_angular_dps.to_radians(),
            accel_mps2: opt("motion.accel_mps2", f.motion.accel_mps2, 0.3, 0.01, 10.0)?,
            angular_accel_rps2: opt(
                "motion.angular_accel_dps2",
                f.motion.angular_accel_dps2,
                100.0,
                1.0,
                2000.0,
            )?
            .to_radians(),
        };
        let o = &f.odometry;
        let odometry = OdometryErrors {
            scale_left: check("odometry.scale_left", o.scale_left, -0.5, 0.5)?,
            scale_right: check("odometry.scale_right", o.scale_right, -0.5, 0.5)?,
            track_error: check("odometry.track_error", o.track_error, -0.5, 0.5)?,
            heading_drift_rad_per_m: check(
                "odometry.heading_drift_deg_per_m",
                o.heading_drift_deg_per_m,
                -45.0,
                45.0,
            )?
            .to_radians(),
            slip_per_sqrt_m: check("odometry.slip_per_sqrt_m", o.slip_per_sqrt_m, 0.0, 1.0)?,
        };

        // Start and route: the footprint must fit.
        let start = Pose2::new(
            check("start.x", f.start.x, -1e4, 1e4)?,
            check("start.y", f.start.y, -1e4, 1e4)?,
            check("start.heading_deg", f.start.heading_deg, -360.0, 360.0)?.to_radians(),
        );
        let r = drive.radius_m;
        let fits = |p: Vec2| arena.clearance(p, r) >= r;
        if !fits(start.position()) {
            return Err(invalid(
                "start",
                format!(
                    "the robot (radius {r} m) at ({}, {}) overlaps a wall",
                    start.x, start.y
                ),
            ));
        }
        let route = match &f.route {
            None => None,
            Some(rf) => {
                if rf.waypoints.is_empty() || rf.waypoints.len() > MAX_ITEMS {
                    return Err(invalid(
                        "route.waypoints",
                        format!("needs 1–{MAX_ITEMS} points, got {}", rf.waypoints.len()),
                    ));
                }
                let speed = check("route.speed_mps", rf.speed_mps, 0.01, drive.max_linear_mps)?;
                let look = check("route.lookahead_m", rf.lookahead_m, 0.05, 10.0)?;
                let wps: Vec<Vec2> = rf.waypoints.iter().map(|p| Vec2::new(p[0], p[1])).collect();
                let mut prev = start.position();
                for (i, &w) in wps.iter().enumerate() {
                    if !w.is_finite() {
                        return Err(invalid(
                            &format!("route.waypoints[{i}]"),
                            "not a finite point".into(),
                        ));
                    }
                    let len = (w - prev).norm();
                    let n = (len / 0.05).ceil().max(1.0) as usize;
                    for k in 0..=n {
                        let p = prev + (w - prev) * (k as f64 / n as f64);
                        if !fits(p) {
                            return Err(invalid(
                                &format!("route.waypoints[{i}]"),
                                format!(
                                    "the leg to ({}, {}) passes ({:.2}, {:.2}), where the robot (radius {r} m) would touch a wall",
                                    w.x, w.y, p.x, p.y
                                ),
                            ));
                        }
                    }
                    prev = w;
                }
                Some(Route {
                    waypoints: wps,
                    speed_mps: speed,
                    lookahead_m: look,
                    looped: rf.looped,
                })
            }
        };

        // Smoke.
        let d = SmokeParams::default();
        let s = &f.smoke;
        let wind = s.wind_mps.unwrap_or([0.0, 0.0]);
        let smoke = SmokeParams {
            cell_m: opt("smoke.cell_m", s.cell_m, d.cell_m, 0.02, 1.0)?,
            diffusion_m2ps: opt(
                "smoke.diffusion_m2ps",
                s.diffusion_m2ps,
                d.diffusion_m2ps,
                0.0,
                1.0,
            )?,
            decay_per_s: opt("smoke.decay_per_s", s.decay_per_s, d.decay_per_s, 0.0, 10.0)?,
            wind_mps: Vec2::new(
                check("smoke.wind_mps", wind[0], -5.0, 5.0)?,
                check("smoke.wind_mps", wind[1], -5.0, 5.0)?,
            ),
            layer_height_m: opt(
                "smoke.layer_height_m",
                s.layer_height_m,
                d.layer_height_m,
                0.1,
                20.0,
            )?,
            mass_extinction_m2pg: opt(
                "smoke.mass_extinction_m2pg",
                s.mass_extinction_m2pg,
                d.mass_extinction_m2pg,
                0.0,
                100.0,
            )?,
        };
        let (lo, hi) = arena.bounds();
        let cells = ((hi.x - lo.x) / smoke.cell_m) * ((hi.y - lo.y) / smoke.cell_m);
        if cells > 16e6 {
            return Err(invalid(
                "smoke.cell_m",
                format!("{:.0} cells over this arena; use larger cells", cells),
            ));
        }
        if s.source.len() > MAX_ITEMS || s.patch.len() > MAX_ITEMS {
            return Err(invalid(
                "smoke",
                format!("at most {MAX_ITEMS} sources and patches"),
            ));
        }
        let mut sources = Vec::new();
        for (i, src) in s.source.iter().enumerate() {
            let key = format!("smoke.source[{i}]");
            if src.schedule.len() > MAX_ITEMS {
                return Err(invalid(
                    &format!("{key}.schedule"),
                    "too many pulses".into(),
                ));
            }
            let mut schedule = Vec::new();
            for (j, p) in src.schedule.iter().enumerate() {
                let k = format!("{key}.schedule[{j}]");
                schedule.push(Pulse {
                    start_s: check(&format!("{k}.start_s"), p.start_s, 0.0, MAX_DURATION_S)?,
                    duration_s: check(
                        &format!("{k}.duration_s"),
                        p.duration_s,
                        0.0,
                        MAX_DURATION_S,
                    )?,
                    rate_gps: check(&format!("{k}.rate_gps"), p.rate_gps, 0.0, 1000.0)?,
                });
            }
            sources.push(SmokeSource {
                position: Vec2::new(
                    check(&format!("{key}.position"), src.position[0], -1e4, 1e4)?,
                    check(&format!("{key}.position"), src.position[1], -1e4, 1e4)?,
                ),
                radius_m: check(&format!("{key}.radius_m"), src.radius_m, 0.0, 20.0)?,
                schedule,
            });
        }
        let mut patches = Vec::new();
        for (i, p) in s.patch.iter().enumerate() {
            let key = format!("smoke.patch[{i}]");
            patches.push(Patch {
                center: Vec2::new(
                    check(&format!("{key}.center"), p.center[0], -1e4, 1e4)?,
                    check(&format!("{key}.center"), p.center[1], -1e4, 1e4)?,
                ),
                radius_m: check(&format!("{key}.radius_m"), p.radius_m, 0.0, 100.0)?,
                density_gpm3: check(&format!("{key}.density_gpm3"), p.density_gpm3, 0.0, 100.0)?,
            });
        }
        // A source must sit in open air: try building the field once.
        if let Err(i) = crate::smoke::SmokeField::new(&arena, smoke.clone(), sources.clone()) {
            return Err(invalid(
                &format!("smoke.source[{i}].position"),
                "is inside a wall or outside the arena".into(),
            ));
        }

        // Laser.
        let ld = LaserParams::default();
        let l = &f.laser;
        let laser = LaserParams {
            lidar_ratio_sr: opt(
                "laser.lidar_ratio_sr",
                l.lidar_ratio_sr,
                ld.lidar_ratio_sr,
                1.0,
                1000.0,
            )?,
            wall_reflectance: opt(
                "laser.wall_reflectance",
                l.wall_reflectance,
                ld.wall_reflectance,
                0.01,
                1.0,
            )?,
            min_return: opt("laser.min_return", l.min_return, ld.min_return, 0.0, 1.0)?,
            patchiness: opt("laser.patchiness", l.patchiness, ld.patchiness, 0.0, 3.0)?,
            ..ld
        };
        let m = profile.laser.mount;
        let laser_mount = Pose2::new(m.x, m.y, m.yaw_deg.to_radians());

        // Sonar: geometry from the profile, behaviour by platform unless overridden.
        let sd = match platform {
            Platform::Pioneer => SonarParams::pioneer(),
            Platform::Scout => SonarParams::scout(),
        };
        let so = &f.sonar;
        let sonar = SonarParams {
            cone_deg: profile.sonar.cone_deg,
            min_range_m: profile.sonar.min_range_m,
            max_range_m: profile.sonar.max_range_m,
            critical_angle_deg: opt(
                "sonar.critical_angle_deg",
                so.critical_angle_deg,
                sd.critical_angle_deg,
                0.0,
                90.0,
            )?,
            rays: match so.rays {
                Some(n) if (1..=101).contains(&n) => n,
                Some(n) => return Err(invalid("sonar.rays", format!("must be 1–101, got {n}"))),
                None => sd.rays,
            },
            noise_frac: opt("sonar.noise_frac", so.noise_frac, sd.noise_frac, 0.0, 0.5)?,
            dropout_prob: opt(
                "sonar.dropout_prob",
                so.dropout_prob,
                sd.dropout_prob,
                0.0,
                1.0,
            )?,
            crosstalk_prob: opt(
                "sonar.crosstalk_prob",
                so.crosstalk_prob,
                sd.crosstalk_prob,
                0.0,
                1.0,
            )?,
        };
        let sonar_mounts: Vec<SonarMount> = (0..profile.sonar.count)
            .filter_map(|i| profile.sonar.transducer(i))
            .map(|t| SonarMount {
                index: t.index,
                pose: Pose2::new(t.x, t.y, t.yaw_deg.to_radians()),
            })
            .collect();
        // Pioneer: ARCOS polls one disc per array every 40 ms, in order 1…8 (Pioneer 3
        // operations manual, "Polling Rate"). Scout: conf_sn rate × 4 ms in the configured order.
        let (interval_default, order) = match &profile.base.scout {
            Some(s) => (
                s.sonar_rate as f64 * 0.004,
                s.sonar_order
                    .iter()
                    .copied()
                    .filter(|&i| i < profile.sonar.count)
                    .collect(),
            ),
            None => (0.040, (0..profile.sonar.count).collect::<Vec<u8>>()),
        };
        let sonar_interval_s = opt(
            "sonar.interval_s",
            so.interval_s,
            interval_default.max(0.004),
            0.002,
            10.0,
        )?;

        let md = Mq303aParams::default();
        let ss = &f.smoke_sensor;
        let smoke_sensor = Mq303aParams {
            sensor: SensorParams {
                supply_mv: profile.smoke.vref_mv,
                tau_rise_s: opt(
                    "smoke_sensor.rise_tau_s",
                    ss.rise_tau_s,
                    md.sensor.tau_rise_s,
                    0.0,
                    600.0,
                )?,
                tau_fall_s: opt(
                    "smoke_sensor.fall_tau_s",
                    ss.fall_tau_s,
                    md.sensor.tau_fall_s,
                    0.0,
                    3600.0,
                )?,
                // The driver waits the profile's warm-up; a cold sensor settles over the same time.
                warmup_s: profile.smoke.warmup_s,
                ..md.sensor
            },
            ppm_per_gpm3: opt(
                "smoke_sensor.ppm_per_gpm3",
                ss.ppm_per_gpm3,
                md.ppm_per_gpm3,
                0.0,
                1e6,
            )?,
            noise_mv: opt(
                "smoke_sensor.noise_mv",
                ss.noise_mv,
                md.noise_mv,
                0.0,
                1000.0,
            )?,
            cold_start: ss.cold_start,
        };

        Ok(Scenario {
            name: f.name,
            description: f.description,
            seed: f.seed,
            duration_s,
            file: file.to_owned(),
            arena,
            arena_source,
            start,
            route,
            drive,
            odometry,
            smoke,
            sources,
            patches,
            laser,
            laser_mount,
            sonar,
            sonar_mounts,
            sonar_interval_s,
            sonar_order: order,
            smoke_sensor,
            base_rate_hz: profile.base.rate_hz,
            smoke_rate_hz: profile.smoke.rate_hz,
            adc_vref_mv: profile.smoke.vref_mv,
            adc_bits: profile.smoke.adc_bits,
            truth_rate_hz: opt("truth.rate_hz", f.truth.rate_hz, 10.0, 0.1, 1000.0)?,
            truth_map_resolution_m: opt(
                "truth.map_resolution_m",
                f.truth.map_resolution_m,
                0.05,
                0.005,
                1.0,
            )?,
            profile,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = "name = \"t\"\nseed = 1\nduration_s = 10\nrobot = \"pioneer-3dx\"\n\
                           [arena]\nbuiltin = \"mrl\"\n[start]\nx = 0.7\ny = 0.7\n";

    #[test]
    fn every_bundled_scenario_loads() {
        for (name, _) in BUILTIN_SCENARIOS {
            let s = Scenario::builtin(name).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(s.name, name);
        }
    }

    #[test]
    fn minimal_scenario_takes_platform_defaults() {
        let s = Scenario::parse(MINIMAL, Path::new("min.toml")).unwrap();
        assert_eq!(s.sonar_mounts.len(), 8);
        assert_eq!(s.sonar.cone_deg, 15.0);
        assert!((s.sonar_interval_s - 0.040).abs() < 1e-12);
        assert!((s.laser_mount.x - 0.16).abs() < 1e-12);
        assert!(s.route.is_none());
    }

    #[test]
    fn scout_profile_sets_its_sonar_timing_and_order() {
        let text = MINIMAL.replace("pioneer-3dx", "nomad-scout");
        let s = Scenario::parse(&text, Path::new("scout.toml")).unwrap();
        assert!(
            (s.sonar_interval_s - 0.060).abs() < 1e-12,
            "conf_sn rate 15 × 4 ms"
        );
        assert_eq!(s.sonar_order[..3], [0, 2, 15]);
        assert_eq!(s.sonar.cone_deg, 20.0);
        assert!((s.drive.track_m - 0.345).abs() < 1e-12);
    }

    #[test]
    fn errors_name_the_file_and_key() {
        let cases = [
            (MINIMAL.replace("x = 0.7", "x = 0.1"), "start"),
            (
                MINIMAL.replace("duration_s = 10", "duration_s = -1"),
                "duration_s",
            ),
            (
                MINIMAL.replace("builtin = \"mrl\"", "builtin = \"mrl2\""),
                "arena.builtin",
            ),
            (MINIMAL.to_owned() + "bogus = 1\n", "bogus"),
            (
                MINIMAL.to_owned() + "[route]\nwaypoints = [[4.5, 0.7]]\n",
                "route.waypoints[0]",
            ),
            (
                MINIMAL.to_owned() + "[[smoke.source]]\nposition = [1.5, 0.5]\nschedule = []\n",
                "smoke.source[0].position",
            ),
            (
                MINIMAL.to_owned() + "[laser]\npatchiness = -1\n",
                "laser.patchiness",
            ),
        ];
        for (text, key) in cases {
            let e = Scenario::parse(&text, Path::new("bad.toml"))
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("bad.toml") && e.contains(key),
                "expected {key}: {e}"
            );
        }
    }

    #[test]
    fn missing_map_file_is_named() {
        let text = MINIMAL.replace("builtin = \"mrl\"", "map = \"nowhere.yaml\"");
        let e = Scenario::parse(&text, Path::new("/tmp/x/s.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("nowhere.yaml"), "{e}");
    }

    proptest::proptest! {
        #[test]
        fn arbitrary_text_never_panics(text in "\\PC{0,400}") {
            let _ = Scenario::parse(&text, Path::new("fuzz.toml"));
        }

        #[test]
        fn arbitrary_values_never_panic(x in -100.0f64..100.0, y in -100.0f64..100.0, cell in -1.0f64..2.0, d in -10.0f64..1e5) {
            let text = format!(
                "name = \"f\"\nseed = 1\nduration_s = {d}\nrobot = \"nomad-scout\"\n[arena]\nbuiltin = \"corridor\"\n\
                 [start]\nx = {x}\ny = {y}\n[smoke]\ncell_m = {cell}\n"
            );
            let _ = Scenario::parse(&text, Path::new("fuzz.toml"));
        }
    }
}
