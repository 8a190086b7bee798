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
//! slip_per_sqrt_m; climb_height_m, bump_heading_deg, bump_slip_m: driving
//! over obstacles at most climb_height_m high jolts the heading and spins a
//! wheel, and leaves them out of the truth map), `[smoke]` (cell_m, diffusion_m2ps, decay_per_s, wind_mps,
//! layer_height_m, mass_extinction_m2pg, `[[smoke.source]]`, `[[smoke.patch]]`
//! with center/radius_m/density_gpm3), `[laser]` (height_m, lidar_ratio_sr,
//! wall_reflectance, min_return, patchiness), `[sonar]` (height_m, critical_angle_deg,
//! rays, noise_frac, dropout_prob, crosstalk_prob, interval_s),
//! `[smoke_sensor]` (rise_tau_s, fall_tau_s, ppm_per_gpm3, noise_mv, cold_start),
//! `[truth]` (rate_hz, map_resolution_m). Paths are relative to the scenario file.

use crate::SimError;
use crate::arena::{Arena, ArenaSource, BuiltinArena};
use crate::geom::{Pose2, Position, Vec2};
use crate::laser::LaserParams;
use crate::mq303a::Mq303aParams;
use crate::robot::{DriveParams, OdometryErrors};
use crate::smoke::{Pulse, SmokeField, SmokeParams, SmokeSource};
use crate::sonar::SonarParams;
use serde::Deserialize;
use smokenav_platform_config::{
    BUILTIN_PROFILES, ConfigError, Platform, RobotConfig, Validate, Validator,
};
use smokenav_smoke_codec::mq303a::SensorParams;
use std::path::{Path, PathBuf};

