//! Range and PointCloud2 sonar onto the Pioneer 3-DX's front ring (ARIA's
//! p3dx.p poses), and damaged messages: errors, never panics.

use super::*;
use crate::bag_decode::PlanarTransform;
use crate::cdr::{CDR_LE_HEADER, CdrWriter};

fn pioneer() -> SonarSection {
    smokenav_platform_config::RobotConfig::builtin("pioneer-3dx")
        .unwrap()
        .sonar
}

fn range_msg(stamp_ns: u64, frame: &str, range: f32) -> Vec<u8> {
    let mut buf = Vec::new();
    let mut w = CdrWriter::new(&mut buf);
    w.i32((stamp_ns / 1_000_000_000) as i32);
    w.u32((stamp_ns % 1_000_000_000) as u32);
    w.string(frame);
    w.u8(0);
    w.f32(0.26);
    w.f32(0.1);
    w.f32(5.0);
    w.f32(range);
    buf
}

/// A RosAria-shaped cloud: x, y, z float32 (and an intensity field to skip).
fn cloud_msg(stamp_ns: u64, frame: &str, points: &[[f32; 3]]) -> Vec<u8> {
    let mut buf = Vec::new();
    let mut w = CdrWriter::new(&mut buf);
    w.i32((stamp_ns / 1_000_000_000) as i32);
    w.u32((stamp_ns % 1_000_000_000) as u32);
    w.string(frame);
    w.u32(1);
    w.u32(points.len() as u32);
    w.seq_len(4);
    for (name, offset) in [("x", 0u32), ("y", 4), ("z", 8), ("intensity", 12)] {
        w.string(name);
        w.u32(offset);
        w.u8(7);
        w.u32(1);
    }
    w.bool(false);
    w.u32(16);
    w.u32(16 * points.len() as u32);
    w.seq_len(points.len() * 16);
    for p in points {
        for v in [p[0], p[1], p[2], 1.0] {
            for b in v.to_le_bytes() {
                w.u8(b);
            }
        }
    }
    w.bool(true);
    buf
}

fn tf(child: &str, x: f64, y: f64, yaw_deg: f64) -> PlanarTransform {
    PlanarTransform {
        stamp_ns: 0,
        parent: "base_link".into(),
        child: child.into(),
        x,
        y,
        yaw: yaw_deg.to_radians(),
    }
}

fn frames(transforms: Vec<PlanarTransform>) -> Frames {
    Frames {
        static_transforms: transforms,
        ..Default::default()
    }
}

/// The echo point of transducer `t` at `range` in base_link.
fn echo(t: &smokenav_platform_config::Transducer, range: f64) -> [f32; 3] {
    let yaw = t.yaw_deg.to_radians();
    [
        (t.x + range * yaw.cos()) as f32,
        (t.y + range * yaw.sin()) as f32,
        0.0,
    ]
}

#[test]
fn range_topics_placed_by_tf_static_map_to_the_profiles_transducers() {
    let g = pioneer();
    // Frames named in reverse: only their poses say which transducer each is.
    let transforms = g
        .transducers
        .iter()
        .map(|t| tf(&format!("s{}", 7 - t.index), t.x, t.y, t.yaw_deg))
        .collect();
    let topics: Vec<String> = (0..8).map(|i| format!("/sonar/{i}")).collect();
    let mut m = SonarMapper::new(SonarKind::Range, topics, false, frames(transforms), &g);
    let mut rings = Vec::new();
    for cycle in 0..2u64 {
        for slot in 0..8usize {
            let range = match slot {
                2 => f32::INFINITY,
                5 => f32::NAN,
                _ => 1.0 + slot as f32 * 0.25,
            };
            let data = range_msg(
                10_000_000_000 + cycle * 100_000_000,
                &format!("s{slot}"),
                range,
            );
            rings.extend(m.range(slot, &data).unwrap());
        }
    }
    assert_eq!(rings.len(), 2, "one ring per complete cycle");
    let r = &rings[1];
    assert_eq!(r.header.stamp_ns, 10_100_000_000);
    assert_eq!(r.len(), 8);
    // Topic slot s carries frame s<s>, which sits where transducer 7 − s does.
    let of = |index: u8| *r.by_index(index).unwrap();
    assert_eq!(of(7), SonarReading::new(7, 1.0, SonarStatus::Valid));
    assert_eq!(of(5), SonarReading::new(5, 5.0, SonarStatus::Saturated));
    assert_eq!(of(2), SonarReading::new(2, 0.0, SonarStatus::Invalid));
    assert_eq!(of(0), SonarReading::new(0, 2.75, SonarStatus::Valid));
}

