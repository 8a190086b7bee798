//! A team's own ROS 2 bags in: a simulator run recorded by smokenav, then
//! rewritten by an independent writer (the Python `rosbags` package, after
//! decoding with `mcap_ros2`) as rosbag2 folders in both storages, MCAP and
//! sqlite3, on ROS 2 topic names (`/scan`, `/odom`, `/tf_static`) and with
//! only what standard messages carry (REP 117 ranges, quaternion headings,
//! no companions). `smokenav slam --bag` on each must give the trajectory
//! it gives on smokenav's own recording (which is read exactly). The sonar
//! ring goes in as a ROS 2 robot publishes it — one `sensor_msgs/Range`
//! topic per transducer (placed by `/tf_static`, or only by the order of
//! `--sonar`), or RosAria's one `sensor_msgs/PointCloud2` — and `fuse --bag`
//! and `play` must give what they give on the native recording.

use smokenav_platform_bus::{Subscriber, Waiter, topics};
use smokenav_platform_recording::{AnyMessage, Playback};
use smokenav_platform_recording::{AnyMessageRef, Recorder, RobotGeometry, SinkOptions};
use smokenav_shared_types::{LaserScan, Odometry, SonarRing};
use smokenav_sim_link::{DirectDrivers, DirectMessage};
use smokenav_sim_world::{Scenario, StepOutput, World};
use smokenav_tests::{Child, bin, open_bus, python, unique_instance, workspace_root};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;
use std::time::Instant;

/// Sim time 0 in the recording, ns (as the demo's fast path).
const T0_NS: u64 = 1_000_000_000;
/// Simulated seconds: the corridor's first stretch, enough for scan matching to matter.
const SIM_S: u64 = 25;

/// The corridor, straight from the simulator through the drivers' cores, as `smokenav record` writes it.
fn record_native(path: &Path) -> anyhow::Result<u64> {
    record_native_with_truth(path, None)
}

/// [`record_native`], also writing the world's true pose after every 0.1 s
/// step to `truth` (`timestamp x y theta`, on the simulator's own ticks, as
/// `smokenav-lab` writes its truth).
fn record_native_with_truth(path: &Path, truth: Option<&Path>) -> anyhow::Result<u64> {
    let mut truth_text = String::from("# timestamp x y theta\n");
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
                DirectMessage::Sonar(r) => rec.record(msg.topic(), AnyMessageRef::SonarRing(r), t),
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
        let p = world.truth_pose();
        truth_text.push_str(&format!(
            "{:.6} {:.6} {:.6} {:.6}\n",
            (T0_NS + world.time_ns()) as f64 * 1e-9,
            p.x,
            p.y,
            p.theta
        ));
    }
    rec.finish(None)?;
    if let Some(t) = truth {
        std::fs::write(t, truth_text)?;
    }
    Ok(n)
}

fn slam(bag: &Path, out: &Path) -> anyhow::Result<(String, String)> {
    slam_with(bag, out, &[])
}

