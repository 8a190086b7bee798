//! The robot's heading relative to a wall beside it, from the sonar that
//! faces it.
//!
//! While smoke blinds the laser, the heading is the odometry's, and wheel
//! slip turns it by a degree or more per metre, randomly (the dense-smoke
//! trial's base: ±5° within 4 m). A transducer at ±90° facing a straight
//! wall reads its perpendicular distance (the wall's normal lies in its
//! cone), and that distance changes with the distance driven as the sine
//! of the angle between the robot and the wall, whatever the odometry
//! turned meanwhile. On the dense-smoke trial's Scout ring (one reading per
//! transducer a second, in whole inches) the angle fitted over 0.8 m was
//! 1.1° RMS from the truth. The wall's own direction is the square
//! building's (see [`crate::frontend`]).
//!
//! The fitted line also gives the wall's distance from the robot's centre
//! now ([`SideFit::range_m`]). Where the laser mapped that wall before the
//! smoke (the front end's local map), that distance places the robot across
//! it outright; the fit's change alone only says how far it drifted since
//! the window began, and an error from before (a slip in the turn into the
//! smoke) stays. On twelve draws of the dense-smoke trial no tuning saw,
//! the graph's map error went from 0.0555 to 0.0530 m with it (9 better).

use smokenav_shared_types::Pose2;
use std::collections::VecDeque;

/// Shortest travel the readings must span, as a share of the window.
const MIN_SPAN_SHARE: f64 = 2.0 / 3.0;
/// Fewest readings in the window.
const MIN_SAMPLES: usize = 5;
/// Largest RMS distance of the readings from the fitted line: more is a
/// door, a corner or a box passing, not one straight wall, m.
const MAX_RMS_M: f64 = 0.012;
/// Largest angle between robot and wall taken as driving along it, rad.
const MAX_RELATIVE_RAD: f64 = 0.14;
/// Largest turn of the odometry's heading within the window, rad: the
/// robot drives along the wall, it does not turn off it. Readings taken
/// more than this away from the newest one's heading are from before a
/// turn and leave the window.
const MAX_TURN_RAD: f64 = 0.12;
/// Largest change between one reading and the next taken as the same
/// wall, m: driving along a wall at up to `MAX_RELATIVE_RAD` the range moves
/// ~4 cm in the second between a Scout transducer's readings; a wall that
/// begins or ends beside the robot (a partition's end, a doorway) moves it
/// by metres. The readings before such a jump are another surface.
const MAX_JUMP_M: f64 = 0.15;
/// Readings kept per side (a scan's each; 1.5 m at 10 Hz and 0.3 m/s is 50).
const CAPACITY: usize = 128;

#[derive(Debug, Clone, Copy, PartialEq)]
struct Sample {
    travel_m: f64,
    range_m: f64,
    heading: f64,
    /// The front end's pose for the scan ([`SideWalls::annotate`]).
    pose: Option<Pose2>,
}

#[derive(Debug, Clone, Default)]
struct Side {
    samples: VecDeque<Sample>,
}

/// A side's readings fitted as one straight wall.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SideFit {
    /// The robot's heading minus the wall's direction, rad.
    pub relative_heading: f64,
    /// How far the robot closed on the wall since the window's first
    /// reading, by the fitted line, m (negative: it moved away).
    pub closed_m: f64,
    /// The front end's pose at the window's first reading.
    pub first_pose: Option<Pose2>,
    /// The wall's distance now, by the fitted line, m (from the robot's
    /// centre when the readings are [`SideSonars::ranges`]).
    pub range_m: f64,
}

/// Tracks the two side transducers' readings against the distance driven.
#[derive(Debug, Clone, Default)]
pub struct SideWalls {
    /// Travel over which a side's readings are fitted, m.
    window_m: f64,
    sides: [Side; 2],
    travel_m: f64,
    last_odom: Option<Pose2>,
}

/// Which side of the robot a transducer faces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SideOf {
    Left = 0,
    Right = 1,
}

impl SideWalls {
    /// Fits the readings of the last `window_m` of travel (`[slam]
    /// side_wall_window_m`).
    pub fn new(window_m: f64) -> Self {
        Self {
            window_m,
            ..Self::default()
        }
    }

    /// Forgets everything (an odometry reset).
    pub fn reset(&mut self) {
        *self = Self::new(self.window_m);
    }

