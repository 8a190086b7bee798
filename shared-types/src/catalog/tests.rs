//! The catalog's tables are consistent, `visit` calls back with the right
//! type, and every catalog type survives its JSON form bit for bit.

use super::*;
use crate::fused::SectionDecision;
use crate::health::{MAX_METRICS, Metric};
use crate::laser::{BEAM_BEYOND_MAX, BEAM_NO_RETURN, BEAM_OK, BEAM_SENSOR_CODE, MAX_BEAMS};
use crate::record::TopicRecord;
use crate::sonar::{MAX_SONARS, SonarReading};
use crate::text::FixedStr;
use crate::{
    FusedScan, Health, LaserScan, MapInfo, Odometry, PoseEstimate, SmokeReading, SonarRing,
    VelocityCommand,
};
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};

#[test]
fn names_topics_and_ros2_types_are_unique_and_consistent() {
    let mut names: Vec<&str> = MessageKind::ALL.iter().map(|k| k.name()).collect();
    names.sort_unstable();
    names.dedup();
    assert_eq!(names.len(), MessageKind::ALL.len());
    for &k in MessageKind::ALL {
        assert_eq!(MessageKind::from_name(k.name()), Some(k));
        assert!(k.topics().next().is_some(), "{k} travels on no topic");
        assert_eq!(k.ros2_type().split('/').nth(1), Some("msg"), "{k}");
        // Kinds that share a standard ROS 2 type are told apart by their companion.
        for &other in MessageKind::ALL.iter().filter(|&&o| o != k) {
            if other.ros2_type() == k.ros2_type() {
                let (a, b) = (k.companion().unwrap(), other.companion().unwrap());
                assert_ne!(a.ros2_type, b.ros2_type, "{k} and {other}");
            }
        }
        if let Some(c) = k.companion() {
            assert!(c.suffix.starts_with('/'), "{k}");
            assert!(c.ros2_type.starts_with("smokenav_msgs/msg/"), "{k}");
            assert!(
                MessageKind::ALL
                    .iter()
                    .all(|o| o.ros2_type() != c.ros2_type),
                "{k}'s companion is also a main type"
            );
        }
    }
    for (i, t) in TOPICS.iter().enumerate() {
        assert_eq!(t.ros2_name, format!("/{}", t.name));
        assert!(TOPICS[..i].iter().all(|o| o.name != t.name), "{}", t.name);
        assert_eq!(t.family, t.name.ends_with('/'), "{}", t.name);
    }
}

#[test]
fn topics_resolve_to_their_kind_and_families_to_their_members() {
    assert_eq!(topic_kind("laser/scan"), Some(MessageKind::LaserScan));
    assert_eq!(topic_kind("fusion/scan"), Some(MessageKind::FusedScan));
    assert_eq!(topic_kind("slam/map"), Some(MessageKind::Map));
    assert_eq!(topic_kind("mapping/projected"), Some(MessageKind::Map));
    assert_eq!(topic_kind("mapping/voxels"), Some(MessageKind::VoxelCloud));
    assert_eq!(topic_kind("health/hokuyo"), Some(MessageKind::Health));
    assert_eq!(
        topic_kind("health/"),
        None,
        "a family's prefix is not a topic"
    );
    assert_eq!(topic_kind("health/a/b"), None);
    assert_eq!(topic_kind("lazer/scan"), None);
    assert_eq!(topic_info("slam/pose").unwrap().ros2_name, "/slam/pose");
    assert_eq!(ros2_topic_name("health/fusion"), "/health/fusion");
    assert_eq!(MessageKind::Map.name(), "MapInfo");
    assert!(MessageKind::Map.latched() && !MessageKind::LaserScan.latched());
}

struct WhatType;

