//! The Zenoh link end to end: real publishers on the bus, the real
//! `smokenav-zenoh`, and Zenoh sessions nobody here wrote — the Python
//! `eclipse-zenoh` package (`tests/python/zenoh_client.py`), which builds
//! rmw_zenoh's key from the `rosbags` type store's own type hash and
//! decodes the CDR with `rosbags` — all on 127.0.0.1, multicast scouting off.
//!
//! - one robot: `/laser/scan` arrives on `0/laser/scan/sensor_msgs::msg::
//!   dds_::LaserScan_/RIHS01_…` with the ranges published on the bus and
//!   rmw_zenoh's attachment; the node and publisher liveliness tokens are
//!   there; `cmd_vel` from Python reaches `base/cmd_vel` (a stale sample
//!   never does, and nothing is forwarded once Python stops); RViz's
//!   `initialpose` in `map` reaches `slam/initial_pose` (one in `odom` is
//!   refused and counted); every
//!   socket of the bridge is bound to loopback.
//! - a remote controller killed: the Pioneer emulator, the real driver and
//!   the bridge; the base is commanded to stop by the driver's own command
//!   timeout, as when `smokenav drive` dies.
//! - every type hash equals the one `rosbags` computes.
//! - two robots (two bus instances, namespaces `/robot1`, `/robot2`):
//!   `smokenav status --zenoh` shows both robots' health and pose; killing
//!   robot 2's bridge shows it unreachable within 2 s while robot 1 goes on.

use serde_json::Value;
use smokenav_platform_bus::topics;
use smokenav_platform_config::{RobotConfig, ZenohSection};
use smokenav_shared_types::{
    BeamReading, Header, Health, HealthState, LaserScan, PoseEstimate, VelocityCommand,
};
use smokenav_tests::{Child, bin, open_bus, profile, python, unique_instance, workspace_root};
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

const BEAMS: usize = 181;

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn zenoh_profile(
    dir: &std::path::Path,
    name: &str,
    port: u16,
    ns: &str,
    cmd_vel: bool,
) -> std::path::PathBuf {
    let path = profile(dir, "pioneer-3dx.toml", |c: &mut RobotConfig| {
        c.zenoh = ZenohSection {
            listen: vec![format!("tcp/127.0.0.1:{port}")],
            connect: vec![],
            namespace: ns.into(),
            cmd_vel,
            initial_pose: cmd_vel,
            ..ZenohSection::default()
        };
    });
    let named = dir.join(format!("{name}.toml"));
    std::fs::rename(&path, &named).unwrap();
    named
}

fn bridge(config: &std::path::Path, instance: &str) -> Child {
    let c = Child::spawn(
        &bin("smokenav-zenoh"),
        &["--config", config.to_str().unwrap()],
        instance,
    )
    .unwrap();
    // Generous: a loaded 2-core machine may take long to start a process.
    c.wait_for_line("on Zenoh as", Duration::from_secs(60))
        .unwrap();
    c
}

fn scan(seq_ns: u64) -> LaserScan {
    let mut s = LaserScan {
        header: Header::new(seq_ns, 0, "laser"),
        angle_min: -1.5,
        angle_increment: 1.0f32.to_radians(),
        scan_time: 0.1,
        range_min: 0.02,
        range_max: 5.6,
        count: BEAMS as u32,
        ..LaserScan::default()
    };
    for i in 0..BEAMS {
        s.set_beam(i, BeamReading::Range(1.0 + i as f32 * 0.01));
    }
    s
}