    /// One scan's odometry and its side transducers' ranges (left, right;
    /// `None` where the transducer heard nothing or there is none). A
    /// reading the ring repeats is taken again: a ring that reports whole
    /// inches (the Scout) repeats a value it measured anew, and the fit
    /// needs those.
    pub fn observe(&mut self, odom: &Pose2, ranges: [Option<f64>; 2]) {
        if let Some(last) = self.last_odom.replace(*odom) {
            self.travel_m += last.between(odom).translation_norm();
        }
        for (side, range) in self.sides.iter_mut().zip(ranges) {
            let Some(r) = range.filter(|r| r.is_finite() && *r > 0.0) else {
                side.samples.clear();
                continue;
            };
            // A new surface: the fit starts afresh instead of waiting for
            // the old surface's readings to leave the window.
            if side
                .samples
                .back()
                .is_some_and(|last| (r - last.range_m).abs() > MAX_JUMP_M)
            {
                side.samples.clear();
            }
            if side.samples.len() >= CAPACITY {
                side.samples.pop_front();
            }
            side.samples.push_back(Sample {
                travel_m: self.travel_m,
                range_m: r,
                heading: odom.theta,
                pose: None,
            });
            // Readings from before a turn (a corner, a doorway the robot
            // turned through) are another stretch: kept, they failed the
            // fit until 1.5 m of driving had pushed them out of the window,
            // and the odometry slips most in and just after a turn (10° in
            // the 3 m after one corner of the dense-smoke trial).
            while side.samples.front().is_some_and(|s| {
                self.travel_m - s.travel_m > self.window_m
                    || smokenav_shared_types::normalize_angle(s.heading - odom.theta).abs()
                        > MAX_TURN_RAD
            }) {
                side.samples.pop_front();
            }
        }
    }

    /// The front end's pose for the scan last observed.
    pub fn annotate(&mut self, pose: Pose2) {
        let travel = self.travel_m;
        for side in &mut self.sides {
            if let Some(last) = side.samples.back_mut().filter(|s| s.travel_m == travel) {
                last.pose = Some(pose);
            }
        }
    }

    /// `side`'s readings as one straight wall the robot drives along, if they are.
    pub fn fit(&self, side: SideOf) -> Option<SideFit> {
        let s = &self.sides[side as usize].samples;
        let (first, last) = (s.front()?, s.back()?);
        if self.window_m <= 0.0
            || s.len() < MIN_SAMPLES
            || last.travel_m - first.travel_m < MIN_SPAN_SHARE * self.window_m
        {
            return None;
        }
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for x in s {
            let d = smokenav_shared_types::normalize_angle(x.heading - last.heading);
            lo = lo.min(d);
            hi = hi.max(d);
        }
        if hi - lo > MAX_TURN_RAD {
            return None;
        }
        // Least squares range = a + k · travel.
        let n = s.len() as f64;
        let mt = s.iter().map(|x| x.travel_m).sum::<f64>() / n;
        let mr = s.iter().map(|x| x.range_m).sum::<f64>() / n;
        let (mut stt, mut str) = (0.0, 0.0);
        for x in s {
            stt += (x.travel_m - mt).powi(2);
            str += (x.travel_m - mt) * (x.range_m - mr);
        }
        let k = str / stt;
        let rss: f64 = s
            .iter()
            .map(|x| (x.range_m - mr - k * (x.travel_m - mt)).powi(2))
            .sum();
        if (rss / n).sqrt() > MAX_RMS_M || k.abs() >= 1.0 {
            return None;
        }
        // Turned towards a wall on the left, the robot closes on it.
        let psi = match side {
            SideOf::Left => -k.asin(),
            SideOf::Right => k.asin(),
        };
        (psi.abs() <= MAX_RELATIVE_RAD).then_some(SideFit {
            relative_heading: psi,
            closed_m: -k * (self.travel_m - first.travel_m),
            first_pose: first.pose,
            range_m: mr + k * (self.travel_m - mt),
        })
    }
}

/// Which of the ring's transducers face the sides (their axes within
/// [`SIDE_AXIS_TOLERANCE_RAD`] of ±90°), and the range beyond which a
/// reading is no echo.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SideSonars {
    pub left: Option<u8>,
    pub right: Option<u8>,
    pub max_range_m: f64,
    /// How far out along its axis each side transducer sits from the
    /// robot's centre (left, right), m: added to its readings, they are
    /// the wall's distance from the centre, what a map can be checked with.
    pub axis_offset_m: [f64; 2],
}

/// How far from ±90° a side transducer's axis may point, rad.
pub const SIDE_AXIS_TOLERANCE_RAD: f64 = 0.09;

/// Echoes further than this say little about a wall's angle (±1 % range
/// noise, and the cone's footprint spans more than a door), m.
pub const SIDE_MAX_RANGE_M: f64 = 3.0;

