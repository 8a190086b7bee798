//! `smokenav fuse` as a user runs it: the real binary, JSON lines on stdin.

use smokenav_algorithms_fusion::geometry::SonarGeometry;
use smokenav_algorithms_fusion::testkit::{Room, smoke_reading, smoky_scan};
use smokenav_platform_config::RobotConfig;
use smokenav_shared_types::SmokeTrend;
use smokenav_shared_types::record::{FusedScanRecord, Message, TopicRecord};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

const MS: u64 = 1_000_000;

fn profile_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../config")
        .join(name)
}

fn line(topic: &str, message: Message) -> String {
    serde_json::to_string(&TopicRecord {
        topic: topic.into(),
        message,
    })
    .unwrap()
}

/// 10 Hz cycles; `dense(k)` puts cycle k in dense smoke (laser 0.5 m, level 250).
fn recording(profile: &Path, n: u64, dense: impl Fn(u64) -> bool) -> String {
    let cfg = RobotConfig::load(profile).unwrap();
    let g = SonarGeometry::from_config(&cfg.laser, &cfg.sonar, &cfg.fusion).unwrap();
    let half_cone = cfg.sonar.cone_deg / 2.0;
    let room = Room::default();
    let mut out = String::new();
    for k in 0..n {
        let t = 2_000 * MS + k * 100 * MS;
        let scan = if dense(k) {
            smoky_scan(t, k)
        } else {
            room.scan(t, k)
        };
        let ring = room.ring(&g, half_cone, t + 2 * MS, k);
        let smoke = smoke_reading(
            t + 4 * MS,
            k,
            if dense(k) { 250.0 } else { 0.0 },
            SmokeTrend::Rising,
        );
        for l in [
            line("laser/scan", Message::LaserScan((&scan).into())),
            line("base/sonar", Message::SonarRing((&ring).into())),
            line("base/odom", Message::Odometry(Default::default())),
            line("smoke/level", Message::SmokeReading((&smoke).into())),
        ] {
            out.push_str(&l);
            out.push('\n');
        }
    }
    out
}

fn fuse(args: &[&str], stdin: &str) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_smokenav"))
        .arg("fuse")
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut input = child.stdin.take().unwrap();
    let data = stdin.to_owned();
    let writer = std::thread::spawn(move || input.write_all(data.as_bytes()));
    let out = child.wait_with_output().unwrap();
    writer.join().unwrap().unwrap();
    out
}

fn records(out: &Output) -> Vec<FusedScanRecord> {
    String::from_utf8(out.stdout.clone())
        .unwrap()
        .lines()
        .map(|l| {
            let r: TopicRecord = serde_json::from_str(l).unwrap();
            assert_eq!(r.topic, "fusion/scan");
            let Message::FusedScan(f) = r.message else {
                panic!("not a FusedScan: {l}")
            };
            f
        })
        .collect()
}

#[test]
fn v2_replaces_the_smoky_scans_with_sonar_and_keeps_the_clean_ones() {
    let p = profile_path("nomad-scout.toml");
    let out = fuse(
        &["--method", "v2", "--config", p.to_str().unwrap()],
        &recording(&p, 8, |k| k >= 4),
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let f = records(&out);
    assert_eq!(f.len(), 8);
    for (k, r) in f.iter().enumerate() {
        assert_eq!(r.method, "v2");
        assert_eq!(
            r.sections.len(),
            11,
            "the Scout's 11 sonars the URG-04LX sees"
        );
        let expected = if k >= 4 { 1.0 } else { 0.0 };
        assert_eq!(r.sonar_usage, expected, "scan {k}");
    }
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("8 fused scans") && err.contains("other topics 8"),
        "{err}"
    );
}

#[test]
fn laser_only_without_config_uses_the_built_in_profile_and_changes_nothing() {
    let p = profile_path("pioneer-3dx.toml");
    let input = recording(&p, 5, |_| true);
    let out = fuse(&["--method", "laser-only"], &input);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let f = records(&out);
    assert_eq!(f.len(), 5);
    let scans: Vec<_> = input
        .lines()
        .filter_map(
            |l| match serde_json::from_str::<TopicRecord>(l).unwrap().message {
                Message::LaserScan(s) => Some(s),
                _ => None,
            },
        )
        .collect();
    for (r, s) in f.iter().zip(&scans) {
        assert_eq!(&r.scan, s);
        assert_eq!(r.sections.len(), 8, "the P3-DX's 8 front sonars");
    }
}

#[test]
fn bad_lines_are_named_on_stderr_and_the_rest_is_fused() {
    let p = profile_path("pioneer-3dx.toml");
    let mut lines: Vec<String> = recording(&p, 3, |_| false)
        .lines()
        .map(str::to_owned)
        .collect();
    lines.insert(2, "garbage".into());
    lines.insert(5, r#"{"topic":"smoke/level","type":"SmokeReading"}"#.into());
    let out = fuse(&["--method", "v1"], &(lines.join("\n") + "\n"));
    assert!(out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("line 3:"), "{err}");
    assert!(err.contains("line 6:"), "{err}");
    assert!(err.contains("bad 2"), "{err}");
    assert_eq!(records(&out).len(), 3);
}

#[test]
fn same_recording_gives_the_same_bytes() {
    let p = profile_path("pioneer-3dx.toml");
    let input = recording(&p, 12, |k| k % 3 == 0);
    let a = fuse(&["--method", "v1"], &input);
    let b = fuse(&["--method", "v1"], &input);
    assert!(a.status.success() && !a.stdout.is_empty());
    assert_eq!(a.stdout, b.stdout);
}

#[test]
fn unknown_method_and_missing_profile_fail_with_a_reason() {
    let out = fuse(&["--method", "v3"], "");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("v3"));
    let out = fuse(
        &["--method", "v2", "--config", "/nonexistent/robot.toml"],
        "",
    );
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/robot.toml"));
}