/// Publishes what a robot's processes would, until `stop`: scans at 10 Hz,
/// a SLAM pose and health at 5 Hz.
fn robot(instance: String, x: f64, stop: Arc<AtomicBool>) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let bus = open_bus(&instance);
        let mut scans = bus.publisher(topics::LASER_SCAN).unwrap();
        let mut poses = bus.publisher(topics::SLAM_POSE).unwrap();
        let mut health = bus.publisher(topics::health("slam")).unwrap();
        let mut i = 0u64;
        while !stop.load(Ordering::Relaxed) {
            let now = smokenav_shared_types::clock::monotonic_now_ns();
            scans.publish(&scan(now)).unwrap();
            if i.is_multiple_of(2) {
                poses
                    .publish(&PoseEstimate {
                        header: Header::new(now, 0, "map"),
                        x,
                        y: 0.5,
                        theta: 0.25,
                        ..PoseEstimate::default()
                    })
                    .unwrap();
                let mut h = Health::new("slam", std::process::id());
                h.header.stamp_ns = now;
                h.set_state(HealthState::Ok);
                health.publish(&h).unwrap();
            }
            i += 1;
            std::thread::sleep(Duration::from_millis(100));
        }
    })
}

/// Local addresses of the sockets process `pid` holds (TCP and UDP, v4 and v6).
fn socket_addresses(pid: u32) -> Vec<(String, String)> {
    let inodes: Vec<String> = std::fs::read_dir(format!("/proc/{pid}/fd"))
        .unwrap()
        .filter_map(|e| std::fs::read_link(e.ok()?.path()).ok())
        .filter_map(|l| {
            let l = l.to_string_lossy().into_owned();
            Some(l.strip_prefix("socket:[")?.strip_suffix(']')?.to_owned())
        })
        .collect();
    let mut out = Vec::new();
    for table in ["tcp", "tcp6", "udp", "udp6"] {
        let text = std::fs::read_to_string(format!("/proc/{pid}/net/{table}")).unwrap();
        for line in text.lines().skip(1) {
            let f: Vec<&str> = line.split_whitespace().collect();
            if f.len() > 9 && inodes.iter().any(|i| i == f[9]) {
                out.push((table.to_owned(), f[1].to_owned()));
            }
        }
    }
    out
}

/// `0100007F:1F90` (127.0.0.1) or `…01000000:…` (::1) or v4-mapped 127.x.
fn is_loopback(hex_addr: &str) -> bool {
    let ip = hex_addr.split(':').next().unwrap_or("");
    match ip.len() {
        8 => ip.ends_with("7F"),
        32 => {
            ip == "00000000000000000000000001000000"
                || (ip.starts_with("0000000000000000FFFF0000") && ip.ends_with("7F"))
        }
        _ => false,
    }
}

