//! `smokenav arcos decode` options as a user types them: the codec's own
//! `CaptureFormat` and `Direction` are the command-line values.

use std::io::Write;
use std::process::{Command, Output, Stdio};

fn decode(args: &[&str], input: &[u8]) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_smokenav"))
        .args(["arcos", "decode"])
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("smokenav runs");
    child
        .stdin
        .take()
        .unwrap()
        .write_all(input)
        .expect("write stdin");
    child.wait_with_output().unwrap()
}

fn only_object(out: &Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout.clone()).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 1, "{text}");
    serde_json::from_str(lines[0]).unwrap()
}

/// SYNC0 reads as a command from the host and as the robot's echo from the robot.
const SYNC0: &str = "fa fb 03 00 00 00\n";

#[test]
fn from_names_who_sent_unmarked_bytes() {
    let host = only_object(&decode(
        &["--format", "hex", "--from", "host"],
        SYNC0.as_bytes(),
    ));
    assert_eq!(host["dir"], "to_robot");
    assert_eq!(host["kind"], "command");
    let robot = only_object(&decode(
        &["--format", "hex", "--from", "robot"],
        SYNC0.as_bytes(),
    ));
    assert_eq!(robot["dir"], "from_robot");
    assert_eq!(robot["kind"], "sync_echo");
    let guess = only_object(&decode(&["--from", "guess"], SYNC0.as_bytes()));
    assert_eq!(guess["dir"], "unknown");
}

#[test]
fn raw_format_reads_the_bytes_as_they_crossed_the_wire() {
    let raw = only_object(&decode(
        &["--format", "raw", "--from", "host"],
        &[0xfa, 0xfb, 0x03, 0x00, 0x00, 0x00],
    ));
    assert_eq!(raw["hex"], "fa fb 03 00 00 00");
    assert_eq!(raw["kind"], "command");
}

#[test]
fn an_unknown_value_lists_the_possible_ones() {
    let out = decode(&["--from", "bogus"], b"");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("host, robot, guess"), "{err}");
    let out = decode(&["--format", "json"], b"");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("auto, hex, raw"), "{err}");
}
