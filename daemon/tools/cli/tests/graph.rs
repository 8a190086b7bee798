//! `smokenav graph optimize` as a user runs it: the real binary on real files.

use std::path::PathBuf;
use std::process::Command;

fn mitb() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../algorithms/slam/tests/data/input_MITb_g2o.g2o")
}

fn smokenav(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_smokenav"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn chi2_after(stdout: &str) -> f64 {
    stdout
        .lines()
        .find_map(|l| l.strip_prefix("chi2      after  "))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("no χ² in {stdout}"))
}

#[test]
fn optimize_mitb_prints_chi2_and_writes_the_optimum() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("opt.g2o");
    let (ok, stdout, stderr) = smokenav(&[
        "graph",
        "optimize",
        mitb().to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("808 vertices, 827 edges"), "{stdout}");
    assert!(stdout.contains("chi2      before"), "{stdout}");
    assert!(stdout.contains("iterations"), "{stdout}");
    assert!(stdout.contains("CPU-s"), "{stdout}");
    let chi2 = chi2_after(&stdout);
    assert!((chi2 - 770.24).abs() < 0.01 * 770.24, "{chi2}");
    // Optimising the optimum again changes next to nothing.
    let (ok, again, stderr) = smokenav(&["graph", "optimize", out.to_str().unwrap()]);
    assert!(ok, "{stderr}");
    assert!((chi2_after(&again) - chi2).abs() < 1e-3 * chi2, "{again}");
}

#[test]
fn under_constrained_vertex_and_bad_lines_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, text: &str| {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        p
    };
    let lonely = write(
        "lonely.g2o",
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 5 5 0\n\
         EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n",
    );
    let out = dir.path().join("never.g2o");
    let (ok, _, stderr) = smokenav(&[
        "graph",
        "optimize",
        lonely.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(stderr.contains("vertex 2 is under-constrained"), "{stderr}");
    assert!(
        !out.exists(),
        "nothing is written for a graph that cannot be optimised"
    );
    let dangling = write(
        "dangling.g2o",
        "VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 3 1 0 0 1 0 0 1 0 1\n",
    );
    let (ok, _, stderr) = smokenav(&["graph", "optimize", dangling.to_str().unwrap()]);
    assert!(!ok);
    assert!(
        stderr.contains("line 2") && stderr.contains("vertex 3"),
        "{stderr}"
    );
    let indefinite = write(
        "npd.g2o",
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 3 0 1 0 1\n",
    );
    let (ok, _, stderr) = smokenav(&["graph", "optimize", indefinite.to_str().unwrap()]);
    assert!(!ok);
    assert!(
        stderr.contains("line 3") && stderr.contains("positive definite"),
        "{stderr}"
    );
    let malformed = write("bad.g2o", "VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0\n");
    let (ok, _, stderr) = smokenav(&["graph", "optimize", malformed.to_str().unwrap()]);
    assert!(!ok);
    assert!(stderr.contains("line 2"), "{stderr}");
}

#[test]
fn slam_with_the_graph_back_end_saves_a_graph_that_optimises() {
    let dir = tempfile::tempdir().unwrap();
    let data = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../algorithms/slam/tests/data");
    let graph = dir.path().join("run.g2o");
    let (ok, stdout, stderr) = smokenav(&[
        "slam",
        "--carmen",
        data.join("csail-prefix-200.clf").to_str().unwrap(),
        "--backend",
        "graph",
        "--out",
        dir.path().to_str().unwrap(),
        "--reference",
        data.join("csail-reference-poses.txt").to_str().unwrap(),
        "--save-graph",
        graph.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("back-end           graph\n"), "{stdout}");
    assert!(stdout.contains("loop closures"), "{stdout}");
    assert!(dir.path().join("map.png").exists());
    let (ok, out, stderr) = smokenav(&["graph", "optimize", graph.to_str().unwrap()]);
    assert!(ok, "{stderr}");
    assert!(out.contains("chi2      after"), "{out}");
    // The particle filter keeps no graph to save.
    let (ok, _, stderr) = smokenav(&[
        "slam",
        "--carmen",
        data.join("csail-prefix-200.clf").to_str().unwrap(),
        "--out",
        dir.path().to_str().unwrap(),
        "--save-graph",
        graph.to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(stderr.contains("--backend graph"), "{stderr}");
}