#[test]
fn laser_scan_reaches_a_python_zenoh_session_on_the_rmw_zenoh_key() {
    let dir = tempfile::tempdir().unwrap();
    let instance = unique_instance("zenoh_one");
    let port = free_port();
    let config = zenoh_profile(dir.path(), "robot", port, "", true);
    let py = python();
    let stop = Arc::new(AtomicBool::new(false));
    let publisher = robot(instance.clone(), 1.0, stop.clone());
    let mut b = bridge(&config, &instance);

    // Commands from outside land on base/cmd_vel.
    let bus = open_bus(&instance);
    let cmds = bus.subscriber(topics::BASE_CMD_VEL).unwrap();
    let given = bus
        .subscriber::<PoseEstimate>(topics::SLAM_INITIAL_POSE)
        .unwrap();
    let out = Command::new(&py)
        .arg(workspace_root().join("tests/python/zenoh_client.py"))
        .arg(format!("tcp/127.0.0.1:{port}"))
        .args(["--scans", "5", "--cmd-vel", "0.25,-0.1,1.0"])
        // RViz's 2D Pose Estimate: in `odom` (refused), then in `map`.
        .args(["--initial-pose", "4.2,-1.0,2.5,odom,map"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    let sockets = socket_addresses(b.pid());
    assert!(
        out.status.success(),
        "zenoh_client.py: {}\n{}",
        String::from_utf8_lossy(&out.stderr),
        b.output()
    );
    let lines: Vec<Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();

    // The graph: the node and its /laser/scan publisher, as rmw_zenoh declares them.
    let tokens: Vec<&str> = lines.iter().find(|l| l["op"] == "tokens").unwrap()["keys"]
        .as_array()
        .unwrap()
        .iter()
        .map(|k| k.as_str().unwrap())
        .collect();
    assert!(
        tokens
            .iter()
            .any(|t| t.starts_with("@ros2_lv/0/") && t.ends_with("/0/0/NN/%/%/smokenav_zenoh")),
        "{tokens:#?}"
    );
    let scan_token = tokens
        .iter()
        .find(|t| {
            t.contains(
                "/MP/%/%/smokenav_zenoh/%laser%scan/sensor_msgs::msg::dds_::LaserScan_/RIHS01_",
            )
        })
        .unwrap_or_else(|| panic!("{tokens:#?}"));
    assert!(scan_token.ends_with("/::,10:,:,:,,"), "{scan_token}");

    // The scans, decoded by rosbags from the key rosbags' own hash names.
    let scans: Vec<&Value> = lines.iter().filter(|l| l["op"] == "scan").collect();
    assert_eq!(scans.len(), 5);
    let mut last_seq = 0;
    for s in &scans {
        let key = s["key"].as_str().unwrap();
        assert!(
            key.starts_with("0/laser/scan/sensor_msgs::msg::dds_::LaserScan_/RIHS01_"),
            "{key}"
        );
        assert!(scan_token.contains(key.rsplit('/').next().unwrap()));
        assert_eq!(s["frame_id"], "laser");
        assert!((s["angle_min"].as_f64().unwrap() + 1.5).abs() < 1e-6);
        let ranges = s["ranges"].as_array().unwrap();
        assert_eq!(ranges.len(), BEAMS);
        for (i, r) in ranges.iter().enumerate() {
            let want = 1.0 + i as f32 * 0.01;
            assert!(
                (r.as_f64().unwrap() as f32 - want).abs() < 1e-6,
                "beam {i}: {r}"
            );
        }
        let a = &s["attachment"];
        assert_eq!(a["len"], 33);
        assert_eq!(a["gid_len"], 16);
        let seq = a["seq"].as_i64().unwrap();
        assert!(seq > last_seq, "sequence numbers rise");
        last_seq = seq;
        let unix = a["unix_ns"].as_i64().unwrap();
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos() as i64;
        assert!(
            (now - unix).abs() < 120_000_000_000,
            "attachment time is Unix time"
        );
    }

    // cmd_vel: the fresh commands arrived, the stale one (9 m/s) never.
    let sent = lines.iter().find(|l| l["op"] == "sent_cmd").unwrap()["count"]
        .as_u64()
        .unwrap();
    let mut got: Vec<VelocityCommand> = Vec::new();
    while let Some(c) = cmds.receive().unwrap() {
        got.push(*c);
    }
    assert!(
        sent >= 5 && got.len() as u64 >= sent / 2,
        "sent {sent}, forwarded {}",
        got.len()
    );
    assert!(
        got.iter().all(|c| c.linear == 0.25 && c.angular == -0.1),
        "{got:?}"
    );
    // Python has stopped: nothing more is forwarded, so the driver's timeout stops the base.
    std::thread::sleep(Duration::from_millis(500));
    assert!(
        cmds.receive().unwrap().is_none(),
        "a command after the controller stopped"
    );
    let stale_seen = smokenav_tests::wait_for(
        &bus,
        topics::health("zenoh"),
        Duration::from_secs(10),
        |h: &Health| h.metric("cmd_stale").is_some_and(|v| v >= 1.0),
    );
    assert!(
        stale_seen.is_ok(),
        "the stale command is not counted: {stale_seen:?}"
    );

    // initialpose: the one in `map` is on slam/initial_pose, the `odom` one refused.
    let mut poses: Vec<PoseEstimate> = Vec::new();
    while let Some(p) = given.receive().unwrap() {
        poses.push(*p);
    }
    assert_eq!(poses.len(), 1, "{poses:?}\n{}", b.output());
    let p = &poses[0];
    assert_eq!(p.header.frame_id.as_str(), "map");
    assert!(
        (p.x - 4.2).abs() < 1e-9 && (p.y + 1.0).abs() < 1e-9 && (p.theta - 2.5).abs() < 1e-9,
        "{p:?}"
    );
    assert_eq!(
        (p.covariance[0], p.covariance[4], p.covariance[8]),
        (0.25, 0.25, 0.0685)
    );
    let refused = smokenav_tests::wait_for(
        &bus,
        topics::health("zenoh"),
        Duration::from_secs(10),
        |h: &Health| h.metric("initial_poses_refused") == Some(1.0),
    );
    assert!(
        refused.is_ok(),
        "the `odom` pose is not counted: {refused:?}"
    );
    assert!(b.output().contains("frame `odom`"), "{}", b.output());

    // Every socket of the bridge is on loopback, and it has some (the listener).
    assert!(!sockets.is_empty(), "no socket found for the bridge");
    for (table, addr) in &sockets {
        assert!(
            is_loopback(addr),
            "{table} socket bound to {addr}: {sockets:?}"
        );
    }
    stop.store(true, Ordering::Relaxed);
    publisher.join().unwrap();
    b.terminate(Duration::from_secs(10)).unwrap();
}

fn robots_in(line: &Value) -> Vec<&Value> {
    line["robots"]
        .as_array()
        .map(|a| a.iter().collect())
        .unwrap_or_default()
}

fn robot_named<'a>(line: &'a Value, ns: &str) -> Option<&'a Value> {
    robots_in(line).into_iter().find(|r| r["namespace"] == ns)
}

