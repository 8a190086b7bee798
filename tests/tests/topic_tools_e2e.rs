//! `smokenav topic list|echo|hz` against a live publisher in another process.

use smokenav_shared_types::laser::BeamReading;
use smokenav_shared_types::record::{Message, TopicRecord};
use smokenav_tests::{Child, bin, unique_instance};
use std::process::Command;
use std::time::Duration;

const RATE_HZ: f64 = 20.0;

/// A 20 Hz laser publisher: the test binary re-executed in this role.
#[test]
#[ignore = "child process entry point, run by the tests below"]
fn child_laser_publisher() {
    let instance = std::env::var("SMOKENAV_INSTANCE").unwrap();
    let bus = smokenav_tests::open_bus(&instance);
    let mut publisher = bus
        .publisher(smokenav_platform_bus::topics::LASER_SCAN)
        .unwrap();
    println!("publishing");
    for n in 0u64.. {
        publisher
            .publish_with(|s| {
                s.header.stamp_ns = smokenav_shared_types::clock::monotonic_now_ns();
                s.header.frame_id.set("laser");
                s.count = 682;
                s.angle_min = -2.0862;
                s.angle_increment = 0.0061359;
                s.range_max = 5.6;
                for i in 0..682 {
                    s.set_beam(i, BeamReading::Range(1.0 + (n % 10) as f32 * 0.1));
                }
                s.set_beam(5, BeamReading::SensorCode(7));
            })
            .unwrap();
        std::thread::sleep(Duration::from_secs_f64(1.0 / RATE_HZ));
    }
}

fn start_publisher(instance: &str) -> Child {
    let exe = std::env::current_exe().unwrap();
    let child = Child::spawn(
        &exe,
        &[
            "child_laser_publisher",
            "--exact",
            "--ignored",
            "--nocapture",
        ],
        instance,
    )
    .unwrap();
    child
        .wait_for_line("publishing", Duration::from_secs(30))
        .unwrap();
    child
}

fn smokenav(instance: &str, args: &[&str]) -> (bool, String, String) {
    smokenav_env(instance, args, &[])
}