fn slam_with(bag: &Path, out: &Path, extra: &[&str]) -> anyhow::Result<(String, String)> {
    let run = Command::new(bin("smokenav"))
        .args(["slam", "--particles", "8", "--seed", "3", "--bag"])
        .arg(bag)
        .arg("--out")
        .arg(out)
        .args(extra)
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

/// The summary's count of sweeps deskewed by odometry.
fn deskewed(report: &str) -> u64 {
    report
        .split(" sweeps deskewed by odometry")
        .next()
        .and_then(|head| head.rsplit(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0)
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

/// The native recording and, beside it, `bags/{mcap,sqlite3,tf-only}` as rosbags writes them.
fn native_and_bags(dir: &Path) -> anyhow::Result<(PathBuf, PathBuf)> {
    let native = dir.join("native.mcap");
    let recorded = record_native(&native)?;
    assert!(recorded >= 400, "{recorded} messages");

    let script = workspace_root().join("tests/python/write_ros2_bag.py");
    let bags = dir.join("bags");
    let out = Command::new(python())
        .arg(&script)
        .arg(&native)
        .arg(&bags)
        .arg(workspace_root().join("config/pioneer-3dx.toml"))
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
    assert!(
        summary["topics"]["sonar rings"].as_u64() > Some(100),
        "{summary}"
    );
    assert!(bags.join("mcap/metadata.yaml").exists());
    assert!(
        std::fs::read_dir(bags.join("sqlite3"))?
            .any(|e| e.is_ok_and(|e| e.path().extension().is_some_and(|x| x == "db3"))),
        "no .db3 in the sqlite3 bag"
    );
    Ok((native, bags))
}

#[test]
fn slam_on_rosbags_written_bags_matches_the_native_recording() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let (native, bags) = native_and_bags(dir.path())?;

    let (reference, native_report) = slam(&native, &dir.path().join("out-native"))?;
    let reference = poses(&reference);
    assert!(reference.len() > 100, "{native_report}");
    // The driver's time between beams reached the SLAM: its sweeps were
    // deskewed by the odometry, and the bags' must be too to match.
    assert!(deskewed(&native_report) > 100, "{native_report}");
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

/// A recording scored against a truth sampled on the simulator's own clock
/// (not at the scans' stamps): the truth is interpolated for the ATE, and
/// the scans drawn at it are the map's truth. Both came out empty before
/// ("only 0 estimated pose(s) …", "the ground-truth map has no occupied cells").
#[test]
fn slam_on_a_bag_scores_against_a_truth_on_its_own_clock() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let (native, truth) = (dir.path().join("native.mcap"), dir.path().join("truth.txt"));
    record_native_with_truth(&native, Some(&truth))?;
    let (_, report) = slam_with(
        &native,
        &dir.path().join("out"),
        &["--reference", truth.to_str().unwrap()],
    )?;
    let line = |head: &str| {
        report
            .lines()
            .find(|l| l.starts_with(head))
            .unwrap_or_else(|| panic!("no {head} line:\n{report}"))
            .to_owned()
    };
    let ate = line("ATE trajectory");
    assert!(
        ate.contains("paired with the reference interpolated"),
        "{ate}"
    );
    let rms: f64 = ate
        .split("RMS ")
        .nth(1)
        .and_then(|t| t.split(' ').next())
        .and_then(|t| t.parse().ok())
        .unwrap_or_else(|| panic!("{ate}"));
    // The corridor's first 25 s in clean air: centimetres.
    assert!(rms < 0.15, "{ate}");
    let map = line("map error");
    assert!(map.contains("k-NN"), "{map}");
    Ok(())
}

/// `smokenav slam --bag --fuse v2` maps from the fused laser and sonar:
/// the Range bag's per-transducer topics give the trajectory the native
/// recording's rings give (`fuse_on_a_foreign_bag…` shows the rings change
/// the fused scans); `--sonar` without `--fuse` is refused.
#[test]
fn slam_fuses_a_foreign_bags_sonar_as_the_native_recordings() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let (native, bags) = native_and_bags(dir.path())?;
    let fuse = ["--fuse", "v2", "--max-scans", "120"];
    let (want, native_report) = slam_with(&native, &dir.path().join("native"), &fuse)?;
    assert!(native_report.contains("sonar rings"), "{native_report}");
    let (got, report) = slam_with(&bags.join("mcap"), &dir.path().join("mcap"), &fuse)?;
    assert!(
        report.contains("/sonar/0") && report.contains("fused scans"),
        "{report}"
    );
    let (want, got) = (poses(&want), poses(&got));
    assert!(want.len() >= 100, "{native_report}");
    assert_eq!(got.len(), want.len(), "{report}");
    for (i, (a, b)) in got.iter().zip(&want).enumerate() {
        assert_eq!(a[0], b[0], "pose {i} stamp");
        let d = (a[1] - b[1]).hypot(a[2] - b[2]);
        assert!(
            d < 1e-6 && (a[3] - b[3]).abs() < 1e-6,
            "pose {i} {a:?} vs native {b:?}"
        );
    }
    let err = slam_with(
        &bags.join("mcap"),
        &dir.path().join("x"),
        &["--sonar", "/sonar/0"],
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("add --fuse"), "{err}");
    Ok(())
}

/// The fused scans `smokenav fuse --bag` writes (one JSON value each) and its summary.
fn fuse(bag: &Path, extra: &[&str]) -> anyhow::Result<(Vec<serde_json::Value>, String)> {
    let run = Command::new(bin("smokenav"))
        .args(["fuse", "--method", "v2", "--bag"])
        .arg(bag)
        .args(extra)
        .output()?;
    let stderr = String::from_utf8_lossy(&run.stderr).into_owned();
    anyhow::ensure!(
        run.status.success(),
        "smokenav fuse --bag {} failed:\n{stderr}",
        bag.display(),
    );
    let mut fused = Vec::new();
    for line in String::from_utf8_lossy(&run.stdout).lines() {
        let v: serde_json::Value = serde_json::from_str(line)?;
        assert_eq!(v["topic"], "fusion/scan", "{line}");
        fused.push(v);
    }
    Ok((fused, stderr))
}

/// Fused scans equal up to `tol` in their float fields (0: bit for bit as
/// printed), but for the header's sequence number.
fn assert_same_fused(what: &str, got: &[serde_json::Value], want: &[serde_json::Value], tol: f64) {
    fn close(
        a: &serde_json::Value,
        b: &serde_json::Value,
        tol: f64,
        at: &str,
    ) -> Result<(), String> {
        use serde_json::Value::*;
        match (a, b) {
            (Number(x), Number(y)) if x.is_f64() || y.is_f64() => {
                let (x, y) = (
                    x.as_f64().unwrap_or(f64::NAN),
                    y.as_f64().unwrap_or(f64::NAN),
                );
                if (x - y).abs() <= tol {
                    Ok(())
                } else {
                    Err(format!("{at}: {x} vs {y}"))
                }
            }
            (Array(x), Array(y)) if x.len() == y.len() => x
                .iter()
                .zip(y)
                .enumerate()
                .try_for_each(|(i, (a, b))| close(a, b, tol, &format!("{at}[{i}]"))),
            // ROS 2 headers carry no sequence number.
            (Object(x), Object(y)) if x.len() == y.len() => x
                .iter()
                .filter(|(k, _)| k.as_str() != "seq")
                .try_for_each(|(k, a)| {
                    close(a, y.get(k).unwrap_or(&Null), tol, &format!("{at}.{k}"))
                }),
            _ if a == b => Ok(()),
            _ => Err(format!("{at}: {a} vs {b}")),
        }
    }
    assert_eq!(got.len(), want.len(), "{what}: fused scans");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        if let Err(e) = close(g, w, tol, "") {
            panic!("{what}: fused scan {i} differs at {e}");
        }
    }
}

