//! The live view end to end: the simulator's world feeds the device
//! emulators; the real drivers, fusion and SLAM processes run on them; then
//! `smokenav-view` on a free loopback port, watched by two WebSocket
//! clients nobody here wrote (Python `websockets`, `foxglove.websocket.v1`,
//! CDR decoded by `mcap-ros2-support` from the schemas the server
//! advertised; `tests/python/view_client.py`).
//!
//! Checked: the scans, maps and poses the clients decode are what
//! `smokenav topic echo --json` prints for the same stamps; `/tf` chains
//! map → odom → base_link to the SLAM pose and `/tf_static` holds the
//! profile's laser mount; and a second client that reads nothing for 5 s
//! loses stream messages (counted in `health/view`, per client) while the
//! first keeps receiving scans at the laser's rate and loses none, and
//! fusion keeps its rate.
//!
//! `VIEW_E2E_DUMP=DIR` keeps both clients' output and the view's log there.

use serde_json::Value;
use smokenav_platform_bus::topics;
use smokenav_platform_config::slam::SlamInput;
use smokenav_shared_types::record::{Message, TopicRecord};
use smokenav_shared_types::{Health, HealthState};
use smokenav_sim_link::{SimLink, SimLinkConfig, TruthPublisher, Until};
use smokenav_sim_world::Scenario;
use smokenav_tests::{Child, bin, open_bus, python, unique_instance, wait_for, workspace_root};
use std::collections::HashMap;
use std::process::{Command, Output, Stdio};
use std::thread::JoinHandle;
use std::time::Duration;

const CLIENT_SECONDS: f64 = 16.0;
const STALL_AFTER: f64 = 3.0;
const STALL: f64 = 5.0;

fn smokenav(instance: &str, args: &[&str]) -> Vec<TopicRecord> {
    let out = Command::new(bin("smokenav"))
        .args(args)
        .env("SMOKENAV_INSTANCE", instance)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "smokenav {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect()
}

/// A client process; its output is read as it comes (a full pipe would stall it).
fn client(url: &str, args: &[&str]) -> JoinHandle<std::io::Result<Output>> {
    let child = Command::new(python())
        .arg(workspace_root().join("tests/python/view_client.py"))
        .arg(url)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::spawn(move || child.wait_with_output())
}

/// The client's output lines, after it exited successfully.
fn finish(c: JoinHandle<std::io::Result<Output>>, name: &str) -> Vec<Value> {
    let out = c.join().unwrap().unwrap();
    assert!(
        out.status.success(),
        "{name} client failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect()
}

fn msgs<'a>(lines: &'a [Value], topic: &'a str) -> impl Iterator<Item = &'a Value> + 'a {
    lines
        .iter()
        .filter(move |l| l["op"] == "msg" && l["topic"] == topic)
}

fn metric(h: &TopicRecord, name: &str) -> f64 {
    let Message::Health(h) = &h.message else {
        panic!("not health: {h:?}")
    };
    h.metrics
        .iter()
        .find(|m| m.name == name)
        .unwrap_or_else(|| panic!("no metric {name}: {h:?}"))
        .value
}

fn yaw(t: &Value) -> f64 {
    2.0 * t["qz"].as_f64().unwrap().atan2(t["qw"].as_f64().unwrap())
}

fn wrap(a: f64) -> f64 {
    (a + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI) - std::f64::consts::PI
}

