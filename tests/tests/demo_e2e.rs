//! `smokenav-lab demo --fast` end to end (the real binary): a recording straight
//! from the simulator, fusion + SLAM three ways, scored against the ground
//! truth, and every promised output file. Kept short (`--duration`,
//! `--particles`) so a debug build on two cores finishes well within CI's
//! two minutes.

use smokenav_platform_recording::Playback;
use smokenav_tests::bin;
use std::path::Path;
use std::process::Command;

/// Width and height from a PNG's IHDR chunk (the file must be a PNG).
fn png_size(path: &Path) -> (u32, u32) {
    let b = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(
        &b[..8],
        b"\x89PNG\r\n\x1a\n",
        "{} is not a PNG",
        path.display()
    );
    assert_eq!(&b[12..16], b"IHDR");
    let be = |i: usize| u32::from_be_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
    (be(16), be(20))
}

fn demo(args: &[&str]) -> serde_json::Value {
    let out = Command::new(bin("smokenav-lab"))
        .arg("demo")
        .args(args)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "smokenav-lab demo failed: {}\n{stderr}",
        out.status
    );
    let stdout = String::from_utf8(out.stdout).unwrap();
    serde_json::from_str(stdout.trim())
        .unwrap_or_else(|e| panic!("stdout is not one JSON object ({e}):\n{stdout}\n{stderr}"))
}

