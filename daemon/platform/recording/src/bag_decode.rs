//! Pure decoders for the standard ROS 2 messages of a team's own bags that
//! smokenav's recordings do not carry as such: `tf2_msgs/TFMessage` (the
//! sensors' mounting poses from `/tf_static`), `sensor_msgs/Range` and the
//! x, y, z of a `sensor_msgs/PointCloud2` (a sonar ring as points). Bytes
//! in, values or a [`CdrError`] out; no I/O. `sensor_msgs/LaserScan` and
//! `nav_msgs/Odometry` decode with [`crate::codec`], as in a recording.

use crate::cdr::{CdrError, CdrReader};
use smokenav_shared_types::header::FRAME_ID_LEN;

/// Largest transform list read from one TFMessage (a robot has dozens).
pub const MAX_TRANSFORMS: usize = 4096;

/// One `geometry_msgs/TransformStamped` projected onto the plane.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanarTransform {
    pub stamp_ns: u64,
    pub parent: String,
    pub child: String,
    pub x: f64,
    pub y: f64,
    pub yaw: f64,
}

fn yaw_of(q: [f64; 4]) -> f64 {
    let [x, y, z, w] = q;
    (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
}

fn read_stamp(r: &mut CdrReader) -> Result<u64, CdrError> {
    let sec = r.i32("header.stamp.sec")?;
    let nanosec = r.u32("header.stamp.nanosec")?;
    Ok(sec.max(0) as u64 * 1_000_000_000 + u64::from(nanosec))
}

/// Appends the transforms of a `tf2_msgs/TFMessage` to `out` (frame names
/// longer than a smokenav frame id are an error; a leading `/` is dropped,
/// as tf2 does).
pub fn decode_tf_message(data: &[u8], out: &mut Vec<PlanarTransform>) -> Result<(), CdrError> {
    let mut r = CdrReader::new(data)?;
    // A TransformStamped is at least 4+4+4+4 + 7×8 bytes.
    let n = r.seq_len("transforms", MAX_TRANSFORMS, 72)?;
    for _ in 0..n {
        let stamp_ns = read_stamp(&mut r)?;
        let parent = r.string("header.frame_id", FRAME_ID_LEN)?;
        let child = r.string("child_frame_id", FRAME_ID_LEN)?;
        let x = r.f64("transform.translation.x")?;
        let y = r.f64("transform.translation.y")?;
        let _z = r.f64("transform.translation.z")?;
        let mut q = [0.0; 4];
        r.array_f64("transform.rotation", &mut q)?;
        out.push(PlanarTransform {
            stamp_ns,
            parent: parent.trim_start_matches('/').to_owned(),
            child: child.trim_start_matches('/').to_owned(),
            x,
            y,
            yaw: yaw_of(q),
        });
    }
    Ok(())
}

/// `sensor_msgs/Range` (Humble, and Jazzy's trailing `variance`, which is ignored).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RangeReading {
    pub stamp_ns: u64,
    /// 0 ultrasound, 1 infrared.
    pub radiation_type: u8,
    pub field_of_view: f32,
    pub min_range: f32,
    pub max_range: f32,
    /// m; +inf/−inf for "nothing detected"/"too close" (REP 117).
    pub range: f32,
}

/// Decodes a `sensor_msgs/Range`; the frame id goes into `frame`.
pub fn decode_range(data: &[u8], frame: &mut String) -> Result<RangeReading, CdrError> {
    let mut r = CdrReader::new(data)?;
    let stamp_ns = read_stamp(&mut r)?;
    frame.clear();
    frame.push_str(r.string("header.frame_id", FRAME_ID_LEN)?);
    Ok(RangeReading {
        stamp_ns,
        radiation_type: r.u8("radiation_type")?,
        field_of_view: r.f32("field_of_view")?,
        min_range: r.f32("min_range")?,
        max_range: r.f32("max_range")?,
        range: r.f32("range")?,
    })
}

/// Largest point cloud read as a sonar ring (a ring has at most dozens of
/// transducers; this bounds what a crafted or mis-chosen cloud can cost).
pub const MAX_CLOUD_POINTS: usize = 4096;
/// Largest field list of a PointCloud2 (real ones have a handful).
pub const MAX_CLOUD_FIELDS: usize = 64;

/// `sensor_msgs/PointField` datatypes smokenav reads.
const FLOAT32: u8 = 7;
const FLOAT64: u8 = 8;

/// What a `sensor_msgs/PointCloud2` says besides its points.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CloudInfo {
    pub stamp_ns: u64,
    /// Points read (`width × height`).
    pub points: usize,
}

/// Where one coordinate lies in a point, and how wide it is.
#[derive(Clone, Copy)]
struct Coord {
    offset: usize,
    double: bool,
}