#[test]
fn foxglove_clients_see_the_live_pipeline_and_a_slow_one_disturbs_nobody() {
    let python = python(); // install the client's packages before anything starts
    assert!(python.exists());
    let dir = tempfile::tempdir().unwrap();
    let scenario = Scenario::builtin("corridor").unwrap();
    let mut link = SimLink::start(SimLinkConfig::new(scenario, dir.path().join("dev"))).unwrap();
    let instance = unique_instance("view");
    let mut profile = link.driver_profile(Some(&instance));
    profile.slam.input = SlamInput::Fused;
    profile.slam.particles = 10;
    let cfg_path = dir.path().join("robot.toml");
    std::fs::write(&cfg_path, profile.to_toml()).unwrap();
    let cfg = cfg_path.to_string_lossy().into_owned();
    let bus = open_bus(&instance);
    let base = link.devices().platform.driver_role();
    let roles = ["hokuyo", base, "smoke", "fusion", "slam"];
    let mut procs: Vec<Child> = roles
        .iter()
        .map(|r| {
            Child::spawn(
                &bin(&format!("smokenav-{r}")),
                &["--config", &cfg],
                &instance,
            )
            .unwrap()
        })
        .collect();
    for (role, p) in roles.iter().zip(&procs) {
        let pid = p.pid();
        wait_for::<Health>(&bus, topics::health(role), Duration::from_secs(60), |h| {
            h.pid == pid && matches!(h.state(), HealthState::Ok | HealthState::Degraded)
        })
        .unwrap_or_else(|e| panic!("{role} not ready: {e}\n{}", p.output()));
    }
    let world = {
        let instance = instance.clone();
        std::thread::spawn(move || {
            let bus = open_bus(&instance);
            let mut truth = TruthPublisher::new(&bus).unwrap();
            link.run(
                Until::SimSeconds(CLIENT_SECONDS + 14.0),
                &|| false,
                &mut |s, host| truth.publish(s, host).unwrap(),
                &mut |_| {},
            );
        })
    };

    // A small queue and send buffer: 5 s without reading overflows them.
    let view = Child::spawn(
        &bin("smokenav-view"),
        &[
            "--config",
            &cfg,
            "--listen",
            "127.0.0.1:0",
            "--queue",
            "64",
            "--send-buffer",
            "8192",
        ],
        &instance,
    )
    .unwrap();
    let line = view
        .wait_for_line("serving", Duration::from_secs(30))
        .unwrap();
    let addr: String = line
        .split("ws://")
        .nth(1)
        .unwrap_or_else(|| panic!("no address in `{line}`"))
        .chars()
        .take_while(|c| c.is_ascii_digit() || *c == '.' || *c == ':')
        .collect();
    assert!(addr.starts_with("127.0.0.1:"), "{addr}");
    let url = format!("ws://{addr}");
    // SLAM has published a map before the clients come.
    wait_for::<Health>(&bus, topics::health("slam"), Duration::from_secs(30), |h| {
        h.metrics()
            .iter()
            .any(|m| m.name.as_str() == "maps_published" && m.value > 0.0)
    })
    .unwrap();

    let secs = CLIENT_SECONDS.to_string();
    let fast = client(
        &url,
        &[
            "--topics",
            "/laser/scan,/slam/map,/tf,/tf_static,/slam/pose",
            "--seconds",
            &secs,
        ],
    );
    std::thread::sleep(Duration::from_millis(700));
    let slow = client(
        &url,
        &[
            "--all",
            "--seconds",
            &secs,
            "--stall-after",
            &STALL_AFTER.to_string(),
            "--stall",
            &STALL.to_string(),
            "--rcvbuf",
            "32768",
        ],
    );
    std::thread::sleep(Duration::from_millis(1500));
    let echo = |args: &'static [&'static str]| {
        let instance = instance.clone();
        std::thread::spawn(move || smokenav(&instance, args))
    };
    let scans = echo(&[
        "topic",
        "echo",
        "laser/scan",
        "--json",
        "-n",
        "30",
        "--timeout",
        "20",
    ]);
    let maps = echo(&[
        "topic",
        "echo",
        "slam/map",
        "--json",
        "--with-data",
        "-n",
        "3",
        "--timeout",
        "20",
    ]);
    let poses = echo(&[
        "topic",
        "echo",
        "slam/pose",
        "--json",
        "-n",
        "20",
        "--timeout",
        "20",
    ]);
    // In the middle of the slow client's stall (it started ~0.7 s after the fast one).
    std::thread::sleep(Duration::from_secs_f64(STALL_AFTER + STALL - 1.5 - 1.5));
    let fusion_during = echo(&[
        "topic",
        "echo",
        "health/fusion",
        "--json",
        "-n",
        "2",
        "--timeout",
        "10",
    ]);
    let during = smokenav(
        &instance,
        &[
            "topic",
            "echo",
            "health/view",
            "--json",
            "-n",
            "2",
            "--timeout",
            "10",
        ],
    );
    let fusion_during = fusion_during.join().unwrap();
    let (scans, maps, poses) = (
        scans.join().unwrap(),
        maps.join().unwrap(),
        poses.join().unwrap(),
    );
    let fast = finish(fast, "fast");
    let slow = finish(slow, "slow");
    if let Ok(d) = std::env::var("VIEW_E2E_DUMP") {
        for (n, v) in [("fast", &fast), ("slow", &slow)] {
            let text: Vec<String> = v.iter().map(|l| l.to_string()).collect();
            std::fs::write(format!("{d}/{n}.jsonl"), text.join("\n")).unwrap();
        }
        std::fs::write(format!("{d}/view.log"), view.output()).unwrap();
    }
    let after = smokenav(
        &instance,
        &[
            "topic",
            "echo",
            "health/view",
            "--json",
            "-n",
            "2",
            "--timeout",
            "10",
        ],
    );

    // What was advertised: the recordings' channels.
    let hello = &fast[0];
    assert_eq!(hello["op"], "hello");
    assert_eq!(hello["subprotocol"], "foxglove.websocket.v1");
    let adv: HashMap<&str, &Value> = hello["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| (c["topic"].as_str().unwrap(), c))
        .collect();
    for (topic, schema) in [
        ("/laser/scan", "sensor_msgs/msg/LaserScan"),
        ("/fusion/scan", "sensor_msgs/msg/LaserScan"),
        ("/base/odom", "nav_msgs/msg/Odometry"),
        ("/base/sonar/points", "sensor_msgs/msg/PointCloud2"),
        ("/slam/map", "nav_msgs/msg/OccupancyGrid"),
        ("/slam/pose", "geometry_msgs/msg/PoseStamped"),
        ("/smoke/level", "smokenav_msgs/msg/SmokeReading"),
        ("/health/slam", "smokenav_msgs/msg/Health"),
        ("/tf", "tf2_msgs/msg/TFMessage"),
        ("/tf_static", "tf2_msgs/msg/TFMessage"),
    ] {
        let c = adv
            .get(topic)
            .unwrap_or_else(|| panic!("{topic} not advertised"));
        assert_eq!(c["schemaName"], schema, "{topic}");
        assert_eq!(c["encoding"], "cdr", "{topic}");
        assert_eq!(c["schemaEncoding"], "ros2msg", "{topic}");
    }

    // Scans: the same values `topic echo` printed, matched by stamp.
    let by_stamp: HashMap<u64, &Value> = msgs(&fast, "/laser/scan")
        .map(|m| (m["stamp_ns"].as_u64().unwrap(), m))
        .collect();
    let mut matched = 0;
    for r in &scans {
        let Message::LaserScan(s) = &r.message else {
            panic!("{r:?}")
        };
        let Some(m) = by_stamp.get(&s.header.stamp_ns) else {
            continue;
        };
        matched += 1;
        assert_eq!(m["frame_id"], s.header.frame_id.as_str());
        assert_eq!(m["angle_min"].as_f64().unwrap() as f32, s.angle_min);
        assert_eq!(
            m["angle_increment"].as_f64().unwrap() as f32,
            s.angle_increment
        );
        assert_eq!(m["range_max"].as_f64().unwrap() as f32, s.range_max);
        let ranges: Vec<Option<f32>> = m["ranges"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().map(|r| r as f32))
            .collect();
        assert_eq!(ranges.len(), s.ranges.len());
        for (i, (got, want)) in ranges.iter().zip(&s.ranges).enumerate() {
            match want {
                Some(w) => assert_eq!(*got, Some(*w), "beam {i} of scan {}", s.header.seq),
                None => assert_eq!(*got, None, "beam {i} of scan {}", s.header.seq),
            }
        }
    }
    assert!(
        matched >= 20,
        "only {matched} of {} echoed scans reached the client",
        scans.len()
    );

    // Maps: geometry and every cell (CRC-32 of the bytes) by stamp.
    let maps_ws: HashMap<u64, &Value> = msgs(&fast, "/slam/map")
        .map(|m| (m["stamp_ns"].as_u64().unwrap(), m))
        .collect();
    let mut matched_maps = 0;
    for r in &maps {
        let Message::MapInfo(m) = &r.message else {
            panic!("{r:?}")
        };
        let Some(w) = maps_ws.get(&m.header.stamp_ns) else {
            continue;
        };
        matched_maps += 1;
        assert_eq!(w["width"].as_u64(), Some(u64::from(m.width)));
        assert_eq!(w["height"].as_u64(), Some(u64::from(m.height)));
        assert_eq!(w["resolution"].as_f64().unwrap() as f32, m.resolution);
        assert_eq!(w["origin_x"].as_f64(), Some(m.origin_x));
        assert_eq!(w["origin_y"].as_f64(), Some(m.origin_y));
        let cells: Vec<u8> = m.data.as_ref().unwrap().iter().map(|&c| c as u8).collect();
        assert_eq!(w["cells"].as_u64(), Some(cells.len() as u64));
        assert_eq!(w["cells_crc32"].as_u64(), Some(u64::from(crc32(&cells))));
    }
    assert!(matched_maps >= 1, "no echoed map reached the client");

    // /tf_static: base_link → laser as mounted in the profile.
    let st = msgs(&fast, "/tf_static").next().expect("no /tf_static");
    let t = &st["transforms"][0];
    assert_eq!(t["parent"], "base_link");
    assert_eq!(t["child"], profile.laser.frame_id.as_str());
    assert!((t["x"].as_f64().unwrap() - profile.laser.mount.x).abs() < 1e-9);
    assert!((t["y"].as_f64().unwrap() - profile.laser.mount.y).abs() < 1e-9);
    assert!(wrap(yaw(t) - profile.laser.mount.yaw_rad()).abs() < 1e-9);

    // /tf: map → odom (at a pose's stamp) after odom → base_link gives the pose.
    let mut odom_base: Option<Value> = None;
    let mut map_odom: HashMap<u64, (Value, Value)> = HashMap::new();
    for m in msgs(&fast, "/tf") {
        for t in m["transforms"].as_array().unwrap() {
            if t["child"] == "base_link" {
                odom_base = Some(t.clone());
            } else if t["parent"] == "map"
                && let Some(ob) = &odom_base
            {
                map_odom.insert(t["stamp_ns"].as_u64().unwrap(), (t.clone(), ob.clone()));
            }
        }
    }
    let mut chained = 0;
    for r in &poses {
        let Message::PoseEstimate(p) = &r.message else {
            panic!("{r:?}")
        };
        let Some((mo, ob)) = map_odom.get(&p.header.stamp_ns) else {
            continue;
        };
        chained += 1;
        let (a, b) = (yaw(mo), yaw(ob));
        let (ox, oy) = (ob["x"].as_f64().unwrap(), ob["y"].as_f64().unwrap());
        let x = mo["x"].as_f64().unwrap() + a.cos() * ox - a.sin() * oy;
        let y = mo["y"].as_f64().unwrap() + a.sin() * ox + a.cos() * oy;
        assert!(
            (x - p.x).abs() < 1e-6 && (y - p.y).abs() < 1e-6,
            "({x}, {y}) vs {p:?}"
        );
        assert!(
            wrap(a + b - p.theta).abs() < 1e-6,
            "{} vs {}",
            a + b,
            p.theta
        );
    }
    assert!(chained >= 5, "only {chained} poses found on /tf");

    // The slow client: the fast one kept its scans through the stall.
    let mark = |op: &str| -> u64 {
        slow.iter()
            .find(|l| l["op"] == op)
            .unwrap_or_else(|| panic!("slow client: no {op}"))["t_ns"]
            .as_u64()
            .unwrap()
    };
    let (stall, resume) = (mark("stall"), mark("resume"));
    let arrivals: Vec<u64> = msgs(&fast, "/laser/scan")
        .map(|m| m["t_ns"].as_u64().unwrap())
        .filter(|&t| t >= stall && t <= resume)
        .collect();
    let rate = arrivals.len() as f64 / ((resume - stall) as f64 * 1e-9);
    let all: Vec<u64> = msgs(&fast, "/laser/scan")
        .map(|m| m["t_ns"].as_u64().unwrap())
        .collect();
    assert!(
        rate > 7.0,
        "the fast client got {rate:.1} scans/s while the other stalled ({stall}..{resume}); \
         its {} scans arrived {:?}..{:?}\n{}",
        all.len(),
        all.first(),
        all.last(),
        view.output()
    );
    let worst_gap = arrivals
        .windows(2)
        .map(|w| w[1] - w[0])
        .max()
        .unwrap_or(u64::MAX);
    assert!(
        worst_gap < 500_000_000,
        "a {} ms gap in the fast client's scans",
        worst_gap / 1_000_000
    );
    // … and once what its own socket buffers held is read (stale, queued
    // before the stall), the slow client gets a fresh pose: the newest-value
    // slot overtakes the full stream queue (the unit tests check the order;
    // here the bounds leave room for a loaded machine).
    let fresh = msgs(&slow, "/slam/pose").find(|m| {
        let t = m["t_ns"].as_u64().unwrap();
        t > resume && t - m["stamp_ns"].as_u64().unwrap() < 2_000_000_000
    });
    let fresh = fresh.expect("no fresh pose reached the slow client after its stall");
    let after_resume = fresh["t_ns"].as_u64().unwrap() - resume;
    assert!(
        after_resume < 5_000_000_000,
        "the slow client's first fresh pose came {} ms after it read again",
        after_resume / 1_000_000
    );

    // Fusion kept the laser's rate meanwhile: the view is only a subscriber.
    let f = fusion_during.last().unwrap();
    assert!(
        metric(f, "fused_hz") > 7.0,
        "fusion slowed down while a view client stalled: {f:?}"
    );

    // Health: drops counted for the slow client only.
    let h = during.last().unwrap();
    assert_eq!(metric(h, "clients"), 2.0, "{h:?}");
    assert_eq!(
        metric(h, "client0_dropped"),
        0.0,
        "the fast client lost messages: {h:?}"
    );
    assert!(
        metric(h, "client1_dropped") > 0.0,
        "the stall dropped nothing: {h:?}"
    );
    let h = after.last().unwrap();
    assert!(metric(h, "dropped_total") > 0.0, "{h:?}");
    assert_eq!(
        metric(h, "bus_lost"),
        0.0,
        "the view fell behind the bus: {h:?}"
    );

    world.join().unwrap();
    let mut view = view;
    assert!(
        view.terminate(Duration::from_secs(10)).unwrap().success(),
        "{}",
        view.output()
    );
    for p in &mut procs {
        p.terminate(Duration::from_secs(10)).unwrap();
    }
}

