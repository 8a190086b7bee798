//! The dense-smoke trial drawn again and again: SmokeNav v2's map error in
//! smoke over its clean-air twin, per SLAM back-end, on several simulator
//! seeds side by side. One draw (the live `./demo`, or `--fast`) can sit
//! far from another — on 2026-12-07 the graph back-end's ratio went from
//! 1.50× to 2.11× over eight draws — so a change is judged here, on draws
//! it was not tuned on, not on one run.
//!
//! Each draw is the real `smokenav-lab demo --fast --sim-seed N --seeds 1
//! --no-vote --no-map3d --json` (built in this bench's profile first): the
//! recording straight from the simulator, fusion and both back-ends over it
//! and over the smoke-free twin, scored against the ground truth.
//!
//! Run: `cargo bench -p smokenav-sim-lab --bench draws` (about 2 minutes a
//! draw on 2 cores in release). `DRAWS_BENCH_SEEDS` lists the simulator
//! seeds (default `3,47,53,59,61,67,71,73,79`: the scenario's own, then
//! eight more), `DRAWS_BENCH_SCENARIO` the scenario (default
//! `r32-dense-crossing`).

mod support;

use serde_json::Value;
use std::process::Command;
use std::time::Instant;

const BACKENDS: [&str; 2] = ["rbpf", "graph"];

/// (v2's map error in smoke, in clean air, their ratio) of `backend`, m.
fn v2_errors(v: &Value, backend: &str) -> Option<(f64, f64, f64)> {
    let b = &v["backends"][backend];
    Some((
        b["methods"]["v2"]["map_error_m"].as_f64()?,
        b["clean_reference"]["v2"]["map_error_m"].as_f64()?,
        b["smoke_over_clean"]["v2"].as_f64()?,
    ))
}

fn main() {
    let seeds: Vec<u64> = std::env::var("DRAWS_BENCH_SEEDS")
        .unwrap_or_else(|_| "3,47,53,59,61,67,71,73,79".into())
        .split(',')
        .map(|s| {
            s.trim()
                .parse()
                .expect("DRAWS_BENCH_SEEDS: comma-separated integers")
        })
        .collect();
    let scenario =
        std::env::var("DRAWS_BENCH_SCENARIO").unwrap_or_else(|_| "r32-dense-crossing".into());
    support::build(&["smokenav-sim-lab"]);
    let lab = support::profile_dir().join("smokenav-lab");
    let out = std::env::temp_dir().join(format!("smokenav-draws-{}", std::process::id()));
    println!(
        "{scenario}: SmokeNav v2's map error in smoke / in clean air, one SLAM seed, {} draws",
        seeds.len()
    );
    println!(
        "{:>6}  {:>26}  {:>26}  {:>6}",
        "seed", "rbpf smoke / clean = ratio", "graph smoke / clean = ratio", "s"
    );
    let mut rows: Vec<[(f64, f64, f64); 2]> = Vec::new();
    for seed in &seeds {
        let started = Instant::now();
        let dir = out.join(format!("s{seed}"));
        let run = Command::new(&lab)
            .args([
                "demo",
                "--fast",
                "--seeds",
                "1",
                "--no-vote",
                "--no-map3d",
                "--json",
            ])
            .args(["--scenario", &scenario, "--sim-seed", &seed.to_string()])
            .arg("--out")
            .arg(&dir)
            .output()
            .expect("cannot run smokenav-lab");
        assert!(
            run.status.success(),
            "smokenav-lab demo --sim-seed {seed} failed:\n{}",
            String::from_utf8_lossy(&run.stderr)
        );
        let v: Value = serde_json::from_slice(&run.stdout).expect("demo --json prints one object");
        let row = BACKENDS.map(|b| {
            v2_errors(&v, b).unwrap_or_else(|| panic!("draw {seed}: no v2 figures for {b}"))
        });
        let cell = |(s, c, r): (f64, f64, f64)| format!("{s:.4} / {c:.4} = {r:.2}×");
        println!(
            "{seed:>6}  {:>26}  {:>26}  {:>6.0}",
            cell(row[0]),
            cell(row[1]),
            started.elapsed().as_secs_f64()
        );
        rows.push(row);
        // The recordings are large and the figures printed: keep the disk clean.
        let _ = std::fs::remove_dir_all(&dir);
    }
    let _ = std::fs::remove_dir_all(&out);
    let n = rows.len() as f64;
    for (k, b) in BACKENDS.iter().enumerate() {
        let smoke = rows.iter().map(|r| r[k].0).sum::<f64>() / n;
        let clean = rows.iter().map(|r| r[k].1).sum::<f64>() / n;
        let (lo, hi) = rows.iter().fold((f64::MAX, f64::MIN), |(lo, hi), r| {
            (lo.min(r[k].2), hi.max(r[k].2))
        });
        println!(
            "{b:>6}: mean {smoke:.4} m in smoke / {clean:.4} m in clean air = {:.2}×; per draw {lo:.2}× … {hi:.2}×",
            smoke / clean
        );
    }
}
