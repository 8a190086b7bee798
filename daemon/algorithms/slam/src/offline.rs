//! Offline input for the pipeline: a CARMEN log (scans with the odometry pose
//! the logger attached; bad lines counted and kept, the first few, for the
//! report), and recorded bus messages replayed in receive order exactly as
//! the SLAM process handles them live.

use crate::backend::SlamUpdate;
use crate::carmen::{CarmenError, CarmenReader, LineError, Record};
use crate::pipeline::SlamPipeline;
use crate::scan::RangeScan;
use smokenav_shared_types::Pose2;
use smokenav_shared_types::{FusedScan, LaserScan, Odometry};
use std::io::BufRead;

/// A message the SLAM process subscribes to.
#[derive(Debug, Clone, Copy)]
pub enum Received<'a> {
    Odometry(&'a Odometry),
    Fused(&'a FusedScan),
    Laser(&'a LaserScan),
}

/// Feeds `(receive time ns, message)` pairs in receive order through the
/// pipeline, polling after each one at its receive time as the process polls
/// after each wake-up, then flushes the scan still waiting at the end.
/// `on_update` sees every update in order.
pub fn replay<'a>(
    pipeline: &mut SlamPipeline,
    received: impl IntoIterator<Item = (u64, Received<'a>)>,
    mut on_update: impl FnMut(&SlamUpdate),
) {
    for (now_ns, message) in received {
        match message {
            Received::Odometry(o) => pipeline.push_odom(o),
            Received::Fused(f) => pipeline.push_fused(f),
            Received::Laser(l) => pipeline.push_laser(l),
        }
        if let Some(u) = pipeline.poll(now_ns) {
            on_update(&u);
        }
    }
    if let Some(u) = pipeline.flush() {
        on_update(&u);
    }
}

/// Bad lines kept for the report; later ones are only counted.
pub const KEPT_ERRORS: usize = 100;

/// Limits past which a log's odometry cannot be real motion.
///
/// Generous on purpose: real logs glitch (MIT CSAIL's raw odometry has a
/// 0.94 m step in 0.21 s, 4.5 m/s, and a 1.49 rad turn in one record), and
/// those are the matcher's to absorb. What the gate refuses is what no robot
/// does: metres per record, stamps running backwards, kilometre coordinates
/// from a flipped digit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OdometryLimits {
    /// Fastest plausible travel, m/s.
    pub max_speed_mps: f64,
    /// Travel allowed whatever the time step, m (stamps are coarse).
    pub slack_m: f64,
    /// Largest plausible coordinate, m or rad.
    pub max_abs: f64,
    /// Consecutive records that agree with each other but not with the last
    /// accepted one: taken as the odometry frame jumping (a reset), not as
    /// corruption.
    pub reset_after: usize,
}

impl Default for OdometryLimits {
    fn default() -> Self {
        Self {
            max_speed_mps: 10.0,
            slack_m: 0.5,
            max_abs: 1.0e5,
            reset_after: 3,
        }
    }
}

/// Why a record's odometry was refused.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum ImplausibleOdometry {
    #[error("odometry ({x:.3}, {y:.3}, {theta:.3}) is beyond ±{max_abs} (a corrupt record?)")]
    OutOfBounds {
        x: f64,
        y: f64,
        theta: f64,
        max_abs: f64,
    },
    #[error("timestamp goes back {back_s:.3} s from the previous scan")]
    StampBackwards { back_s: f64 },
    #[error(
        "odometry jumps {jump_m:.2} m in {dt_s:.3} s (at most {allowed_m:.2} m is plausible): \
         scan skipped"
    )]
    Jump {
        jump_m: f64,
        dt_s: f64,
        allowed_m: f64,
    },
}

/// Screens the odometry a log attaches to its scans: refuses single corrupt
/// records, and stitches a run of records that agree among themselves onto
/// the trajectory so far (an odometry reset), so the jump is never taken as
/// motion.
#[derive(Debug, Clone)]
pub struct OdometryGate {
    limits: OdometryLimits,
    /// The last accepted record, as published (after stitching).
    last: Option<(u64, Pose2)>,
    /// Refused records since, raw, when they agree with each other.
    suspects: Vec<(u64, Pose2)>,
    /// Maps the log's odometry frame to the published one.
    stitch: Pose2,
    /// Resets detected.
    pub resets: usize,
    /// The coarsest step the log's stamps can show, ns: two records under
    /// one stamp may be that far apart in time.
    stamp_resolution_ns: u64,
}

