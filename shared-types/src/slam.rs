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
    /// Position in the map frame, m.
    pub x: f64,
    /// Position in the map frame, m.
    pub y: f64,
    /// Heading in the map frame, rad.
    pub theta: f64,
    /// Row-major 3×3 covariance of (x, y, θ) over the particle set.
    pub covariance: [f64; 9],
    /// Effective sample size of the particle weights after this update.
    pub n_eff: f32,
    /// Particles in the filter.
    pub particles: u32,
    /// Scans skipped so far because the filter fell behind.
    pub scans_skipped: u64,
    /// Time spent processing this scan, µs.
    pub processing_us: u32,
    /// Zero.
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
    /// Stamp, sequence number, map frame.
    pub header: Header,
    /// Cell edge, m.
    pub resolution: f32,
    /// Cells per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Zero.
    pub _reserved: u32,
    /// Pose of the lower-left corner of cell (0, 0) in the map frame.
    pub origin_x: f64,
    /// Lower-left corner of cell (0, 0), m.
    pub origin_y: f64,
    /// Heading of the grid in the map frame, rad.
    pub origin_theta: f64,
}

impl MapInfo {
    /// Cells in the grid: `width × height`.
    pub fn cell_count(&self) -> usize {
        self.width as usize * self.height as usize
    }
}
