//! A team's own ROS 2 bags in: a simulator run recorded by smokenav, then
//! rewritten by an independent writer (the Python `rosbags` package, after
//! decoding with `mcap_ros2`) as rosbag2 folders in both storages, MCAP and
//! sqlite3, on ROS 2 topic names (`/scan`, `/odom`, `/tf_static`) and with
//! only what standard messages carry (REP 117 ranges, quaternion headings,
//! no companions). `smokenav slam --bag` on each must give the trajectory
//! it gives on smokenav's own recording (which is read exactly).

use smokenav_platform_recording::{AnyMessageRef, Recorder, RobotGeometry, SinkOptions};
use smokenav_sim_link::{DirectDrivers, DirectMessage};
use smokenav_sim_world::{Scenario, StepOutput, World};
use smokenav_tests::{bin, python, workspace_root};
use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

/// Sim time 0 in the recording, ns (as the demo's fast path).
const T0_NS: u64 = 1_000_000_000;
/// Simulated seconds: the corridor's first stretch, enough for scan matching to matter.
const SIM_S: u64 = 25;

/// The corridor, straight from the simulator through the drivers' cores, as `smokenav record` writes it.
fn record_native(path: &Path) -> anyhow::Result<u64> {
    let scenario = Scenario::builtin("corridor")?;
    let profile = scenario.profile.clone();
    let mut drivers = DirectDrivers::new(&profile, T0_NS)?;
    let mut world = World::new(scenario)?;
    let file = std::io::BufWriter::new(std::fs::File::create(path)?);
    let mut rec = Recorder::create(
        file,
        SinkOptions::default(),
        Some(RobotGeometry::from_config(&profile)),
        &BTreeMap::new(),
        T0_NS,
    )?;
    let mut out = StepOutput::default();
    let mut n = 0u64;
    let mut failed = None;
    while world.time_ns() < SIM_S * 1_000_000_000 {
        out.clear();
        world.step_into(Duration::from_millis(100), &mut out);
        drivers.convert(&out, |t, msg| {
            let r = match &msg {
                DirectMessage::Laser(s) => rec.record(msg.topic(), AnyMessageRef::LaserScan(s), t),
                DirectMessage::Odometry(o) => {
                    rec.record(msg.topic(), AnyMessageRef::Odometry(o), t)
                }
                _ => return,
            };
            match r {
                Ok(()) => n += 1,
                Err(e) => failed = Some(e),
            }
        });
        if let Some(e) = failed.take() {
            return Err(e.into());
        }
    }
    rec.finish(None)?;
    Ok(n)
}

fn slam(bag: &Path, out: &Path) -> anyhow::Result<(String, String)> {
    let run = Command::new(bin("smokenav"))
        .args(["slam", "--particles", "8", "--seed", "3", "--bag"])
        .arg(bag)
        .arg("--out")
        .arg(out)
        .output()?;
    let stdout = String::from_utf8_lossy(&run.stdout).into_owned();
    anyhow::ensure!(
        run.status.success(),
        "smokenav slam --bag {} failed:\n{stdout}{}",
        bag.display(),
        String::from_utf8_lossy(&run.stderr)
    );
    Ok((std::fs::read_to_string(out.join("trajectory.txt"))?, stdout))
}

/// (stamp s, x, y, theta) per line.
fn poses(text: &str) -> Vec<[f64; 4]> {
    text.lines()
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|f| f.parse().unwrap()).collect();
            [v[0], v[1], v[2], v[3]]
        })
        .collect()
}

#[test]
fn slam_on_rosbags_written_bags_matches_the_native_recording() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let native = dir.path().join("native.mcap");
    let recorded = record_native(&native)?;
    assert!(recorded >= 400, "{recorded} messages");

    let script = workspace_root().join("tests/python/write_ros2_bag.py");
    let bags = dir.path().join("bags");
    let out = Command::new(python())
        .arg(&script)
        .arg(&native)
        .arg(&bags)
        .output()?;
    assert!(
        out.status.success(),
        "{} failed:\n{}{}",
        script.display(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    assert_eq!(summary["topics"]["/tf_static"], 1, "{summary}");
    assert!(bags.join("mcap/metadata.yaml").exists());
    assert!(
        std::fs::read_dir(bags.join("sqlite3"))?
            .any(|e| e.is_ok_and(|e| e.path().extension().is_some_and(|x| x == "db3"))),
        "no .db3 in the sqlite3 bag"
    );

    let (reference, native_report) = slam(&native, &dir.path().join("out-native"))?;
    let reference = poses(&reference);
    assert!(reference.len() > 100, "{native_report}");
    for storage in ["mcap", "sqlite3"] {
        let (traj, report) = slam(
            &bags.join(storage),
            &dir.path().join(format!("out-{storage}")),
        )?;
        assert!(
            report.contains("on /scan") && report.contains("on /odom"),
            "{report}"
        );
        assert!(report.contains("from /tf_static"), "{report}");
        let got = poses(&traj);
        assert_eq!(got.len(), reference.len(), "{storage}: {report}");
        for (i, (a, b)) in got.iter().zip(&reference).enumerate() {
            assert_eq!(a[0], b[0], "{storage}: pose {i} stamp");
            // Headings pass through a quaternion in the standard messages: the
            // last bits may differ, nothing more.
            let d = (a[1] - b[1]).hypot(a[2] - b[2]);
            assert!(
                d < 1e-6 && (a[3] - b[3]).abs() < 1e-6,
                "{storage}: pose {i} {a:?} vs native {b:?}"
            );
        }
    }
    Ok(())
}
