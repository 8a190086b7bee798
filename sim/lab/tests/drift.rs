//! `smokenav-lab drift` on a gzip-compressed corrected log shaped like
//! Radish's: a loop of FLASER records whose stamps repeat for a stretch
//! (CSAIL's keep six digits) and an ODOM record stamped before zero at the
//! end (as most corrected Radish logs end).

use std::io::Write;
use std::path::Path;
use std::process::Command;

/// A 20 m × 10 m loop at 0.5 m per record (120 FLASER records of 5 beams),
/// stamped 1 s apart except records 40..50, which all carry record 40's stamp.
fn corrected_log() -> String {
    let mut s = String::from("# message formats defined: PARAM SYNC ODOM FLASER\n");
    let (mut x, mut y, mut t) = (0.0f64, 0.0f64, 0.0f64);
    let mut k = 0usize;
    for len in [20.0, 10.0, 20.0, 10.0] {
        let steps = (len / 0.5) as usize;
        for i in 0..steps {
            x += 0.5 * t.cos();
            y += 0.5 * t.sin();
            if i + 1 == steps {
                t += std::f64::consts::FRAC_PI_2;
            }
            let stamp = if (40..50).contains(&k) { 40 } else { k };
            s.push_str(&format!(
                "FLASER 5 1 2 3 4 5 {x} {y} {t} {x} {y} {t} {stamp}.25 host {stamp}.25\n"
            ));
            k += 1;
        }
    }
    s.push_str("ODOM 0 0 0 0 0 0 -14.4854 host -14.4854\n");
    s
}

fn gzip(path: &Path, text: &str) {
    let mut enc = flate2::write::GzEncoder::new(
        std::fs::File::create(path).unwrap(),
        flate2::Compression::default(),
    );
    enc.write_all(text.as_bytes()).unwrap();
    enc.finish().unwrap();
}

fn drift(dir: &Path, log: &Path, seed: u64, extra: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_smokenav-lab"))
        .arg("drift")
        .arg(log)
        .args(["--seed", &seed.to_string()])
        .arg("--out")
        .arg(dir.join(format!("drifted-{seed}.log")))
        .arg("--reference")
        .arg(dir.join("reference.txt"))
        .args(extra)
        .output()
        .unwrap()
}

/// `timestamp x y theta` rows of a file, comments left out.
fn rows(path: &Path) -> Vec<Vec<f64>> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| l.split_whitespace().map(|v| v.parse().unwrap()).collect())
        .collect()
}

#[test]
fn a_corrected_log_becomes_a_drifted_one_and_its_poses_the_reference() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("loop-corrected.log.gz");
    gzip(&log, &corrected_log());
    let out = drift(dir.path(), &log, 3, &[]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("120 laser records over 59.5 m"), "{stdout}");
    assert!(
        stdout.contains("1 unreadable line left out (the first: line 122: ODOM"),
        "{stdout}"
    );
    assert!(
        stdout.contains("9 records stamped at or before the record before moved a second after it (the first: record 41"),
        "{stdout}"
    );

    // The reference: the input's poses, one per record, stamps strictly increasing.
    let reference = rows(&dir.path().join("reference.txt"));
    assert_eq!(reference.len(), 120);
    assert!(reference.windows(2).all(|w| w[0][0] < w[1][0]));
    assert_eq!(reference[0][1..], [0.5, 0.0, 0.0]);
    assert!(
        (reference[49][0] - 49.25).abs() < 1e-9,
        "{:?}",
        reference[49]
    );
    // The drifted log: the same stamps, the same scans, odometry metres off by the end.
    let drifted = std::fs::read_to_string(dir.path().join("drifted-3.log")).unwrap();
    let records: Vec<Vec<&str>> = drifted
        .lines()
        .map(|l| l.split_whitespace().collect())
        .collect();
    assert_eq!(records.len(), 120);
    let mut end_offset = 0.0;
    for (r, truth) in records.iter().zip(&reference) {
        assert_eq!(r[..7], ["FLASER", "5", "1", "2", "3", "4", "5"]);
        let n = r.len();
        let stamp: f64 = r[n - 3].parse().unwrap();
        assert!((stamp - truth[0]).abs() < 1e-6, "{r:?} {truth:?}");
        let (x, y): (f64, f64) = (r[10].parse().unwrap(), r[11].parse().unwrap());
        end_offset = (x - truth[1]).hypot(y - truth[2]);
    }
    assert!(end_offset > 1.0, "the loop does not drift: {end_offset} m");
    let ate: f64 = stdout
        .split("odometry ATE RMS ")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no ATE in {stdout}"));
    assert!(ate > 0.3, "{stdout}");

    // The same seed writes the same log; another seed another.
    assert!(drift(dir.path(), &log, 3, &[]).status.success());
    assert!(drift(dir.path(), &log, 4, &[]).status.success());
    let again = std::fs::read_to_string(dir.path().join("drifted-3.log")).unwrap();
    let other = std::fs::read_to_string(dir.path().join("drifted-4.log")).unwrap();
    assert_eq!(drifted, again);
    assert_ne!(drifted, other);

    // No drift at all: the odometry is the reference.
    let zero = [
        "--scale",
        "0",
        "--turn-scale",
        "0",
        "--heading-bias",
        "0",
        "--sigma-t",
        "0",
        "--sigma-r",
        "0",
        "--sigma-r-per-m",
        "0",
    ];
    let out = drift(dir.path(), &log, 5, &zero);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}");
    assert!(stdout.contains("odometry ATE RMS 0.000 m"), "{stdout}");
}

#[test]
fn bad_arguments_and_missing_or_empty_logs_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("loop.log");
    std::fs::write(&log, corrected_log()).unwrap();
    let err = |out: std::process::Output| {
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let e = err(drift(dir.path(), &log, 1, &["--sigma-t", "-0.1"]));
    assert!(e.contains("--sigma-t is a standard deviation"), "{e}");
    let e = err(drift(dir.path(), &log, 1, &["--scale", "-1.5"]));
    assert!(e.contains("--scale -1.5"), "{e}");
    let e = err(drift(dir.path(), &dir.path().join("nowhere.log"), 1, &[]));
    assert!(
        e.contains("cannot open") && e.contains("nowhere.log"),
        "{e}"
    );
    let empty = dir.path().join("empty.log");
    std::fs::write(&empty, "ODOM 0 0 0 0 0 0 1.0 host 1.0\n").unwrap();
    let e = err(drift(dir.path(), &empty, 1, &[]));
    assert!(e.contains("holds no laser record"), "{e}");
}