/// Decodes the x, y, z of every point of a little-endian
/// `sensor_msgs/PointCloud2` into `out` (cleared first; NaN points kept, so a
/// caller can count them); the frame id goes into `frame`. Fields other than
/// x, y, z are skipped; x, y, z must be float32 or float64 inside the point.
pub fn decode_point_cloud2(
    data: &[u8],
    frame: &mut String,
    out: &mut Vec<[f64; 3]>,
) -> Result<CloudInfo, CdrError> {
    let bad = |field: &'static str, reason: String| CdrError::Inconsistent { field, reason };
    let mut r = CdrReader::new(data)?;
    let stamp_ns = read_stamp(&mut r)?;
    frame.clear();
    frame.push_str(r.string("header.frame_id", FRAME_ID_LEN)?);
    let height = r.u32("height")? as usize;
    let width = r.u32("width")? as usize;
    // A PointField is at least a 4-byte string length + offset + datatype + count.
    let n_fields = r.seq_len("fields", MAX_CLOUD_FIELDS, 13)?;
    let mut coords: [Option<Coord>; 3] = [None; 3];
    for _ in 0..n_fields {
        let name = r.string("fields.name", 64)?;
        let offset = r.u32("fields.offset")? as usize;
        let datatype = r.u8("fields.datatype")?;
        let count = r.u32("fields.count")?;
        let slot = match name {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            _ => continue,
        };
        let double = match datatype {
            FLOAT32 => false,
            FLOAT64 => true,
            other => {
                return Err(bad(
                    "fields.datatype",
                    format!(
                        "field {name} has datatype {other}; smokenav reads float32 (7) or float64 (8)"
                    ),
                ));
            }
        };
        if count == 0 {
            return Err(bad("fields.count", format!("field {name} has count 0")));
        }
        coords[slot] = Some(Coord { offset, double });
    }
    if r.bool("is_bigendian")? {
        return Err(bad(
            "is_bigendian",
            "big-endian point data; smokenav reads little-endian".into(),
        ));
    }
    let point_step = r.u32("point_step")? as usize;
    let row_step = r.u32("row_step")? as usize;
    let bytes = r.seq_bytes("data", usize::MAX)?;
    let _is_dense = r.bool("is_dense")?;
    let [Some(x), Some(y), z] = coords else {
        return Err(bad("fields", "no float x and y fields".into()));
    };
    let points = width
        .checked_mul(height)
        .filter(|&n| n <= MAX_CLOUD_POINTS)
        .ok_or_else(|| {
            bad(
                "width",
                format!("{width} × {height} points; a sonar ring has at most {MAX_CLOUD_POINTS}"),
            )
        })?;
    for (name, c) in [("x", Some(x)), ("y", Some(y)), ("z", z)] {
        if let Some(c) = c {
            let size = if c.double { 8 } else { 4 };
            if c.offset
                .checked_add(size)
                .is_none_or(|end| end > point_step)
            {
                return Err(bad(
                    "fields.offset",
                    format!(
                        "field {name} at offset {} lies outside the {point_step}-byte point",
                        c.offset
                    ),
                ));
            }
        }
    }
    if width > 0 && row_step < width.saturating_mul(point_step) {
        return Err(bad(
            "row_step",
            format!("{row_step} bytes for {width} points of {point_step} bytes"),
        ));
    }
    let need = row_step
        .saturating_mul(height.saturating_sub(1))
        .saturating_add(width.saturating_mul(point_step));
    if points > 0 && bytes.len() < need {
        return Err(CdrError::Truncated {
            field: "data",
            need,
            at: 0,
            len: bytes.len(),
        });
    }
    let read = |p: &[u8], c: Coord| -> f64 {
        // In bounds: offset + size <= point_step, checked above.
        if c.double {
            let mut b = [0u8; 8];
            b.copy_from_slice(&p[c.offset..c.offset + 8]);
            f64::from_le_bytes(b)
        } else {
            let mut b = [0u8; 4];
            b.copy_from_slice(&p[c.offset..c.offset + 4]);
            f64::from(f32::from_le_bytes(b))
        }
    };
    out.clear();
    for row in 0..height {
        for col in 0..width {
            let start = row * row_step + col * point_step;
            let p = &bytes[start..start + point_step];
            out.push([read(p, x), read(p, y), z.map_or(0.0, |z| read(p, z))]);
        }
    }
    Ok(CloudInfo { stamp_ns, points })
}

/// The `child_frame_id` of a `nav_msgs/Odometry` (the robot's base frame).
pub fn odometry_child_frame(data: &[u8]) -> Result<&str, CdrError> {
    let mut r = CdrReader::new(data)?;
    read_stamp(&mut r)?;
    r.string("header.frame_id", FRAME_ID_LEN)?;
    r.string("child_frame_id", FRAME_ID_LEN)
}