impl MessageVisitor for WhatType {
    type Output = (Option<MessageKind>, &'static str);
    fn fixed<M: Cataloged>(&mut self) -> Self::Output {
        (Some(M::KIND), M::NAME)
    }
    fn map(&mut self) -> Self::Output {
        (None, "map")
    }
}

#[test]
fn visit_calls_back_with_the_kinds_own_type() {
    for &k in MessageKind::ALL {
        let (kind, name) = k.visit(&mut WhatType);
        match kind {
            Some(kind) => {
                assert_eq!(kind, k);
                assert_eq!(name, k.name());
            }
            None => assert_eq!(k, MessageKind::Map),
        }
    }
}

// ---- JSON ------------------------------------------------------------------

/// Floats of every class: specials often, then any bit pattern. NaN is the
/// canonical one: the JSON form keeps NaN, not its payload bits.
fn f32s() -> impl Strategy<Value = f32> {
    prop_oneof![
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
        1 => Just(f32::NEG_INFINITY),
        1 => Just(-0.0f32),
        1 => Just(f32::MIN_POSITIVE / 2.0),
        8 => any::<u32>().prop_map(|b| canonical32(f32::from_bits(b))),
    ]
}

fn f64s() -> impl Strategy<Value = f64> {
    prop_oneof![
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(f64::NEG_INFINITY),
        1 => Just(-0.0f64),
        1 => Just(f64::MIN_POSITIVE / 2.0),
        8 => any::<u64>().prop_map(|b| canonical64(f64::from_bits(b))),
    ]
}

fn canonical32(v: f32) -> f32 {
    if v.is_nan() { f32::NAN } else { v }
}

fn canonical64(v: f64) -> f64 {
    if v.is_nan() { f64::NAN } else { v }
}

/// Text that fits `max` bytes.
fn text(max_chars: usize) -> impl Strategy<Value = String> {
    proptest::collection::vec(any::<char>(), 0..=max_chars).prop_map(|c| c.into_iter().collect())
}

fn header() -> impl Strategy<Value = Header> {
    (any::<u64>(), any::<u64>(), text(8)).prop_map(|(t, s, f)| Header::new(t, s, &f))
}

/// A scan as a publisher fills it: beams without a range hold what
/// `set_beam` writes, unused capacity its default.
fn laser_scan() -> impl Strategy<Value = Box<LaserScan>> {
    let beam = (0u8..4, f32s(), any::<u8>(), f32s());
    (
        header(),
        proptest::collection::vec(f32s(), 6),
        proptest::collection::vec(beam, 0..=MAX_BEAMS),
        any::<bool>(),
    )
        .prop_map(|(header, v, beams, intensities)| {
            let mut s = Box::new(LaserScan {
                header,
                angle_min: v[0],
                angle_increment: v[1],
                time_increment: v[2],
                scan_time: v[3],
                range_min: v[4],
                range_max: v[5],
                count: beams.len() as u32,
                has_intensities: u32::from(intensities),
                ..Default::default()
            });
            for (i, (reason, range, code, intensity)) in beams.into_iter().enumerate() {
                let (range, error) = match reason {
                    0 => (range, BEAM_OK),
                    1 => (f32::INFINITY, BEAM_NO_RETURN),
                    2 => (f32::INFINITY, BEAM_BEYOND_MAX),
                    _ => (f32::NAN, BEAM_SENSOR_CODE | u16::from(code)),
                };
                s.ranges[i] = range;
                s.beam_error[i] = error;
                if intensities {
                    s.intensities[i] = intensity;
                }
            }
            s
        })
}

fn fused_scan() -> impl Strategy<Value = Box<FusedScan>> {
    let section = (
        any::<u16>(),
        any::<u16>(),
        any::<u8>(),
        0u8..4,
        (f32s(), f32s(), f32s()),
    );
    (
        laser_scan(),
        any::<u8>(),
        (0u8..3, 0u8..3),
        proptest::collection::vec(section, 0..=MAX_SONARS),
        (f32s(), f32s(), any::<u64>(), any::<u64>()),
    )
        .prop_map(
            |(scan, seed, (method, sync), sections, (smoke, spread, ts, tm))| {
                let mut f = Box::new(FusedScan {
                    scan: *scan,
                    method,
                    sync_state: sync,
                    section_count: sections.len() as u32,
                    smoke_level: smoke,
                    laser_spread: spread,
                    sonar_stamp_ns: ts,
                    smoke_stamp_ns: tm,
                    ..Default::default()
                });
                for i in 0..f.scan.len() {
                    f.beam_source[i] = seed.wrapping_add(i as u8) % 4;
                }
                for (d, (first, end, sonar, source, (rs, rl, range))) in
                    f.sections.iter_mut().zip(sections)
                {
                    *d = SectionDecision {
                        first_beam: first,
                        end_beam: end,
                        sonar_index: sonar,
                        source,
                        _reserved: [0; 2],
                        rho_sonar: rs,
                        rho_laser: rl,
                        sonar_range: range,
                    };
                }
                f
            },
        )
}

fn odometry() -> impl Strategy<Value = Odometry> {
    (
        header(),
        proptest::collection::vec(f64s(), 5),
        any::<u32>(),
        any::<u32>(),
        f32s(),
    )
        .prop_map(|(header, v, flags, bumpers, battery_v)| Odometry {
            header,
            x: v[0],
            y: v[1],
            theta: v[2],
            linear: v[3],
            angular: v[4],
            flags,
            bumpers,
            battery_v,
            _reserved: 0,
        })
}

fn sonar_ring() -> impl Strategy<Value = SonarRing> {
    let reading = (any::<u8>(), f32s(), 0u8..3);
    (
        header(),
        f32s(),
        proptest::collection::vec(reading, 0..=MAX_SONARS),
    )
        .prop_map(|(header, max_range, readings)| {
            let mut r = SonarRing {
                header,
                max_range,
                ..Default::default()
            };
            for (index, range, status) in readings {
                r.push(SonarReading {
                    range,
                    index,
                    status,
                    _reserved: [0; 2],
                });
            }
            r
        })
}

fn velocity_command() -> impl Strategy<Value = VelocityCommand> {
    (header(), f64s(), f64s()).prop_map(|(header, linear, angular)| VelocityCommand {
        header,
        linear,
        angular,
    })
}

fn smoke_reading() -> impl Strategy<Value = SmokeReading> {
    (
        header(),
        (f32s(), any::<u32>(), f32s(), f32s()),
        (0u8..3, 0u8..4),
    )
        .prop_map(
            |(header, (raw_mv, raw_counts, level, baseline_mv), (trend, state))| SmokeReading {
                header,
                raw_mv,
                raw_counts,
                level,
                baseline_mv,
                trend,
                state,
                _reserved: [0; 6],
            },
        )
}

fn pose_estimate() -> impl Strategy<Value = PoseEstimate> {
    (
        header(),
        proptest::collection::vec(f64s(), 12),
        f32s(),
        (any::<u32>(), any::<u64>(), any::<u32>()),
    )
        .prop_map(
            |(header, v, n_eff, (particles, skipped, us))| PoseEstimate {
                header,
                x: v[0],
                y: v[1],
                theta: v[2],
                covariance: v[3..].try_into().unwrap(),
                n_eff,
                particles,
                scans_skipped: skipped,
                processing_us: us,
                _reserved: 0,
            },
        )
}

fn voxel_cloud() -> impl Strategy<Value = Box<crate::VoxelCloud>> {
    (
        header(),
        f32s(),
        any::<u32>(),
        proptest::collection::vec((f32s(), f32s(), f32s()), 0..40),
    )
        .prop_map(|(header, resolution, truncated, points)| {
            let mut c = Box::<crate::VoxelCloud>::default();
            c.header = header;
            c.resolution = resolution;
            for (x, y, z) in points {
                c.push([x, y, z]);
            }
            c.truncated = truncated;
            c
        })
}

fn health() -> impl Strategy<Value = Box<Health>> {
    (
        header(),
        (text(4), any::<u32>(), 0u8..5, f64s()),
        (f32s(), f32s(), f32s(), any::<u64>()),
        proptest::collection::vec((text(5), f64s(), f64s()), 0..=MAX_METRICS),
        text(40),
    )
        .prop_map(
            |(header, (role, pid, state, uptime), (p50, p99, max, misses), metrics, error)| {
                let mut h = Box::new(Health::new(&role, pid));
                h.header = header;
                h.state = state;
                h.uptime_s = uptime;
                h.latency_p50_us = p50;
                h.latency_p99_us = p99;
                h.latency_max_us = max;
                h.deadline_misses = misses;
                h.metric_count = metrics.len() as u32;
                for (i, (m, (name, value, expected))) in
                    h.metrics.iter_mut().zip(metrics).enumerate()
                {
                    // Names are keys: a report never holds one twice.
                    *m = Metric {
                        name: FixedStr::from_str_truncate(&format!("{i:02}{name}")),
                        value,
                        expected,
                    };
                }
                h.last_error = FixedStr::from_str_truncate(&error);
                h
            },
        )
}

fn map() -> impl Strategy<Value = (MapInfo, Vec<i8>)> {
    (
        header(),
        f32s(),
        0u32..24,
        0u32..24,
        (f64s(), f64s(), f64s()),
    )
        .prop_flat_map(|(header, resolution, width, height, (x, y, theta))| {
            let info = MapInfo {
                header,
                resolution,
                width,
                height,
                _reserved: 0,
                origin_x: x,
                origin_y: y,
                origin_theta: theta,
            };
            (
                Just(info),
                proptest::collection::vec(any::<i8>(), info.cell_count()),
            )
        })
}

/// Messages of `kind` as a publisher fills them.
fn messages(kind: MessageKind) -> BoxedStrategy<AnyMessage> {
    match kind {
        MessageKind::LaserScan => laser_scan().prop_map(AnyMessage::LaserScan).boxed(),
        MessageKind::Odometry => odometry().prop_map(AnyMessage::Odometry).boxed(),
        MessageKind::SonarRing => sonar_ring().prop_map(AnyMessage::SonarRing).boxed(),
        MessageKind::VelocityCommand => velocity_command()
            .prop_map(AnyMessage::VelocityCommand)
            .boxed(),
        MessageKind::SmokeReading => smoke_reading().prop_map(AnyMessage::SmokeReading).boxed(),
        MessageKind::SimClock => header()
            .prop_map(|header| AnyMessage::SimClock(crate::SimClock { header }))
            .boxed(),
        MessageKind::FusedScan => fused_scan().prop_map(AnyMessage::FusedScan).boxed(),
        MessageKind::PoseEstimate => pose_estimate().prop_map(AnyMessage::PoseEstimate).boxed(),
        MessageKind::Health => health().prop_map(AnyMessage::Health).boxed(),
        MessageKind::VoxelCloud => voxel_cloud().prop_map(AnyMessage::VoxelCloud).boxed(),
        MessageKind::Map => map().prop_map(|(i, c)| AnyMessage::Map(i, c)).boxed(),
    }
}

fn through_json(m: &AnyMessage) -> AnyMessage {
    let line = serde_json::to_string(&TopicRecord {
        topic: "t".into(),
        message: m.to_json(),
    })
    .unwrap();
    let back: TopicRecord = serde_json::from_str(&line).unwrap_or_else(|e| panic!("{e}: {line}"));
    AnyMessage::from_json(&back.message).unwrap_or_else(|e| panic!("{e}: {line}"))
}

#[test]
fn every_catalog_type_survives_json_bit_for_bit() {
    for &kind in MessageKind::ALL {
        let mut runner = TestRunner::new(Config {
            cases: 64,
            ..Config::default()
        });
        runner
            .run(&messages(kind), |m| {
                let back = through_json(&m);
                prop_assert_eq!(back.kind(), kind);
                prop_assert!(back.bit_identical(&m), "{:?}\nvs\n{:?}", back, m);
                Ok(())
            })
            .unwrap_or_else(|e| panic!("{kind}: {e}"));
    }
}

#[test]
fn cataloged_json_matches_the_any_message_json() {
    let mut h = Health::new("fusion", 7);
    h.set_metric("scan_hz", f64::INFINITY, Some(10.0));
    let direct = Cataloged::to_json(&h);
    assert_eq!(direct, AnyMessage::Health(Box::new(h)).to_json());
    let mut back = Health::default();
    Health::from_json(&direct, &mut back).unwrap();
    assert!(back.bit_identical(&h));
    let mut scan = LaserScan::default();
    assert!(matches!(
        LaserScan::from_json(&direct, &mut scan),
        Err(ConversionError::WrongType {
            expected: "LaserScan",
            got: "Health"
        })
    ));
}

#[test]
fn non_finite_floats_are_named_strings_in_json() {
    let mut scan = LaserScan {
        count: 2,
        range_max: f32::INFINITY,
        angle_min: f32::NEG_INFINITY,
        ..Default::default()
    };
    scan.ranges[0] = f32::NAN;
    scan.beam_error[0] = BEAM_OK;
    scan.set_beam(1, crate::BeamReading::SensorCode(3));
    let json = serde_json::to_string(&Cataloged::to_json(&scan)).unwrap();
    assert!(json.contains(r#""range_max":"Infinity""#), "{json}");
    assert!(json.contains(r#""angle_min":"-Infinity""#), "{json}");
    // A valid beam whose range is NaN is not a beam without a range.
    assert!(json.contains(r#""ranges":["NaN",null]"#), "{json}");
}

#[test]
fn null_floats_written_by_older_versions_read_as_nan() {
    let line = r#"{"topic":"base/sonar","type":"SonarRing","header":{"stamp_ns":1,"seq":2,"frame_id":"s"},
        "max_range":null,"readings":[{"index":3,"range":null,"status":"invalid"}]}"#;
    let rec: TopicRecord = serde_json::from_str(line).unwrap();
    let AnyMessage::SonarRing(r) = AnyMessage::from_json(&rec.message).unwrap() else {
        panic!("not a sonar ring")
    };
    assert!(r.max_range.is_nan());
    assert!(r.readings()[0].range.is_nan());
    assert!(serde_json::from_str::<TopicRecord>(&line.replace("null,", "\"nan\",")).is_err());
}

#[test]
fn a_map_record_without_its_cells_is_not_a_map() {
    let info = MapInfo {
        width: 2,
        height: 3,
        ..Default::default()
    };
    let rec = record::MapInfoRecord::from(&info);
    assert_eq!(
        rec.to_map(),
        Err(ConversionError::LengthMismatch {
            field: "data",
            len: 0,
            expected: 6
        })
    );
}

#[test]
fn a_reused_scan_buffer_is_overwritten_entirely() {
    let mut long = LaserScan {
        count: 5,
        has_intensities: 1,
        ..Default::default()
    };
    long.ranges[..5].fill(3.0);
    long.beam_error[..5].fill(BEAM_OK);
    long.intensities[..5].fill(9.0);
    let mut short = LaserScan {
        count: 1,
        ..Default::default()
    };
    short.set_beam(0, crate::BeamReading::Range(1.0));
    let mut buf = long;
    LaserScan::write_record(&short.to_record(), &mut buf).unwrap();
    assert!(buf.bit_identical(&short));
}
