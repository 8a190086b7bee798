//! The world and its deterministic stepping.
//!
//! Time is an integer count of 1 ms ticks from the scenario's start. Every
//! model advances on that tick grid, and every sensor fires at the first tick
//! at or after its schedule, so the outputs depend only on the scenario, the
//! seed and the commands given — never on how a caller slices time into
//! `step` calls (a fraction of a tick left over is carried to the next call).

use crate::geom::{Pose2, Position, normalize_angle};
use crate::laser::{LaserModel, URG_SCAN_PERIOD_NS, URG_STEPS};
use crate::mq303a::SmokeSensor;
use crate::robot::{Robot, RouteFollower};
use crate::scenario::{Scenario, SonarMount};
use crate::smoke::SmokeField;
use crate::sonar::SonarModel;
use crate::{SimError, TruthSample};
use smokenav_platform_map::OccupancyGrid;
use smokenav_shared_types::Rng;
use std::time::Duration;

/// The simulation tick, ns.
pub const TICK_NS: u64 = 1_000_000;
/// The smoke field (and the MQ303A bead) advance every this many ns.
pub const SMOKE_FIELD_PERIOD_NS: u64 = 50_000_000;

/// Independent random streams, one per model.
mod stream {
    pub const ROBOT: u64 = 1;
    pub const LASER: u64 = 2;
    pub const SONAR: u64 = 3;
    pub const SMOKE_SENSOR: u64 = 4;
}

/// One URG-04LX turn.
#[derive(Debug, Clone, PartialEq)]
pub struct LaserFrame {
    /// Scan counter from 0.
    pub seq: u64,
    /// Sim time of step 0 of this turn, ns; step `s` was measured at
    /// `t_ns + s · 97.66 µs` and the turn ends `URG_SCAN_PERIOD_NS` later.
    pub t_ns: u64,
    /// Steps AMIN (44) … AMAX (725) in mm; values below 20 are URG error codes.
    pub ranges_mm: [u16; URG_STEPS],
}

/// One sonar ping.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SonarSample {
    pub t_ns: u64,
    /// Transducer index as numbered in the robot profile.
    pub index: u8,
    /// Range, m; the sonar's maximum when saturated (what the device reports).
    pub range_m: f64,
    /// No echo came back.
    pub saturated: bool,
}

/// What the base's controller reports.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OdometrySample {
    pub t_ns: u64,
    /// Integrated wheel odometry, in the odometry frame (the start is the origin).
    pub pose: Pose2,
    /// Measured forward velocity, m/s, and turn rate, rad/s, over the last period.
    pub linear_mps: f64,
    pub angular_rps: f64,
    /// Measured wheel speeds over the last period, m/s.
    pub left_mps: f64,
    pub right_mps: f64,
    /// The last motion was blocked by a wall (stall / bumper).
    pub stalled: bool,
}

/// One ADC conversion of the MQ303A.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SmokeSample {
    pub t_ns: u64,
    /// The sensor's output at the ADC pin, mV (with noise).
    pub output_mv: f64,
    /// ADC counts for the profile's `vref_mv` and `adc_bits`.
    pub adc_counts: u32,
    /// True smoke concentration at the robot, g/m³ (ground truth, not a sensor value).
    pub true_density_gpm3: f64,
    /// The same as the sensor's alcohol-equivalent ppm: what an emulator running
    /// its own MQ303A model (with its own dynamics) should be fed instead of `output_mv`.
    pub ambient_ppm: f64,
}

/// Everything the sensors produced during one `step`, in time order per kind.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StepOutput {
    pub laser: Vec<LaserFrame>,
    pub sonar: Vec<SonarSample>,
    pub odometry: Vec<OdometrySample>,
    pub smoke: Vec<SmokeSample>,
    pub truth: Vec<TruthSample>,
}

