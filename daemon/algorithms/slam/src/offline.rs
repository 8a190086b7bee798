//! Feeding a CARMEN log to a back-end: scans with the odometry pose the
//! logger attached, bad lines counted and kept (the first few) for the report.

use crate::carmen::{CarmenReader, LineError, Record};
use crate::pose::Pose2;
use crate::scan::RangeScan;
use std::io::BufRead;

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