#[test]
fn range_topics_without_frames_follow_the_order_given_and_a_repeat_ends_a_ring() {
    let g = pioneer();
    let topics: Vec<String> = (0..8).map(|i| format!("/sonar/{i}")).collect();
    let mut m = SonarMapper::new(SonarKind::Range, topics.clone(), true, frames(vec![]), &g);
    // Transducers 0..3 report, then 0 again: the first ring ends with four readings.
    let mut rings = Vec::new();
    for (slot, stamp) in [(0, 1), (1, 1), (2, 1), (3, 1), (0, 2)] {
        let data = range_msg(stamp * 1_000_000_000, "", 1.5);
        rings.extend(m.range(slot, &data).unwrap());
    }
    assert_eq!(rings.len(), 1);
    let idx: Vec<u8> = rings[0].readings().iter().map(|r| r.index).collect();
    assert_eq!(idx, [0, 1, 2, 3]);
    assert_eq!(rings[0].header.stamp_ns, 1_000_000_000);
    // The bag ends: the cycle being collected comes out.
    let last = m.finish().unwrap();
    assert_eq!(last.readings().len(), 1);
    assert_eq!(last.header.stamp_ns, 2_000_000_000);

    // Guessed topics with no /tf_static: no way to know which is which.
    let mut m = SonarMapper::new(SonarKind::Range, topics, false, frames(vec![]), &g);
    let Err(SonarError::Map(e)) = m.range(0, &range_msg(0, "sonar_0", 1.0)) else {
        panic!("an unplaced frame must be an error");
    };
    assert!(e.contains("sonar_0") && e.contains("--sonar"), "{e}");
}

#[test]
fn one_range_topic_with_a_frame_per_transducer_needs_tf_static() {
    let g = pioneer();
    let transforms = g
        .transducers
        .iter()
        .map(|t| tf(&format!("sonar_{}", t.index), t.x, t.y, t.yaw_deg))
        .collect();
    let mut m = SonarMapper::new(
        SonarKind::Range,
        vec!["/sonar".into()],
        true,
        frames(transforms),
        &g,
    );
    let mut rings = Vec::new();
    for i in 0..8 {
        rings.extend(
            m.range(0, &range_msg(5, &format!("sonar_{i}"), 2.0))
                .unwrap(),
        );
    }
    assert_eq!(rings.len(), 1);
    assert_eq!(rings[0].len(), 8);
    assert_eq!(m.mapping().len(), 8);

    // Without them, the second frame on the one topic is refused by name.
    let mut m = SonarMapper::new(
        SonarKind::Range,
        vec!["/sonar".into()],
        true,
        frames(vec![]),
        &g,
    );
    m.range(0, &range_msg(5, "sonar_0", 2.0)).unwrap();
    let Err(SonarError::Map(e)) = m.range(0, &range_msg(5, "sonar_1", 2.0)) else {
        panic!("two frames on one unplaced topic must be an error");
    };
    assert!(e.contains("sonar_0") && e.contains("sonar_1"), "{e}");
}

#[test]
fn a_frame_that_fits_no_transducer_names_the_nearest() {
    let g = pioneer();
    // Looking backwards: the front ring has nothing there.
    let mut m = SonarMapper::new(
        SonarKind::Range,
        vec!["/sonar/back".into()],
        true,
        frames(vec![tf("rear", -0.2, 0.0, 180.0)]),
        &g,
    );
    let Err(SonarError::Map(e)) = m.range(0, &range_msg(5, "rear", 2.0)) else {
        panic!("a frame matching no transducer must be an error");
    };
    assert!(e.contains("rear") && e.contains("nearest: index"), "{e}");
}

