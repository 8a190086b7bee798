//! `fuse_jsonl` over constructed recordings in the `topic echo --json` format.

use smokenav_algorithms_fusion::offline::{BadLine, LineError, OfflineReport, fuse_jsonl};
use smokenav_algorithms_fusion::pipeline::FusionPipeline;
use smokenav_algorithms_fusion::testkit::{Room, smoke_reading, smoky_scan};
use smokenav_platform_config::RobotConfig;
use smokenav_shared_types::record::{FusedScanRecord, Message, TopicRecord};
use smokenav_shared_types::{FusionMethod, LaserScan, SmokeTrend, SonarRing};
use std::path::PathBuf;

const MS: u64 = 1_000_000;

fn profile() -> RobotConfig {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../config/pioneer-3dx.toml");
    RobotConfig::load(&p).unwrap()
}

fn line(topic: &str, message: Message) -> String {
    serde_json::to_string(&TopicRecord {
        topic: topic.into(),
        message,
    })
    .unwrap()
}

fn laser_line(s: &LaserScan) -> String {
    line("laser/scan", Message::LaserScan(s.into()))
}

fn sonar_line(r: &SonarRing) -> String {
    line("base/sonar", Message::SonarRing(r.into()))
}

/// `n` cycles at 10 Hz: laser at t, sonar at t + 3 ms, smoke at t + 6 ms.
/// Cycles in `smoky` have dense smoke (laser 0.5 m uniform, level 250).
fn recording(n: u64, smoky: impl Fn(u64) -> bool, with_sonar: bool) -> Vec<String> {
    let pipeline = FusionPipeline::from_config(&profile(), None).unwrap();
    let geometry = pipeline.engine().geometry().clone();
    let room = Room::default();
    let mut lines = Vec::new();
    for k in 0..n {
        let t = 1_000 * MS + k * 100 * MS;
        let dense = smoky(k);
        let scan = if dense {
            smoky_scan(t, k)
        } else {
            room.scan(t, k)
        };
        lines.push(laser_line(&scan));
        if with_sonar {
            lines.push(sonar_line(&room.ring(&geometry, 7.5, t + 3 * MS, k)));
        }
        let level = if dense { 250.0 } else { 0.0 };
        let reading = smoke_reading(t + 6 * MS, k, level, SmokeTrend::Rising);
        lines.push(line(
            "smoke/level",
            Message::SmokeReading((&reading).into()),
        ));
    }
    lines
}

fn run(
    method: FusionMethod,
    input: &str,
) -> (Vec<FusedScanRecord>, OfflineReport, Vec<(u64, String)>) {
    let mut pipeline = FusionPipeline::from_config(&profile(), Some(method)).unwrap();
    let mut out = Vec::new();
    let mut bad = Vec::new();
    let report = fuse_jsonl(&mut pipeline, input.as_bytes(), &mut out, |b: &BadLine| {
        bad.push((b.line, b.error.to_string()))
    })
    .unwrap();
    let text = String::from_utf8(out).unwrap();
    let fused = text
        .lines()
        .map(|l| {
            let rec: TopicRecord = serde_json::from_str(l).unwrap();
            assert_eq!(rec.topic, "fusion/scan");
            match rec.message {
                Message::FusedScan(f) => f,
                other => panic!("unexpected {other:?}"),
            }
        })
        .collect();
    (fused, report, bad)
}

#[test]
fn laser_only_writes_every_scan_unchanged() {
    let lines = recording(10, |k| k >= 5, true);
    let (fused, report, bad) = run(FusionMethod::LaserOnly, &lines.join("\n"));
    assert!(bad.is_empty());
    assert_eq!(report.laser, 10);
    assert_eq!(fused.len(), 10);
    for (k, f) in fused.iter().enumerate() {
        let Message::LaserScan(input) = serde_json::from_str::<TopicRecord>(&lines[3 * k])
            .unwrap()
            .message
        else {
            panic!()
        };
        assert_eq!(f.scan, input, "scan {k} must be the input, bit for bit");
        assert_eq!(f.method, "laser-only");
        assert_eq!(f.sonar_usage, 0.0);
    }
}