impl SideSonars {
    /// From the ring's `(index, mount in the robot frame)`: the
    /// transducer's position and its axis direction.
    pub fn from_mounts(mounts: impl IntoIterator<Item = (u8, Pose2)>, max_range_m: f64) -> Self {
        let mut out = Self {
            max_range_m: max_range_m.min(SIDE_MAX_RANGE_M),
            ..Self::default()
        };
        let half = std::f64::consts::FRAC_PI_2;
        for (index, mount) in mounts {
            let yaw = smokenav_shared_types::normalize_angle(mount.theta);
            let (s, c) = yaw.sin_cos();
            let offset = mount.x * c + mount.y * s;
            if (yaw - half).abs() <= SIDE_AXIS_TOLERANCE_RAD && out.left.is_none() {
                out.left = Some(index);
                out.axis_offset_m[0] = offset;
            } else if (yaw + half).abs() <= SIDE_AXIS_TOLERANCE_RAD && out.right.is_none() {
                out.right = Some(index);
                out.axis_offset_m[1] = offset;
            }
        }
        out
    }

    /// The side transducers' echoes among a scan's `(index, range)`
    /// readings, as distances from the robot's centre (the reading plus
    /// the transducer's [`Self::axis_offset_m`]).
    pub fn ranges(&self, readings: &[(u8, f64)]) -> [Option<f64>; 2] {
        let pick = |index: Option<u8>, offset: f64| {
            let index = index?;
            readings
                .iter()
                .find(|&&(i, _)| i == index)
                .map(|&(_, r)| r)
                .filter(|r| r.is_finite() && *r > 0.0 && *r < self.max_range_m)
                .map(|r| r + offset)
        };
        [
            pick(self.left, self.axis_offset_m[0]),
            pick(self.right, self.axis_offset_m[1]),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    /// Drives `metres` in 3 cm steps at true heading `psi` to a wall along
    /// x on the left at y = 1.2 (and one on the right at y = −0.8), the
    /// odometry's heading wandering by `jitter` rad.
    fn drive(psi: f64, metres: f64, jitter: f64) -> SideWalls {
        let mut w = SideWalls::new(0.8);
        let (mut x, mut y) = (0.0, 0.0);
        let steps = (metres / 0.03) as usize;
        for i in 0..steps {
            x += 0.03 * psi.cos();
            y += 0.03 * psi.sin();
            let wobble = jitter * (i as f64 * 0.7).sin();
            let odom = Pose2::new(x, y, psi + wobble);
            // The perpendicular distances (the normal is in the cones).
            w.observe(&odom, [Some(1.2 - y), Some(y + 0.8)]);
        }
        w
    }

    #[test]
    fn the_angle_to_a_wall_alongside_comes_from_the_range_change() {
        for psi in [-0.08_f64, -0.02, 0.0, 0.05, 0.1] {
            let w = drive(psi, 1.0, 0.03);
            for side in [SideOf::Left, SideOf::Right] {
                let got = w
                    .fit(side)
                    .map(|f| f.relative_heading)
                    .expect("a straight wall");
                assert!((got - psi).abs() < 1e-6, "{side:?} {psi}: {got}");
            }
        }
    }

    #[test]
    fn too_short_a_stretch_or_a_broken_wall_says_nothing() {
        assert_eq!(
            drive(0.05, 0.3, 0.0)
                .fit(SideOf::Left)
                .map(|f| f.relative_heading),
            None
        );
        let mut w = SideWalls::new(0.8);
        for i in 0..40 {
            let x = 0.03 * f64::from(i);
            // A door: 0.4 m deeper between 0.4 and 0.8 m.
            let r = if (0.4..0.8).contains(&x) { 1.6 } else { 1.2 };
            w.observe(&Pose2::new(x, 0.0, 0.0), [Some(r), None]);
        }
        assert_eq!(w.fit(SideOf::Left).map(|f| f.relative_heading), None);
        assert_eq!(w.fit(SideOf::Right).map(|f| f.relative_heading), None);
    }

    #[test]
    fn a_wall_that_begins_beside_the_robot_is_fitted_once_it_spans_enough_of_the_window() {
        // The far wall of a bay (2.7 m) for the first metre, then a
        // partition 1.2 m away the robot drives along at 0.05 rad: once
        // 0.6 m of it are read (window 0.8 m) the fit is the partition's,
        // though the window still reaches back into the bay.
        let psi = 0.05_f64;
        let mut w = SideWalls::new(0.8);
        let mut fitted_at = None;
        for i in 0..60 {
            let t = 0.03 * f64::from(i);
            let odom = Pose2::new(t, 0.0, 0.0);
            let r = if t < 1.0 {
                2.7
            } else {
                1.2 - (t - 1.0) * psi.sin()
            };
            w.observe(&odom, [Some(r), None]);
            if let Some(f) = w.fit(SideOf::Left).filter(|_| t >= 1.0) {
                assert!(
                    (f.relative_heading - psi).abs() < 1e-6,
                    "{t}: {}",
                    f.relative_heading
                );
                fitted_at.get_or_insert(t);
            }
        }
        let at = fitted_at.expect("the partition is fitted");
        assert!(
            at < 1.0 + 0.8,
            "fitted only once the bay left the window: {at}"
        );
    }

    #[test]
    fn after_a_corner_the_fit_starts_on_the_new_wall() {
        // 1.5 m north along a wall 1 m to the left, a quarter turn to the
        // right on the spot (the range happens to stay 1 m: no jump), then
        // east along the next wall at 0.04 rad. The readings from before
        // the turn leave the window with it: the new wall is fitted after
        // 2/3 of the window (0.8 m), not once the turn has left it.
        let psi = 0.04_f64;
        let mut w = SideWalls::new(0.8);
        for i in 0..50 {
            let odom = Pose2::new(0.0, 0.03 * f64::from(i), FRAC_PI_2);
            w.observe(&odom, [Some(1.0), None]);
        }
        assert!(w.fit(SideOf::Left).is_some(), "the first wall is fitted");
        for i in 1..=10 {
            let odom = Pose2::new(0.0, 1.5, FRAC_PI_2 * (1.0 - f64::from(i) / 10.0));
            w.observe(&odom, [Some(1.0), None]);
        }
        let mut fitted_at = None;
        for i in 1..=40 {
            let t = 0.03 * f64::from(i);
            let odom = Pose2::new(t, 1.5, 0.0);
            w.observe(&odom, [Some(1.0 - t * psi.sin()), None]);
            if let Some(f) = w.fit(SideOf::Left) {
                assert!((f.relative_heading - psi).abs() < 1e-6, "{t}: {f:?}");
                fitted_at.get_or_insert(t);
            }
        }
        let at = fitted_at.expect("the second wall is fitted");
        assert!(at < 0.7, "fitted only once the turn left the window: {at}");
    }

    #[test]
    fn turning_off_the_wall_says_nothing() {
        let mut w = SideWalls::new(0.8);
        let mut th: f64 = 0.0;
        let (mut x, mut y) = (0.0, 0.0);
        for _ in 0..30 {
            th += 0.02;
            x += 0.03 * th.cos();
            y += 0.03 * th.sin();
            w.observe(&Pose2::new(x, y, th), [Some(1.2 - y), None]);
        }
        assert_eq!(w.fit(SideOf::Left).map(|f| f.relative_heading), None);
    }

    #[test]
    fn the_side_transducers_are_those_facing_left_and_right() {
        // The Pioneer's front ring, then its rear ring (both have ±90°).
        let pioneer = [
            90.0, 50.0, 30.0, 10.0, -10.0, -30.0, -50.0, -90.0, -90.0, -130.0, 90.0_f64,
        ];
        let at = |d: f64| Pose2::new(0.0, 0.0, d.to_radians());
        let s = SideSonars::from_mounts(
            pioneer.iter().enumerate().map(|(i, &d)| (i as u8, at(d))),
            5.0,
        );
        assert_eq!(
            (s.left, s.right, s.max_range_m),
            (Some(0), Some(7), SIDE_MAX_RANGE_M)
        );
        // A saturated or far reading is no echo; a missing transducer none.
        assert_eq!(s.ranges(&[(0, 1.2), (7, 4.9)]), [Some(1.2), None]);
        assert_eq!(s.ranges(&[(3, 1.2)]), [None, None]);
        let none = SideSonars::from_mounts([(0, at(0.0)), (1, at(0.6))], 5.0);
        assert_eq!((none.left, none.right), (None, None));
    }

    #[test]
    fn side_ranges_are_the_wall_s_distance_from_the_robot_s_centre() {
        // A ring of radius 0.2 m, its left transducer 0.05 m ahead of the
        // centre (that does not bring it nearer a wall beside the robot).
        let s = SideSonars::from_mounts(
            [
                (0, Pose2::new(0.2, 0.0, 0.0)),
                (1, Pose2::new(0.05, 0.2, FRAC_PI_2)),
                (2, Pose2::new(0.0, -0.2, -FRAC_PI_2)),
            ],
            5.0,
        );
        assert_eq!((s.left, s.right), (Some(1), Some(2)));
        let [left, right] = s.ranges(&[(1, 1.0), (2, 0.5)]);
        assert!((left.unwrap() - 1.2).abs() < 1e-12, "{left:?}");
        assert!((right.unwrap() - 0.7).abs() < 1e-12, "{right:?}");
    }
}