/// The `header.frame_id` of any message that starts with a `std_msgs/Header`.
pub fn header_frame(data: &[u8]) -> Result<&str, CdrError> {
    let mut r = CdrReader::new(data)?;
    read_stamp(&mut r)?;
    r.string("header.frame_id", FRAME_ID_LEN)
}

/// The pose of frame `child` in frame `root` through a tree of transforms
/// (the newest of each child wins), or `None` when `child` does not hang
/// below `root`. Depth is bounded, so a cycle in a crafted file ends.
pub fn resolve(transforms: &[PlanarTransform], root: &str, child: &str) -> Option<(f64, f64, f64)> {
    let child = child.trim_start_matches('/');
    let (mut x, mut y, mut yaw) = (0.0f64, 0.0f64, 0.0f64);
    let mut frame = child;
    for _ in 0..64 {
        if frame == root {
            return Some((x, y, yaw));
        }
        let t = transforms.iter().rev().find(|t| t.child == frame)?;
        // p_parent = T(parent←frame) · p_frame
        let (s, c) = t.yaw.sin_cos();
        let nx = t.x + c * x - s * y;
        let ny = t.y + s * x + c * y;
        x = nx;
        y = ny;
        yaw += t.yaw;
        frame = t.parent.as_str();
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::{Transform2, encode_tf_message};

    #[test]
    fn tf_message_round_trips_through_the_recorders_encoder() {
        let mut buf = Vec::new();
        encode_tf_message(
            &[
                Transform2 {
                    stamp_ns: 5_000_000_001,
                    parent: "base_link",
                    child: "laser",
                    x: 0.16,
                    y: -0.02,
                    yaw: 0.5,
                },
                Transform2 {
                    stamp_ns: 5_000_000_001,
                    parent: "odom",
                    child: "base_link",
                    x: 1.0,
                    y: 2.0,
                    yaw: -1.0,
                },
            ],
            &mut buf,
        );
        let mut out = Vec::new();
        decode_tf_message(&buf, &mut out).unwrap();
        assert_eq!(out.len(), 2);
        assert_eq!(out[0].stamp_ns, 5_000_000_001);
        assert_eq!(
            (out[0].parent.as_str(), out[0].child.as_str()),
            ("base_link", "laser")
        );
        assert!((out[0].yaw - 0.5).abs() < 1e-12 && (out[0].x - 0.16).abs() < 1e-15);
        let (x, y, yaw) = resolve(&out, "odom", "laser").unwrap();
        // laser at (0.16, -0.02) in base, base at (1, 2) turned by −1 rad.
        let (s, c) = (-1.0f64).sin_cos();
        assert!((x - (1.0 + c * 0.16 + s * 0.02)).abs() < 1e-12);
        assert!((y - (2.0 + s * 0.16 - c * 0.02)).abs() < 1e-12);
        assert!((yaw + 0.5).abs() < 1e-12);
        assert_eq!(resolve(&out, "base_link", "camera"), None);
    }

    #[test]
    fn cyclic_transforms_do_not_hang() {
        let t = |p: &str, c: &str| PlanarTransform {
            stamp_ns: 0,
            parent: p.into(),
            child: c.into(),
            x: 0.0,
            y: 0.0,
            yaw: 0.0,
        };
        assert_eq!(resolve(&[t("a", "b"), t("b", "a")], "root", "a"), None);
    }

    #[test]
    fn range_reads_humble_and_jazzy_layouts() {
        let mut buf = Vec::new();
        let mut w = crate::cdr::CdrWriter::new(&mut buf);
        w.i32(3);
        w.u32(7);
        w.string("sonar_2");
        w.u8(0);
        w.f32(0.26);
        w.f32(0.1);
        w.f32(5.0);
        w.f32(1.25);
        let humble = buf.clone();
        // Jazzy appends `float32 variance`.
        buf.extend_from_slice(&0.01f32.to_le_bytes());
        for data in [&humble, &buf] {
            let mut frame = String::new();
            let r = decode_range(data, &mut frame).unwrap();
            assert_eq!(frame, "sonar_2");
            assert_eq!(r.stamp_ns, 3_000_000_007);
            assert_eq!(r.range, 1.25);
        }
    }

    #[test]
    fn garbage_never_panics() {
        let mut out = Vec::new();
        let mut frame = String::new();
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        for len in 0..400 {
            let mut data = vec![0u8; len];
            for b in &mut data {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                *b = state as u8;
            }
            if len >= 4 {
                data[..4].copy_from_slice(&crate::cdr::CDR_LE_HEADER);
            }
            out.clear();
            let _ = decode_tf_message(&data, &mut out);
            let _ = decode_range(&data, &mut frame);
            let mut scan = smokenav_shared_types::LaserScan::default();
            let _ = crate::codec::decode_laser_scan(&data, &mut scan);
            let _ = crate::codec::decode_odometry(&data);
        }
    }
}