impl OdometryGate {
    pub fn new(limits: OdometryLimits) -> Self {
        Self {
            limits,
            last: None,
            suspects: Vec::with_capacity(limits.reset_after),
            stitch: Pose2::default(),
            resets: 0,
            stamp_resolution_ns: 1,
        }
    }

    /// Widens the time between records by the stamps' resolution (see
    /// [`crate::carmen::stamp_resolution_ns`]): GMapping writes its corrected
    /// logs with `%g` stamps, every record of a run under one or two values,
    /// and a speed check against 0 s would refuse every step. Only ever grows.
    pub fn note_stamp_resolution(&mut self, resolution_ns: u64) {
        self.stamp_resolution_ns = self.stamp_resolution_ns.max(resolution_ns);
    }

    /// See [`Self::note_stamp_resolution`].
    pub fn stamp_resolution_ns(&self) -> u64 {
        self.stamp_resolution_ns
    }

    fn step(&self, from: (u64, Pose2), to: (u64, Pose2)) -> Result<(), ImplausibleOdometry> {
        if to.0 < from.0 {
            return Err(ImplausibleOdometry::StampBackwards {
                back_s: (from.0 - to.0) as f64 / 1e9,
            });
        }
        let dt_s = (to.0 - from.0) as f64 / 1e9;
        let jump_m = from.1.between(&to.1).translation_norm();
        let longest_s = dt_s + self.stamp_resolution_ns.saturating_sub(1) as f64 / 1e9;
        let allowed_m = self.limits.slack_m + self.limits.max_speed_mps * longest_s;
        if jump_m > allowed_m {
            return Err(ImplausibleOdometry::Jump {
                jump_m,
                dt_s,
                allowed_m,
            });
        }
        Ok(())
    }

    /// The odometry to use for a scan stamped `stamp_ns`, or why the record
    /// is refused (the scan is then skipped).
    pub fn check(&mut self, stamp_ns: u64, raw: Pose2) -> Result<Pose2, ImplausibleOdometry> {
        let m = self.limits.max_abs;
        if !(raw.x.abs() <= m && raw.y.abs() <= m && raw.theta.abs() <= m) {
            return Err(ImplausibleOdometry::OutOfBounds {
                x: raw.x,
                y: raw.y,
                theta: raw.theta,
                max_abs: m,
            });
        }
        let pose = self.stitch.compose(&raw);
        let Some(last) = self.last else {
            self.last = Some((stamp_ns, pose));
            return Ok(pose);
        };
        let refused = match self.step(last, (stamp_ns, pose)) {
            Ok(()) => {
                self.suspects.clear();
                self.last = Some((stamp_ns, pose));
                return Ok(pose);
            }
            Err(e) => e,
        };
        // A run of refused records that agree with each other is a new frame.
        let agrees = self
            .suspects
            .last()
            .is_some_and(|&prev| self.step(prev, (stamp_ns, raw)).is_ok());
        if !agrees {
            self.suspects.clear();
        }
        self.suspects.push((stamp_ns, raw));
        if self.suspects.len() >= self.limits.reset_after.max(1) {
            // Continue from where the robot was last known, standing still.
            self.stitch = last.1.compose(&raw.inverse());
            self.suspects.clear();
            self.resets += 1;
            self.last = Some((stamp_ns, last.1));
            return Ok(last.1);
        }
        Err(refused)
    }
}

pub struct LogScans<R> {
    reader: CarmenReader<R>,
    scan: RangeScan,
    gate: OdometryGate,
    /// The first [`KEPT_ERRORS`] bad lines.
    pub errors: Vec<LineError>,
    pub error_count: usize,
    pub odom_records: usize,
    pub laser_records: usize,
    mount: LaserMount,
    /// Most significant digits a laser stamp was written with so far.
    stamp_digits: u32,
}

/// Farthest a record's laser pose may sit from its odometry pose plus the
/// first record's mount, m and rad. A raw log's two poses differ by one
/// fixed offset, to the precision the log prints them with; a corrected log (GMapping's `.gfs.log`: the laser pose
/// corrected, the odometry raw) drifts apart by metres.
pub const MOUNT_TOLERANCE: (f64, f64) = (0.05, 0.05);

/// Farthest a laser is taken to sit from the robot's origin, m.
pub const MAX_MOUNT_M: f64 = 2.0;

/// The laser's mount as the log's records state it, checked for staying fixed.
#[derive(Debug, Clone, Copy, Default)]
struct LaserMount {
    first: Option<Pose2>,
    /// The record (1-based, among laser records) whose mount first moved, and by how much (m).
    moved: Option<(usize, f64)>,
}

