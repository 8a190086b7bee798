//! A differential-drive base: true motion with acceleration limits and
//! collisions, and the wheel odometry it reports, with configurable errors.

use crate::arena::Arena;
use crate::geom::{Pose2, Position, Vec2, normalize_angle};
use smokenav_shared_types::Rng;

#[derive(Debug, Clone, PartialEq)]
pub struct DriveParams {
    /// Distance between the drive wheels, m.
    pub track_m: f64,
    /// Footprint radius, m (collisions).
    pub radius_m: f64,
    pub max_linear_mps: f64,
    pub max_angular_rps: f64,
    /// Translational acceleration limit, m/s² (ARIA's P3-DX default is 0.3).
    pub accel_mps2: f64,
    /// Rotational acceleration limit, rad/s² (ARIA's P3-DX default is 100°/s²).
    pub angular_accel_rps2: f64,
}

/// Systematic and random odometry errors (Borenstein & Feng's classes:
/// unequal wheel diameters, wrong effective track, and non-systematic slip).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct OdometryErrors {
    /// Left wheel travel read this fraction too long (negative: too short).
    pub scale_left: f64,
    /// Right wheel likewise.
    pub scale_right: f64,
    /// The controller's track differs from the real one by this fraction, so
    /// turns integrate wrong (effective wheelbase error).
    pub track_error: f64,
    /// Heading drift while driving, rad per metre travelled (floor tilt, tyre wear).
    pub heading_drift_rad_per_m: f64,
    /// Random wheel slip: 1σ travel error of each wheel per √m of its travel.
    pub slip_per_sqrt_m: f64,
    /// Obstacles whose top is at most this high (cables, a cable tray, a
    /// sill) are driven over rather than bumped into, m; 0: none.
    pub climb_height_m: f64,
    /// Each time the base climbs onto or off such an obstacle its true
    /// heading jolts by this much (1σ, rad), unseen by the encoders.
    pub bump_heading_rad: f64,
    /// … and one wheel's encoder counts this much travel that did not happen
    /// (1σ, m: the wheel spins while climbing).
    pub bump_slip_m: f64,
}

#[derive(Debug, Clone)]
pub struct Robot {
    pub params: DriveParams,
    pub errors: OdometryErrors,
    truth: Pose2,
    /// Actual velocities.
    linear: f64,
    angular: f64,
    /// Commanded velocities (already clamped).
    cmd_linear: f64,
    cmd_angular: f64,
    /// Odometry pose, in the odometry frame (starts at the origin).
    odom: Pose2,
    /// Measured wheel travel since the last `take_wheel_travel`, m.
    travel_left: f64,
    travel_right: f64,
    stalled: bool,
    rng: Rng,
    /// Bumps draw from their own stream: an arena without low obstacles
    /// keeps the very same motion as before bumps existed.
    bump_rng: Rng,
    /// On a low obstacle at the last tick.
    on_low: bool,
    bumps: u64,
    /// Nose-down pitch of the base, rad (negative: nose up): a base with one
    /// end on a cable or tray is tilted, and so is the laser's scan plane.
    pitch: f64,
}

impl Robot {
    pub fn new(params: DriveParams, errors: OdometryErrors, start: Pose2, rng: Rng) -> Self {
        Self {
            params,
            errors,
            truth: start,
            linear: 0.0,
            angular: 0.0,
            cmd_linear: 0.0,
            cmd_angular: 0.0,
            odom: Pose2::default(),
            travel_left: 0.0,
            travel_right: 0.0,
            stalled: false,
            bump_rng: Rng::new(rng.clone().next_u64(), 0xb0b),
            rng,
            on_low: false,
            bumps: 0,
            pitch: 0.0,
        }
    }

    /// Nose-down pitch of the base, rad (negative: nose up; 0 on a level floor).
    pub fn pitch(&self) -> f64 {
        self.pitch
    }

    /// Times the base climbed onto or off a low obstacle.
    pub fn bumps(&self) -> u64 {
        self.bumps
    }

