//! Offline input for the pipeline: a CARMEN log (scans with the odometry pose
//! the logger attached; bad lines counted and kept, the first few, for the
//! report), and recorded bus messages replayed in receive order exactly as
//! the SLAM process handles them live.

use crate::backend::SlamUpdate;
use crate::carmen::{CarmenReader, LineError, Record};
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

pub struct LogScans<R> {
    reader: CarmenReader<R>,
    scan: RangeScan,
    /// The first [`KEPT_ERRORS`] bad lines.
    pub errors: Vec<LineError>,
    pub error_count: usize,
    pub odom_records: usize,
    pub laser_records: usize,
}

impl<R: BufRead> LogScans<R> {
    pub fn new(input: R) -> Self {
        Self {
            reader: CarmenReader::new(input),
            scan: RangeScan::default(),
            errors: Vec::new(),
            error_count: 0,
            odom_records: 0,
            laser_records: 0,
        }
    }

    /// The next laser scan and the robot's odometry pose at it, skipping (and
    /// recording) bad lines. The scan buffer is reused.
    pub fn next_scan(&mut self) -> Option<(&RangeScan, Pose2)> {
        loop {
            match self.reader.next()? {
                Ok(Record::Laser(l)) => {
                    self.laser_records += 1;
                    l.fill_range_scan(&mut self.scan);
                    return Some((&self.scan, l.robot_pose));
                }
                Ok(Record::Odom(_)) => self.odom_records += 1,
                Err(e) => {
                    tracing::warn!("{e}");
                    self.error_count += 1;
                    if self.errors.len() < KEPT_ERRORS {
                        self.errors.push(e);
                    }
                }
            }
        }
    }

    /// Number of the last line read.
    pub fn line(&self) -> usize {
        self.reader.line()
    }
}
