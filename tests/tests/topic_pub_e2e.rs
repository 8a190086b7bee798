//! `smokenav topic pub` from a real process onto the bus: a message from
//! JSON (fields left out keep their defaults), and the motion guard it
//! shares with `smokenav drive`.

use smokenav_platform_bus::{Subscriber, Waiter, topics};
use smokenav_shared_types::{SmokeReading, VelocityCommand};
use smokenav_tests::{bin, open_bus, unique_instance};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn smokenav(instance: &str, args: &[&str]) -> Output {
    Command::new(bin("smokenav"))
        .args(args)
        .env("SMOKENAV_INSTANCE", instance)
        .output()
        .expect("run smokenav")
}

/// Runs `smokenav ARGS` while taking what `sub` receives (a gone
/// publisher's samples cannot be taken afterwards); its output and the messages.
fn run_receiving<T: smokenav_platform_bus::Message + Copy>(
    instance: &str,
    args: &[&str],
    sub: &Subscriber<T>,
    waiter: &Waiter,
) -> (std::process::ExitStatus, String, Vec<T>) {
    let mut child = Command::new(bin("smokenav"))
        .args(args)
        .env("SMOKENAV_INSTANCE", instance)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run smokenav");
    let mut got = Vec::new();
    let end = Instant::now() + Duration::from_secs(60);
    let status = loop {
        let _ = waiter.wait(Some(Duration::from_millis(50)));
        while let Some(m) = sub.receive().unwrap() {
            got.push(*m);
        }
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        assert!(Instant::now() < end, "smokenav {args:?} did not end");
    };
    let mut err = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
    (status, err, got)
}

#[test]
fn motion_commands_need_the_flag_and_end_with_stops() {
    let instance = unique_instance("topic_pub_motion");
    let bus = open_bus(&instance);
    let cmds: Subscriber<VelocityCommand> = bus.subscriber(topics::BASE_CMD_VEL).unwrap();
    let waiter = Waiter::new().unwrap();
    let _g = waiter.attach(&cmds).unwrap();

    let refused = smokenav(
        &instance,
        &["topic", "pub", "/base/cmd_vel", r#"{"linear": 0.2}"#],
    );
    assert!(!refused.status.success());
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(err.contains("--motion"), "{err}");
    let unbounded = smokenav(
        &instance,
        &[
            "topic",
            "pub",
            "base/cmd_vel",
            r#"{"linear": 0.2}"#,
            "--motion",
        ],
    );
    assert!(!unbounded.status.success());
    assert!(String::from_utf8_lossy(&unbounded.stderr).contains("--for"));
    assert!(
        cmds.receive().unwrap().is_none(),
        "a refused command was sent"
    );

    let (status, err, got) = run_receiving(
        &instance,
        &[
            "topic",
            "pub",
            "base/cmd_vel",
            r#"{"linear": 0.2, "angular": -0.1}"#,
            "--motion",
            "--for",
            "1",
        ],
        &cmds,
        &waiter,
    );
    assert!(status.success(), "{err}");
    // 10 Hz for 1 s, then 3 stops; a loaded machine sends fewer, never none.
    assert!(got.len() >= 4, "{} commands", got.len());
    let (moving, stops) = got.split_at(got.len() - 3);
    assert!(
        moving.iter().all(|c| c.linear == 0.2 && c.angular == -0.1),
        "{moving:?}"
    );
    assert!(
        stops.iter().all(|c| c.linear == 0.0 && c.angular == 0.0),
        "{stops:?}"
    );
    assert!(
        got.windows(2)
            .all(|w| w[0].header.stamp_ns < w[1].header.stamp_ns)
    );
}

#[test]
fn a_json_message_is_published_over_the_types_defaults() {
    let instance = unique_instance("topic_pub_json");
    let bus = open_bus(&instance);
    let smoke: Subscriber<SmokeReading> = bus.subscriber(topics::SMOKE_LEVEL).unwrap();
    let waiter = Waiter::new().unwrap();
    let _g = waiter.attach(&smoke).unwrap();
    let (status, err, got) = run_receiving(
        &instance,
        &[
            "topic",
            "pub",
            "smoke/level",
            r#"{"level": 123.5, "header": {"frame_id": "mq303a"}}"#,
            "--times",
            "3",
            "--rate",
            "20",
        ],
        &smoke,
        &waiter,
    );
    assert!(status.success(), "{err}");
    assert_eq!(got.len(), 3);
    assert!(
        got.iter()
            .all(|s| s.level == 123.5 && s.header.frame_id.as_str() == "mq303a")
    );
    assert!(got.iter().all(|s| s.raw_mv == 0.0));

    let bad = smokenav(
        &instance,
        &["topic", "pub", "smoke/level", r#"{"level": "high"}"#],
    );
    assert!(!bad.status.success());
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        err.contains("key level") && err.lines().count() == 1,
        "{err}"
    );
}