/// CRC-32 (IEEE), as Python's `zlib.crc32`.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// Foxglove's "2D Pose Estimate" through the real `smokenav-view
/// --initial-pose`: a Python client (`websockets`, the pose serialised by
/// `rosbags`) advertises `/initialpose` and publishes one pose; it arrives
/// on the bus as `slam/initial_pose`, counted in `health/view`.
#[test]
fn a_foxglove_pose_estimate_reaches_slam_initial_pose() {
    let python = python();
    let dir = tempfile::tempdir().unwrap();
    let instance = unique_instance("view_pose");
    let cfg = smokenav_tests::profile(dir.path(), "nomad-scout.toml", |_| {});
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let listen = format!("127.0.0.1:{port}");
    let view = Child::spawn(
        &bin("smokenav-view"),
        &[
            "--config",
            cfg.to_str().unwrap(),
            "--listen",
            &listen,
            "--initial-pose",
        ],
        &instance,
    )
    .unwrap();
    view.wait_for_line("/initialpose in", Duration::from_secs(60))
        .unwrap();
    let bus = open_bus(&instance);
    let given = bus
        .subscriber::<smokenav_shared_types::PoseEstimate>(topics::SLAM_INITIAL_POSE)
        .unwrap();
    let out = Command::new(&python)
        .arg(workspace_root().join("tests/python/view_client.py"))
        .arg(format!("ws://{listen}"))
        .args(["--publish-pose", "1.5,-2.0,0.7"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&out.stderr),
        view.output()
    );
    let said: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(said["capabilities"], serde_json::json!(["clientPublish"]));
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    let pose = loop {
        if let Some(p) = given.receive().unwrap() {
            break *p;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "no slam/initial_pose\n{}",
            view.output()
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(pose.header.frame_id.as_str(), "map");
    assert!(
        (pose.x - 1.5).abs() < 1e-9
            && (pose.y + 2.0).abs() < 1e-9
            && (pose.theta - 0.7).abs() < 1e-9,
        "{pose:?}"
    );
    assert_eq!(pose.covariance[0], 0.25);
    wait_for::<Health>(&bus, topics::health("view"), Duration::from_secs(10), |h| {
        h.metric("initial_poses_taken") == Some(1.0)
    })
    .unwrap();
}