#[test]
fn fast_demo_compares_three_methods_against_ground_truth_and_writes_every_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let out_s = out.to_string_lossy().into_owned();
    // The first 30 s of the dense-smoke trial: the robot maps the left bay in clean air.
    let v = demo(&[
        "--fast",
        "--seeds",
        "1",
        "--duration",
        "30",
        "--particles",
        "10",
        "--json",
        "--format",
        "tum",
        "--out",
        &out_s,
    ]);

    assert_eq!(v["scenario"], "r32-dense-crossing");
    assert_eq!(v["sim_seed"], 3, "the scenario's own seed");
    assert_eq!(v["duration_s"], 30.0);
    // The occupancy comparison per rule on `heights` (its first 30 s, as --duration says).
    let occ = &v["occupancy_rules"];
    assert_eq!(occ["scenario"], "heights", "{occ}");
    let rules: Vec<&str> = occ["rules"]
        .as_array()
        .expect("rules")
        .iter()
        .map(|r| r["rule"].as_str().unwrap())
        .collect();
    assert_eq!(rules, ["LOP", "LIOP", "IOP", "Bayes"]);
    assert!(occ["laser_only_out_of_plane_recall"].as_f64().unwrap() <= 0.1);
    assert!(occ["rules"][3]["out_of_plane_recall"].as_f64().unwrap() > 0.3);
    assert!(out.join("map3d").join("octree.bt").exists());
    let scans = v["scans"].as_u64().unwrap();
    assert!((295..=300).contains(&scans), "10 Hz for 30 s: {scans}");
    for section in [&v["methods"], &v["clean_reference"]["methods"]] {
        for m in ["laser-only", "v1", "v2"] {
            let r = &section[m];
            for k in ["map_error_m", "ate_m", "sonar_usage"] {
                assert!(r[k].is_f64(), "{m}.{k} missing in {r}");
            }
            // Clean air so far: every method localises within centimetres, no sonar needed.
            assert!(r["ate_m"].as_f64().unwrap() < 0.3, "{m}: {r}");
            assert_eq!(r["sonar_usage"].as_f64().unwrap(), 0.0, "{m}: {r}");
        }
    }
    assert_eq!(
        v["clean_reference"]["scenario"],
        "r32-dense-crossing (no smoke)"
    );
    // Judged beam by beam against the twin: laser-only hands SLAM every
    // beam; in the clean air of the first 30 s v2 withholds almost none.
    for m in ["laser-only", "v1", "v2"] {
        let j = &v["methods"][m]["laser_verdict"];
        assert!(j["scans"].as_u64().unwrap() >= 290, "{m}: {j}");
        assert!(j["clean_beams"].as_u64().unwrap() > 100_000, "{m}: {j}");
    }
    let lo = &v["methods"]["laser-only"]["laser_verdict"];
    assert_eq!(lo["clean_beams_withheld"], 0, "{lo}");
    assert_eq!(lo["smoke_beams_kept"], lo["smoke_beams"], "{lo}");
    let v2 = &v["methods"]["v2"]["laser_verdict"];
    assert!(v2["clean_withheld_share"].as_f64().unwrap() < 0.05, "{v2}");
    // The file holds what stdout printed.
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("comparison.json")).unwrap())
            .unwrap();
    assert_eq!(file, v);

    // Ground truth and one map_server map and trajectory per method.
    let truth = smokenav_platform_map::load_map_server(&out.join("truth.yaml")).unwrap();
    assert!((truth.resolution - 0.05).abs() < 1e-9);
    for m in ["laser-only", "v1", "v2"] {
        let map =
            smokenav_platform_map::load_map_server(&out.join("maps").join(format!("{m}.yaml")))
                .unwrap();
        assert!(!map.occupied_points(65).is_empty(), "{m}: a map with walls");
        let traj =
            std::fs::read_to_string(out.join("trajectories").join(format!("{m}.txt"))).unwrap();
        let poses = traj.lines().filter(|l| !l.starts_with('#')).count();
        assert!(poses >= 250, "{m}: {poses} poses");
        // --format tum: the same poses as TUM lines, for evo.
        let tum =
            std::fs::read_to_string(out.join("trajectories").join(format!("{m}.tum"))).unwrap();
        assert_eq!(tum.lines().count(), poses, "{m}.tum");
        assert!(tum.lines().all(|l| l.split(' ').count() == 8), "{m}.tum");
    }
    assert!(out.join("truth.tum").exists());
    let truth_poses = std::fs::read_to_string(out.join("truth.txt")).unwrap();
    assert!(truth_poses.lines().filter(|l| !l.starts_with('#')).count() >= 295);

    // Four panels side by side; three stacked plots.
    let (w, h) = png_size(&out.join("maps.png"));
    assert!(w > 3 * h, "maps.png is a row of four panels: {w}×{h}");
    // Where each map's error lies: a panel per method.
    let (w, h) = png_size(&out.join("errors.png"));
    assert!(w > 2 * h, "errors.png is a row of three panels: {w}×{h}");
    let (w, h) = png_size(&out.join("smoke.png"));
    assert!(w >= 1000 && h >= 700, "smoke.png {w}×{h}");
    // With a smoke-free twin the plot has a fourth panel: the laser beams the smoke changed.
    let (_, h_twin) = png_size(&out.join("clean-reference").join("smoke.png"));
    assert!(h > h_twin, "{h} vs {h_twin}");
    let (w, _) = png_size(&out.join("clean-reference").join("maps.png"));
    assert!(w > 1000);

    // The recording replays: every sensor topic at 10 Hz.
    let mut play = Playback::open(&out.join("recording.mcap")).unwrap();
    let mut counts = std::collections::BTreeMap::<String, u64>::new();
    while let Some(p) = play.read_next().unwrap() {
        *counts.entry(p.topic).or_default() += 1;
    }
    for t in ["laser/scan", "base/odom", "base/sonar", "smoke/level"] {
        let n = counts.get(t).copied().unwrap_or(0);
        assert!(
            (290..=301).contains(&n),
            "{t}: {n} messages in 30 s ({counts:?})"
        );
    }
    assert_eq!(play.stats().decode_errors, 0);
}

#[test]
fn a_scenario_without_smoke_has_no_clean_reference() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out").to_string_lossy().into_owned();
    let v = demo(&[
        "--fast",
        "--seeds",
        "1",
        "--scenario",
        "mrl-clean",
        "--sim-seed",
        "11",
        "--no-map3d",
        "--duration",
        "12",
        "--particles",
        "5",
        "--json",
        "--out",
        &out,
    ]);
    assert_eq!(v["scenario"], "mrl-clean");
    // Another draw of the same scenario: the simulator ran with that seed.
    assert_eq!(v["sim_seed"], 11, "{v}");
    let mut play = Playback::open(&Path::new(&out).join("recording.mcap")).unwrap();
    while play.read_next().unwrap().is_some() {}
    let meta = play.source().metadata();
    let seed = meta.iter().find_map(|(_, m)| m.get("seed").cloned());
    assert_eq!(seed.as_deref(), Some("11"), "{meta:?}");
    assert!(v.get("occupancy_rules").is_none(), "--no-map3d");
    assert!(v.get("clean_reference").is_none(), "{v}");
    assert!(v["methods"]["v2"]["map_error_m"].is_f64());
}