/// `smokenav fuse --bag` fuses a foreign bag's laser and sonar as it fuses
/// the native recording's (neither has a smoke sensor, so v2 takes the air
/// for smoky and the sonar witnesses every section): the same fused scans
/// from Range topics placed by `/tf_static` (MCAP and sqlite3), from Range
/// topics known only by the order of `--sonar`, and — within float32
/// coordinates — from RosAria's PointCloud2.
#[test]
fn fuse_on_a_foreign_bag_matches_the_native_recording() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let (native, bags) = native_and_bags(dir.path())?;
    let (want, native_report) = fuse(&native, &[])?;
    assert!(want.len() > 200, "{} fused scans", want.len());
    // The sonar matters: rings are fused and some beams come from them or are dropped by them.
    let with_ring = want
        .iter()
        .filter(|v| v["sonar_stamp_ns"].as_u64() > Some(0))
        .count();
    let not_laser = want
        .iter()
        .filter(|v| {
            v["beam_source"]
                .as_array()
                .is_some_and(|b| b.iter().any(|s| s != 0))
        })
        .count();
    assert!(
        with_ring > 200 && not_laser > 0,
        "{with_ring} scans with a ring, {not_laser} with beams not the laser's\n{native_report}"
    );

    for storage in ["mcap", "sqlite3"] {
        let (got, report) = fuse(&bags.join(storage), &[])?;
        assert!(
            report.contains("/sonar/0") && report.contains("sensor_msgs/Range"),
            "{report}"
        );
        assert_same_fused(storage, &got, &want, 0.0);
    }
    let order: Vec<String> = (0..8)
        .flat_map(|i| ["--sonar".to_owned(), format!("/sonar/{i}")])
        .collect();
    let order: Vec<&str> = order.iter().map(String::as_str).collect();
    let (got, _) = fuse(&bags.join("range-notf"), &order)?;
    assert_same_fused("range-notf --sonar ×8", &got, &want, 0.0);
    // Guessed, with nothing to say which transducer a frame is: an error saying what to give.
    let err = fuse(&bags.join("range-notf"), &[]).unwrap_err().to_string();
    assert!(
        err.contains("/tf_static does not place frame `sonar_0`") && err.contains("--sonar"),
        "{err}"
    );
    for storage in ["cloud-mcap", "cloud-sqlite3"] {
        let (got, report) = fuse(&bags.join(storage), &[])?;
        assert!(
            report.contains("/sonar_pointcloud2") && report.contains(" 0 cloud points dropped"),
            "{report}"
        );
        // Ranges come back from float32 echo coordinates: within a micrometre or so.
        assert_same_fused(storage, &got, &want, 1e-5);
    }
    Ok(())
}