    /// Sets the velocity the base should reach (clamped to the platform's limits).
    pub fn command(&mut self, linear_mps: f64, angular_rps: f64) {
        let lin = if linear_mps.is_finite() {
            linear_mps
        } else {
            0.0
        };
        let ang = if angular_rps.is_finite() {
            angular_rps
        } else {
            0.0
        };
        self.cmd_linear = lin.clamp(-self.params.max_linear_mps, self.params.max_linear_mps);
        self.cmd_angular = ang.clamp(-self.params.max_angular_rps, self.params.max_angular_rps);
    }

    pub fn truth(&self) -> Pose2 {
        self.truth
    }

    pub fn odometry(&self) -> Pose2 {
        self.odom
    }

    /// Actual (linear, angular) velocity.
    pub fn velocity(&self) -> (f64, f64) {
        (self.linear, self.angular)
    }

    /// True when the last motion was blocked by a wall.
    pub fn stalled(&self) -> bool {
        self.stalled
    }

    /// Measured wheel travel (left, right) since the last call, m.
    pub fn take_wheel_travel(&mut self) -> (f64, f64) {
        let t = (self.travel_left, self.travel_right);
        self.travel_left = 0.0;
        self.travel_right = 0.0;
        t
    }

    /// The pitch at the current pose: an end of the base (the front or the
    /// rear half of its footprint) on a low obstacle and the other on the
    /// floor tilts it by atan(top / footprint diameter); both ends on it, or
    /// neither, leave it level.
    fn pitch_over(&self, arena: &Arena) -> f64 {
        let climb = self.errors.climb_height_m;
        if climb <= 0.0 {
            return 0.0;
        }
        let half = self.params.radius_m / 2.0;
        let heading = Vec2::from_angle(self.truth.theta);
        let at = |sign: f64| {
            arena.low_obstacle_top_within(
                self.truth.position() + heading * (sign * half),
                half,
                climb,
            )
        };
        let length = 2.0 * self.params.radius_m;
        match (at(1.0), at(-1.0)) {
            (Some(top), None) => -(top / length).atan(),
            (None, Some(top)) => (top / length).atan(),
            _ => 0.0,
        }
    }

    /// Advances `dt` seconds.
    pub fn tick(&mut self, dt: f64, arena: &Arena) {
        // Random draws first and always, so their number never depends on the motion.
        let slip_l = self.rng.normal();
        let slip_r = self.rng.normal();
        let approach =
            |v: f64, target: f64, max_step: f64| v + (target - v).clamp(-max_step, max_step);
        self.linear = approach(self.linear, self.cmd_linear, self.params.accel_mps2 * dt);
        self.angular = approach(
            self.angular,
            self.cmd_angular,
            self.params.angular_accel_rps2 * dt,
        );
        let ds = self.linear * dt;
        let dth = self.angular * dt;
        if ds == 0.0 && dth == 0.0 {
            self.stalled = false;
            return;
        }
        // Exact arc for constant velocities over the tick.
        let th = self.truth.theta;
        let (dx, dy) = if dth.abs() < 1e-9 {
            (ds * th.cos(), ds * th.sin())
        } else {
            let r = ds / dth;
            (
                r * ((th + dth).sin() - th.sin()),
                -r * ((th + dth).cos() - th.cos()),
            )
        };
        let next = Pose2::new(
            self.truth.x + dx,
            self.truth.y + dy,
            normalize_angle(th + dth),
        );
        let r = self.params.radius_m;
        let climb = self.errors.climb_height_m;
        let ahead = arena.clearance_above(next.position(), r, climb);
        // Touching a wall blocks motion into it, never motion away from it.
        let blocked = ahead < r && ahead < arena.clearance_above(self.truth.position(), r, climb);
        if blocked {
            // A bumper stop: the base stalls and the wheels do not turn.
            self.linear = 0.0;
            self.angular = 0.0;
            self.stalled = true;
            return;
        }
        self.stalled = false;
        self.truth = next;
        // Climbing onto or off a cable: a heading jolt the encoders do not
        // see, and a wheel that spins (seed 004's robot driving over small
        // obstacles). The wheels touch it within half the track of the centre.
        let on_low = arena.low_obstacle_within(next.position(), self.params.track_m / 2.0, climb);
        let (mut spin_l, mut spin_r) = (0.0, 0.0);
        if on_low != self.on_low {
            self.on_low = on_low;
            self.bumps += 1;
            let jolt = self.bump_rng.gaussian(self.errors.bump_heading_rad);
            self.truth.theta = normalize_angle(self.truth.theta + jolt);
            let spin = self.bump_rng.gaussian(self.errors.bump_slip_m).abs();
            if self.bump_rng.chance(0.5) {
                spin_l = spin;
            } else {
                spin_r = spin;
            }
        }
        self.pitch = self.pitch_over(arena);
        // What the encoders count.
        let b = self.params.track_m;
        let (true_l, true_r) = (ds - dth * b / 2.0, ds + dth * b / 2.0);
        let e = &self.errors;
        let meas_l = true_l * (1.0 + e.scale_left)
            + e.slip_per_sqrt_m * true_l.abs().sqrt() * slip_l
            + spin_l * ds.signum();
        let meas_r = true_r * (1.0 + e.scale_right)
            + e.slip_per_sqrt_m * true_r.abs().sqrt() * slip_r
            + spin_r * ds.signum();
        self.travel_left += meas_l;
        self.travel_right += meas_r;
        // The controller integrates with the track it believes in.
        let ods = (meas_l + meas_r) / 2.0;
        let odth =
            (meas_r - meas_l) / (b * (1.0 + e.track_error)) + e.heading_drift_rad_per_m * ods.abs();
        let oth = self.odom.theta + odth / 2.0;
        self.odom = Pose2::new(
            self.odom.x + ods * oth.cos(),
            self.odom.y + ods * oth.sin(),
            normalize_angle(self.odom.theta + odth),
        );
    }
}