impl<R: BufRead> LogScans<R> {
    pub fn new(input: R) -> Self {
        Self {
            reader: CarmenReader::new(input),
            scan: RangeScan::default(),
            gate: OdometryGate::new(OdometryLimits::default()),
            errors: Vec::new(),
            error_count: 0,
            odom_records: 0,
            laser_records: 0,
            mount: LaserMount::default(),
            stamp_digits: 0,
        }
    }

    /// Where the log's laser poses stopped being its odometry poses plus one
    /// fixed mount: (laser record, how far the mount had moved, m). From
    /// there on every scan is taken at its odometry pose with the laser at
    /// the robot's origin, and the scans before it keep the first mount.
    pub fn mount_moved(&self) -> Option<(usize, f64)> {
        self.mount.moved
    }

    /// Keeps the scan's mount while the records agree on one; once they do not, the robot's origin.
    fn check_mount(&mut self) {
        let m = self.scan.sensor_pose;
        if self.mount.moved.is_none() {
            let (dt, dr) = match self.mount.first {
                Some(first) => {
                    let d = first.between(&m);
                    (d.translation_norm(), d.theta.abs())
                }
                None if m.translation_norm() <= MAX_MOUNT_M => {
                    self.mount.first = Some(m);
                    return;
                }
                // No laser sits metres from its base: the two poses are in different frames.
                None => (m.translation_norm(), 0.0),
            };
            if dt <= MOUNT_TOLERANCE.0 && dr <= MOUNT_TOLERANCE.1 {
                return;
            }
            tracing::warn!(
                record = self.laser_records,
                moved_m = dt,
                "the log's laser poses are not its odometry plus a fixed mount (a corrected log?): scans taken at the odometry pose from here on"
            );
            self.mount.moved = Some((self.laser_records, dt));
        }
        self.scan.sensor_pose = Pose2::default();
    }

    fn bad_line(&mut self, e: LineError) {
        tracing::warn!("{e}");
        self.error_count += 1;
        if self.errors.len() < KEPT_ERRORS {
            self.errors.push(e);
        }
    }

    /// The next laser scan and the robot's odometry pose at it, skipping (and
    /// recording) bad lines and scans whose odometry cannot be real (see
    /// [`OdometryGate`]). The scan buffer is reused.
    pub fn next_scan(&mut self) -> Option<(&RangeScan, Pose2)> {
        loop {
            match self.reader.next()? {
                Ok(Record::Laser(l)) => {
                    self.laser_records += 1;
                    // A stamp with fewer significant digits than the log
                    // wrote before had trailing zeros dropped (`%g`): its
                    // step is the one those digits give, not what it shows.
                    let resolution = if l.stamp_digits < self.stamp_digits {
                        l.stamp_resolution_ns
                            .min(crate::carmen::resolution_at_digits_ns(
                                l.ipc_timestamp_ns,
                                self.stamp_digits,
                            ))
                    } else {
                        l.stamp_resolution_ns
                    };
                    self.stamp_digits = self.stamp_digits.max(l.stamp_digits);
                    self.gate.note_stamp_resolution(resolution);
                    match self.gate.check(l.ipc_timestamp_ns, l.robot_pose) {
                        Ok(odom) => {
                            l.fill_range_scan(&mut self.scan);
                            self.check_mount();
                            return Some((&self.scan, odom));
                        }
                        Err(e) => {
                            let line = self.reader.line();
                            self.bad_line(LineError {
                                line,
                                error: CarmenError::Odometry(e),
                            });
                        }
                    }
                }
                Ok(Record::Odom(_)) => self.odom_records += 1,
                Err(e) => self.bad_line(e),
            }
        }
    }

    /// Laser records of kinds not read (`RAWLASER*`, `RLASER`).
    pub fn unread_laser_records(&self) -> usize {
        self.reader.unread_laser_records
    }

    /// The coarsest step the log's laser stamps can show, ns.
    pub fn stamp_resolution_ns(&self) -> u64 {
        self.gate.stamp_resolution_ns()
    }

    /// Odometry resets found in the log (runs of records that jumped together).
    pub fn odometry_resets(&self) -> usize {
        self.gate.resets
    }