/// `smokenav play` of a foreign bag publishes its LaserScan and Odometry
/// topics as laser/scan and base/odom, and its per-transducer Range topics
/// as base/sonar rings, message for message; a bag with none of them is an
/// error (it used to play 0 messages and exit 0).
#[test]
fn play_publishes_a_foreign_bags_standard_topics() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let (native, bags) = native_and_bags(dir.path())?;
    let mut want_scans: Vec<LaserScan> = Vec::new();
    let mut want_odom: Vec<Odometry> = Vec::new();
    let mut want_rings: Vec<SonarRing> = Vec::new();
    for p in Playback::open(&native)? {
        match p?.message {
            AnyMessage::LaserScan(s) => want_scans.push(*s),
            AnyMessage::Odometry(o) => want_odom.push(o),
            AnyMessage::SonarRing(r) => want_rings.push(r),
            _ => {}
        }
    }

    let instance = unique_instance("rosbag_play");
    let bus = open_bus(&instance);
    let scans: Subscriber<LaserScan> = bus.subscriber(topics::LASER_SCAN)?;
    let odom: Subscriber<Odometry> = bus.subscriber(topics::BASE_ODOM)?;
    let sonar: Subscriber<SonarRing> = bus.subscriber(topics::BASE_SONAR)?;
    let waiter = Waiter::new()?;
    let _g = [
        waiter.attach(&scans)?,
        waiter.attach(&odom)?,
        waiter.attach(&sonar)?,
    ];
    let bag = bags.join("sqlite3");
    let bag_s = bag.to_str().unwrap();
    let mut player = Child::spawn(
        &bin("smokenav"),
        &["play", bag_s, "--rate", "5", "--instance", &instance],
        &instance,
    )?;
    let (mut got_scans, mut got_odom, mut got_rings) = (Vec::new(), Vec::new(), Vec::new());
    let deadline = Instant::now() + Duration::from_secs(60);
    while got_scans.len() < want_scans.len()
        || got_odom.len() < want_odom.len()
        || got_rings.len() < want_rings.len()
    {
        assert!(
            Instant::now() < deadline,
            "replay incomplete: {} scans, {} odometry, {} sonar rings\n{}",
            got_scans.len(),
            got_odom.len(),
            got_rings.len(),
            player.output()
        );
        waiter.wait(Some(Duration::from_millis(200)))?;
        while let Some(s) = scans.receive()? {
            got_scans.push(*s);
        }
        while let Some(o) = odom.receive()? {
            got_odom.push(*o);
        }
        while let Some(r) = sonar.receive()? {
            got_rings.push(*r);
        }
    }
    let status = player.wait_exit(Duration::from_secs(30))?;
    assert!(status.success(), "{}", player.output());
    assert!(player.output().contains("published"), "{}", player.output());
    assert_eq!(got_scans.len(), want_scans.len());
    for (i, (g, w)) in got_scans.iter().zip(&want_scans).enumerate() {
        assert_eq!(g.header.stamp_ns, w.header.stamp_ns, "scan {i}");
        assert_eq!(g.len(), w.len(), "scan {i}");
        assert!(
            (0..w.len()).all(|b| match w.beam(b) {
                smokenav_shared_types::BeamReading::Range(r) =>
                    g.beam(b) == smokenav_shared_types::BeamReading::Range(r),
                _ => !matches!(g.beam(b), smokenav_shared_types::BeamReading::Range(_)),
            }),
            "scan {i}: every range as recorded, every beam without one still without"
        );
    }
    assert_eq!(got_odom.len(), want_odom.len());
    for (i, (g, w)) in got_odom.iter().zip(&want_odom).enumerate() {
        assert_eq!(g.header.stamp_ns, w.header.stamp_ns, "odometry {i}");
        assert_eq!((g.x, g.y), (w.x, w.y), "odometry {i}");
        assert!((g.theta - w.theta).abs() < 1e-9, "odometry {i}");
    }
    assert_eq!(got_rings.len(), want_rings.len());
    for (i, (g, w)) in got_rings.iter().zip(&want_rings).enumerate() {
        assert_eq!(g.header.stamp_ns, w.header.stamp_ns, "ring {i}");
        assert_eq!(
            g.readings(),
            w.readings(),
            "ring {i}: every transducer, range and status"
        );
        assert_eq!(g.max_range, w.max_range, "ring {i}");
    }

    let tf_only = bags.join("tf-only");
    let run = Command::new(bin("smokenav"))
        .arg("play")
        .arg(&tf_only)
        .args(["--fast", "--instance", &instance])
        .output()?;
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success(), "{stderr}");
    assert!(
        stderr.contains("no sensor_msgs/msg/LaserScan or nav_msgs/msg/Odometry topic to play")
            && stderr.contains("/tf_static"),
        "{stderr}"
    );
    Ok(())
}

