//! Every example runs and does what its README line says.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// `target/<profile>/examples/<name>` (cargo builds the examples before it runs tests).
fn example(name: &str) -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let profile = exe.parent().and_then(Path::parent).unwrap();
    let path = profile.join("examples").join(name);
    assert!(path.exists(), "{} was not built", path.display());
    path
}

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_owned()
}

fn run(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{cmd:?} failed ({}):\n{stdout}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

#[test]
fn publish_scan_and_echo_scan_talk_across_processes() {
    let instance = format!("examples_{}", std::process::id());
    let mut echo = Command::new(example("echo_scan"))
        .args([&instance, "5"])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let published = run(Command::new(example("publish_scan")).args([&instance, "5"]));
    assert!(published.contains("published 5"), "{published}");
    let end = Instant::now() + Duration::from_secs(20);
    while echo.try_wait().unwrap().is_none() {
        assert!(Instant::now() < end, "echo_scan did not finish");
        std::thread::sleep(Duration::from_millis(50));
    }
    let out = echo.wait_with_output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    // Every scan, in order, with what the publisher put in it.
    for seq in 0..5 {
        assert!(
            text.contains(&format!(
                "scan seq {seq} with 400 beams, first {:.3} m",
                1.0 + seq as f32
            )),
            "scan {seq} missing:\n{text}"
        );
    }
    assert!(text.contains("received 5, lost 0"), "{text}");
}

#[test]
fn driver_with_emulator_streams_five_scans() {
    let out = run(&mut Command::new(example("driver_with_emulator")));
    assert!(out.contains("connected to a URG-04LX"), "{out}");
    assert_eq!(out.matches(": 682 beams").count(), 5, "{out}");
    assert!(out.contains("done: 5 scans"), "{out}");
}

#[test]
fn slam_over_log_runs_both_back_ends_on_the_csail_prefix() {
    let log = workspace_root().join("daemon/algorithms/slam/tests/data/csail-prefix-200.clf");
    for backend in ["rbpf", "graph"] {
        let out = run(Command::new(example("slam_over_log"))
            .arg(&log)
            .arg(backend));
        assert!(
            out.starts_with(&format!("{backend} back-end: 200 scans")),
            "{out}"
        );
    }
    let err = Command::new(example("slam_over_log"))
        .arg(&log)
        .arg("karto")
        .output()
        .unwrap();
    assert!(!err.status.success());
    assert!(String::from_utf8_lossy(&err.stderr).contains("unknown back-end karto"));
}
