//! The 3D map's occupied voxels, as a bounded point message.

use crate::header::Header;
use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;

/// Voxels one message can hold: a 10 × 10 m arena's walls, 2 m high at
/// 5 cm, are about 32 000 voxels seen from both sides; what the laser and
/// the sonar cones actually mark is far less. Beyond it `truncated` counts
/// the voxels left out (192 KiB a message).
pub const MAX_VOXELS: usize = 16_384;

/// The centres of the octree's occupied voxels, in the map frame.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("smokenav::VoxelCloud")]
pub struct VoxelCloud {
    /// Stamp of the newest scan mapped, sequence number, map frame.
    pub header: Header,
    /// Voxel side, m.
    pub resolution: f32,
    /// Points in use (`<= MAX_VOXELS`).
    pub count: u32,
    /// Occupied voxels left out because the message was full.
    pub truncated: u32,
    /// Zero.
    pub _reserved: u32,
    /// Voxel centres `[x, y, z]`, m; the first `count` are in use.
    pub points: [[f32; 3]; MAX_VOXELS],
}

impl Default for VoxelCloud {
    fn default() -> Self {
        Self {
            header: Header::default(),
            resolution: 0.0,
            count: 0,
            truncated: 0,
            _reserved: 0,
            points: [[0.0; 3]; MAX_VOXELS],
        }
    }
}

impl VoxelCloud {
    /// Points in use, clamped to the capacity (a peer could send anything).
    pub fn len(&self) -> usize {
        (self.count as usize).min(MAX_VOXELS)
    }

    /// Whether no point is in use.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The points in use.
    pub fn points(&self) -> &[[f32; 3]] {
        &self.points[..self.len()]
    }

    /// Empties the cloud (the capacity's old points stay, unused).
    pub fn clear(&mut self) {
        self.count = 0;
        self.truncated = 0;
    }

    /// Appends a point, or counts it in `truncated` when the cloud is full.
    pub fn push(&mut self, p: [f32; 3]) {
        let n = self.len();
        if n < MAX_VOXELS {
            self.points[n] = p;
            self.count = n as u32 + 1;
        } else {
            self.truncated = self.truncated.saturating_add(1);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_cloud_counts_what_it_leaves_out() {
        let mut c = Box::<VoxelCloud>::default();
        for i in 0..MAX_VOXELS + 5 {
            c.push([i as f32, 0.0, 0.0]);
        }
        assert_eq!((c.len(), c.truncated), (MAX_VOXELS, 5));
        assert_eq!(c.points()[MAX_VOXELS - 1][0], (MAX_VOXELS - 1) as f32);
        c.count = u32::MAX;
        assert_eq!(c.len(), MAX_VOXELS);
        c.clear();
        assert!(c.is_empty() && c.truncated == 0);
    }
}