/// `topic hz` measures on receive time: a replay that keeps its recorded
/// stamps (no `--restamp`; they lie far behind the bus clock) is measured
/// like live data. It used to report 0 Hz, taking every message for the
/// topic's history.
#[test]
fn topic_hz_measures_a_replay_without_restamp() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let native = dir.path().join("native.mcap");
    record_native(&native)?;
    let instance = unique_instance("rosbag_hz");
    let mut hz = Child::spawn(
        &bin("smokenav"),
        &["topic", "hz", "laser/scan", "--duration", "6", "--json"],
        &instance,
    )?;
    // hz has subscribed once it waits; the replay starts after.
    std::thread::sleep(Duration::from_millis(500));
    let mut player = Child::spawn(
        &bin("smokenav"),
        &[
            "play",
            native.to_str().unwrap(),
            "--rate",
            "2",
            "--instance",
            &instance,
        ],
        &instance,
    )?;
    let status = hz.wait_exit(Duration::from_secs(60))?;
    assert!(status.success(), "{}", hz.output());
    let _ = player.terminate(Duration::from_secs(10));
    let line = hz
        .output()
        .lines()
        .find(|l| l.starts_with('{'))
        .map(str::to_owned)
        .unwrap_or_else(|| panic!("no JSON from topic hz:\n{}", hz.output()));
    let v: serde_json::Value = serde_json::from_str(&line)?;
    let received = v["received"].as_u64().unwrap_or(0);
    let rate = v["rate_hz"].as_f64().unwrap_or(0.0);
    // 20 Hz of scans at --rate 2 for up to 5 s; a loaded machine delivers fewer, never none.
    assert!(received >= 5 && rate > 0.0, "{line}");
    Ok(())
}