fn smokenav_env(instance: &str, args: &[&str], env: &[(&str, &str)]) -> (bool, String, String) {
    let out = Command::new(bin("smokenav"))
        .args(args)
        .env("SMOKENAV_INSTANCE", instance)
        .envs(env.iter().copied())
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn topic_echo_json_prints_live_scans_from_another_process() {
    let instance = unique_instance("echo");
    let _publisher = start_publisher(&instance);
    // The ROS spelling of the topic: the bus calls it laser/scan.
    let (ok, out, err) = smokenav(
        &instance,
        &[
            "topic",
            "echo",
            "/laser/scan",
            "--count",
            "5",
            "--json",
            "--timeout",
            "20",
        ],
    );
    assert!(ok, "{err}");
    let records: Vec<TopicRecord> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    assert_eq!(records.len(), 5);
    let mut last_seq = None;
    for r in &records {
        assert_eq!(r.topic, "laser/scan");
        let Message::LaserScan(s) = &r.message else {
            panic!("not a scan: {r:?}")
        };
        assert_eq!(s.ranges.len(), 682);
        assert_eq!(s.ranges[5], None, "the sensor error code is not a range");
        assert_eq!(s.beam_error[5], 0x100 | 7);
        assert!(s.ranges[0].is_some_and(|r| (1.0..=1.95).contains(&r)));
        if let Some(prev) = last_seq {
            assert!(s.header.seq > prev);
        }
        last_seq = Some(s.header.seq);
    }
}

#[test]
fn topic_hz_measures_the_publishers_rate() {
    let instance = unique_instance("hz");
    let _publisher = start_publisher(&instance);
    let (ok, out, err) = smokenav(
        &instance,
        &["topic", "hz", "laser/scan", "--duration", "3", "--json"],
    );
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    let rate = v["rate_hz"].as_f64().unwrap();
    // sleep() only guarantees a minimum; a loaded CI machine runs slower, never faster.
    assert!(
        rate > RATE_HZ * 0.6 && rate < RATE_HZ * 1.1,
        "rate {rate}: {out}"
    );
    assert!(v["received"].as_u64().unwrap() >= 30, "{out}");
    assert_eq!(v["lost"].as_u64(), Some(0), "{out}");
}

#[test]
fn topic_list_shows_the_live_topic_and_its_type() {
    let instance = unique_instance("list");
    let _publisher = start_publisher(&instance);
    let (ok, out, err) = smokenav(&instance, &["topic", "list"]);
    assert!(ok, "{err}");
    let line = out
        .lines()
        .find(|l| l.starts_with("laser/scan"))
        .unwrap_or_else(|| panic!("laser/scan not listed:\n{out}"));
    assert!(line.contains("smokenav::LaserScan"), "{line}");
}

#[test]
fn topic_echo_rejects_an_unknown_topic() {
    let (ok, _out, err) = smokenav(
        &unique_instance("unknown"),
        &["topic", "echo", "lazer/scan"],
    );
    assert!(!ok);
    assert!(err.contains("unknown topic `lazer/scan`"), "{err}");
}

#[test]
fn a_user_error_is_one_message_without_a_backtrace_unless_debug() {
    let instance = unique_instance("backtrace");
    let (ok, _out, err) = smokenav_env(
        &instance,
        &["topic", "echo", "lazer/scan"],
        &[("RUST_BACKTRACE", "1")],
    );
    assert!(!ok);
    assert!(err.contains("unknown topic `lazer/scan`"), "{err}");
    assert!(!err.to_lowercase().contains("backtrace"), "{err}");
    assert!(!err.contains('\x1b'), "ANSI codes in a pipe: {err:?}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    // --debug asks for the whole story.
    let (ok, _out, err) = smokenav_env(
        &instance,
        &["topic", "echo", "lazer/scan", "--debug"],
        &[("RUST_BACKTRACE", "1")],
    );
    assert!(!ok);
    assert!(err.contains("Stack backtrace"), "{err}");
}

#[test]
fn topic_info_lists_the_publisher_and_subscriber_processes() {
    let instance = unique_instance("info");
    let _publisher = start_publisher(&instance);
    // A second process subscribes: a `topic echo` left running.
    let echo = Child::spawn(
        &bin("smokenav"),
        &["topic", "echo", "laser/scan", "--json"],
        &instance,
    )
    .unwrap();
    echo.wait_for_line("\"topic\"", Duration::from_secs(30))
        .unwrap();
    let (ok, out, err) = smokenav(&instance, &["topic", "info", "/laser/scan", "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(v["topic"], "laser/scan", "{out}");
    assert_eq!(v["ros2_type"], "sensor_msgs/msg/LaserScan", "{out}");
    assert_eq!(v["bus_type"], "smokenav::LaserScan", "{out}");
    let publishers = v["publishers"].as_array().unwrap();
    let subscribers = v["subscribers"].as_array().unwrap();
    assert_eq!(publishers.len(), 1, "{out}");
    assert_eq!(subscribers.len(), 1, "{out}");
    assert_eq!(publishers[0]["alive"], true, "{out}");
    assert!(
        subscribers[0]["node"]
            .as_str()
            .unwrap()
            .starts_with("topic-echo"),
        "{out}"
    );
    assert_eq!(v["qos"]["queue"], 32, "{out}");
    // The text form, as `ros2 topic info` words it.
    let (ok, text, err) = smokenav(&instance, &["topic", "info", "laser/scan"]);
    assert!(ok, "{err}");
    assert!(text.contains("Publisher count: 1"), "{text}");
    assert!(text.contains("Subscription count: 1"), "{text}");
    // A topic nobody opened is reported, not an error.
    let (ok, text, err) = smokenav(&instance, &["topic", "info", "slam/pose"]);
    assert!(ok, "{err}");
    assert!(text.contains("Publisher count: 0"), "{text}");
}

#[test]
fn topic_bw_measures_bytes_per_second() {
    let instance = unique_instance("bw");
    let _publisher = start_publisher(&instance);
    let (ok, out, err) = smokenav(
        &instance,
        &["topic", "bw", "laser/scan", "--duration", "3", "--json"],
    );
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    let size = std::mem::size_of::<smokenav_shared_types::LaserScan>() as f64;
    assert_eq!(v["mean_bytes"].as_f64(), Some(size), "{out}");
    let bw = v["bytes_per_s"].as_f64().unwrap();
    // As for hz: a loaded machine publishes slower, never faster.
    assert!(
        bw > RATE_HZ * size * 0.6 && bw < RATE_HZ * size * 1.1,
        "{bw} B/s for {size} B at {RATE_HZ} Hz: {out}"
    );
}