#[test]
fn bad_arguments_are_refused_with_a_reason() {
    let out = Command::new(bin("smokenav-lab"))
        .args(["demo", "--fast", "--scenario", "no-such-scenario"])
        .env("RUST_BACKTRACE", "1")
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no-such-scenario"), "{err}");
    // A user error, not a crash: no backtrace even with RUST_BACKTRACE=1.
    assert!(!err.to_lowercase().contains("backtrace"), "{err}");
    let out = Command::new(bin("smokenav-lab"))
        .args(["demo", "--fast", "--duration=-3"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--duration"));
}

/// The acceptance check on the whole dense-smoke trial (about 4 min in
/// release on 2 cores, so not in the default run):
/// `cargo test --release -p smokenav-tests --test demo_e2e -- --ignored`.
#[test]
#[ignore = "the full trial: run in release with --ignored"]
fn full_dense_trial_v2_maps_far_better_than_laser_only_and_no_worse_in_clean_air() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out").to_string_lossy().into_owned();
    let v = demo(&["--fast", "--seeds", "3", "--json", "--out", &out]);
    let err = |section: &serde_json::Value, m: &str| section[m]["map_error_m"].as_f64().unwrap();
    let smoke = &v["methods"];
    let (laser, v1, v2) = (err(smoke, "laser-only"), err(smoke, "v1"), err(smoke, "v2"));
    eprintln!(
        "dense smoke: map error laser-only {laser:.3} m, v1 {v1:.3} m ({:.2}×), v2 {v2:.3} m ({:.2}×)",
        v1 / laser,
        v2 / laser
    );
    assert!(v2 < 0.5 * laser, "v2 {v2} vs laser-only {laser}");
    assert!(v1 < laser, "v1 {v1} vs laser-only {laser}");
    // The fusion's own verdict against the smoke-free twin: how many of the
    // beams the smoke changed each method still handed to SLAM.
    let kept = |m: &str| {
        smoke[m]["laser_verdict"]["smoke_kept_share"]
            .as_f64()
            .unwrap()
    };
    eprintln!(
        "smoke-changed beams handed to SLAM: laser-only {:.3}, v1 {:.3}, v2 {:.3}",
        kept("laser-only"),
        kept("v1"),
        kept("v2")
    );
    assert_eq!(kept("laser-only"), 1.0);
    assert!(kept("v2") < 0.25, "v2 kept {}", kept("v2"));
    let clean = &v["clean_reference"]["methods"];
    let base = err(clean, "laser-only");
    for m in ["v1", "v2"] {
        let ratio = err(clean, m) / base;
        eprintln!("clean air: {m} {ratio:.3}× laser-only");
        assert!((0.95..=1.05).contains(&ratio), "{m}: {ratio}× in clean air");
    }
}

/// `smokenav-lab sim --sim-seed`: the world runs with the seed given, not the
/// scenario's (the same route with other sensor noise and odometry error).
#[test]
fn the_simulator_runs_with_the_seed_it_is_given() {
    let dir = tempfile::tempdir().unwrap();
    let run = |seed: Option<&str>| {
        let mut cmd = Command::new(bin("smokenav-lab"));
        cmd.args(["sim", "mrl-clean", "--duration", "1", "--speed", "10"])
            .arg("--instance")
            .arg(format!("simseed{}", std::process::id()))
            .arg("--out")
            .arg(dir.path().join("out"));
        if let Some(s) = seed {
            cmd.args(["--sim-seed", s]);
        }
        let out = cmd.output().unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
        assert!(
            out.status.success(),
            "{stdout}\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        stdout
    };
    assert!(run(Some("5")).contains("(1 s, seed 5)"));
    assert!(run(None).contains("(1 s, seed 1)"), "mrl-clean's own seed");
}
