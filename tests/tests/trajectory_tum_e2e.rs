//! `smokenav slam --format tum` writes trajectories that evo, the tool robot
//! teams score SLAM with, reads: `evo_ape tum` (installed from PyPI into the
//! tests' virtual environment) compares the offline and online trajectories
//! of a CSAIL prefix and finds the same ATE as smokenav's own evaluation.

use smokenav_algorithms_eval::{TrajectoryOptions, evaluate_trajectories, load_trajectory};
use smokenav_tests::{bin, csail_prefix_path, python};
use std::process::Command;

#[test]
fn evo_ape_reads_the_tum_trajectories_smokenav_slam_writes() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let log = csail_prefix_path();
    let out = Command::new(bin("smokenav"))
        .args(["slam", "--particles", "5", "--format", "tum", "--carmen"])
        .arg(&log)
        .arg("--out")
        .arg(dir.path())
        .output()?;
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let offline = dir.path().join("trajectory.tum");
    let online = dir.path().join("trajectory_online.tum");
    let first = std::fs::read_to_string(&offline)?;
    let first = first.lines().next().unwrap_or_default();
    assert_eq!(first.split(' ').count(), 8, "not a TUM line: {first}");

    // evo's own reader; --align is its SE(3) Umeyama alignment, which for
    // planar trajectories is the rigid 2D alignment smokenav's ATE uses.
    let evo_ape = python().with_file_name("evo_ape");
    let home = tempfile::tempdir()?;
    let evo = Command::new(&evo_ape)
        .arg("tum")
        .arg(&offline)
        .arg(&online)
        .args(["--align", "--no_warnings"])
        // evo keeps its settings under $HOME/.evo.
        .env("HOME", home.path())
        .env("MPLBACKEND", "Agg")
        .output()?;
    let stdout = String::from_utf8_lossy(&evo.stdout);
    assert!(
        evo.status.success(),
        "{} failed: {stdout}{}",
        evo_ape.display(),
        String::from_utf8_lossy(&evo.stderr)
    );
    let rmse: f64 = stdout
        .lines()
        .find_map(|l| {
            let mut f = l.split_whitespace();
            (f.next() == Some("rmse")).then(|| f.next()?.parse().ok())?
        })
        .unwrap_or_else(|| panic!("no rmse in evo's output:\n{stdout}"));
    let ours = evaluate_trajectories(
        &load_trajectory(&offline)?,
        &load_trajectory(&online)?,
        &TrajectoryOptions::same_stamp(),
    )?;
    eprintln!(
        "evo_ape rmse {rmse:.6} m, smokenav ATE rmse {:.6} m over {} poses",
        ours.ate_m.rmse, ours.pairs
    );
    assert!(ours.pairs > 100, "{ours:?}");
    assert!(
        (rmse - ours.ate_m.rmse).abs() < 1e-4 + 1e-3 * ours.ate_m.rmse,
        "evo {rmse} vs smokenav {}",
        ours.ate_m.rmse
    );
    Ok(())
}