/// (stamp, bus time it arrived at) of each scan replayed, and the clock messages' times.
type Replayed = (Vec<(u64, u64)>, Vec<u64>);

/// Replays `native` onto a fresh instance with `extra` arguments.
fn replay_collect(native: &Path, extra: &[&str]) -> anyhow::Result<Replayed> {
    use smokenav_shared_types::SimClock;
    let instance = unique_instance("rosbag_clock");
    let bus = open_bus(&instance);
    let scans: Subscriber<LaserScan> = bus.subscriber(topics::LASER_SCAN)?;
    let clock: Subscriber<SimClock> = bus.subscriber(topics::CLOCK)?;
    let waiter = Waiter::new()?;
    let _g = [waiter.attach(&scans)?, waiter.attach(&clock)?];
    let mut args = vec!["play", native.to_str().unwrap(), "--instance", &instance];
    args.extend_from_slice(extra);
    let mut player = Child::spawn(&bin("smokenav"), &args, &instance)?;
    let (mut got, mut clocks) = (Vec::new(), Vec::new());
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        waiter.wait(Some(Duration::from_millis(100)))?;
        while let Some(s) = scans.receive()? {
            got.push((
                s.header.stamp_ns,
                smokenav_shared_types::clock::monotonic_now_ns(),
            ));
        }
        while let Some(c) = clock.receive()? {
            clocks.push(c.header.stamp_ns);
        }
        if !player.is_running() {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "replay did not end:\n{}",
            player.output()
        );
    }
    let status = player.wait_exit(Duration::from_secs(10))?;
    assert!(status.success(), "{}", player.output());
    Ok((got, clocks))
}

/// `play` publishes sim time on `clock` (the data's instant, at any
/// `--rate`), and `--rate 4 --restamp` keeps every stamp at its message's
/// arrival on the bus clock: a constant shift used to run the stamps ahead
/// of the data by the time the faster replay saved (19 s here by the end).
#[test]
fn play_publishes_sim_time_and_restamps_at_the_replay_pace() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let native = dir.path().join("native.mcap");
    record_native(&native)?;

    let (scans, clocks) = replay_collect(&native, &["--rate", "4"])?;
    assert!(scans.len() > 100, "{} scans", scans.len());
    assert!(clocks.len() > 100, "{} clock messages", clocks.len());
    assert!(
        clocks.windows(2).all(|w| w[0] <= w[1]),
        "sim time went back"
    );
    // Sim time is the recording's own time (its stamps' clock), not the bus clock.
    let (first, last) = (scans[0].0, scans[scans.len() - 1].0);
    assert!(
        clocks[0] <= first + 100_000_000 && *clocks.last().unwrap() + 200_000_000 >= last,
        "clock {}..{} vs scans {first}..{last}",
        clocks[0],
        clocks.last().unwrap()
    );
    assert!(*clocks.last().unwrap() <= last + 200_000_000);

    let (scans, _) = replay_collect(&native, &["--rate", "4", "--restamp", "--no-clock"])?;
    assert!(scans.len() > 100, "{} scans", scans.len());
    for (i, &(stamp, arrived)) in scans.iter().enumerate() {
        let ahead = stamp as i128 - arrived as i128;
        assert!(
            ahead < 2_000_000_000,
            "scan {i} stamped {:.1} s after it arrived",
            ahead as f64 * 1e-9
        );
    }
    // Stamps advance at the replay's pace: 4× closer than recorded.
    let span = (scans[scans.len() - 1].0 - scans[0].0) as f64 * 1e-9;
    assert!(span < 0.5 * 25.0, "restamped stamps span {span:.1} s");
    Ok(())
}
