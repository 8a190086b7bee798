//! `smokenav-lab map3d` on the bundled `heights` scenario (the real binary):
//! its must-be-true figures hold (it exits non-zero otherwise), and the
//! Bayes octree it exports as `octree.bt` opens in OctoMap's own tools —
//! `bt2vrml` (Debian `octomap-tools`) reads it and writes one VRML box per
//! occupied leaf, which must be as many as the export wrote, within the same
//! bounds, inside the arena.
//!
//! `./test` installs `octomap-tools`; run alone, this test installs it when
//! root, and as anyone else without it says so and checks only the export's
//! own figures.

use serde_json::Value;
use smokenav_tests::bin;
use std::process::Command;

#[test]
fn map3d_meets_its_figures_and_its_octree_opens_in_octomap() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(bin("smokenav-lab"))
        .args(["map3d", "--out"])
        .arg(dir.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "map3d failed:\n{stdout}\n{stderr}");
    for rule in ["LOP", "LIOP", "IOP", "Bayes", "laser only"] {
        assert!(stdout.contains(rule), "no {rule} row:\n{stdout}");
    }
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("report.json")).unwrap())
            .unwrap();
    let leaves = report["bt_occupied_leaves"].as_u64().unwrap();
    assert!(leaves > 1000, "{report}");
    assert!(
        report["octree_bytes"].as_u64() < report["dense_grid_bytes"].as_u64(),
        "{report}"
    );
    let bounds: Vec<Vec<f64>> =
        serde_json::from_value(report["occupied_bounds_m"].clone()).unwrap();
    // The arena is 9 × 8 m. A sonar cap may reach up to 0.5 m behind a wall
    // in corners (the echo came from the other wall; the specular one sent
    // none back), and nothing lies above the highest cone (0.3 + 3 · tan 10° m).
    assert!(
        bounds[0][0] >= -0.6 && bounds[0][1] >= -0.6 && bounds[0][2] >= 0.0,
        "{bounds:?}"
    );
    assert!(
        bounds[1][0] <= 9.6 && bounds[1][1] <= 8.6 && bounds[1][2] <= 1.0,
        "{bounds:?}"
    );

    if !smokenav_tests::ensure_octomap_tools() {
        eprintln!(
            "bt2vrml (octomap-tools) missing and not root: checked the export's own figures only"
        );
        return;
    }
    let bt = dir.path().join("octree.bt");
    let run = Command::new("bt2vrml").arg(&bt).output().unwrap();
    let said = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "bt2vrml: {said}{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let wrl = std::fs::read_to_string(dir.path().join("octree.bt.wrl")).unwrap();
    // One `Transform { translation x y z` + `Box { size s s s}` per occupied leaf.
    let mut n = 0u64;
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    let mut lines = wrl.lines();
    while let Some(l) = lines.next() {
        let Some(rest) = l.strip_prefix("Transform { translation ") else {
            continue;
        };
        let c: Vec<f64> = rest
            .split_whitespace()
            .map(|v| v.parse().unwrap())
            .collect();
        let size_line = lines.next().unwrap();
        let size: f64 = size_line
            .split("size ")
            .nth(1)
            .unwrap()
            .split_whitespace()
            .next()
            .unwrap()
            .trim_end_matches('}')
            .parse()
            .unwrap();
        for a in 0..3 {
            lo[a] = lo[a].min(c[a] - size / 2.0);
            hi[a] = hi[a].max(c[a] + size / 2.0);
        }
        n += 1;
    }
    assert_eq!(
        n, leaves,
        "OctoMap reads as many occupied leaves as were written ({said})"
    );
    for a in 0..3 {
        assert!(
            (lo[a] - bounds[0][a]).abs() < 1e-3,
            "axis {a}: {lo:?} vs {bounds:?}"
        );
        assert!(
            (hi[a] - bounds[1][a]).abs() < 1e-3,
            "axis {a}: {hi:?} vs {bounds:?}"
        );
    }
}
