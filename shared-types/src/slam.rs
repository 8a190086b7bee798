//! SLAM outputs: the pose estimate and the occupancy grid's metadata.

use crate::header::Header;
use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;

/// The robot pose in the map frame, published once per processed scan.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("smokenav::PoseEstimate")]
pub struct PoseEstimate {
    /// Stamp of the scan this pose belongs to; frame `map`.
    pub header: Header,
    pub x: f64,
    pub y: f64,
    pub theta: f64,
    /// Row-major 3×3 covariance of (x, y, θ) over the particle set.
    pub covariance: [f64; 9],
    /// Effective sample size of the particle weights after this update.
    pub n_eff: f32,
    pub particles: u32,
    /// Scans skipped so far because the filter fell behind.
    pub scans_skipped: u64,
    /// Time spent processing this scan, µs.
    pub processing_us: u32,
    pub _reserved: u32,
}

/// Metadata of an occupancy grid, sent as the user header of the `slam/map`
/// service whose payload is a slice of cells (`i8`, row-major from the
/// lower-left corner, -1 unknown, 0 free … 100 occupied — ROS
/// `nav_msgs/OccupancyGrid` conventions).
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("smokenav::MapInfo")]
pub struct MapInfo {
    pub header: Header,
    /// Cell edge, m.
    pub resolution: f32,
    pub width: u32,
    pub height: u32,
    pub _reserved: u32,
    /// Pose of the lower-left corner of cell (0, 0) in the map frame.
    pub origin_x: f64,
    pub origin_y: f64,
    pub origin_theta: f64,
}

impl MapInfo {
    pub fn cell_count(&self) -> usize {
        self.width as usize * self.height as usize
    }
}