#[test]
fn v2_uses_the_sonar_only_while_the_laser_is_in_smoke() {
    let (fused, report, bad) = run(
        FusionMethod::V2,
        &recording(10, |k| (3..7).contains(&k), true).join("\n"),
    );
    assert!(bad.is_empty(), "{bad:?}");
    assert_eq!(
        report.written, 10,
        "one fused scan per laser scan, the last one flushed"
    );
    for (k, f) in fused.iter().enumerate() {
        assert_eq!(f.scan.header.stamp_ns, 1_000 * MS + k as u64 * 100 * MS);
        assert_eq!(f.sync_state, "complete");
        assert_eq!(f.sonar_stamp_ns, f.scan.header.stamp_ns + 3 * MS);
        if (3..7).contains(&k) {
            assert_eq!(f.sonar_usage, 1.0, "cycle {k}");
            assert!(
                f.sections
                    .iter()
                    .all(|s| s.source == "sonar" && s.rho_sonar > 0.5)
            );
        } else {
            assert_eq!(f.sonar_usage, 0.0, "cycle {k}");
        }
    }
}

#[test]
fn bad_lines_are_reported_with_their_numbers_and_skipped() {
    let mut lines = recording(4, |_| false, true);
    lines.insert(1, "{not json".into()); // line 2
    let sonar_on_laser_topic =
        lines[2].replace("\"topic\":\"base/sonar\"", "\"topic\":\"laser/scan\"");
    lines.insert(3, sonar_on_laser_topic); // line 4
    lines.insert(4, String::new()); // line 5: blank, fine
    let short = lines[0].replace("\"beam_error\":[0,", "\"beam_error\":[");
    lines.insert(5, short); // line 6: one beam_error short
    lines.insert(6, line("base/odom", Message::Odometry(Default::default()))); // line 7: other topic
    let (fused, report, bad) = run(FusionMethod::V1, &lines.join("\n"));
    let numbers: Vec<u64> = bad.iter().map(|b| b.0).collect();
    assert_eq!(numbers, vec![2, 4, 6], "{bad:?}");
    assert!(bad[0].1.contains("JSON"), "{}", bad[0].1);
    assert!(
        bad[1].1.contains("LaserScan") && bad[1].1.contains("SonarRing"),
        "{}",
        bad[1].1
    );
    assert!(bad[2].1.contains("beam_error"), "{}", bad[2].1);
    assert_eq!(report.bad, 3);
    assert_eq!(report.ignored, 1);
    assert_eq!(fused.len(), 4);
}

#[test]
fn replaying_a_recording_gives_identical_bytes() {
    let input = recording(20, |k| k % 4 == 1, true).join("\n");
    let once = || {
        let mut pipeline = FusionPipeline::from_config(&profile(), Some(FusionMethod::V2)).unwrap();
        let mut out = Vec::new();
        fuse_jsonl(&mut pipeline, input.as_bytes(), &mut out, |_| {}).unwrap();
        out
    };
    let a = once();
    assert!(!a.is_empty());
    assert_eq!(a, once());
}

#[test]
fn recording_without_sonar_degrades_to_laser_only_after_the_timeout() {
    // No sonar at all; timeout 0.5 s: scans from t = 1.0 s are held until the
    // virtual clock passes 1.5 s, then every scan goes out as the laser alone.
    let (fused, _, bad) = run(FusionMethod::V2, &recording(10, |_| true, false).join("\n"));
    assert!(bad.is_empty());
    assert_eq!(fused.len(), 10);
    for f in &fused {
        assert_eq!(f.sync_state, "laser-only");
        assert_eq!(f.sonar_usage, 0.0);
        assert!(
            f.scan.ranges.iter().all(|r| r.is_some_and(|r| r < 0.52)),
            "the laser, untouched"
        );
    }
}

#[test]
fn too_long_and_non_utf8_lines_are_bad_not_fatal() {
    let mut input = recording(2, |_| false, true).join("\n").into_bytes();
    input.extend_from_slice(b"\n\xff\xfe\n");
    input.extend(std::iter::repeat_n(b'x', 5 << 20));
    input.push(b'\n');
    let mut pipeline = FusionPipeline::from_config(&profile(), Some(FusionMethod::V2)).unwrap();
    let mut bad = Vec::new();
    let report = fuse_jsonl(&mut pipeline, &input[..], std::io::sink(), |b| {
        bad.push((
            b.line,
            matches!(b.error, LineError::NotUtf8),
            matches!(b.error, LineError::TooLong { .. }),
        ))
    })
    .unwrap();
    assert_eq!(bad, vec![(7, true, false), (8, false, true)]);
    assert_eq!(report.written, 2);
}

#[test]
fn laser_only_still_tracks_the_smoke_state() {
    let mut pipeline =
        FusionPipeline::from_config(&profile(), Some(FusionMethod::LaserOnly)).unwrap();
    let input = recording(3, |_| true, true).join("\n");
    fuse_jsonl(&mut pipeline, input.as_bytes(), std::io::sink(), |_| {}).unwrap();
    assert_eq!(
        pipeline.engine().smoke_state(),
        smokenav_algorithms_fusion::v1::SmokeState::Dense
    );
}