fn healthy_with_pose(r: Option<&Value>, x: f64) -> bool {
    r.is_some_and(|r| {
        r["reachable"] == true
            && r["healthy"] == true
            && r["pose"]["x"].as_f64() == Some(x)
            && r["processes"].as_array().is_some_and(|p| {
                ["slam", "zenoh"]
                    .iter()
                    .all(|role| p.iter().any(|q| q["role"] == *role && q["status"] == "up"))
            })
    })
}

#[test]
fn two_robots_over_zenoh_one_bridge_killed_shows_unreachable_within_2s() {
    let dir = tempfile::tempdir().unwrap();
    let (i1, i2) = (unique_instance("zenoh_r1"), unique_instance("zenoh_r2"));
    let (p1, p2) = (free_port(), free_port());
    let c1 = zenoh_profile(dir.path(), "robot1", p1, "/robot1", false);
    let c2 = zenoh_profile(dir.path(), "robot2", p2, "/robot2", false);
    let stop = Arc::new(AtomicBool::new(false));
    let r1 = robot(i1.clone(), 1.0, stop.clone());
    let r2 = robot(i2.clone(), 2.0, stop.clone());
    let mut b1 = bridge(&c1, &i1);
    let mut b2 = bridge(&c2, &i2);
    let endpoints = [format!("tcp/127.0.0.1:{p1}"), format!("tcp/127.0.0.1:{p2}")];

    // One look: both robots healthy, exit status 0.
    let deadline = Instant::now() + Duration::from_secs(30);
    let once = loop {
        let out = Command::new(bin("smokenav"))
            .args(["status", "--json", "--robots", "/robot1,/robot2"])
            .args(["--zenoh", &endpoints[0], "--zenoh", &endpoints[1]])
            .output()
            .unwrap();
        let line: Value = serde_json::from_slice(&out.stdout).unwrap_or(Value::Null);
        if out.status.success() || Instant::now() > deadline {
            break (out, line);
        }
    };
    assert!(
        once.0.status.success(),
        "status --zenoh: {}\n{}",
        once.1,
        String::from_utf8_lossy(&once.0.stderr)
    );
    assert!(
        healthy_with_pose(robot_named(&once.1, "/robot1"), 1.0),
        "{}",
        once.1
    );
    assert!(
        healthy_with_pose(robot_named(&once.1, "/robot2"), 2.0),
        "{}",
        once.1
    );

    // Watching: kill robot 2's bridge.
    let watch = Child::spawn(
        &bin("smokenav"),
        &[
            "status",
            "--json",
            "--watch",
            "0.2",
            "--robots",
            "/robot1,/robot2",
            "--zenoh",
            &endpoints[0],
            "--zenoh",
            &endpoints[1],
        ],
        &i1,
    )
    .unwrap();
    let both = |l: &str| {
        serde_json::from_str::<Value>(l).is_ok_and(|v| {
            healthy_with_pose(robot_named(&v, "/robot1"), 1.0)
                && healthy_with_pose(robot_named(&v, "/robot2"), 2.0)
        })
    };
    let end = Instant::now() + Duration::from_secs(30);
    while !both(
        &watch
            .wait_for_line("\"robots\"", Duration::from_secs(30))
            .unwrap(),
    ) {
        assert!(
            Instant::now() < end,
            "never both healthy: {}",
            watch.output()
        );
    }
    let killed = Instant::now();
    b2.signal(nix::sys::signal::Signal::SIGKILL);
    let gone = loop {
        let l = watch
            .wait_for_line("\"robots\"", Duration::from_secs(10))
            .unwrap();
        let v: Value = serde_json::from_str(&l).unwrap();
        if robot_named(&v, "/robot2").is_some_and(|r| r["reachable"] == false) {
            break v;
        }
        assert!(
            killed.elapsed() < Duration::from_secs(10),
            "robot 2 never unreachable"
        );
    };
    let latency = killed.elapsed();
    eprintln!(
        "robot 2 unreachable {:.0} ms after its bridge was killed",
        latency.as_secs_f64() * 1e3
    );
    assert!(latency < Duration::from_secs(2), "took {latency:?}");
    assert_eq!(gone["healthy"], false);
    assert!(
        healthy_with_pose(robot_named(&gone, "/robot1"), 1.0),
        "{gone}"
    );
    // Robot 1 continues: its pose stays fresh for another second.
    let until = Instant::now() + Duration::from_secs(1);
    while Instant::now() < until {
        let l = watch
            .wait_for_line("\"robots\"", Duration::from_secs(10))
            .unwrap();
        let v: Value = serde_json::from_str(&l).unwrap();
        let r1v = robot_named(&v, "/robot1").unwrap();
        assert!(healthy_with_pose(Some(r1v), 1.0), "{v}");
        assert!(r1v["pose"]["age_s"].as_f64().unwrap() < 1.0, "{v}");
        assert_eq!(robot_named(&v, "/robot2").unwrap()["reachable"], false);
    }
    drop(watch);
    stop.store(true, Ordering::Relaxed);
    r1.join().unwrap();
    r2.join().unwrap();
    b1.terminate(Duration::from_secs(10)).unwrap();
    let _ = b2.wait_exit(Duration::from_secs(5));
}

