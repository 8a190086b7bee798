//! Taps end to end: `smokenav record` on a live bus (publisher processes at
//! 10 Hz), the file checked by readers smokenav did not write (Python `mcap`,
//! `mcap-ros2-support`, `rosbags`), `smokenav play` onto a fresh bus instance
//! reproducing every message bit for bit, a recorder killed with SIGKILL
//! whose file still yields every message of its finished chunks, and a live
//! run's recorded inputs replayed into fresh fusion and SLAM processes giving
//! the live run's fused scans and poses.
//!
//! The publishers are this test binary re-executed in a child role (see
//! `child_role`), like the drivers they stand in for: `laser` (laser/scan),
//! `base` (base/odom and base/sonar), `smoke` (smoke/level).
//!
//! The Python packages are required, not optional: without them the
//! recording tests fail and say how to install them.

use smokenav_platform_bus::{Message as BusMsg, Subscriber, Topic, Waiter, topics};
use smokenav_platform_config::slam::SlamInput;
use smokenav_platform_recording::{AnyMessage, BitIdentical, EndOfData, McapSource, Playback};
use smokenav_shared_types::clock::monotonic_now_ns;
use smokenav_shared_types::laser::BEAM_SENSOR_CODE;
use smokenav_shared_types::{
    BeamReading, FusedScan, Header, LaserScan, Odometry, PoseEstimate, SmokeReading, SonarReading,
    SonarRing, SonarStatus,
};
use smokenav_tests::{Child, bin, open_bus, profile, python, unique_instance, workspace_root};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

const ROLE_ENV: &str = "SMOKENAV_TEST_ROLE";

// ---- what the publishers send: a pure function of the sequence number ------

/// A URG-04LX sweep (682 beams over 240°) with every kind of beam: ranges,
/// no return, beyond max, and sensor error codes 0..19, which REP 117 can
/// only show as NaN. Intensities on even scans.
fn make_scan(base: u64, seq: u64, s: &mut LaserScan) {
    s.header = Header::new(base + seq * 100_000_000, seq, "laser");
    s.angle_min = -2.094_395_2;
    s.angle_increment = 0.006_135_923;
    s.time_increment = 9.765_625e-5;
    s.scan_time = 0.1;
    s.range_min = 0.02;
    s.range_max = 5.6;
    s.count = 682;
    s.has_intensities = u32::from(seq.is_multiple_of(2));
    for i in 0..682 {
        let k = i as u64 + seq;
        let reading = match k % 13 {
            0 => BeamReading::NoReturn,
            1 => BeamReading::BeyondMax,
            2 | 3 => BeamReading::SensorCode((k % 20) as u16),
            _ => BeamReading::Range(0.02 + ((k * 37) % 5580) as f32 / 1000.0),
        };
        s.set_beam(i, reading);
        if s.has_intensities == 1 {
            s.intensities[i] = ((k * 11) % 4096) as f32;
        }
    }
}

fn make_odom(base: u64, seq: u64) -> Odometry {
    let t = seq as f64 * 0.1;
    Odometry {
        header: Header::new(base + seq * 100_000_000 + 1_000, seq, "odom"),
        x: 0.3 * t,
        y: 0.05 * t * t,
        theta: smokenav_shared_types::odom::normalize_angle(0.4 * t),
        linear: 0.3,
        angular: 0.4,
        flags: 1 | u32::from(seq.is_multiple_of(7)) << 1,
        bumpers: (seq % 3) as u32,
        battery_v: 12.9 - seq as f32 * 0.001,
        _reserved: 0,
    }
}

fn make_sonar(base: u64, seq: u64) -> SonarRing {
    let mut r = SonarRing {
        header: Header::new(base + seq * 100_000_000 + 2_000, seq, "base_link"),
        max_range: 5.0,
        ..Default::default()
    };
    for i in 0..8u8 {
        let k = seq + u64::from(i);
        let (range, status) = match k % 5 {
            0 => (5.0, SonarStatus::Saturated),
            1 => (0.0, SonarStatus::Invalid),
            _ => (0.2 + (k % 40) as f32 * 0.1, SonarStatus::Valid),
        };
        r.push(SonarReading::new(i, range, status));
    }
    r
}

fn make_smoke(base: u64, seq: u64) -> SmokeReading {
    SmokeReading {
        header: Header::new(base + seq * 100_000_000 + 3_000, seq, "smoke"),
        raw_mv: 1_400.0 - seq as f32,
        raw_counts: 287 - (seq % 200) as u32,
        level: seq as f32 * 2.5,
        baseline_mv: 1_400.0,
        trend: (seq % 3) as u8,
        state: 1,
        _reserved: [0; 6],
    }
}

fn expected(base: u64, topic: &str, seq: u64) -> AnyMessage {
    match topic {
        "laser/scan" => {
            let mut s = Box::<LaserScan>::default();
            make_scan(base, seq, &mut s);
            AnyMessage::LaserScan(s)
        }
        "base/odom" => AnyMessage::Odometry(make_odom(base, seq)),
        "base/sonar" => AnyMessage::SonarRing(make_sonar(base, seq)),
        "smoke/level" => AnyMessage::SmokeReading(make_smoke(base, seq)),
        other => panic!("no generator for {other}"),
    }
}

const TOPICS: [&str; 4] = ["laser/scan", "base/odom", "base/sonar", "smoke/level"];

// ---- child processes ----------------------------------------------------------

