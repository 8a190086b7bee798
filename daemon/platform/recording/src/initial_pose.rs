//! `initialpose` from outside: RViz's or Foxglove's "2D Pose Estimate", a
//! `geometry_msgs/msg/PoseWithCovarianceStamped`, decoded and checked
//! before it becomes a bus `slam/initial_pose` (by `smokenav-zenoh` from
//! rmw_zenoh, by `smokenav-view` from a Foxglove client's publish).
//!
//! The pose must be in the `map` frame (RViz's fixed frame when it shows
//! the robot's map) and planar: its position and the heading about z are
//! taken, with the covariance of x, y and yaw. A pose in another frame, a
//! rotation out of the plane, a non-finite number or a malformed payload is
//! refused with the reason; nothing is guessed.

use crate::cdr::{CdrError, CdrReader, CdrWriter};
use smokenav_shared_types::{Header, PoseEstimate};
use thiserror::Error;

/// Longest `frame_id` read (RViz sends `map`).
const MAX_FRAME_ID: usize = 256;

/// Why an `initialpose` sample was not forwarded.
#[derive(Debug, Error, PartialEq)]
pub enum InitialPoseError {
    #[error(transparent)]
    Cdr(#[from] CdrError),
    #[error("the pose is in frame `{0}`: SLAM's map frame is `map`")]
    Frame(String),
    #[error("a non-finite number in the pose or its covariance")]
    NotFinite,
    #[error(
        "the orientation is not a unit quaternion about z (roll/pitch {0:.2} rad): a planar robot's pose turns about z only"
    )]
    NotPlanar(f64),
}

/// What a planar SLAM takes from a PoseWithCovarianceStamped.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanarPose {
    pub x: f64,
    pub y: f64,
    /// Heading about z, rad.
    pub yaw: f64,
    /// Variances of x, y and yaw (the 6×6 covariance's (0,0), (1,1), (5,5)).
    pub var_x: f64,
    pub var_y: f64,
    pub var_yaw: f64,
}

impl PlanarPose {
    /// The bus message `slam/initial_pose` carries: map frame, stamped
    /// `stamp_ns`, the variances on the (x, y, θ) covariance's diagonal.
    pub fn to_estimate(&self, stamp_ns: u64) -> PoseEstimate {
        PoseEstimate {
            header: Header::new(stamp_ns, 0, "map"),
            x: self.x,
            y: self.y,
            theta: self.yaw,
            covariance: [
                self.var_x,
                0.0,
                0.0,
                0.0,
                self.var_y,
                0.0,
                0.0,
                0.0,
                self.var_yaw,
            ],
            ..PoseEstimate::default()
        }
    }
}

/// Decodes a CDR PoseWithCovarianceStamped: header (stamp, frame_id), pose
/// (position x y z, orientation x y z w), covariance (36 float64, row-major
/// over x, y, z, roll, pitch, yaw).
pub fn decode(cdr: &[u8]) -> Result<PlanarPose, InitialPoseError> {
    let mut r = CdrReader::new(cdr)?;
    r.i32("header.stamp.sec")?;
    r.u32("header.stamp.nanosec")?;
    let frame = r.string("header.frame_id", MAX_FRAME_ID)?;
    if frame != "map" {
        return Err(InitialPoseError::Frame(frame.chars().take(64).collect()));
    }
    let mut v = [0.0; 7];
    r.array_f64("pose.pose", &mut v)?;
    let mut cov = [0.0; 36];
    r.array_f64("pose.covariance", &mut cov)?;
    if v.iter().chain(&cov).any(|x| !x.is_finite()) {
        return Err(InitialPoseError::NotFinite);
    }
    let [x, y, _z, qx, qy, qz, qw] = v;
    let norm = (qx * qx + qy * qy + qz * qz + qw * qw).sqrt();
    // Off-plane rotation: the x and y parts of the unit quaternion.
    let tilt = 2.0 * (qx.hypot(qy) / norm.max(f64::MIN_POSITIVE)).asin();
    if !(0.9..=1.1).contains(&norm) || tilt > 0.1 {
        return Err(InitialPoseError::NotPlanar(tilt));
    }
    let yaw = 2.0 * qz.atan2(qw);
    Ok(PlanarPose {
        x,
        y,
        yaw: yaw.sin().atan2(yaw.cos()),
        var_x: cov[0],
        var_y: cov[7],
        var_yaw: cov[35],
    })
}

/// A CDR PoseWithCovarianceStamped in `frame` (for tests and tools): `pose`
/// with the variances on the covariance's diagonal.
pub fn encode(frame: &str, pose: &PlanarPose) -> Vec<u8> {
    let mut buf = Vec::new();
    let mut w = CdrWriter::new(&mut buf);
    w.i32(0);
    w.u32(0);
    w.string(frame);
    let (s, c) = (0.5 * pose.yaw).sin_cos();
    for v in [pose.x, pose.y, 0.0, 0.0, 0.0, s, c] {
        w.f64(v);
    }
    let mut cov = [0.0; 36];
    cov[0] = pose.var_x;
    cov[7] = pose.var_y;
    cov[35] = pose.var_yaw;
    w.array_f64(&cov);
    buf
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose() -> PlanarPose {
        PlanarPose {
            x: 4.2,
            y: -1.0,
            yaw: 2.5,
            var_x: 0.25,
            var_y: 0.16,
            var_yaw: 0.068,
        }
    }

    #[test]
    fn rviz_pose_round_trips() {
        let p = decode(&encode("map", &pose())).unwrap();
        assert!((p.x - 4.2).abs() < 1e-12 && (p.y + 1.0).abs() < 1e-12);
        assert!((p.yaw - 2.5).abs() < 1e-12, "{}", p.yaw);
        assert_eq!((p.var_x, p.var_y, p.var_yaw), (0.25, 0.16, 0.068));
    }

    #[test]
    fn bad_input_is_refused_with_its_reason() {
        assert_eq!(
            decode(&encode("odom", &pose())),
            Err(InitialPoseError::Frame("odom".into()))
        );
        let nan = PlanarPose {
            x: f64::NAN,
            ..pose()
        };
        assert_eq!(
            decode(&encode("map", &nan)),
            Err(InitialPoseError::NotFinite)
        );
        let full = encode("map", &pose());
        for cut in [0, 3, 4, 11, 20, full.len() - 1] {
            assert!(
                matches!(decode(&full[..cut]), Err(InitialPoseError::Cdr(_))),
                "{cut} bytes"
            );
        }
        // Tilted 90° about x: not a planar pose.
        let mut tilted = full.clone();
        let q = full.len() - 36 * 8 - 4 * 8;
        for (i, v) in [0.5f64.sqrt(), 0.0, 0.0, 0.5f64.sqrt()].iter().enumerate() {
            tilted[q + 8 * i..q + 8 * i + 8].copy_from_slice(&v.to_le_bytes());
        }
        assert!(matches!(
            decode(&tilted),
            Err(InitialPoseError::NotPlanar(_))
        ));
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(2000))]
        /// Any bytes, and a valid pose with any byte changed and any tail
        /// cut, decode or are refused without a panic.
        #[test]
        fn any_bytes_decode_or_fail_without_panicking(
            noise in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..512),
            at in 0usize..400,
            byte in proptest::prelude::any::<u8>(),
            keep in 0usize..400,
        ) {
            let _ = decode(&noise);
            let mut b = encode("map", &pose());
            let n = b.len();
            b[at % n] = byte;
            b.truncate(keep.min(n));
            let _ = decode(&b);
        }
    }
}