impl StepOutput {
    pub fn clear(&mut self) {
        self.laser.clear();
        self.sonar.clear();
        self.odometry.clear();
        self.smoke.clear();
        self.truth.clear();
    }

    pub fn is_empty(&self) -> bool {
        self.laser.is_empty()
            && self.sonar.is_empty()
            && self.odometry.is_empty()
            && self.smoke.is_empty()
            && self.truth.is_empty()
    }

    /// Moves `other`'s samples to the end of `self`'s.
    pub fn append(&mut self, other: &mut StepOutput) {
        self.laser.append(&mut other.laser);
        self.sonar.append(&mut other.sonar);
        self.odometry.append(&mut other.odometry);
        self.smoke.append(&mut other.smoke);
        self.truth.append(&mut other.truth);
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Drive {
    Route,
    External,
}

/// A periodic schedule on the tick grid.
#[derive(Debug, Clone, Copy)]
struct Every {
    period_ns: u64,
    next_ns: u64,
}

impl Every {
    fn new(period_ns: u64) -> Self {
        let period_ns = period_ns.max(TICK_NS);
        Self {
            period_ns,
            next_ns: period_ns,
        }
    }

    /// True (once per period) when `now_ns` has reached the schedule.
    fn due(&mut self, now_ns: u64) -> bool {
        if now_ns >= self.next_ns {
            self.next_ns += self.period_ns;
            true
        } else {
            false
        }
    }
}

fn hz_to_ns(hz: f64) -> u64 {
    (1e9 / hz).round() as u64
}

/// A running simulation.
pub struct World {
    scenario: Scenario,
    smoke: SmokeField,
    robot: Robot,
    route: Option<RouteFollower>,
    drive: Drive,
    laser: LaserModel,
    sonar: SonarModel,
    sonar_mounts: Vec<SonarMount>,
    sonar_cursor: usize,
    mq: SmokeSensor,
    now_ns: u64,
    carry_ns: u64,
    field: Every,
    scan: Every,
    scan_start_pose: Pose2,
    scan_start_ns: u64,
    scan_seq: u64,
    ping: Every,
    odom: Every,
    last_odom_pose: Pose2,
    adc: Every,
    truth: Every,
    laser_enabled: bool,
}

impl World {
    pub fn new(scenario: Scenario) -> Result<Self, SimError> {
        let seed = scenario.seed;
        let smoke = scenario.smoke_field()?;
        let robot = Robot::new(
            scenario.drive.clone(),
            scenario.odometry.clone(),
            scenario.start,
            Rng::new(seed, stream::ROBOT),
        );
        let route = scenario.route.as_ref().map(|r| {
            let mut path = vec![scenario.start.position()];
            path.extend_from_slice(&r.waypoints);
            RouteFollower::new(path, r.speed_mps, r.lookahead_m, r.looped)
        });
        let laser = LaserModel::new(
            scenario.laser.clone(),
            scenario.laser_mount,
            Rng::new(seed, stream::LASER),
        );
        let sonar = SonarModel::new(scenario.sonar.clone(), Rng::new(seed, stream::SONAR));
        let mq = SmokeSensor::new(
            scenario.smoke_sensor.clone(),
            Rng::new(seed, stream::SMOKE_SENSOR),
        );
        // Firing order resolved to mounts once.
        let sonar_mounts: Vec<SonarMount> = scenario
            .sonar_order
            .iter()
            .filter_map(|i| {
                scenario
                    .sonar_mounts
                    .iter()
                    .find(|m| m.index == *i)
                    .copied()
            })
            .collect();
        let mut world = Self {
            smoke,
            robot,
            drive: if route.is_some() {
                Drive::Route
            } else {
                Drive::External
            },
            route,
            laser,
            sonar,
            sonar_mounts,
            sonar_cursor: 0,
            mq,
            now_ns: 0,
            carry_ns: 0,
            field: Every::new(SMOKE_FIELD_PERIOD_NS),
            scan: Every::new(URG_SCAN_PERIOD_NS),
            scan_start_pose: scenario.start,
            scan_start_ns: 0,
            scan_seq: 0,
            ping: Every::new((scenario.sonar_interval_s * 1e9).round() as u64),
            odom: Every::new(hz_to_ns(scenario.base_rate_hz)),
            last_odom_pose: Pose2::default(),
            adc: Every::new(hz_to_ns(scenario.smoke_rate_hz)),
            truth: Every::new(hz_to_ns(scenario.truth_rate_hz)),
            laser_enabled: true,
            scenario,
        };
        world.update_route_command();
        Ok(world)
    }

    pub fn scenario(&self) -> &Scenario {
        &self.scenario
    }

    /// Sim time, ns since the start.
    pub fn time_ns(&self) -> u64 {
        self.now_ns
    }

    /// True once the scenario's duration has elapsed.
    pub fn is_finished(&self) -> bool {
        self.now_ns as f64 >= self.scenario.duration_s * 1e9
    }

    /// True when a scripted route exists and has been completed.
    pub fn route_done(&self) -> bool {
        self.route.as_ref().is_some_and(|r| r.done())
    }

    pub fn truth_pose(&self) -> Pose2 {
        self.robot.truth()
    }

    pub fn odometry_pose(&self) -> Pose2 {
        self.robot.odometry()
    }

    pub fn smoke_field(&self) -> &SmokeField {
        &self.smoke
    }

    /// The true map at the scenario's `truth.map_resolution_m`: what the
    /// base must keep clear of. Obstacles on the floor no higher than
    /// `[odometry] climb_height_m` (cables, a cable tray) are left out: the
    /// base drives over them, a map that shows them blocks routes the robot
    /// can take, and SLAMfusion scored its maps against the course without
    /// the ramp it drove over.
    pub fn truth_map(&self) -> OccupancyGrid {
        let (res, start) = (
            self.scenario.truth_map_resolution_m,
            self.scenario.start.position(),
        );
        let climb = self.scenario.odometry.climb_height_m;
        if climb > 0.0 {
            self.scenario
                .arena
                .truth_map_where(res, start, |s| s.z[1] > climb)
        } else {
            self.scenario.arena.truth_map(res, start)
        }
    }

    /// Drives the base by velocity (m/s, rad/s), as a driver's `cmd_vel` would.
    /// From the first call on, the scripted route (if any) no longer steers.
    pub fn set_velocity_command(&mut self, linear_mps: f64, angular_rps: f64) {
        self.drive = Drive::External;
        self.robot.command(linear_mps, angular_rps);
    }

    /// Drives the base by wheel speeds (m/s), as the Scout's `vm` and the
    /// Pioneer's `VEL2` do: v = (l + r)/2, ω = (r − l)/track.
    pub fn set_wheel_command(&mut self, left_mps: f64, right_mps: f64) {
        let track = self.scenario.drive.track_m;
        self.set_velocity_command((left_mps + right_mps) / 2.0, (right_mps - left_mps) / track);
    }

    /// Switches the laser model on or off (on at start). Off, no scans are
    /// computed or emitted (the emulated sensor's laser is off, e.g. after
    /// `QT`), which saves the ray casting; the scan schedule keeps running, so
    /// scans resume on the same 100 ms grid. Its noise stream is not advanced
    /// meanwhile, so later scans differ from a run that kept it on.
    pub fn set_laser_enabled(&mut self, on: bool) {
        self.laser_enabled = on;
    }

    /// Advances by `dt` and returns what the sensors produced meanwhile.
    pub fn step(&mut self, dt: Duration) -> StepOutput {
        let mut out = StepOutput::default();
        self.step_into(dt, &mut out);
        out
    }

    /// As [`World::step`], appending to `out` (reuse it to avoid allocating).
    pub fn step_into(&mut self, dt: Duration, out: &mut StepOutput) {
        let total = self
            .carry_ns
            .saturating_add(dt.as_nanos().min(u64::MAX as u128) as u64);
        let ticks = total / TICK_NS;
        self.carry_ns = total % TICK_NS;
        for _ in 0..ticks {
            self.tick(out);
        }
    }

    fn update_route_command(&mut self) {
        if self.drive != Drive::Route {
            return;
        }
        if let Some(route) = &mut self.route {
            let (v, w) = route.command(&self.robot.truth(), self.scenario.drive.max_angular_rps);
            self.robot.command(v, w);
        }
    }

    fn tick(&mut self, out: &mut StepOutput) {
        let dt = TICK_NS as f64 * 1e-9;
        self.robot.tick(dt, &self.scenario.arena);
        self.now_ns += TICK_NS;
        let now = self.now_ns;

        if self.field.due(now) {
            let period = self.field.period_ns as f64 * 1e-9;
            let t0 = (now - self.field.period_ns) as f64 * 1e-9;
            self.smoke.advance(t0, period);
            let density = self.smoke.density_at(self.robot.truth().position());
            self.mq.update(density, period);
        }

        if self.odom.due(now) {
            let period = self.odom.period_ns as f64 * 1e-9;
            let pose = self.robot.odometry();
            let (l, r) = self.robot.take_wheel_travel();
            let last = self.last_odom_pose;
            let ds = ((pose.x - last.x).powi(2) + (pose.y - last.y).powi(2)).sqrt();
            let heading = normalize_angle(pose.theta - last.theta);
            let forward =
                (pose.x - last.x) * last.theta.cos() + (pose.y - last.y) * last.theta.sin();
            out.odometry.push(OdometrySample {
                t_ns: now,
                pose,
                linear_mps: ds.copysign(forward) / period,
                angular_rps: heading / period,
                left_mps: l / period,
                right_mps: r / period,
                stalled: self.robot.stalled(),
            });
            self.last_odom_pose = pose;
            self.update_route_command();
        }

        if self.ping.due(now) && !self.sonar_mounts.is_empty() {
            let mount = self.sonar_mounts[self.sonar_cursor % self.sonar_mounts.len()];
            self.sonar_cursor = (self.sonar_cursor + 1) % self.sonar_mounts.len();
            let echo = self
                .sonar
                .ping(&self.scenario.arena, &self.robot.truth(), &mount.pose);
            out.sonar.push(SonarSample {
                t_ns: now,
                index: mount.index,
                range_m: echo.range_m,
                saturated: echo.saturated,
            });
        }

        if self.scan.due(now) {
            let end = self.robot.truth();
            if self.laser_enabled {
                let mut ranges = [0u16; URG_STEPS];
                self.laser.set_pitch(self.robot.pitch());
                self.laser.scan(
                    &self.scenario.arena,
                    &self.smoke,
                    &self.scan_start_pose,
                    &end,
                    &mut ranges,
                );
                out.laser.push(LaserFrame {
                    seq: self.scan_seq,
                    t_ns: self.scan_start_ns,
                    ranges_mm: ranges,
                });
                self.scan_seq += 1;
            }
            self.scan_start_pose = end;
            self.scan_start_ns = now;
        }

        if self.adc.due(now) {
            let (mv, counts) = self
                .mq
                .sample(self.scenario.adc_vref_mv, self.scenario.adc_bits);
            let density = self.smoke.density_at(self.robot.truth().position());
            out.smoke.push(SmokeSample {
                t_ns: now,
                output_mv: mv,
                adc_counts: counts,
                true_density_gpm3: density,
                ambient_ppm: self.mq.ppm_of(density),
            });
        }

        if self.truth.due(now) {
            let pose = self.robot.truth();
            out.truth.push(TruthSample {
                t_ns: now,
                pose,
                smoke_gpm3: self.smoke.density_at(pose.position()),
            });
        }
    }
}