/// A scripted route followed by pure pursuit (Coulter, "Implementation of the
/// pure pursuit path tracking algorithm", CMU-RI-TR-92-01): steer along the
/// arc through a point one look-ahead distance down the path; turn in place
/// first when that point lies well off the heading.
#[derive(Debug, Clone)]
pub struct RouteFollower {
    path: Vec<Vec2>,
    pub speed_mps: f64,
    pub lookahead_m: f64,
    pub looped: bool,
    /// Index of the path segment being followed.
    seg: usize,
    done: bool,
}

/// Within this of the last waypoint, the route is finished, m.
const GOAL_TOLERANCE_M: f64 = 0.08;
/// Heading errors above this turn the robot in place first.
const TURN_IN_PLACE_RAD: f64 = 1.0;

impl RouteFollower {
    /// `path` starts at the robot's start position.
    pub fn new(path: Vec<Vec2>, speed_mps: f64, lookahead_m: f64, looped: bool) -> Self {
        let done = path.len() < 2;
        Self {
            path,
            speed_mps,
            lookahead_m,
            looped,
            seg: 0,
            done,
        }
    }

    pub fn done(&self) -> bool {
        self.done
    }

    /// Velocity command (linear m/s, angular rad/s) for the robot at `pose`.
    pub fn command(&mut self, pose: &Pose2, max_angular: f64) -> (f64, f64) {
        if self.done {
            return (0.0, 0.0);
        }
        let p = pose.position();
        let n = self.path.len();
        // Advance past segments whose end is already behind us.
        loop {
            let (a, b) = (self.path[self.seg], self.path[(self.seg + 1) % n]);
            let ab = b - a;
            let len2 = ab.dot(ab).max(1e-12);
            let s = (p - a).dot(ab) / len2;
            let last = !self.looped && self.seg + 2 >= n;
            if (s >= 1.0 || (b - p).norm() < self.lookahead_m) && !last {
                self.seg = (self.seg + 1) % if self.looped { n } else { n - 1 };
                continue;
            }
            break;
        }
        let goal = self.path[n - 1];
        if !self.looped && self.seg + 2 >= n && (goal - p).norm() < GOAL_TOLERANCE_M {
            self.done = true;
            return (0.0, 0.0);
        }
        let target = self.lookahead_point(p);
        let to = target - p;
        let alpha = normalize_angle(to.y.atan2(to.x) - pose.theta);
        if alpha.abs() > TURN_IN_PLACE_RAD {
            return (0.0, alpha.signum() * max_angular * 0.6);
        }
        let dist = to.norm().max(1e-6);
        // Slow down towards the end of the route.
        let remaining = if !self.looped && self.seg + 2 >= n {
            (goal - p).norm()
        } else {
            f64::INFINITY
        };
        let mut v = self.speed_mps * alpha.cos().max(0.2) * (remaining / 0.5).clamp(0.15, 1.0);
        let mut w = 2.0 * v * alpha.sin() / dist;
        if w.abs() > max_angular {
            v *= max_angular / w.abs();
            w = w.signum() * max_angular;
        }
        (v, w)
    }

