//! `smokenav slam --backend fuzzy` as a user runs it: the real binary on a
//! real CARMEN log (the first 200 scans of MIT CSAIL).

use std::path::PathBuf;
use std::process::Command;

fn data() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../algorithms/slam/tests/data")
}

fn slam(out: &std::path::Path, extra: &[&str]) -> (bool, String, String) {
    let data = data();
    let mut args = vec![
        "slam".to_owned(),
        "--carmen".to_owned(),
        data.join("csail-prefix-200.clf").display().to_string(),
        "--backend".to_owned(),
        "fuzzy".to_owned(),
        "--out".to_owned(),
        out.display().to_string(),
        "--reference".to_owned(),
        data.join("csail-reference-poses.txt").display().to_string(),
    ];
    args.extend(extra.iter().map(|s| s.to_string()));
    let o = Command::new(env!("CARGO_BIN_EXE_smokenav"))
        .args(&args)
        .env_remove("RUST_BACKTRACE")
        .output()
        .unwrap();
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

fn ate_rms(stdout: &str) -> f64 {
    stdout
        .lines()
        .find_map(|l| l.strip_prefix("ATE trajectory     RMS "))
        .and_then(|v| v.split(' ').next()?.parse().ok())
        .unwrap_or_else(|| panic!("no ATE in {stdout}"))
}

#[test]
fn fuzzy_back_end_tracks_csail_and_two_runs_are_bit_identical() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let (ok, stdout, stderr) = slam(a.path(), &["--seed", "7"]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("back-end           fuzzy\n"), "{stdout}");
    // Clean air: every scan but the first is registered or refused, none withheld.
    let fuzzy = stdout
        .lines()
        .find_map(|l| l.strip_prefix("fuzzy              "))
        .unwrap_or_else(|| panic!("no fuzzy line in {stdout}"));
    let count = |after: &str| -> u64 {
        let at = fuzzy
            .find(after)
            .unwrap_or_else(|| panic!("{after:?} in {fuzzy}"));
        fuzzy[..at]
            .split_whitespace()
            .last()
            .unwrap()
            .parse()
            .unwrap()
    };
    assert_eq!(count(" registered") + count(" refused"), 199, "{fuzzy}");
    assert!(
        fuzzy.ends_with(" 0 mostly withheld from the laser"),
        "{fuzzy}"
    );
    // 0.03 m when measured; the odometry alone is off by decimetres here.
    let ate = ate_rms(&stdout);
    assert!(ate < 0.15, "ATE {ate} m\n{stdout}");
    assert!(a.path().join("map.png").exists() && a.path().join("map.yaml").exists());
    let (ok, _, stderr) = slam(b.path(), &["--seed", "7"]);
    assert!(ok, "{stderr}");
    let read = |d: &tempfile::TempDir| std::fs::read(d.path().join("trajectory.txt")).unwrap();
    assert!(!read(&a).is_empty());
    assert_eq!(read(&a), read(&b), "same seed, same trajectory");
}

#[test]
fn a_misspelt_fuzzy_key_is_named_with_its_line() {
    let dir = tempfile::tempdir().unwrap();
    let params = dir.path().join("slam.toml");
    std::fs::write(&params, "[fuzzy]\nwindow_m = 0.2\ncuckoo_nest = 10\n").unwrap();
    let (ok, _, stderr) = slam(dir.path(), &["--slam-params", params.to_str().unwrap()]);
    assert!(!ok);
    assert!(
        stderr.contains("slam.toml:3") && stderr.contains("fuzzy.cuckoo_nest"),
        "{stderr}"
    );
}