/// Every type the bridge publishes hashes as `rosbags` hashes it: the
/// standard ones against its Jazzy type store, smokenav_msgs registered
/// there from the same definitions the recordings carry.
#[test]
fn every_type_hash_is_the_one_rosbags_computes() {
    use smokenav_nodes_zenoh::rihs;
    use smokenav_platform_recording::schema;
    // The catalog's types, the Twist `cmd_vel` takes and RViz's `initialpose`.
    let all: Vec<&schema::MsgDef> = schema::ALL
        .iter()
        .copied()
        .chain([&schema::TWIST, &schema::POSE_WITH_COVARIANCE_STAMPED])
        .collect();
    let defs: Vec<Value> = all
        .iter()
        .map(|d| {
            serde_json::json!({
                "name": d.name,
                "text": d.schema_text(),
                "ours": rihs::type_hash(d).unwrap(),
            })
        })
        .collect();
    let script = r#"
import json, sys
from rosbags.typesys import Stores, get_typestore, get_types_from_msg
store = get_typestore(Stores.ROS2_JAZZY)
defs = json.load(sys.stdin)
for d in defs:
    if d["name"] not in store.types:
        store.register(get_types_from_msg(d["text"], d["name"]))
bad = [(d["name"], d["ours"], store.hash_rihs01(d["name"])) for d in defs if store.hash_rihs01(d["name"]) != d["ours"]]
print(json.dumps({"checked": len(defs), "mismatches": bad}))
"#;
    let mut child = Command::new(python())
        .args(["-c", script])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    use std::io::Write;
    child
        .stdin
        .take()
        .unwrap()
        .write_all(serde_json::to_string(&defs).unwrap().as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["checked"].as_u64(), Some(all.len() as u64));
    assert_eq!(v["mismatches"], serde_json::json!([]), "{v}");
}