    /// Number of the last line read.
    pub fn line(&self) -> usize {
        self.reader.line()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: u64 = 1_000_000_000;

    /// A robot driving 0.5 m/s along x, one scan per 0.2 s.
    fn drive(n: u64) -> impl Iterator<Item = (u64, Pose2)> {
        (0..n).map(|i| (i * S / 5, Pose2::new(0.1 * i as f64, 0.0, 0.0)))
    }

    /// FLASER lines of a robot driving along x, 0.1 m per record: the laser
    /// pose given by `laser(i, odometry x)`.
    fn flaser_log(n: usize, laser: impl Fn(usize, f64) -> (f64, f64, f64)) -> String {
        (0..n)
            .map(|i| {
                let x = 0.1 * i as f64;
                let (lx, ly, lt) = laser(i, x);
                format!(
                    "FLASER 3 1.0 2.0 3.0 {lx:.6} {ly:.6} {lt:.6} {x:.6} 0.000000 0.000000 {}.{:06} h 0\n",
                    100 + i / 5,
                    (i % 5) * 200_000
                )
            })
            .collect()
    }

    /// The mount every record's laser pose sits at, and what the log says moved.
    fn mounts(log: &str) -> (Vec<Pose2>, Option<(usize, f64)>) {
        let mut scans = LogScans::new(log.as_bytes());
        let mut out = Vec::new();
        while let Some((scan, _)) = scans.next_scan() {
            out.push(scan.sensor_pose);
        }
        (out, scans.mount_moved())
    }

    #[test]
    fn a_raw_logs_fixed_laser_offset_is_its_mount() {
        // The laser 0.12 m ahead of the base, as CARMEN writes FLASER's laser pose.
        let (m, moved) = mounts(&flaser_log(20, |_, x| (x + 0.12, 0.0, 0.0)));
        assert_eq!(moved, None);
        assert_eq!(m.len(), 20);
        assert!(
            m.iter()
                .all(|p| (p.x - 0.12).abs() < 1e-6 && p.y.abs() < 1e-6)
        );
    }

    /// GMapping's `.gfs.log`: the laser pose corrected, the odometry raw. The
    /// mount between them was taken as the laser's: every scan metres off
    /// (a CSAIL log built so: 8.67 m ATE, 0.14 m with this).
    #[test]
    fn laser_poses_in_another_frame_leave_the_scans_at_the_odometry() {
        // Corrected poses drifting 2 cm per record from the odometry.
        let (m, moved) = mounts(&flaser_log(20, |i, x| (x + 0.02 * i as f64, 0.0, 0.0)));
        let (record, by) = moved.expect("the mount moved");
        assert_eq!(record, 4);
        assert!(by > MOUNT_TOLERANCE.0, "{by}");
        assert!(m[..3].iter().all(|p| p.x.abs() <= MOUNT_TOLERANCE.0));
        assert!(m[3..].iter().all(|p| *p == Pose2::default()));
        // The frames hundreds of metres apart from the start: no record's mount is used.
        let (m, moved) = mounts(&flaser_log(5, |_, x| (x + 400.0, -12.0, 1.0)));
        assert_eq!(moved.map(|(r, _)| r), Some(1));
        assert!(m.iter().all(|p| *p == Pose2::default()));
    }

    /// GMapping's corrected logs stamp a whole run alike (`%g`) and keep one
    /// scan per metre: checked against 0 s, every step was refused.
    #[test]
    fn steps_under_one_coarse_stamp_are_checked_against_the_stamps_resolution() {
        let metre_apart = |gate: &mut OdometryGate| {
            (0..10)
                .filter(|&i| gate.check(5 * S, Pose2::new(i as f64, 0.0, 0.0)).is_err())
                .count()
        };
        let mut fine = OdometryGate::new(OdometryLimits::default());
        // 1 m in 0 s: every step refused (and never by each other agreed: no reset).
        assert_eq!(metre_apart(&mut fine), 9);
        let mut coarse = OdometryGate::new(OdometryLimits::default());
        coarse.note_stamp_resolution(10_000 * S);
        assert_eq!(metre_apart(&mut coarse), 0);
        // A flipped digit is still refused: 10 m/s for 10⁴ s is 100 km.
        assert!(coarse.check(5 * S, Pose2::new(2.0e5, 0.0, 0.0)).is_err());
        // Only ever coarser.
        coarse.note_stamp_resolution(1_000);
        assert_eq!(coarse.stamp_resolution_ns(), 10_000 * S);
    }

    /// The stamp resolution a log read whole reports, its lines' stamps given.
    fn log_resolution_ns(stamps: &[&str]) -> u64 {
        let log: String = stamps
            .iter()
            .enumerate()
            .map(|(i, t)| format!("FLASER 3 1 2 3 {i} 0 0 {i} 0 0 {t} host {t}\n"))
            .collect();
        let mut scans = LogScans::new(log.as_bytes());
        while scans.next_scan().is_some() {}
        scans.stamp_resolution_ns()
    }

    /// Intel's corrected log writes its stamps with `%g`'s six significant
    /// digits, trailing zeros dropped: `940` is 940.000 s beside `32.9068`,
    /// and was read as a log stamped to whole seconds (`smokenav slam`
    /// said "written to 1 s only").
    #[test]
    fn stamps_whose_trailing_zeros_were_dropped_keep_the_logs_digits() {
        let ms = 1_000_000;
        assert_eq!(log_resolution_ns(&["32.9068", "33.1", "940", "941.5"]), ms);
        // Past 1000 s six digits leave hundredths.
        assert_eq!(
            log_resolution_ns(&["32.9068", "940", "1438.98", "1440"]),
            10 * ms
        );
        // A log written in whole seconds throughout is one.
        assert_eq!(log_resolution_ns(&["940", "941", "1500"]), S);
        // GMapping's CSAIL output: every stamp the same six digits of a Unix time.
        assert_eq!(
            log_resolution_ns(&["1.13486e+09", "1.13486e+09", "1.13487e+09"]),
            10_000 * S
        );
        // Fixed decimals stay what they show.
        assert_eq!(log_resolution_ns(&["1.000000", "2.000000"]), 1_000);
    }

    #[test]
    fn one_corrupt_record_is_refused_and_the_next_accepted() {
        let mut gate = OdometryGate::new(OdometryLimits::default());
        for (i, (t, p)) in drive(20).enumerate() {
            // A flipped digit: 812 m instead of 1.2 m.
            let raw = if i == 12 {
                Pose2::new(812.0 + p.x, 0.0, 0.0)
            } else {
                p
            };
            let got = gate.check(t, raw);
            if i == 12 {
                assert!(
                    matches!(got, Err(ImplausibleOdometry::Jump { jump_m, .. }) if jump_m > 800.0),
                    "{got:?}"
                );
            } else {
                assert_eq!(got, Ok(p), "record {i}");
            }
        }
        assert_eq!(gate.resets, 0);
    }

    #[test]
    fn a_run_of_records_in_a_new_frame_is_a_reset_not_motion() {
        let mut gate = OdometryGate::new(OdometryLimits::default());
        let mut out = Vec::new();
        for (i, (t, p)) in drive(20).enumerate() {
            // From record 10 on the base reports a frame 40 m away.
            let raw = if i >= 10 {
                Pose2::new(p.x - 40.0, 7.0, 1.0)
            } else {
                p
            };
            out.push(gate.check(t, raw));
        }
        assert_eq!(gate.resets, 1);
        // Two refused, the third stitched: standing still across the jump,
        // then moving on in the old frame's terms.
        assert!(out[10].is_err() && out[11].is_err());
        let at_reset = out[12].unwrap();
        assert!(at_reset.between(&out[9].unwrap()).translation_norm() < 1e-9);
        let next = out[13].unwrap();
        let step = at_reset.between(&next);
        assert!((step.translation_norm() - 0.1).abs() < 1e-9, "{step:?}");
        assert!(
            out.iter()
                .flatten()
                .collect::<Vec<_>>()
                .windows(2)
                .all(|w| { w[0].between(w[1]).translation_norm() < 0.2 })
        );
    }

    #[test]
    fn stamps_backwards_and_absurd_coordinates_are_refused() {
        let mut gate = OdometryGate::new(OdometryLimits::default());
        assert!(gate.check(10 * S, Pose2::new(1.0, 0.0, 0.0)).is_ok());
        assert!(matches!(
            gate.check(9 * S, Pose2::new(1.0, 0.0, 0.0)),
            Err(ImplausibleOdometry::StampBackwards { .. })
        ));
        assert!(matches!(
            gate.check(11 * S, Pose2::new(1.0, 3.0e7, 0.0)),
            Err(ImplausibleOdometry::OutOfBounds { .. })
        ));
        assert!(matches!(
            gate.check(11 * S, Pose2::new(1.0, 0.0, 1.0e9)),
            Err(ImplausibleOdometry::OutOfBounds { .. })
        ));
        assert!(gate.check(11 * S, Pose2::new(1.2, 0.0, 0.3)).is_ok());
    }

    #[test]
    fn the_real_csail_prefix_passes_the_gate_untouched() {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/data/csail-prefix-200.clf"
        );
        let mut scans = LogScans::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
        let mut n = 0;
        while scans.next_scan().is_some() {
            n += 1;
        }
        assert_eq!(scans.error_count, 0, "{:?}", scans.errors);
        assert_eq!(n, scans.laser_records);
        assert_eq!(scans.odometry_resets(), 0);
    }
}