    fn lookahead_point(&self, p: Vec2) -> Vec2 {
        let n = self.path.len();
        let (a, b) = (self.path[self.seg], self.path[(self.seg + 1) % n]);
        let ab = b - a;
        let len = ab.norm().max(1e-12);
        let s = ((p - a).dot(ab) / (len * len)).clamp(0.0, 1.0);
        let mut left = self.lookahead_m;
        let mut cur = a + ab * s;
        let mut seg = self.seg;
        loop {
            let end = self.path[(seg + 1) % n];
            let d = (end - cur).norm();
            if d >= left {
                return cur + (end - cur) * (left / d);
            }
            left -= d;
            cur = end;
            seg += 1;
            if !self.looped && seg + 1 >= n {
                return cur;
            }
            if self.looped && seg >= self.seg + n {
                return cur;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::arena::BuiltinArena;
    use std::f64::consts::PI;

    fn params() -> DriveParams {
        DriveParams {
            track_m: 0.33,
            radius_m: 0.26,
            max_linear_mps: 0.5,
            max_angular_rps: 1.0,
            accel_mps2: 0.3,
            angular_accel_rps2: 100f64.to_radians(),
        }
    }

    fn run(robot: &mut Robot, arena: &Arena, secs: f64) {
        for _ in 0..(secs * 1000.0).round() as usize {
            robot.tick(0.001, arena);
        }
    }

    #[test]
    fn perfect_odometry_matches_truth() {
        let arena = BuiltinArena::R32.load().unwrap();
        let mut r = Robot::new(
            params(),
            OdometryErrors::default(),
            Pose2::new(1.0, 1.0, PI / 2.0),
            Rng::new(1, 1),
        );
        r.command(0.3, 0.2);
        run(&mut r, &arena, 5.0);
        let (t, o) = (r.truth(), r.odometry());
        // Odometry frame starts at the origin heading 0: rotate back by the start pose.
        let rel = (t.position() - Vec2::new(1.0, 1.0)).rotated(-PI / 2.0);
        assert!(
            (rel.x - o.x).abs() < 1e-4 && (rel.y - o.y).abs() < 1e-4,
            "{rel:?} vs {o:?}"
        );
        assert!((normalize_angle(t.theta - PI / 2.0) - o.theta).abs() < 1e-6);
    }

    #[test]
    fn wheel_scale_error_curves_a_straight_run() {
        let arena = BuiltinArena::Corridor.load().unwrap();
        let errors = OdometryErrors {
            scale_right: 0.01,
            ..Default::default()
        };
        let mut r = Robot::new(params(), errors, Pose2::new(1.0, 1.0, 0.0), Rng::new(1, 1));
        r.command(0.4, 0.0);
        run(&mut r, &arena, 20.0);
        let (t, o) = (r.truth(), r.odometry());
        assert!((t.y - 1.0).abs() < 1e-9, "truth runs straight");
        // Right wheel 1 % long: the heading drifts left by 0.01·d/track, ≈ 0.23 rad over 7.7 m.
        let d = t.x - 1.0;
        let expect = 0.01 * d / 0.33;
        assert!(
            (o.theta - expect).abs() < 0.01,
            "odom heading {} vs {expect}",
            o.theta
        );
    }

    #[test]
    fn slip_noise_grows_like_the_square_root_of_distance() {
        let arena = BuiltinArena::Corridor.load().unwrap();
        let errors = OdometryErrors {
            slip_per_sqrt_m: 0.02,
            ..Default::default()
        };
        let mut spread = 0.0;
        let runs = 40;
        for seed in 0..runs {
            let mut r = Robot::new(
                params(),
                errors.clone(),
                Pose2::new(1.0, 1.0, 0.0),
                Rng::new(seed, 7),
            );
            r.command(0.4, 0.0);
            run(&mut r, &arena, 10.0);
            let (l, rr) = r.take_wheel_travel();
            let truth = r.truth().x - 1.0;
            spread += (l - truth).powi(2) + (rr - truth).powi(2);
        }
        let sd = (spread / (2.0 * runs as f64)).sqrt();
        let d: f64 = 3.8; // ≈ distance with the acceleration ramp
        assert!((sd / (0.02 * d.sqrt()) - 1.0).abs() < 0.35, "sd {sd}");
    }

    /// A 4 m corridor-like room with a 3 cm cable across the way at x = 3 and
    /// a 20 cm crate further on at x = 6.
    fn cable_room() -> Arena {
        Arena::from_vector_str(
            "[[wall]]\npoints = [[0.0, 0.0], [9.0, 0.0], [9.0, 4.0], [0.0, 4.0]]\nclosed = true\n\
             [[box]]\ncenter = [3.0, 2.0]\nsize = [0.04, 4.0]\nheight_m = [0.0, 0.03]\n\
             [[box]]\ncenter = [6.0, 2.0]\nsize = [0.6, 4.0]\nheight_m = [0.0, 0.2]\n",
            std::path::Path::new("cable.toml"),
        )
        .unwrap()
    }

    #[test]
    fn the_base_tilts_nose_up_then_nose_down_over_a_cable_and_is_level_after() {
        let arena = cable_room();
        let errors = OdometryErrors {
            climb_height_m: 0.05,
            ..Default::default()
        };
        let mut r = Robot::new(params(), errors, Pose2::new(1.0, 2.0, 0.0), Rng::new(3, 1));
        r.command(0.4, 0.0);
        let (mut up, mut down) = (0.0f64, 0.0f64);
        let mut order = Vec::new();
        for _ in 0..12_000 {
            r.tick(0.001, &arena);
            let p = r.pitch();
            up = up.min(p);
            down = down.max(p);
            let sign = p.signum() as i8 * i8::from(p != 0.0);
            if order.last() != Some(&sign) {
                order.push(sign);
            }
        }
        assert!(r.truth().x > 3.6, "past the cable: {:?}", r.truth());
        // A 3 cm cable under one end of a 0.52 m base: atan(0.03 / 0.52) = 3.3°.
        let tilt = (0.03f64 / 0.52).atan();
        assert!((up + tilt).abs() < 1e-9, "nose up {up}");
        assert!((down - tilt).abs() < 1e-9, "nose down {down}");
        assert_eq!(
            order,
            [0, -1, 0, 1, 0],
            "level, front up, on it, rear up, level"
        );
        assert_eq!(r.pitch(), 0.0);
        // An arena without climbing never tilts the base.
        let mut flat = Robot::new(
            params(),
            OdometryErrors::default(),
            Pose2::new(1.0, 2.0, 0.0),
            Rng::new(3, 1),
        );
        flat.command(0.4, 0.0);
        for _ in 0..5_000 {
            flat.tick(0.001, &arena);
            assert_eq!(flat.pitch(), 0.0);
        }
    }

    #[test]
    fn the_base_drives_over_a_cable_with_a_bump_but_not_over_a_crate() {
        let arena = cable_room();
        let errors = OdometryErrors {
            climb_height_m: 0.05,
            bump_heading_rad: 3f64.to_radians(),
            bump_slip_m: 0.05,
            ..Default::default()
        };
        let mut r = Robot::new(params(), errors, Pose2::new(1.0, 2.0, 0.0), Rng::new(3, 1));
        r.command(0.4, 0.0);
        run(&mut r, &arena, 20.0);
        let (t, o) = (r.truth(), r.odometry());
        assert!(t.x > 3.3, "over the cable: {t:?}");
        assert!(
            r.stalled() && t.x < 6.0 - 0.3 + 1e-6,
            "stopped by the crate: {t:?}"
        );
        assert_eq!(r.bumps(), 2, "onto the cable and off it");
        // The truth turned where the odometry saw nothing, and a wheel spun.
        assert!(t.theta.abs() > 1e-4 && (t.y - 2.0).abs() > 1e-4, "{t:?}");
        assert!((o.x - (t.x - 1.0)).abs() > 1e-3 || (o.theta - t.theta).abs() > 1e-4);
        // With no climbing the cable is a wall like any other.
        let mut stuck = Robot::new(
            params(),
            OdometryErrors::default(),
            Pose2::new(1.0, 2.0, 0.0),
            Rng::new(3, 1),
        );
        stuck.command(0.4, 0.0);
        run(&mut stuck, &arena, 20.0);
        assert!(
            stuck.stalled() && stuck.truth().x < 3.0,
            "{:?}",
            stuck.truth()
        );
        assert_eq!(stuck.bumps(), 0);
    }

    #[test]
    fn bumps_leave_the_other_random_draws_alone() {
        // Same seed, one arena with a cable and climbing, one without: up to
        // the cable the two runs are bit for bit the same.
        let errors = OdometryErrors {
            slip_per_sqrt_m: 0.02,
            climb_height_m: 0.05,
            bump_heading_rad: 0.05,
            bump_slip_m: 0.05,
            ..Default::default()
        };
        let plain = BuiltinArena::Corridor.load().unwrap();
        let mut a = Robot::new(
            params(),
            errors.clone(),
            Pose2::new(1.0, 1.0, 0.0),
            Rng::new(5, 1),
        );
        let mut b = Robot::new(params(), errors, Pose2::new(1.0, 1.0, 0.0), Rng::new(5, 1));
        a.command(0.4, 0.0);
        b.command(0.4, 0.0);
        let cable = cable_room();
        run(&mut a, &cable, 4.0);
        run(&mut b, &plain, 4.0);
        assert!(a.truth().x < 2.6);
        assert_eq!(a.truth(), b.truth());
        assert_eq!(a.odometry(), b.odometry());
    }

    #[test]
    fn wall_stops_the_robot_and_reports_a_stall() {
        let arena = BuiltinArena::Corridor.load().unwrap();
        let mut r = Robot::new(
            params(),
            OdometryErrors::default(),
            Pose2::new(1.0, 1.0, PI / 2.0),
            Rng::new(1, 1),
        );
        r.command(0.3, 0.0);
        run(&mut r, &arena, 6.0);
        assert!(r.stalled());
        assert!(r.truth().y <= 2.0 - 0.26 + 1e-6, "{:?}", r.truth());
        assert!(r.truth().y > 1.6);
    }

    #[test]
    fn pure_pursuit_drives_an_l_shaped_route() {
        let arena = BuiltinArena::R32.load().unwrap();
        let start = Pose2::new(1.0, 1.0, PI / 2.0);
        let mut r = Robot::new(params(), OdometryErrors::default(), start, Rng::new(1, 1));
        let mut route = RouteFollower::new(
            vec![
                Vec2::new(1.0, 1.0),
                Vec2::new(1.0, 3.0),
                Vec2::new(3.4, 3.0),
            ],
            0.3,
            0.5,
            false,
        );
        let mut max_dev: f64 = 0.0;
        for k in 0..60_000 {
            if k % 100 == 0 {
                let (v, w) = route.command(&r.truth(), 1.0);
                r.command(v, w);
            }
            r.tick(0.001, &arena);
            let p = r.truth();
            let dev = if p.y < 2.5 {
                (p.x - 1.0).abs()
            } else {
                (p.y - 3.0).abs().min((p.x - 1.0).abs())
            };
            max_dev = max_dev.max(dev);
            if route.done() {
                break;
            }
        }
        assert!(route.done(), "route not finished: {:?}", r.truth());
        assert!((r.truth().position() - Vec2::new(3.4, 3.0)).norm() < 0.1);
        assert!(max_dev < 0.3, "cross-track deviation {max_dev}");
    }
}