fn run_publisher(instance: &str, role: &str, count: u64, base: u64) {
    let bus = open_bus(instance);
    let mut scans = (role == "laser").then(|| bus.publisher(topics::LASER_SCAN).unwrap());
    let mut odom = (role == "base").then(|| bus.publisher(topics::BASE_ODOM).unwrap());
    let mut sonar = (role == "base").then(|| bus.publisher(topics::BASE_SONAR).unwrap());
    let mut smoke = (role == "smoke").then(|| bus.publisher(topics::SMOKE_LEVEL).unwrap());
    // Connect to the recorder before the first message (iceoryx2 connects lazily).
    if let Some(p) = &scans {
        p.update_connections().unwrap();
    }
    if let Some(p) = &odom {
        p.update_connections().unwrap();
    }
    if let Some(p) = &sonar {
        p.update_connections().unwrap();
    }
    if let Some(p) = &smoke {
        p.update_connections().unwrap();
    }
    println!("publishing as {role}");
    for seq in 0..count {
        // AnyMessage `seq` is stamped base + seq × 100 ms (host CLOCK_MONOTONIC,
        // shared by all processes) and published at that instant, like a
        // driver stamping on arrival: every publisher of a test is in step.
        sleep_until_monotonic(base + seq * 100_000_000);
        if let Some(p) = &mut scans {
            assert_eq!(p.publish_with(|s| make_scan(base, seq, s)).unwrap(), seq);
        }
        if let Some(p) = &mut odom {
            assert_eq!(p.publish(&make_odom(base, seq)).unwrap(), seq);
        }
        if let Some(p) = &mut sonar {
            assert_eq!(p.publish(&make_sonar(base, seq)).unwrap(), seq);
        }
        if let Some(p) = &mut smoke {
            assert_eq!(p.publish(&make_smoke(base, seq)).unwrap(), seq);
        }
        if seq % 10 == 9 {
            println!("published {}", seq + 1);
        }
    }
    println!("done {count}");
    // Stay alive like a driver until the test ends (samples stay readable).
    std::thread::sleep(Duration::from_secs(600));
}

/// Entry point of the child processes; does nothing unless started by the tests below.
#[test]
#[ignore = "child process entry point, run by the recording tests"]
fn child_role() {
    let instance = std::env::var("SMOKENAV_INSTANCE").unwrap();
    let role = std::env::var(ROLE_ENV).unwrap();
    let count = std::env::var("COUNT").unwrap().parse().unwrap();
    let base = std::env::var("STAMP_BASE_NS").unwrap().parse().unwrap();
    run_publisher(&instance, &role, count, base);
}

fn sleep_until_monotonic(t: u64) {
    let now = monotonic_now_ns();
    if t > now {
        std::thread::sleep(Duration::from_nanos(t - now));
    }
}

/// A stamp base far enough ahead for child processes to start (debug builds).
fn stamp_base(lead: Duration) -> u64 {
    monotonic_now_ns() + lead.as_nanos() as u64
}

/// Starts a publisher child whose message `seq` is stamped and sent at `base` + seq × 100 ms.
fn spawn_publisher(instance: &str, role: &str, count: u64, base: u64) -> Child {
    let exe = std::env::current_exe().unwrap();
    let count = count.to_string();
    let base = base.to_string();
    let env = [
        (ROLE_ENV, role),
        ("COUNT", count.as_str()),
        ("STAMP_BASE_NS", base.as_str()),
    ];
    Child::spawn_env(
        &exe,
        &[
            "child_role",
            "--exact",
            "--ignored",
            "--nocapture",
            "--test-threads=1",
        ],
        instance,
        &env,
    )
    .unwrap()
}

// ---- the independent reader ------------------------------------------------------

/// The three stand-in drivers publish `COUNT` messages each, starting after
/// `lead`; returns once all are done, with the children (kept alive) and the
/// stamp base their messages are built from.
fn publish_all(instance: &str, lead: Duration) -> (Vec<Child>, u64) {
    let base = stamp_base(lead);
    let publishers: Vec<Child> = ["laser", "base", "smoke"]
        .iter()
        .map(|role| spawn_publisher(instance, role, COUNT, base))
        .collect();
    for p in &publishers {
        p.wait_for_line(&format!("done {COUNT}"), Duration::from_secs(60))
            .unwrap();
    }
    (publishers, base)
}

/// Runs tests/python/check_recording.py with the kit's Python (which has the
/// independent readers).
fn run_python_check(args: &[&Path]) -> String {
    let script = workspace_root().join("tests/python/check_recording.py");
    let out = Command::new(python())
        .arg(&script)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", python().display()));
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !stdout.contains("MISSING"),
        "{stdout}\n{} lacks the independent readers of tests/python/requirements.txt",
        python().display()
    );
    assert!(
        out.status.success(),
        "the independent reader rejected the recording:\n{stdout}\n{stderr}"
    );
    stdout.lines().last().unwrap_or("").to_owned()
}

fn bits32(v: f32) -> u64 {
    u64::from(v.to_bits())
}

fn bits64(v: f64) -> u64 {
    v.to_bits()
}

fn u64s(v: &serde_json::Value) -> Vec<u64> {
    v.as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(|x| x.as_u64().unwrap())
        .collect()
}