#[test]
fn a_rosaria_cloud_becomes_a_ring_by_bearing() {
    let g = pioneer();
    let mut m = SonarMapper::new(
        SonarKind::Cloud,
        vec!["/sonar_pointcloud2".into()],
        false,
        frames(vec![]),
        &g,
    );
    // Out of order, one at the maximum range, one NaN, one pointing nowhere.
    let t = &g.transducers;
    let points = [
        echo(&t[3], 1.25),
        echo(&t[0], 0.8),
        echo(&t[6], 5.0),
        [f32::NAN, f32::NAN, f32::NAN],
        [-1.0, 0.0, 0.0],
        echo(&t[3], 2.0),
    ];
    let ring = m
        .cloud(&cloud_msg(7_000_000_000, "base_link", &points))
        .unwrap()
        .unwrap();
    assert_eq!(ring.header.stamp_ns, 7_000_000_000);
    let idx: Vec<u8> = ring.readings().iter().map(|r| r.index).collect();
    assert_eq!(idx, [0, 3, 6], "by transducer index");
    assert!((ring.by_index(3).unwrap().range - 1.25).abs() < 1e-5);
    assert!((ring.by_index(0).unwrap().range - 0.8).abs() < 1e-5);
    assert_eq!(ring.by_index(6).unwrap().status(), SonarStatus::Saturated);
    // The NaN, the point behind the robot and the second point for transducer 3.
    assert_eq!(m.dropped_points, 3);

    // A cloud in the laser's frame is moved into the base frame through /tf_static.
    let mut m = SonarMapper::new(
        SonarKind::Cloud,
        vec!["/sonar_pointcloud2".into()],
        false,
        frames(vec![tf("laser", 0.1, 0.0, 90.0)]),
        &g,
    );
    let p = echo(&t[4], 1.5);
    // base = (0.1, 0) + R(90°)·laser  →  laser = R(−90°)·(base − (0.1, 0)).
    let (bx, by) = (f64::from(p[0]) - 0.1, f64::from(p[1]));
    let in_laser = [by as f32, (-bx) as f32, 0.0];
    let ring = m
        .cloud(&cloud_msg(1, "laser", &[in_laser]))
        .unwrap()
        .unwrap();
    assert_eq!(ring.len(), 1);
    assert!((ring.by_index(4).unwrap().range - 1.5).abs() < 1e-5);
    let Err(SonarError::Map(e)) = m.cloud(&cloud_msg(1, "camera", &[in_laser])) else {
        panic!("an unplaced cloud frame must be an error");
    };
    assert!(e.contains("camera"), "{e}");
}

#[test]
fn point_cloud2_layout_errors_are_named() {
    let mut frame = String::new();
    let mut out = Vec::new();
    let good = cloud_msg(1, "base_link", &[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
    let info = bag_decode::decode_point_cloud2(&good, &mut frame, &mut out).unwrap();
    assert_eq!(info.points, 2);
    assert_eq!(out, [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
    // point_step 16 → 8: the intensity field and z no longer fit in a point.
    let mut bad = good.clone();
    let at = good.len() - 1 - 32 - 4 - 4 - 4; // is_dense, data, its length, row_step, point_step
    bad[at..at + 4].copy_from_slice(&8u32.to_le_bytes());
    let e = bag_decode::decode_point_cloud2(&bad, &mut frame, &mut out).unwrap_err();
    assert!(e.to_string().contains("outside the 8-byte point"), "{e}");
}

/// Every prefix and many byte flips of both messages: errors or readings, never a panic.
#[test]
fn damaged_sonar_messages_never_panic() {
    let g = pioneer();
    let t = &g.transducers;
    let cloud = cloud_msg(3, "base_link", &[echo(&t[1], 1.0), echo(&t[2], 2.0)]);
    let range = range_msg(3, "sonar_1", 1.0);
    let mut state = 0x2545_f491_4f6c_dd1du64;
    for data in [&cloud, &range] {
        let mut cuts = 0;
        for len in 0..data.len() {
            let mut m =
                SonarMapper::new(SonarKind::Cloud, vec!["c".into()], true, frames(vec![]), &g);
            cuts += usize::from(m.cloud(&data[..len]).is_err());
            let mut m =
                SonarMapper::new(SonarKind::Range, vec!["r".into()], true, frames(vec![]), &g);
            let _ = m.range(0, &data[..len]);
        }
        assert!(cuts >= data.len() - 1, "a cut message decodes as a cloud");
        for _ in 0..2000 {
            let mut d = data.clone();
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let at = 4 + (state as usize) % (d.len() - 4);
            d[at] ^= 1 << ((state >> 32) % 8);
            let mut m =
                SonarMapper::new(SonarKind::Cloud, vec!["c".into()], true, frames(vec![]), &g);
            let _ = m.cloud(&d);
            let mut m =
                SonarMapper::new(SonarKind::Range, vec!["r".into()], true, frames(vec![]), &g);
            let _ = m.range(0, &d);
        }
    }
    assert!(matches!(
        bag_decode::decode_point_cloud2(&CDR_LE_HEADER, &mut String::new(), &mut Vec::new()),
        Err(CdrError::Truncated { .. })
    ));
}