/// Scenarios shipped with the simulator: (name, text).
pub const BUILTIN_SCENARIOS: [(&str, &str); 7] = [
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
    ("heights", include_str!("../../scenarios/heights.toml")),
    ("aisles", include_str!("../../scenarios/aisles.toml")),
    ("cables", include_str!("../../scenarios/cables.toml")),
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
    #[serde(default)]
    climb_height_m: f64,
    #[serde(default)]
    bump_heading_deg: f64,
    #[serde(default)]
    bump_slip_m: f64,
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
    height_m: Option<f64>,
    lidar_ratio_sr: Option<f64>,
    wall_reflectance: Option<f64>,
    min_return: Option<f64>,
    patchiness: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct SonarFile {
    height_m: Option<f64>,
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
    /// The scenario's smoke field at time 0: its sources and patches, before
    /// any [`SmokeField::advance`]. The world starts from this; so can
    /// anything that needs the smoke's history without the whole simulation.
    pub fn smoke_field(&self) -> Result<SmokeField, SimError> {
        let mut smoke = SmokeField::new(&self.arena, self.smoke.clone(), self.sources.clone())
            .map_err(|i| SimError::Invalid {
                file: self.file.clone(),
                key: format!("smoke.source[{i}].position"),
                reason: "is inside a wall or outside the arena".into(),
            })?;
        for p in &self.patches {
            smoke.add_patch(p.center, p.radius_m, p.density_gpm3);
        }
        Ok(smoke)
    }

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
    ///
    /// Every value problem is reported at once, each with its line and key
    /// (as a robot profile's are); the robot profile and the arena are loaded
    /// first, since the values are checked against them.
    pub fn parse(text: &str, file: &Path) -> Result<Self, SimError> {
        let f: ScenarioFile = smokenav_platform_config::parse_toml(text, file)?;
        let dir = file.parent().unwrap_or_else(|| Path::new("."));
        let invalid = |v: Validator| -> SimError {
            let mut v = v;
            v.locate(text);
            SimError::Config(ConfigError::Invalid {
                file: file.to_owned(),
                issues: v.issues,
            })
        };

        // Robot profile: bundled name or a path.
        let profile = if BUILTIN_PROFILES.iter().any(|(n, _)| *n == f.robot) {
            RobotConfig::builtin(&f.robot)?
        } else {
            RobotConfig::load(&dir.join(&f.robot))?
        };

        // Values, table by table.
        let mut v = Validator::default();
        f.validate(&profile, &mut v);
        if !v.issues.is_empty() {
            return Err(invalid(v));
        }

        let arena_source = match &f.arena {
            ArenaFile::Builtin(name) => ArenaSource::Builtin(
                BuiltinArena::from_name(name).expect("checked by ScenarioFile::validate"),
            ),
            ArenaFile::Map(p) => ArenaSource::MapServer(dir.join(p)),
            ArenaFile::Vector(p) => ArenaSource::Vector(dir.join(p)),
        };
        let arena = arena_source.load()?;
        let platform = profile.robot.platform;

        // Motion.
        let drive = f.motion.drive(&profile);
        let o = &f.odometry;
        let odometry = OdometryErrors {
            scale_left: o.scale_left,
            scale_right: o.scale_right,
            track_error: o.track_error,
            heading_drift_rad_per_m: o.heading_drift_deg_per_m.to_radians(),
            slip_per_sqrt_m: o.slip_per_sqrt_m,
            climb_height_m: o.climb_height_m,
            bump_heading_rad: o.bump_heading_deg.to_radians(),
            bump_slip_m: o.bump_slip_m,
        };
        let start = Pose2::new(f.start.x, f.start.y, f.start.heading_deg.to_radians());
        let route = f.route.as_ref().map(|rf| Route {
            waypoints: rf.waypoints.iter().map(|p| Vec2::new(p[0], p[1])).collect(),
            speed_mps: rf.speed_mps,
            lookahead_m: rf.lookahead_m,
            looped: rf.looped,
        });
        let smoke = f.smoke.params();
        let sources: Vec<SmokeSource> = f.smoke.source.iter().map(SourceFile::source).collect();
        let patches: Vec<Patch> = f
            .smoke
            .patch
            .iter()
            .map(|p| Patch {
                center: Vec2::new(p.center[0], p.center[1]),
                radius_m: p.radius_m,
                density_gpm3: p.density_gpm3,
            })
            .collect();

        // Where things are in this arena: the footprint must fit, sources sit in open air.
        let mut v = Validator::default();
        check_placement(
            &arena,
            drive.radius_m,
            odometry.climb_height_m,
            start,
            route.as_ref(),
            &mut v,
        );
        let (lo, hi) = arena.bounds();
        let cells = ((hi.x - lo.x) / smoke.cell_m) * ((hi.y - lo.y) / smoke.cell_m);
        if cells > 16e6 {
            v.fail(
                "smoke.cell_m",
                format!("{cells:.0} cells over this arena; use larger cells"),
            );
        } else if let Err(i) = crate::smoke::SmokeField::new(&arena, smoke.clone(), sources.clone())
        {
            v.fail(
                format!("smoke.source[{i}].position"),
                "is inside a wall or outside the arena",
            );
        }
        if !v.issues.is_empty() {
            return Err(invalid(v));
        }

        let l = &f.laser;
        let ld = LaserParams::default();
        let laser = LaserParams {
            lidar_ratio_sr: l.lidar_ratio_sr.unwrap_or(ld.lidar_ratio_sr),
            wall_reflectance: l.wall_reflectance.unwrap_or(ld.wall_reflectance),
            min_return: l.min_return.unwrap_or(ld.min_return),
            patchiness: l.patchiness.unwrap_or(ld.patchiness),
            height_m: l.height_m.unwrap_or(ld.height_m),
            ..ld
        };
        let m = profile.laser.mount;
        let laser_mount = Pose2::new(m.x, m.y, m.yaw_deg.to_radians());

        // Sonar: geometry from the profile, behaviour by platform unless overridden.
        let sd = sonar_defaults(platform);
        let so = &f.sonar;
        let sonar = SonarParams {
            cone_deg: profile.sonar.cone_deg,
            min_range_m: profile.sonar.min_range_m,
            max_range_m: profile.sonar.max_range_m,
            critical_angle_deg: so.critical_angle_deg.unwrap_or(sd.critical_angle_deg),
            rays: so.rays.unwrap_or(sd.rays),
            noise_frac: so.noise_frac.unwrap_or(sd.noise_frac),
            dropout_prob: so.dropout_prob.unwrap_or(sd.dropout_prob),
            crosstalk_prob: so.crosstalk_prob.unwrap_or(sd.crosstalk_prob),
            height_m: so.height_m.unwrap_or(sd.height_m),
        };
        let sonar_mounts: Vec<SonarMount> = (0..profile.sonar.count)
            .filter_map(|i| profile.sonar.transducer(i))
            .map(|t| SonarMount {
                index: t.index,
                pose: Pose2::new(t.x, t.y, t.yaw_deg.to_radians()),
            })
            .collect();
        let (interval_default, order) = sonar_timing(&profile);
        let sonar_interval_s = so.interval_s.unwrap_or(interval_default);

        let md = Mq303aParams::default();
        let ss = &f.smoke_sensor;
        let smoke_sensor = Mq303aParams {
            sensor: SensorParams {
                supply_mv: profile.smoke.vref_mv,
                tau_rise_s: ss.rise_tau_s.unwrap_or(md.sensor.tau_rise_s),
                tau_fall_s: ss.fall_tau_s.unwrap_or(md.sensor.tau_fall_s),
                // The driver waits the profile's warm-up; a cold sensor settles over the same time.
                warmup_s: profile.smoke.warmup_s,
                ..md.sensor
            },
            ppm_per_gpm3: ss.ppm_per_gpm3.unwrap_or(md.ppm_per_gpm3),
            noise_mv: ss.noise_mv.unwrap_or(md.noise_mv),
            cold_start: ss.cold_start,
        };

        Ok(Scenario {
            name: f.name,
            description: f.description,
            seed: f.seed,
            duration_s: f.duration_s,
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
            truth_rate_hz: f.truth.rate_hz.unwrap_or(DEFAULT_TRUTH_RATE_HZ),
            truth_map_resolution_m: f
                .truth
                .map_resolution_m
                .unwrap_or(DEFAULT_TRUTH_RESOLUTION_M),
            profile,
        })
    }
}

/// Ground-truth rate when `[truth] rate_hz` is not given, Hz.
const DEFAULT_TRUTH_RATE_HZ: f64 = 10.0;
/// Ground-truth map cell when `[truth] map_resolution_m` is not given, m.
const DEFAULT_TRUTH_RESOLUTION_M: f64 = 0.05;

fn sonar_defaults(platform: Platform) -> SonarParams {
    match platform {
        Platform::Pioneer => SonarParams::pioneer(),
        Platform::Scout => SonarParams::scout(),
    }
}

/// The ring's default ping interval and firing order. Pioneer: ARCOS polls
/// one disc per array every 40 ms, in order 1…8 (Pioneer 3 operations manual,
/// "Polling Rate"). Scout: conf_sn rate × 4 ms in the configured order.
fn sonar_timing(profile: &RobotConfig) -> (f64, Vec<u8>) {
    let (interval, order) = match &profile.base.scout {
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
    (interval.max(0.004), order)
}

/// An optional value must lie within `[lo, hi]` when given.
fn within(v: &mut Validator, key: &str, value: Option<f64>, lo: f64, hi: f64) {
    if let Some(x) = value {
        v.within(key, x, lo, hi);
    }
}

/// A point's coordinates, each within ±`limit`.
fn point(v: &mut Validator, key: &str, p: [f64; 2], limit: f64) {
    for c in p {
        v.within(key, c, -limit, limit);
    }
}

/// The robot (radius `r`) must fit at the start and along every leg of the
/// route; obstacles at most `climb_m` high it drives over.
fn check_placement(
    arena: &Arena,
    r: f64,
    climb_m: f64,
    start: Pose2,
    route: Option<&Route>,
    v: &mut Validator,
) {
    let fits = |p: Vec2| arena.clearance_above(p, r, climb_m) >= r;
    if !fits(start.position()) {
        v.fail(
            "start",
            format!(
                "the robot (radius {r} m) at ({}, {}) overlaps a wall",
                start.x, start.y
            ),
        );
    }
    let Some(route) = route else { return };
    let mut prev = start.position();
    for (i, &w) in route.waypoints.iter().enumerate() {
        let len = (w - prev).norm();
        let n = (len / 0.05).ceil().max(1.0) as usize;
        if let Some(p) = (0..=n)
            .map(|k| prev + (w - prev) * (k as f64 / n as f64))
            .find(|&p| !fits(p))
        {
            v.fail(
                format!("route.waypoints[{i}]"),
                format!(
                    "the leg to ({}, {}) passes ({:.2}, {:.2}), where the robot (radius {r} m) would touch a wall",
                    w.x, w.y, p.x, p.y
                ),
            );
        }
        prev = w;
    }
}

impl ScenarioFile {
    /// Checks every value against its range (and the robot `profile`'s limits).
    fn validate(&self, profile: &RobotConfig, v: &mut Validator) {
        v.non_empty("name", &self.name);
        v.within("duration_s", self.duration_s, 0.001, MAX_DURATION_S);
        if let ArenaFile::Builtin(name) = &self.arena
            && BuiltinArena::from_name(name).is_none()
        {
            v.fail(
                "arena.builtin",
                format!(
                    "unknown arena {name:?} (have: {})",
                    BuiltinArena::ALL.map(|a| a.name()).join(", ")
                ),
            );
        }
        self.start.validate("start", v);
        if let Some(route) = &self.route {
            route.validate(profile.base.max_linear_mps, v);
        }
        self.motion.validate("motion", v);
        self.odometry.validate("odometry", v);
        self.smoke.validate("smoke", v);
        self.laser.validate("laser", v);
        self.sonar.validate("sonar", v);
        self.smoke_sensor.validate("smoke_sensor", v);
        self.truth.validate("truth", v);
    }
}

impl Validate for StartFile {
    fn validate(&self, key: &str, v: &mut Validator) {
        v.within(&format!("{key}.x"), self.x, -1e4, 1e4);
        v.within(&format!("{key}.y"), self.y, -1e4, 1e4);
        v.within(
            &format!("{key}.heading_deg"),
            self.heading_deg,
            -360.0,
            360.0,
        );
    }
}

impl RouteFile {
    fn validate(&self, max_speed_mps: f64, v: &mut Validator) {
        if self.waypoints.is_empty() || self.waypoints.len() > MAX_ITEMS {
            v.fail(
                "route.waypoints",
                format!("needs 1–{MAX_ITEMS} points, got {}", self.waypoints.len()),
            );
        }
        v.within("route.speed_mps", self.speed_mps, 0.01, max_speed_mps);
        v.within("route.lookahead_m", self.lookahead_m, 0.05, 10.0);
        for (i, w) in self.waypoints.iter().enumerate().take(MAX_ITEMS) {
            if !w.iter().all(|c| c.is_finite()) {
                v.fail(format!("route.waypoints[{i}]"), "not a finite point");
            } else {
                // Legs are walked in 5 cm steps: far-off points would take forever.
                point(v, &format!("route.waypoints[{i}]"), *w, 1e4);
            }
        }
    }
}

impl MotionFile {
    /// The drive, with the profile's geometry and limits.
    fn drive(&self, profile: &RobotConfig) -> DriveParams {
        DriveParams {
            track_m: self.track_m.unwrap_or_else(|| default_track(profile)),
            radius_m: profile.robot.radius_m,
            max_linear_mps: profile.base.max_linear_mps,
            max_angular_rps: profile.base.max_angular_dps.to_radians(),
            accel_mps2: self.accel_mps2.unwrap_or(0.3),
            angular_accel_rps2: self.angular_accel_dps2.unwrap_or(100.0).to_radians(),
        }
    }
}

/// The Scout's track is in its profile; the P3-DX's drive wheels are about 33 cm apart (measure yours).
fn default_track(profile: &RobotConfig) -> f64 {
    profile.base.scout.as_ref().map_or(0.33, |s| s.track_m)
}

impl Validate for MotionFile {
    fn validate(&self, key: &str, v: &mut Validator) {
        within(v, &format!("{key}.track_m"), self.track_m, 0.05, 2.0);
        within(v, &format!("{key}.accel_mps2"), self.accel_mps2, 0.01, 10.0);
        within(
            v,
            &format!("{key}.angular_accel_dps2"),
            self.angular_accel_dps2,
            1.0,
            2000.0,
        );
    }
}

impl Validate for OdometryFile {
    fn validate(&self, key: &str, v: &mut Validator) {
        v.within(&format!("{key}.scale_left"), self.scale_left, -0.5, 0.5);
        v.within(&format!("{key}.scale_right"), self.scale_right, -0.5, 0.5);
        v.within(&format!("{key}.track_error"), self.track_error, -0.5, 0.5);
        v.within(
            &format!("{key}.heading_drift_deg_per_m"),
            self.heading_drift_deg_per_m,
            -45.0,
            45.0,
        );
        v.within(
            &format!("{key}.slip_per_sqrt_m"),
            self.slip_per_sqrt_m,
            0.0,
            1.0,
        );
        v.within(
            &format!("{key}.climb_height_m"),
            self.climb_height_m,
            0.0,
            0.2,
        );
        v.within(
            &format!("{key}.bump_heading_deg"),
            self.bump_heading_deg,
            0.0,
            45.0,
        );
        v.within(&format!("{key}.bump_slip_m"), self.bump_slip_m, 0.0, 1.0);
    }
}

impl SmokeFile {
    /// The field's parameters: the file's values over the model's defaults.
    fn params(&self) -> SmokeParams {
        let d = SmokeParams::default();
        let wind = self.wind_mps.unwrap_or([0.0, 0.0]);
        SmokeParams {
            cell_m: self.cell_m.unwrap_or(d.cell_m),
            diffusion_m2ps: self.diffusion_m2ps.unwrap_or(d.diffusion_m2ps),
            decay_per_s: self.decay_per_s.unwrap_or(d.decay_per_s),
            wind_mps: Vec2::new(wind[0], wind[1]),
            layer_height_m: self.layer_height_m.unwrap_or(d.layer_height_m),
            mass_extinction_m2pg: self.mass_extinction_m2pg.unwrap_or(d.mass_extinction_m2pg),
        }
    }
}

impl Validate for SmokeFile {
    fn validate(&self, key: &str, v: &mut Validator) {
        let k = |name: &str| format!("{key}.{name}");
        within(v, &k("cell_m"), self.cell_m, 0.02, 1.0);
        within(v, &k("diffusion_m2ps"), self.diffusion_m2ps, 0.0, 1.0);
        within(v, &k("decay_per_s"), self.decay_per_s, 0.0, 10.0);
        if let Some(w) = self.wind_mps {
            point(v, &k("wind_mps"), w, 5.0);
        }
        within(v, &k("layer_height_m"), self.layer_height_m, 0.1, 20.0);
        within(
            v,
            &k("mass_extinction_m2pg"),
            self.mass_extinction_m2pg,
            0.0,
            100.0,
        );
        if self.source.len() > MAX_ITEMS || self.patch.len() > MAX_ITEMS {
            v.fail(key, format!("at most {MAX_ITEMS} sources and patches"));
            return;
        }
        for (i, src) in self.source.iter().enumerate() {
            src.validate(&format!("{key}.source[{i}]"), v);
        }
        for (i, p) in self.patch.iter().enumerate() {
            let k = format!("{key}.patch[{i}]");
            point(v, &format!("{k}.center"), p.center, 1e4);
            v.within(&format!("{k}.radius_m"), p.radius_m, 0.0, 100.0);
            v.within(&format!("{k}.density_gpm3"), p.density_gpm3, 0.0, 100.0);
        }
    }
}

impl SourceFile {
    fn source(&self) -> SmokeSource {
        SmokeSource {
            position: Vec2::new(self.position[0], self.position[1]),
            radius_m: self.radius_m,
            schedule: self
                .schedule
                .iter()
                .map(|p| Pulse {
                    start_s: p.start_s,
                    duration_s: p.duration_s,
                    rate_gps: p.rate_gps,
                })
                .collect(),
        }
    }
}

impl Validate for SourceFile {
    fn validate(&self, key: &str, v: &mut Validator) {
        point(v, &format!("{key}.position"), self.position, 1e4);
        v.within(&format!("{key}.radius_m"), self.radius_m, 0.0, 20.0);
        if self.schedule.len() > MAX_ITEMS {
            v.fail(format!("{key}.schedule"), "too many pulses");
            return;
        }
        for (j, p) in self.schedule.iter().enumerate() {
            let k = format!("{key}.schedule[{j}]");
            v.within(&format!("{k}.start_s"), p.start_s, 0.0, MAX_DURATION_S);
            v.within(
                &format!("{k}.duration_s"),
                p.duration_s,
                0.0,
                MAX_DURATION_S,
            );
            v.within(&format!("{k}.rate_gps"), p.rate_gps, 0.0, 1000.0);
        }
    }
}

impl Validate for LaserFile {
    fn validate(&self, key: &str, v: &mut Validator) {
        let k = |name: &str| format!("{key}.{name}");
        within(v, &k("height_m"), self.height_m, 0.01, 3.0);
        within(v, &k("lidar_ratio_sr"), self.lidar_ratio_sr, 1.0, 1000.0);
        within(v, &k("wall_reflectance"), self.wall_reflectance, 0.01, 1.0);
        within(v, &k("min_return"), self.min_return, 0.0, 1.0);
        within(v, &k("patchiness"), self.patchiness, 0.0, 3.0);
    }
}

impl Validate for SonarFile {
    fn validate(&self, key: &str, v: &mut Validator) {
        let k = |name: &str| format!("{key}.{name}");
        within(
            v,
            &k("critical_angle_deg"),
            self.critical_angle_deg,
            0.0,
            90.0,
        );
        if let Some(n) = self.rays
            && !(1..=101).contains(&n)
        {
            v.fail(k("rays"), format!("must be 1–101, got {n}"));
        }
        within(v, &k("height_m"), self.height_m, 0.01, 3.0);
        within(v, &k("noise_frac"), self.noise_frac, 0.0, 0.5);
        within(v, &k("dropout_prob"), self.dropout_prob, 0.0, 1.0);
        within(v, &k("crosstalk_prob"), self.crosstalk_prob, 0.0, 1.0);
        within(v, &k("interval_s"), self.interval_s, 0.002, 10.0);
    }
}

impl Validate for SmokeSensorFile {
    fn validate(&self, key: &str, v: &mut Validator) {
        let k = |name: &str| format!("{key}.{name}");
        within(v, &k("rise_tau_s"), self.rise_tau_s, 0.0, 600.0);
        within(v, &k("fall_tau_s"), self.fall_tau_s, 0.0, 3600.0);
        within(v, &k("ppm_per_gpm3"), self.ppm_per_gpm3, 0.0, 1e6);
        within(v, &k("noise_mv"), self.noise_mv, 0.0, 1000.0);
    }
}

impl Validate for TruthFile {
    fn validate(&self, key: &str, v: &mut Validator) {
        within(v, &format!("{key}.rate_hz"), self.rate_hz, 0.1, 1000.0);
        within(
            v,
            &format!("{key}.map_resolution_m"),
            self.map_resolution_m,
            0.005,
            1.0,
        );
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
    fn every_value_problem_is_listed_at_once_with_its_line() {
        let text = MINIMAL.replace("duration_s = 10", "duration_s = -1")
            + "[laser]\npatchiness = -1\n[sonar]\nrays = 0\n";
        let e = Scenario::parse(&text, Path::new("bad.toml")).unwrap_err();
        let SimError::Config(c) = &e else {
            panic!("expected invalid values, got {e:?}")
        };
        assert_eq!(
            c.keys(),
            ["duration_s", "laser.patchiness", "sonar.rays"],
            "{e}"
        );
        let line = |prefix: &str| text.lines().position(|l| l.starts_with(prefix)).unwrap() + 1;
        let msg = e.to_string();
        for (prefix, key) in [
            ("duration_s", "duration_s"),
            ("patchiness", "laser.patchiness"),
            ("rays", "sonar.rays"),
        ] {
            let want = format!("bad.toml:{}: key `{key}`: ", line(prefix));
            assert!(msg.contains(&want), "{want} in {msg}");
        }
    }

    #[test]
    fn placement_problems_are_listed_together() {
        let text = MINIMAL.replace("x = 0.7", "x = 0.1")
            + "[route]\nwaypoints = [[4.5, 0.7]]\n[[smoke.source]]\nposition = [1.5, 0.5]\nschedule = []\n";
        let e = Scenario::parse(&text, Path::new("bad.toml")).unwrap_err();
        let SimError::Config(c) = &e else {
            panic!("expected invalid values, got {e:?}")
        };
        assert_eq!(
            c.keys(),
            ["start", "route.waypoints[0]", "smoke.source[0].position"],
            "{e}"
        );
    }

    #[test]
    fn missing_map_file_is_named() {
        let text = MINIMAL.replace("builtin = \"mrl\"", "map = \"nowhere.yaml\"");
        let e = Scenario::parse(&text, Path::new("/tmp/x/s.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("nowhere.yaml"), "{e}");
    }

    /// A scenario error says where: a key, or the file it could not use.
    fn names_a_key_or_file(e: &SimError) -> bool {
        match e {
            SimError::Config(c) => !c.keys().is_empty() || matches!(c, ConfigError::Io { .. }),
            SimError::Invalid { key, .. } => !key.is_empty(),
            SimError::Io { .. } | SimError::Map(_) => true,
        }
    }

    /// A bundled scenario with the value of one `key = value` line replaced.
    fn mutated(text: &str, line: usize, new: &str) -> String {
        let assignments: Vec<usize> = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim_start().starts_with('#') && l.contains(" = "))
            .map(|(i, _)| i)
            .collect();
        let target = assignments[line % assignments.len()];
        text.lines()
            .enumerate()
            .map(|(i, l)| match l.split_once(" = ") {
                Some((k, _)) if i == target => format!("{k} = {new}"),
                _ => l.to_owned(),
            })
            .collect::<Vec<_>>()
            .join("\n")
    }

    fn value() -> impl proptest::strategy::Strategy<Value = String> {
        use proptest::prelude::*;
        prop_oneof![
            any::<f64>().prop_map(|v| format!("{v:?}")),
            any::<i64>().prop_map(|v| v.to_string()),
            Just("nan".to_owned()),
            Just("1e300".to_owned()),
            Just("\"r3.2\"".to_owned()),
            Just("[]".to_owned()),
            Just("[[1e300, -1e300]]".to_owned()),
            Just("true".to_owned()),
        ]
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(400))]

        #[test]
        fn a_mutated_bundled_scenario_loads_or_names_the_key(
            which in 0usize..BUILTIN_SCENARIOS.len(),
            line in 0usize..500,
            new in value(),
        ) {
            let (name, text) = BUILTIN_SCENARIOS[which];
            let file = PathBuf::from(format!("sim/scenarios/{name}.toml"));
            if let Err(e) = Scenario::parse(&mutated(text, line, &new), &file) {
                proptest::prop_assert!(names_a_key_or_file(&e), "{e:?}");
            }
        }
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