/// A remote controller on Zenoh that dies stops the robot exactly as a dead
/// local one does (`pioneer_e2e`'s crashed-controller test, with the
/// command arriving through `smokenav-zenoh` instead of `smokenav drive`):
/// the Pioneer emulator on a PTY, the real driver, the bridge with
/// `cmd_vel = true`, and a Python controller killed without a word.
#[test]
fn a_remote_controller_killed_stops_the_robot_through_the_drivers_timeout() {
    use smokenav_pioneer_emulator::{Emulator, RobotConfig as EmuRobot};
    let dir = tempfile::tempdir().unwrap();
    let emu = Emulator::pty(&dir.path().join("pioneer"), EmuRobot::default()).unwrap();
    let instance = unique_instance("zenoh_ctl");
    let port = free_port();
    let config = zenoh_profile(dir.path(), "robot", port, "", true);
    let mut cfg = RobotConfig::load(&config).unwrap();
    cfg.base.port = emu.port_arg();
    cfg.base.cmd_timeout_s = 0.5;
    std::fs::write(&config, cfg.to_toml()).unwrap();
    let cpath = config.to_str().unwrap();
    let driver = Child::spawn(&bin("smokenav-pioneer"), &["--config", cpath], &instance).unwrap();
    let bus = open_bus(&instance);
    smokenav_tests::wait_for(&bus, topics::BASE_ODOM, Duration::from_secs(15), |_| true)
        .unwrap_or_else(|e| panic!("{e}\n{}", driver.output()));
    let _b = bridge(&config, &instance);
    let h = emu.handle();
    let mut ctl = Command::new(python())
        .arg(workspace_root().join("tests/python/zenoh_client.py"))
        .arg(format!("tcp/127.0.0.1:{port}"))
        .args(["--scans", "0", "--cmd-vel", "0.3,0,60"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let drove = h.wait_for(Duration::from_secs(60), |s| {
        s.robot.commanded.trans == 300.0
    });
    if drove.is_none() {
        let _ = ctl.kill();
        panic!("never drove\n{}", driver.output());
    }
    std::thread::sleep(Duration::from_millis(800));
    // The controller dies without a word (and without closing its session).
    ctl.kill().unwrap();
    let killed = Instant::now();
    let st = h
        .wait_for(Duration::from_secs(3), |s| s.robot.commanded.trans == 0.0)
        .expect("the driver stops the robot");
    let dt = killed.elapsed();
    let _ = ctl.wait();
    eprintln!("robot commanded to stop {dt:?} after the remote controller was killed");
    // Last command ≤ 0.1 s before the kill; timeout 0.5 s; loops ≤ 25 ms each.
    assert!(
        dt <= Duration::from_millis(750),
        "stopped {dt:?} after the crash"
    );
    assert!(
        dt >= Duration::from_millis(300),
        "stopped {dt:?}: too early for the timeout"
    );
    assert_eq!(
        st.robot.counters.watchdog_trips, 0,
        "the driver did it, not the firmware"
    );
}