/// Compares what Python decoded with what the publishers sent.
/// `smokenav info` tells today's date, the topics with their counts, and
/// `--check` passes; a byte flipped inside a chunk makes `--check` name that
/// chunk and fail, which the summary-only `info` cannot see.
fn check_info(file: &Path, dir: &Path) {
    let run = |args: &[&str]| {
        let out = Command::new(bin("smokenav")).args(args).output().unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let (code, text, err) = run(&["info", str_path(file)]);
    assert_eq!(code, Some(0), "{err}");
    eprintln!("smokenav info:\n{text}");
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64;
    let today = &smokenav_platform_recording::info::format_utc(now)[..10];
    assert!(
        text.contains(&format!("Start:             {today}")),
        "{text}"
    );
    let scans = text
        .lines()
        .find(|l| l.contains("Topic: /laser/scan "))
        .unwrap_or_else(|| panic!("no /laser/scan line:\n{text}"));
    assert!(scans.contains("sensor_msgs/msg/LaserScan"), "{scans}");
    assert!(scans.contains(&format!("Count: {COUNT:>7}")), "{scans}");
    // Published at 10 Hz: the rate is the topic's own, not the file's span.
    let rate: f64 = scans
        .split("Rate:")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .and_then(|r| r.parse().ok())
        .unwrap_or_else(|| panic!("no rate in {scans}"));
    assert!((9.0..=11.0).contains(&rate), "{scans}");
    assert!(text.contains("zstd"), "{text}");
    let (code, text, err) = run(&["info", "--check", str_path(file)]);
    assert_eq!(code, Some(0), "{text}{err}");
    assert!(text.contains("Check:             OK"), "{text}");

    let (_, json, _) = run(&["info", "--json", str_path(file)]);
    let v: serde_json::Value = serde_json::from_str(json.trim()).unwrap();
    let chunk = &v["chunks"][0];
    let (offset, length) = (
        chunk["offset"].as_u64().unwrap(),
        chunk["length"].as_u64().unwrap(),
    );
    let mut bytes = std::fs::read(file).unwrap();
    bytes[(offset + length / 2) as usize] ^= 0x01;
    let damaged = dir.join("damaged.mcap");
    std::fs::write(&damaged, &bytes).unwrap();
    let (code, _, err) = run(&["info", str_path(&damaged)]);
    assert_eq!(code, Some(0), "the summary still reads: {err}");
    let (code, text, _) = run(&["info", "--check", str_path(&damaged)]);
    eprintln!("smokenav info --check of a file with a flipped byte:\n{text}");
    assert_eq!(code, Some(1), "{text}");
    assert!(
        text.contains("chunk 0 of ") && text.contains(&format!("at offset {offset}")),
        "{text}"
    );
}

/// The file's log times are real dates (Unix ns, between the test's start
/// `started_unix` and now, give or take a second, as the Python `mcap`
/// reader reads them; "within a minute of now" failed on a loaded machine
/// where the test took 80 s), and its metadata holds the offset
/// that maps them back onto the bus's monotonic clock, where the messages'
/// stamps (from `base` on) live.
fn check_time_base(file: &Path, base: u64, started_unix: i128) {
    let script = workspace_root().join("tests/python/log_times.py");
    let out = Command::new(python())
        .arg(&script)
        .arg(file)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let now_unix = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as i128;
    let second = 1_000_000_000i128;
    for key in [
        "first_log_time",
        "last_log_time",
        "message_start_time",
        "message_end_time",
    ] {
        let t = v[key].as_u64().unwrap() as i128;
        assert!(
            started_unix - second <= t && t <= now_unix + second,
            "{key} {t} is not between the test's start {started_unix} and now {now_unix}: {v}"
        );
    }
    let meta = &v["metadata"]["smokenav"];
    let offset: i128 = meta["unix_offset_ns"].as_str().unwrap().parse().unwrap();
    let start_unix: i128 = meta["start_unix_ns"].as_str().unwrap().parse().unwrap();
    let start_mono: i128 = meta["start_monotonic_ns"]
        .as_str()
        .unwrap()
        .parse()
        .unwrap();
    assert_eq!(start_unix - start_mono, offset, "{meta}");
    // Back on the monotonic clock: the first record (/tf_static) is the
    // start, the last message arrived after the last stamps, before now.
    let first = v["first_log_time"].as_u64().unwrap() as i128 - offset;
    let last = v["last_log_time"].as_u64().unwrap() as i128 - offset;
    assert_eq!(first, start_mono, "{v}");
    assert!(
        last >= base as i128 && last <= monotonic_now_ns() as i128,
        "{last} vs stamps from {base}: {v}"
    );
}

fn check_python_dump(dump: &Path, count: u64, base: u64) {
    let text = std::fs::read_to_string(dump).unwrap();
    let mut per_topic: BTreeMap<String, u64> = BTreeMap::new();
    for line in text.lines() {
        let rec: serde_json::Value = serde_json::from_str(line).unwrap();
        let topic = rec["topic"].as_str().unwrap().to_owned();
        *per_topic.entry(topic.clone()).or_default() += 1;
        let seq = rec["sequence"].as_u64().unwrap();
        let f = &rec["fields"];
        match topic.as_str() {
            "/laser/scan" => {
                let mut s = Box::<LaserScan>::default();
                make_scan(base, seq, &mut s);
                let n = s.len();
                assert_eq!(f["frame_id"], "laser");
                let (sec, nsec) = (
                    s.header.stamp_ns / 1_000_000_000,
                    s.header.stamp_ns % 1_000_000_000,
                );
                assert_eq!(u64s(&f["stamp"]), [sec, nsec]);
                assert_eq!(f["angle_min"].as_u64(), Some(bits32(s.angle_min)));
                assert_eq!(f["angle_max"].as_u64(), Some(bits32(s.angle_max())));
                assert_eq!(f["range_max"].as_u64(), Some(bits32(s.range_max)));
                // REP 117: measured ranges as they are, +inf for no return /
                // beyond max, NaN for a sensor error code.
                let want: Vec<u64> = (0..n)
                    .map(|i| match s.beam(i) {
                        BeamReading::Range(r) => bits32(r),
                        BeamReading::NoReturn | BeamReading::BeyondMax => bits32(f32::INFINITY),
                        BeamReading::SensorCode(_) => bits32(f32::NAN),
                    })
                    .collect();
                assert_eq!(u64s(&f["ranges"]), want, "scan {seq}");
                let want_i: Vec<u64> = if s.has_intensities == 1 {
                    s.intensities[..n].iter().map(|&v| bits32(v)).collect()
                } else {
                    Vec::new()
                };
                assert_eq!(u64s(&f["intensities"]), want_i);
            }
            "/laser/scan/extras" => {
                let mut s = Box::<LaserScan>::default();
                make_scan(base, seq, &mut s);
                let n = s.len();
                assert_eq!(f["stamp_ns"].as_u64(), Some(s.header.stamp_ns));
                assert_eq!(f["seq"].as_u64(), Some(seq));
                let codes: Vec<u64> = s.beam_error[..n].iter().map(|&c| u64::from(c)).collect();
                assert_eq!(u64s(&f["beam_error"]), codes);
                assert!(codes.iter().any(|&c| c & u64::from(BEAM_SENSOR_CODE) != 0));
                let errs: Vec<u64> = (0..n)
                    .filter(|&i| s.beam_error[i] != 0)
                    .map(|i| bits32(s.ranges[i]))
                    .collect();
                assert_eq!(u64s(&f["error_ranges"]), errs);
                assert_eq!(f["has_intensities"].as_bool(), Some(s.has_intensities == 1));
            }
            "/base/odom" => {
                let o = make_odom(base, seq);
                assert_eq!(f["frame_id"], "odom");
                assert_eq!(f["child_frame_id"], "base_link");
                assert_eq!(f["x"].as_u64(), Some(bits64(o.x)));
                assert_eq!(f["y"].as_u64(), Some(bits64(o.y)));
                assert_eq!(f["linear"].as_u64(), Some(bits64(o.linear)));
                assert_eq!(f["angular"].as_u64(), Some(bits64(o.angular)));
                let yaw = f["yaw"].as_f64().unwrap();
                let d = smokenav_shared_types::odom::normalize_angle(yaw - o.theta);
                assert!(d.abs() < 1e-9, "odometry {seq}: yaw {yaw} vs θ {}", o.theta);
            }
            "/base/odom/extras" => {
                let o = make_odom(base, seq);
                assert_eq!(f["theta"].as_u64(), Some(bits64(o.theta)));
                assert_eq!(f["flags"].as_u64(), Some(u64::from(o.flags)));
                assert_eq!(f["bumpers"].as_u64(), Some(u64::from(o.bumpers)));
                assert_eq!(f["battery_v"].as_u64(), Some(bits32(o.battery_v)));
                assert_eq!(f["stamp_ns"].as_u64(), Some(o.header.stamp_ns));
            }
            "/base/sonar" => {
                let r = make_sonar(base, seq);
                assert_eq!(f["stamp_ns"].as_u64(), Some(r.header.stamp_ns));
                assert_eq!(f["seq"].as_u64(), Some(seq));
                assert_eq!(f["max_range"].as_u64(), Some(bits32(r.max_range)));
                let want: Vec<Vec<u64>> = r
                    .readings()
                    .iter()
                    .map(|x| vec![u64::from(x.index), u64::from(x.status), bits32(x.range)])
                    .collect();
                let got: Vec<Vec<u64>> =
                    f["readings"].as_array().unwrap().iter().map(u64s).collect();
                assert_eq!(got, want);
            }
            "/smoke/level" => {
                let s = make_smoke(base, seq);
                assert_eq!(f["stamp_ns"].as_u64(), Some(s.header.stamp_ns));
                assert_eq!(f["level"].as_u64(), Some(bits32(s.level)));
                assert_eq!(f["raw_mv"].as_u64(), Some(bits32(s.raw_mv)));
                assert_eq!(f["raw_counts"].as_u64(), Some(u64::from(s.raw_counts)));
                assert_eq!(f["trend"].as_u64(), Some(u64::from(s.trend)));
            }
            "/tf" => {
                let t = &f["transforms"][0];
                assert_eq!(t[0], "odom");
                assert_eq!(t[1], "base_link");
            }
            "/tf_static" => {
                let t = &f["transforms"][0];
                assert_eq!(
                    (t[0].as_str(), t[1].as_str()),
                    (Some("base_link"), Some("laser"))
                );
                assert_eq!(
                    t[2].as_f64(),
                    Some(0.16),
                    "the Pioneer profile mounts the laser 16 cm ahead"
                );
            }
            "/base/sonar/points" => {
                assert_eq!(f["width"].as_u64(), Some(8));
            }
            other => panic!("unexpected channel {other}"),
        }
    }
    for t in TOPICS {
        assert_eq!(
            per_topic.get(&format!("/{t}")),
            Some(&count),
            "{t}: {per_topic:?}"
        );
    }
    for companion in [
        "/laser/scan/extras",
        "/base/odom/extras",
        "/base/sonar/points",
        "/tf",
    ] {
        assert_eq!(per_topic.get(companion), Some(&count), "{companion}");
    }
    assert_eq!(per_topic.get("/tf_static"), Some(&1));
}

/// `topic  received N  lost M` lines of the recorder's report.
fn recorder_report(out: &str) -> BTreeMap<String, (u64, u64)> {
    let mut m = BTreeMap::new();
    for line in out.lines() {
        let w: Vec<&str> = line.split_whitespace().collect();
        if w.len() >= 5 && w[1] == "received" && w[3] == "lost" {
            m.insert(
                w[0].to_owned(),
                (w[2].parse().unwrap(), w[4].parse().unwrap()),
            );
        }
    }
    m
}

fn smokenav(args: &[&str], instance: &str) -> Child {
    Child::spawn(&bin("smokenav"), args, instance).unwrap()
}

fn str_path(p: &Path) -> &str {
    p.to_str().unwrap()
}

// ---- (a) and (b): record live, check independently, replay bit for bit -----------

const COUNT: u64 = 50;

#[test]
fn live_run_recorded_decodes_in_python_and_replays_bit_identical() {
    let started_unix = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as i128;
    let dir = tempfile::tempdir().unwrap();
    let cfg = profile(dir.path(), "pioneer-3dx.toml", |_| {});
    let file: PathBuf = dir.path().join("run.mcap");
    let live = unique_instance("rec_live");

    // The recorder subscribes first (default: every known topic of the instance).
    let mut recorder = smokenav(
        &[
            "record",
            "-o",
            str_path(&file),
            "--config",
            str_path(&cfg),
            "--instance",
            &live,
        ],
        &live,
    );
    recorder
        .wait_for_line("recording", Duration::from_secs(60))
        .unwrap();
    let (publishers, base) = publish_all(&live, Duration::from_secs(2));
    // The last messages reach the recorder within a wait; then stop it cleanly.
    std::thread::sleep(Duration::from_millis(500));
    recorder.signal(nix::sys::signal::Signal::SIGINT);
    let status = recorder.wait_exit(Duration::from_secs(30)).unwrap();
    assert!(status.success(), "recorder failed:\n{}", recorder.output());
    let out = recorder.output();
    let report = recorder_report(&out);
    for t in TOPICS {
        assert_eq!(
            report.get(t),
            Some(&(COUNT, 0)),
            "{t}: no gaps expected at 10 Hz\n{out}"
        );
    }
    assert!(out.contains("gaps: 0 messages lost"), "{out}");
    drop(publishers);

    // (a) An independent reader decodes every message; compare with what was sent.
    let dump = dir.path().join("dump.jsonl");
    let summary = run_python_check(&[&file, &dump]);
    assert!(summary.starts_with("OK "), "{summary}");
    check_python_dump(&dump, COUNT, base);
    check_time_base(&file, base, started_unix);
    check_info(&file, dir.path());

    // The library reads the file back into exactly what was published.
    let mut recorded: BTreeMap<String, Vec<AnyMessage>> = BTreeMap::new();
    let mut playback = Playback::open(&file).unwrap();
    while let Some(p) = playback.read_next().unwrap() {
        recorded.entry(p.topic).or_default().push(p.message);
    }
    assert_eq!(playback.source().end(), Some(&EndOfData::Complete));
    assert_eq!(playback.stats().orphans, 0);
    for t in TOPICS {
        let msgs = &recorded[t];
        assert_eq!(msgs.len() as u64, COUNT, "{t}");
        for (seq, m) in msgs.iter().enumerate() {
            assert!(
                m.bit_identical(&expected(base, t, seq as u64)),
                "{t} {seq} as recorded"
            );
        }
    }

    // (b) Replay onto a fresh instance; every message arrives as published.
    let fresh = unique_instance("rec_play");
    let bus = open_bus(&fresh);
    let scans: Subscriber<LaserScan> = bus.subscriber(topics::LASER_SCAN).unwrap();
    let odom: Subscriber<Odometry> = bus.subscriber(topics::BASE_ODOM).unwrap();
    let sonar: Subscriber<SonarRing> = bus.subscriber(topics::BASE_SONAR).unwrap();
    let smoke: Subscriber<SmokeReading> = bus.subscriber(topics::SMOKE_LEVEL).unwrap();
    let waiter = Waiter::new().unwrap();
    let _g = [
        waiter.attach(&scans).unwrap(),
        waiter.attach(&odom).unwrap(),
        waiter.attach(&sonar).unwrap(),
        waiter.attach(&smoke).unwrap(),
    ];
    let started = Instant::now();
    let mut player = smokenav(
        &["play", str_path(&file), "--rate", "2", "--instance", &fresh],
        &fresh,
    );
    let mut got: BTreeMap<&str, Vec<AnyMessage>> = BTreeMap::new();
    fn take<T: BusMsg>(
        sub: &Subscriber<T>,
        into: &mut Vec<AnyMessage>,
        wrap: impl Fn(&T) -> AnyMessage,
    ) {
        while let Some(s) = sub.receive().unwrap() {
            into.push(wrap(&s));
        }
    }
    let deadline = Instant::now() + Duration::from_secs(60);
    while got.values().map(Vec::len).sum::<usize>() < 4 * COUNT as usize {
        assert!(
            Instant::now() < deadline,
            "replay incomplete: {:?}",
            got.iter().map(|(k, v)| (k, v.len())).collect::<Vec<_>>()
        );
        waiter.wait(Some(Duration::from_millis(200))).unwrap();
        take(&scans, got.entry("laser/scan").or_default(), |s| {
            AnyMessage::LaserScan(Box::new(*s))
        });
        take(&odom, got.entry("base/odom").or_default(), |o| {
            AnyMessage::Odometry(*o)
        });
        take(&sonar, got.entry("base/sonar").or_default(), |r| {
            AnyMessage::SonarRing(*r)
        });
        take(&smoke, got.entry("smoke/level").or_default(), |s| {
            AnyMessage::SmokeReading(*s)
        });
    }
    let elapsed = started.elapsed();
    let status = player.wait_exit(Duration::from_secs(30)).unwrap();
    assert!(status.success(), "player failed:\n{}", player.output());
    for t in TOPICS {
        let msgs = &got[t];
        assert_eq!(msgs.len() as u64, COUNT, "{t}: same count as recorded");
        for (seq, m) in msgs.iter().enumerate() {
            assert!(
                m.bit_identical(&expected(base, t, seq as u64)),
                "{t} message {seq} replayed differently from what was published"
            );
            assert!(m.bit_identical(&recorded[t][seq]));
        }
    }
    assert_eq!(
        scans.stats().lost + odom.stats().lost + sonar.stats().lost + smoke.stats().lost,
        0
    );
    // 5 s of data at --rate 2 takes about 2.5 s: the recorded timing is kept.
    assert!(
        elapsed >= Duration::from_millis(2_000),
        "replay at rate 2 took only {elapsed:?}"
    );
}

// ---- (c) SIGKILL mid-run ----------------------------------------------------------

#[test]
fn recorder_killed_with_sigkill_leaves_every_message_of_its_finished_chunks() {
    let dir = tempfile::tempdir().unwrap();
    let file: PathBuf = dir.path().join("killed.mcap");
    let live = unique_instance("rec_kill");
    let mut recorder = Child::spawn_env(
        &bin("smokenav"),
        &[
            "record",
            "-o",
            str_path(&file),
            "--chunk-interval",
            "0.3",
            "--instance",
            &live,
        ],
        &live,
        &[("RUST_LOG", "info,smokenav::record=debug")],
    )
    .unwrap();
    recorder
        .wait_for_line("recording", Duration::from_secs(60))
        .unwrap();
    let base = stamp_base(Duration::from_secs(2));
    let publishers: Vec<Child> = ["laser", "base", "smoke"]
        .iter()
        .map(|role| spawn_publisher(&live, role, 10_000, base))
        .collect();
    for p in &publishers {
        p.wait_for_line("published 20", Duration::from_secs(30))
            .unwrap();
    }
    // Let several chunks be committed, then kill without warning.
    for _ in 0..4 {
        recorder
            .wait_for_line("chunk committed", Duration::from_secs(10))
            .unwrap();
    }
    recorder.signal(nix::sys::signal::Signal::SIGKILL);
    recorder.wait_exit(Duration::from_secs(10)).unwrap();
    drop(publishers);
    // The last count the recorder reported as on disk before it died.
    let claimed: u64 = recorder
        .output()
        .lines()
        .filter_map(|l| l.split("chunk committed: ").nth(1))
        .filter_map(|rest| rest.split_whitespace().next()?.parse().ok())
        .next_back()
        .expect("the recorder logged committed chunks");
    assert!(claimed > 0);

    // Raw MCAP messages as this crate's reader sees them.
    let bytes = std::fs::read(&file).unwrap();
    let mut source = McapSource::new(&bytes[..]);
    let mut raw = 0u64;
    while source.next_message(|_| ()).unwrap().is_some() {
        raw += 1;
    }
    assert_eq!(
        source.end(),
        Some(&EndOfData::Truncated),
        "no summary: the writer was killed"
    );
    assert!(
        raw >= claimed,
        "{raw} messages read, {claimed} were committed before the kill"
    );

    // The independent reader finds the same messages in the complete chunks.
    let line = run_python_check(&[Path::new("--truncated"), &file]);
    let python_count: u64 = line
        .strip_prefix("TRUNCATED ")
        .and_then(|n| n.trim().parse().ok())
        .unwrap_or_else(|| panic!("unexpected: {line}"));
    assert_eq!(python_count, raw);

    // Every recovered bus message is the published one, with no hole per topic.
    let mut playback = Playback::new(&bytes[..]);
    let mut next_seq: BTreeMap<String, u64> = BTreeMap::new();
    let mut total = 0u64;
    while let Some(p) = playback.read_next().unwrap() {
        let seq = next_seq.entry(p.topic.clone()).or_insert(0);
        assert_eq!(
            p.message.header().seq,
            *seq,
            "{}: a hole before the cut",
            p.topic
        );
        assert!(
            p.message.bit_identical(&expected(base, &p.topic, *seq)),
            "{} {seq}",
            p.topic
        );
        *seq += 1;
        total += 1;
    }
    assert_eq!(playback.stats().orphans, 0);
    for t in TOPICS {
        assert!(
            next_seq.get(t).copied().unwrap_or(0) >= 10,
            "{t}: {next_seq:?}"
        );
    }

    // `smokenav play` replays the cut file too.
    let other = unique_instance("rec_kill_play");
    let mut player = smokenav(
        &["play", str_path(&file), "--fast", "--instance", &other],
        &other,
    );
    let status = player.wait_exit(Duration::from_secs(30)).unwrap();
    let out = player.output();
    assert!(status.success(), "{out}");
    assert!(out.contains(&format!("played {total} messages")), "{out}");
    assert!(out.contains("cut short"), "{out}");
}

// ---- (d) replay into the fusion and SLAM processes --------------------------------

/// Receives `topic` of `instance` in a thread until `stop` is set and then
/// `quiet` passes without a message (the consumer caught up with its input).
fn collect<T: BusMsg + Send>(
    instance: &str,
    topic: Topic<T>,
    stop: &Arc<AtomicBool>,
    quiet: Duration,
) -> std::thread::JoinHandle<Vec<T>> {
    let instance = instance.to_owned();
    let stop = Arc::clone(stop);
    let (ready_tx, ready) = std::sync::mpsc::channel();
    let handle = std::thread::spawn(move || {
        let bus = open_bus(&instance);
        let sub: Subscriber<T> = bus.subscriber(topic.clone()).unwrap();
        let waiter = Waiter::new().unwrap();
        let _g = waiter.attach(&sub).unwrap();
        ready_tx.send(()).unwrap();
        let mut got = Vec::new();
        let deadline = Instant::now() + Duration::from_secs(120);
        let mut last_arrival = Instant::now();
        let mut stopped_at: Option<Instant> = None;
        loop {
            waiter.wait(Some(Duration::from_millis(100))).unwrap();
            while let Some(m) = sub.receive().unwrap() {
                got.push(*m);
                last_arrival = Instant::now();
            }
            if stopped_at.is_none() && stop.load(Ordering::Relaxed) {
                stopped_at = Some(Instant::now());
            }
            if let Some(t) = stopped_at
                && t.max(last_arrival).elapsed() >= quiet
            {
                assert_eq!(sub.stats().lost, 0, "{topic}: the collector lost messages");
                return got;
            }
            assert!(
                Instant::now() < deadline,
                "{topic}: still receiving after 120 s ({} messages)",
                got.len()
            );
        }
    });
    ready.recv_timeout(Duration::from_secs(30)).unwrap();
    handle
}

fn spawn_fusion_and_slam(cfg: &Path, instance: &str) -> (Child, Child) {
    let fusion = Child::spawn(
        &bin("smokenav-fusion"),
        &["--config", str_path(cfg)],
        instance,
    )
    .unwrap();
    let slam = Child::spawn(
        &bin("smokenav-slam"),
        &["--config", str_path(cfg)],
        instance,
    )
    .unwrap();
    fusion
        .wait_for_line("fusing", Duration::from_secs(60))
        .unwrap();
    slam.wait_for_line("particles on fusion/scan", Duration::from_secs(60))
        .unwrap();
    (fusion, slam)
}

#[test]
fn replayed_inputs_give_fusion_and_slam_the_same_output_as_live() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = profile(dir.path(), "pioneer-3dx.toml", |c| {
        // SLAM consumes the fused scan (the shipped profile's choice; pinned
        // here because the test subscribes to what it expects).
        c.slam.input = SlamInput::Fused;
        // In a debug build 30 particles take 35–110 ms a scan, against a
        // 100 ms scan period; 10 take 33–60 ms (the front end's share does
        // not shrink), so that neither run should skip a scan (see (c)).
        c.slam.particles = 10;
    });
    let file: PathBuf = dir.path().join("fusion.mcap");
    let inputs = ["laser/scan", "base/sonar", "smoke/level", "base/odom"];

    // Live: drivers (stand-ins) → fusion → SLAM, everything recorded.
    let live = unique_instance("rec_fuse_live");
    let (mut fusion, mut slam) = spawn_fusion_and_slam(&cfg, &live);
    let mut args = vec!["record", "-o", str_path(&file), "--instance", &live];
    args.extend(inputs);
    args.extend(["fusion/scan", "slam/pose"]);
    let mut recorder = smokenav(&args, &live);
    recorder
        .wait_for_line("recording", Duration::from_secs(60))
        .unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    // Only to know when SLAM has caught up before the recorder stops.
    let live_watch =
        collect::<PoseEstimate>(&live, topics::SLAM_POSE, &stop, Duration::from_secs(1));
    let (publishers, _) = publish_all(&live, Duration::from_secs(3));
    stop.store(true, Ordering::Relaxed);
    let watched = live_watch.join().unwrap();
    std::thread::sleep(Duration::from_millis(300));
    recorder.signal(nix::sys::signal::Signal::SIGINT);
    assert!(
        recorder
            .wait_exit(Duration::from_secs(30))
            .unwrap()
            .success(),
        "{}",
        recorder.output()
    );
    fusion.terminate(Duration::from_secs(10)).unwrap();
    slam.terminate(Duration::from_secs(10)).unwrap();
    drop(publishers);

    let mut live_fused = Vec::new();
    let mut live_poses = Vec::new();
    let mut odom_recorded = 0;
    let mut playback = Playback::open(&file).unwrap();
    while let Some(p) = playback.read_next().unwrap() {
        match p.message {
            AnyMessage::FusedScan(f) => live_fused.push(*f),
            AnyMessage::PoseEstimate(e) => live_poses.push(e),
            AnyMessage::Odometry(_) => odom_recorded += 1,
            _ => {}
        }
    }
    assert_eq!(odom_recorded, COUNT, "base/odom is recorded");
    assert!(
        live_fused.len() as u64 >= COUNT - 2,
        "live fusion produced {} scans from {COUNT}",
        live_fused.len()
    );
    assert!(
        live_fused
            .iter()
            .any(|f| f.sync_state == 0 && f.section_count > 0),
        "live output includes complete laser + sonar + smoke sets"
    );
    assert_eq!(
        live_poses.len(),
        watched.len(),
        "the recording has every pose SLAM published"
    );
    let live_skipped = live_poses.last().map_or(0, |p| p.scans_skipped);
    eprintln!(
        "live: {} fused scans, {} poses, {live_skipped} scans skipped, slowest scan {} µs",
        live_fused.len(),
        live_poses.len(),
        live_poses
            .iter()
            .map(|p| p.processing_us)
            .max()
            .unwrap_or(0)
    );

    // Offline: the recorded inputs, replayed with their timing, into fresh processes.
    let offline = unique_instance("rec_fuse_play");
    let (mut fusion, mut slam) = spawn_fusion_and_slam(&cfg, &offline);
    let stop = Arc::new(AtomicBool::new(false));
    let quiet = Duration::from_millis(1_500);
    let fused_collector = collect::<FusedScan>(&offline, topics::FUSION_SCAN, &stop, quiet);
    let pose_collector = collect::<PoseEstimate>(&offline, topics::SLAM_POSE, &stop, quiet);
    // --restamp: the synchroniser drops inputs older than its timeout and SLAM
    // waits for odometry relative to now, so the replay must look measured
    // now; the shift is one constant for all stamps.
    let mut args = vec!["play", str_path(&file), "--restamp", "--instance", &offline];
    args.extend(inputs);
    let mut player = smokenav(&args, &offline);
    assert!(
        player.wait_exit(Duration::from_secs(60)).unwrap().success(),
        "{}",
        player.output()
    );
    stop.store(true, Ordering::Relaxed);
    let replayed = fused_collector.join().unwrap();
    let replayed_poses = pose_collector.join().unwrap();
    fusion.terminate(Duration::from_secs(10)).unwrap();
    slam.terminate(Duration::from_secs(10)).unwrap();

    // (a) Fusion: bit for bit.
    assert_eq!(
        replayed.len(),
        live_fused.len(),
        "same number of fused scans as live"
    );
    let offset =
        replayed[0].scan.header.stamp_ns as i64 - live_fused[0].scan.header.stamp_ns as i64;
    assert!(offset > 0, "replayed stamps are later than the live ones");
    for (i, (a, b)) in replayed.iter().zip(&live_fused).enumerate() {
        let mut a = AnyMessage::FusedScan(Box::new(*a));
        a.shift_stamps(-offset);
        let AnyMessage::FusedScan(a) = a else {
            unreachable!()
        };
        assert!(
            a.bit_identical(b),
            "fused scan {i} differs: replay sync {} sections {} sonar usage {} \
             vs live sync {} sections {} sonar usage {}",
            a.sync_state,
            a.section_count,
            a.sonar_usage(),
            b.sync_state,
            b.section_count,
            b.sonar_usage()
        );
    }

    // (b) SLAM published a pose per replayed scan, give or take the scans a
    // process may skip when it falls behind (counted in `scans_skipped`).
    let replay_skipped = replayed_poses.last().map_or(0, |p| p.scans_skipped);
    eprintln!(
        "replay: {} poses, {replay_skipped} scans skipped",
        replayed_poses.len()
    );
    let fused = live_fused.len() as u64;
    for (run, poses, skipped) in [
        ("live", &live_poses, live_skipped),
        ("replay", &replayed_poses, replay_skipped),
    ] {
        assert_eq!(
            poses.len() as u64 + skipped,
            fused,
            "{run}: every fused scan gives a pose or is counted as skipped"
        );
    }
    assert!(
        live_skipped <= MAX_SKIPPED && replay_skipped <= MAX_SKIPPED,
        "SLAM fell behind: {live_skipped} scans skipped live, {replay_skipped} on replay"
    );
    assert!(
        replayed_poses.len().abs_diff(live_poses.len()) as u64 <= MAX_SKIPPED,
        "replay gave {} poses, live {}",
        replayed_poses.len(),
        live_poses.len()
    );

    // (c) Replayed poses agree with the live ones at the same (shifted) stamps.
    let replay_in_live_time: Vec<PoseEstimate> = replayed_poses
        .iter()
        .map(|p| {
            let mut p = *p;
            p.header.stamp_ns = (p.header.stamp_ns as i64 - offset) as u64;
            p
        })
        .collect();
    let difference = |r: &PoseEstimate, l: &PoseEstimate| {
        (
            (r.x - l.x).hypot(r.y - l.y),
            smokenav_shared_types::odom::normalize_angle(r.theta - l.theta).abs(),
        )
    };
    // While both runs processed the same scans, the filters had the same
    // input: it is seeded, the fused scans are bit-identical ((a)), and the
    // odometry is interpolated between the same readings by stamp
    // differences, which one constant shift keeps. Their poses are the same
    // — bit for bit in practice; 1 mm and 1 mrad leave room for rounding only.
    let same_input = replay_in_live_time
        .iter()
        .zip(&live_poses)
        .take_while(|(r, l)| r.header.stamp_ns == l.header.stamp_ns)
        .count();
    assert!(
        same_input > 0,
        "the runs' first poses are for different scans"
    );
    let mut bitwise = 0;
    for (i, (r, l)) in replay_in_live_time
        .iter()
        .zip(&live_poses)
        .take(same_input)
        .enumerate()
    {
        let (d, dtheta) = difference(r, l);
        assert!(
            d <= 1e-3 && dtheta <= 1e-3,
            "pose {i} differs by {d} m, {dtheta} rad with the same input: \
             replay ({}, {}, {}) live ({}, {}, {})",
            r.x,
            r.y,
            r.theta,
            l.x,
            l.y,
            l.theta
        );
        bitwise += usize::from(
            [r.x, r.y, r.theta].map(f64::to_bits) == [l.x, l.y, l.theta].map(f64::to_bits),
        );
    }
    // Once one run skipped a scan the other processed, the particles drew
    // different random numbers and moved in other steps: the same map, a
    // slightly different estimate. Forced skips (60 particles, 1–6 scans
    // skipped per run, five runs) gave differences up to 41 mm and 8.7 mrad;
    // 0.1 m and 0.03 rad still catch a replay that went its own way (the
    // trajectory turns 0.30 rad).
    let live_at: BTreeMap<u64, &PoseEstimate> =
        live_poses.iter().map(|p| (p.header.stamp_ns, p)).collect();
    let mut after = 0;
    let mut largest = (0.0f64, 0.0f64);
    for r in &replay_in_live_time[same_input..] {
        let Some(l) = live_at.get(&r.header.stamp_ns) else {
            continue;
        };
        let (d, dtheta) = difference(r, l);
        assert!(
            d <= 0.1 && dtheta <= 0.03,
            "pose at stamp {} differs by {d} m, {dtheta} rad after the runs' skips \
             ({} live, {} on replay)",
            r.header.stamp_ns,
            l.scans_skipped,
            r.scans_skipped
        );
        largest = (largest.0.max(d), largest.1.max(dtheta));
        after += 1;
    }
    // Every fused scan was compared or skipped by one of the runs.
    assert!(
        (same_input + after) as u64 + live_skipped + replay_skipped >= fused,
        "only {} of {fused} scans have a pose in both runs ({live_skipped} skipped live, \
         {replay_skipped} on replay)",
        same_input + after
    );
    eprintln!(
        "{same_input} poses with the same input ({bitwise} bit-identical), {after} after a \
         skip (largest difference {:.4} m, {:.4} rad)",
        largest.0, largest.1
    );
    // The poses compared are a trajectory, not one pose repeated: the stand-in
    // scans turn by one beam (6.1 mrad) a scan, which SLAM follows.
    let (first, last) = (live_poses[0], live_poses[live_poses.len() - 1]);
    assert!(
        (last.x - first.x).hypot(last.y - first.y) > 0.01
            || smokenav_shared_types::odom::normalize_angle(last.theta - first.theta).abs() > 0.05,
        "SLAM's pose never moved from ({}, {}, {}): the comparison would prove little",
        first.x,
        first.y,
        first.theta
    );
}

/// Scans the SLAM process may skip in one run (a debug build on a busy
/// machine: 7 and 8 of 50 seen with other builds running on both cores).
/// Skips are counted, never hidden; the check above accounts for each one.
const MAX_SKIPPED: u64 = 10;
