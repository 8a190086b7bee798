//! `smokenav slam` on logs a user might really have: the real binary on real files.

use std::path::PathBuf;
use std::process::Command;

fn data() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../algorithms/slam/tests/data")
}

/// The log with the robot pose of the `index`-th FLASER record moved `dx` m.
fn corrupt(index: usize, dx: f64) -> String {
    let text = std::fs::read_to_string(data().join("csail-prefix-200.clf")).unwrap();
    let mut seen = 0;
    let mut out = String::new();
    for line in text.lines() {
        let mut f: Vec<String> = line.split_whitespace().map(str::to_owned).collect();
        if f.first().map(String::as_str) == Some("FLASER") {
            if seen == index {
                let n: usize = f[1].parse().unwrap();
                let x: f64 = f[2 + n + 3].parse().unwrap();
                f[2 + n + 3] = format!("{:.6}", x + dx);
                out.push_str(&f.join(" "));
                out.push('\n');
                seen += 1;
                continue;
            }
            seen += 1;
        }
        out.push_str(line);
        out.push('\n');
    }
    out
}

fn max_step(trajectory: &str) -> f64 {
    let poses: Vec<(f64, f64)> = trajectory
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|t| t.parse().unwrap()).collect();
            (v[1], v[2])
        })
        .collect();
    poses
        .windows(2)
        .map(|w| (w[1].0 - w[0].0).hypot(w[1].1 - w[0].1))
        .fold(0.0, f64::max)
}

#[test]
fn one_corrupt_odometry_record_is_reported_by_line_and_never_taken_as_motion() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("corrupt.clf");
    std::fs::write(&log, corrupt(100, 812.0)).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_smokenav"))
        .args(["slam", "--carmen", log.to_str().unwrap(), "--out"])
        .arg(dir.path().join("run"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains(" 1 bad lines,"), "{stdout}");
    assert!(stdout.contains("odometry jumps 8"), "{stdout}");
    let trajectory = std::fs::read_to_string(dir.path().join("run/trajectory.txt")).unwrap();
    // CSAIL's own odometry moves under 1 m per record; 812 m would show.
    let step = max_step(&trajectory);
    assert!(step < 2.0, "the trajectory jumps {step:.1} m");
}
