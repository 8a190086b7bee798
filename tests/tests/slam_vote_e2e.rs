//! The vote back-end in the real `smokenav-slam` process: a prefix of the
//! MIT CSAIL log replayed over the bus, the three members' maps arrive on
//! `slam/vote/{rbpf,graph,fuzzy}` and the vote on `slam/map`; with a member
//! made to panic or hang (the test-only `SMOKENAV_TEST_VOTE_FAULT`), the vote
//! keeps updating on the others, `health/slam` names the member that is out,
//! and the two left do not vote the union of their maps. SIGUSR1 saves the
//! graph member's pose graph beside the map, as the graph back-end does.

use smokenav_platform_bus::{Bus, Publisher, Topic, Waiter, topics};
use smokenav_platform_config::{MountPose, SlamBackendKind, SlamInput};
use smokenav_shared_types::{
    Clock, Health, HealthState, LaserScan, MapInfo, MonotonicClock, Odometry, PoseEstimate,
};
use smokenav_tests::{
    Child, bin, carmen_odometry, csail_prefix, fill_carmen_scan, open_bus, pose_for_scan, profile,
    unique_instance, wait_for,
};
use std::time::{Duration, Instant};

struct Run {
    slam: Child,
    bus: Bus,
    /// Where SIGUSR1 saves (`--map-dir`).
    maps: std::path::PathBuf,
    _dir: tempfile::TempDir,
}

fn start(name: &str, fault: Option<&str>) -> Run {
    let instance = unique_instance(name);
    let dir = tempfile::tempdir().unwrap();
    let cfg = profile(dir.path(), "pioneer-3dx.toml", |c| {
        c.slam.input = SlamInput::Laser;
        c.slam.backend = SlamBackendKind::Vote;
        c.slam.particles = 5;
        c.slam.map_rate_hz = 2.0;
        c.slam.vote.fuse_period_s = 0.3;
        // The first test also runs the member that maps in height (the
        // replay has no sonar: its map is the laser's at the graph's poses).
        if name == "slam_vote_e2e" {
            c.slam.vote.members.push(SlamBackendKind::Projected);
        }
        // A debug member on a loaded 2-core machine can take over a second
        // for one scan: only the stall test wants a short timeout (its
        // injected stall lasts until shutdown).
        c.slam.vote.stall_timeout_s = if fault.is_some_and(|f| f.contains(":stall")) {
            1.0
        } else {
            30.0
        };
        c.laser.mount = MountPose {
            x: 0.0,
            y: 0.0,
            yaw_deg: 0.0,
        };
    });
    let env: Vec<(&str, &str)> = fault
        .map(|f| vec![("SMOKENAV_TEST_VOTE_FAULT", f)])
        .unwrap_or_default();
    let maps = dir.path().join("maps");
    let slam = Child::spawn_env(
        &bin("smokenav-slam"),
        &[
            "--config",
            cfg.to_str().unwrap(),
            "--map-dir",
            maps.to_str().unwrap(),
        ],
        &instance,
        &env,
    )
    .unwrap();
    slam.wait_for_line("vote on ", Duration::from_secs(30))
        .unwrap_or_else(|e| panic!("{e}\n{}", slam.output()));
    let bus = open_bus(&instance);
    Run {
        slam,
        bus,
        maps,
        _dir: dir,
    }
}

/// Replays `n` scans, each after the pose of the one before came back.
fn replay(r: &Run, n: usize) {
    let mut odom: Publisher<Odometry> = r.bus.publisher(topics::BASE_ODOM).unwrap();
    let mut scans: Publisher<LaserScan> = r.bus.publisher(topics::LASER_SCAN).unwrap();
    let poses = r.bus.subscriber::<PoseEstimate>(topics::SLAM_POSE).unwrap();
    let waiter = Waiter::new().unwrap();
    let _g = waiter.attach(&poses).unwrap();
    let records: Vec<_> = csail_prefix().into_iter().take(n).collect();
    let base = MonotonicClock.now_ns();
    let ipc0 = records[0].ipc_timestamp_ns;
    for rec in &records {
        let stamp = base + (rec.ipc_timestamp_ns - ipc0);
        odom.publish(&carmen_odometry(rec, stamp)).unwrap();
        scans
            .publish_with(|s: &mut LaserScan| fill_carmen_scan(s, rec, stamp))
            .unwrap();
        // The vote answers at once (members work behind it): a pose per scan.
        pose_for_scan(&poses, &waiter, stamp)
            .unwrap_or_else(|e| panic!("{e}\n{}", r.slam.output()));
    }
}

/// The first map on `topic` with at least `walls` occupied cells, within 60 s.
fn map_with_walls(r: &Run, topic: Topic<MapInfo>, walls: usize) -> (MapInfo, Vec<i8>) {
    let sub = r.bus.map_subscriber(topic.clone()).unwrap();
    let waiter = Waiter::new().unwrap();
    let _g = waiter.attach(&sub).unwrap();
    let end = Instant::now() + Duration::from_secs(60);
    loop {
        while let Some(s) = sub.receive().unwrap() {
            let cells = s.payload().to_vec();
            if cells.iter().filter(|&&c| c >= 65).count() >= walls {
                return (*s.user_header(), cells);
            }
        }
        assert!(
            Instant::now() < end,
            "no map with {walls} walls on {}\n{}",
            topic.name(),
            r.slam.output()
        );
        waiter.wait(Some(Duration::from_millis(200))).unwrap();
    }
}

fn health_until(r: &Run, what: &str, done: impl Fn(&Health) -> bool) -> Health {
    let got = wait_for::<Health>(
        &r.bus,
        topics::health("slam"),
        Duration::from_secs(60),
        |h| done(h),
    )
    .unwrap_or_else(|e| panic!("{what}: {e}\n{}", r.slam.output()));
    *got.last().unwrap()
}

#[test]
fn vote_publishes_every_members_map_and_the_fused_one() {
    let r = start("slam_vote_e2e", None);
    replay(&r, 120);
    for topic in [
        topics::SLAM_VOTE_RBPF,
        topics::SLAM_VOTE_GRAPH,
        topics::SLAM_VOTE_FUZZY,
        topics::SLAM_VOTE_PROJECTED,
    ] {
        map_with_walls(&r, topic, 50);
    }
    let (info, fused) = map_with_walls(&r, topics::SLAM_MAP, 200);
    assert_eq!(info.cell_count(), fused.len());
    assert!(
        fused.iter().all(|&c| c == 0 || c == 100 || c == -1),
        "the vote publishes free / occupied / unknown only"
    );
    let h = health_until(&r, "a vote over three members", |h| {
        h.metric("vote_fuses").is_some_and(|n| n >= 1.0)
    });
    assert_eq!(
        h.metric("vote_members_out"),
        Some(0.0),
        "{}",
        r.slam.output()
    );
    assert!(
        h.metric("vote_residual_max_m").is_some_and(|m| m <= 0.15),
        "residual {:?}",
        h.metric("vote_residual_max_m")
    );
    assert!(
        h.metric("vote_local_blocks").is_some_and(|b| b >= 0.0),
        "the blocks re-aligned locally are reported"
    );
    // (The pose rate itself goes low once the replay ends: not the vote's flag.)
    assert!(
        !h.last_error.as_str().contains("vote"),
        "{}",
        h.last_error.as_str()
    );
    // SIGUSR1: the fused map, and the graph member's pose graph beside it,
    // which a graph back-end reads back (to continue or localise on).
    r.slam.signal(nix::sys::signal::Signal::SIGUSR1);
    r.slam
        .wait_for_line("map saved", Duration::from_secs(30))
        .unwrap_or_else(|e| panic!("{e}\n{}", r.slam.output()));
    assert!(r.maps.join("map.pgm").exists());
    let graph = r.maps.join("graph.g2o");
    let run = smokenav_algorithms_slam::graph::saved::load(
        &smokenav_platform_config::SlamSection::default(),
        smokenav_algorithms_slam::graph::GraphParams::default(),
        &graph,
    )
    .unwrap_or_else(|e| panic!("{e}\n{}", r.slam.output()));
    let nodes = run.slam.graph().len();
    assert!(nodes >= 10, "{nodes} nodes");
}

/// Replays until `member` is out with `why` in health, then replays more and
/// returns the health once the vote has fused again without it.
fn member_out_then_more_votes(r: &Run, member: &str, why: &str) -> Health {
    replay(r, 60);
    let out = format!("vote_out_{member}");
    let h = health_until(r, &format!("{member} out"), |h| {
        h.metric(&out) == Some(1.0) && h.state() == HealthState::Degraded
    });
    assert!(
        h.last_error.as_str().contains(member) && h.last_error.as_str().contains(why),
        "{}",
        h.last_error.as_str()
    );
    let fuses = h.metric("vote_fuses").unwrap_or(0.0);
    replay(r, 60);
    health_until(r, "more votes", |h| {
        h.metric("vote_fuses").is_some_and(|n| n > fuses)
    })
}

#[test]
fn a_crashed_member_is_named_and_the_vote_goes_on() {
    // After 3 scans: the member's queue (8) holds more than that whatever
    // it drops, so the fault fires however slow the member is on a loaded
    // machine (after 10, a debug fuzzy member sometimes got fewer than 11
    // scans of the 60 replayed before the replay ended).
    let r = start("slam_vote_crash", Some("fuzzy:panic:3"));
    // The vote keeps updating on rbpf and graph.
    let later = member_out_then_more_votes(&r, "fuzzy", "panicked");
    assert_eq!(later.metric("vote_out_rbpf"), Some(0.0));
    assert_eq!(later.metric("vote_out_graph"), Some(0.0));
    map_with_walls(&r, topics::SLAM_MAP, 100);
    // Two votes left: where graph and rbpf differ there is no majority, and
    // "occupied" there drew both maps' walls. The first member voting (the
    // graph, the reference) decides instead: the fused map is its map.
    let graph = settled_map(&r, topics::SLAM_VOTE_GRAPH);
    let fused = settled_map(&r, topics::SLAM_MAP);
    let walls = |m: &[i8]| m.iter().filter(|&&c| c >= 65).count();
    assert_eq!(
        graph.len(),
        fused.len(),
        "the vote is on the reference's grid"
    );
    let same = graph
        .iter()
        .zip(&fused)
        .filter(|&(&g, &f)| (g >= 65) == (f >= 65))
        .count();
    assert!(
        walls(&fused) <= walls(&graph) + walls(&graph) / 20
            && same >= graph.len() - graph.len() / 200,
        "fused {} walls, graph {} walls, {} of {} cells alike",
        walls(&fused),
        walls(&graph),
        same,
        graph.len()
    );
}

/// The newest map on `topic` once the members are idle (the replay is
/// over): maps arrive at `map_rate_hz`; the last of 3 s of them.
fn settled_map(r: &Run, topic: Topic<MapInfo>) -> Vec<i8> {
    let sub = r.bus.map_subscriber(topic.clone()).unwrap();
    let waiter = Waiter::new().unwrap();
    let _g = waiter.attach(&sub).unwrap();
    std::thread::sleep(Duration::from_secs(2));
    let end = Instant::now() + Duration::from_secs(3);
    let mut last = None;
    while Instant::now() < end || last.is_none() {
        while let Some(s) = sub.receive().unwrap() {
            last = Some(s.payload().to_vec());
        }
        assert!(
            Instant::now() < end + Duration::from_secs(30),
            "no map on {}\n{}",
            topic.name(),
            r.slam.output()
        );
        waiter.wait(Some(Duration::from_millis(200))).unwrap();
    }
    last.unwrap()
}

#[test]
fn a_stalled_member_is_named_and_the_vote_goes_on() {
    // After 3 scans, for the same reason as the crash test's.
    let r = start("slam_vote_stall", Some("graph:stall:3"));
    let later = member_out_then_more_votes(&r, "graph", "stalled");
    assert_eq!(later.metric("vote_out_rbpf"), Some(0.0));
    assert!(later.metric("vote_drops").is_some_and(|d| d > 0.0));
}

/// A room's walls drawn into a grid `shift` away, with an extra wall of its
/// own (`stray`, a phantom only this map has), saved as map_server files.
fn room_map(
    dir: &std::path::Path,
    name: &str,
    shift: (f64, f64),
    stray: Option<f64>,
) -> std::path::PathBuf {
    use smokenav_platform_map::{FREE, OCCUPIED, OccupancyGrid};
    let res = 0.05;
    let mut g = OccupancyGrid::new(160, 120, res, [-4.0, -3.0, 0.0]);
    g.cells.fill(FREE);
    let mut wall = |x0: f64, y0: f64, x1: f64, y1: f64| {
        let n = ((x1 - x0).hypot(y1 - y0) / (res / 2.0)).ceil() as usize;
        for i in 0..=n {
            let t = i as f64 / n as f64;
            let (x, y) = (x0 + t * (x1 - x0) + shift.0, y0 + t * (y1 - y0) + shift.1);
            if let Some((cx, cy)) = g.world_to_cell(x, y) {
                g.set(cx, cy, OCCUPIED);
            }
        }
    };
    wall(-3.0, -2.0, 3.0, -2.0);
    wall(3.0, -2.0, 3.0, 2.0);
    wall(3.0, 2.0, -3.0, 2.0);
    wall(-3.0, 2.0, -3.0, -2.0);
    wall(-1.0, -2.0, -1.0, 0.5);
    if let Some(y) = stray {
        wall(0.5, y, 2.0, y);
    }
    let out = dir.join(name);
    smokenav_platform_map::save_map_server(&g, &out, "map").unwrap();
    out.join("map.yaml")
}

/// `smokenav map vote`: three saved maps, two of them a cell or two off
/// and each with a phantom wall of its own, are aligned to the first and
/// voted; the vote keeps the room and drops every phantom, and is scored
/// beside its members against the truth. Bad uses are refused by name.
#[test]
fn map_vote_aligns_saved_maps_and_votes_out_what_one_member_alone_drew() {
    let dir = tempfile::tempdir().unwrap();
    let truth = room_map(dir.path(), "truth", (0.0, 0.0), None);
    let a = room_map(dir.path(), "a", (0.0, 0.0), Some(1.0));
    // Whole cells: a drawn map moves by whole cells.
    let b = room_map(dir.path(), "b", (0.10, -0.05), Some(-1.0));
    let c = room_map(dir.path(), "c", (-0.05, 0.10), Some(0.0));
    let out = dir.path().join("vote");
    let run = std::process::Command::new(bin("smokenav"))
        .args(["map", "vote"])
        .args([&a, &b, &c])
        .arg("--truth-map")
        .arg(&truth)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&run.stderr)
    );
    eprintln!("{text}");
    // Each shifted member is aligned back (member → reference: minus its shift).
    let aligned = |name: &str| -> (f64, f64) {
        let line = text
            .lines()
            .find(|l| l.contains(name) && l.contains("aligned"))
            .unwrap_or_else(|| panic!("no line for {name}: {text}"));
        let inner = &line[line.find("aligned (").unwrap() + 9..line.find(") m").unwrap()];
        let mut v = inner.split(',').map(|s| s.trim().parse::<f64>().unwrap());
        (v.next().unwrap(), v.next().unwrap())
    };
    let (bx, by) = aligned("b/map.yaml");
    // Within a cell: the walls are drawn into cells, so their shift is
    // known to a cell at best.
    assert!(
        (bx + 0.10).abs() < 0.035 && (by - 0.05).abs() < 0.035,
        "{bx} {by}"
    );
    let (cx, cy) = aligned("c/map.yaml");
    assert!(
        (cx - 0.05).abs() < 0.035 && (cy + 0.10).abs() < 0.035,
        "{cx} {cy}"
    );
    // The vote has none of the phantoms: every member's k-NN error is above it.
    let error = |prefix: &str| -> f64 {
        let line = text
            .lines()
            .find(|l| l.trim_start().starts_with(prefix))
            .unwrap_or_else(|| panic!("no `{prefix}` line: {text}"));
        let at = line.find("k-NN ").unwrap() + 5;
        line[at..].split(' ').next().unwrap().parse().unwrap()
    };
    let vote = error("vote (majority, chosen)");
    let members: Vec<f64> = text
        .lines()
        .filter(|l| l.trim_start().starts_with("member"))
        .map(|l| {
            let at = l.find("k-NN ").unwrap() + 5;
            l[at..].split(' ').next().unwrap().parse().unwrap()
        })
        .collect();
    assert_eq!(members.len(), 3);
    assert!(
        members.iter().all(|&m| m > vote),
        "vote {vote} vs members {members:?}"
    );
    for rule in [
        "vote (weighted)",
        "vote (consensus)",
        "vote (majority-reference)",
        "vote (corroborated)",
        "vote (corroborated-reference)",
    ] {
        assert!(error(rule).is_finite());
    }
    let fused = smokenav_platform_map::load_map_server(&out.join("map.yaml")).unwrap();
    let walls_at = |y: f64| {
        (0..30)
            .filter(|k| {
                let x = 0.55 + 0.05 * *k as f64;
                fused
                    .world_to_cell(x, y)
                    .and_then(|(cx, cy)| fused.get(cx, cy))
                    .is_some_and(|v| v >= 65)
            })
            .count()
    };
    assert_eq!(walls_at(1.0), 0, "a's phantom voted out");
    assert!(out.join("map.png").exists());

    // Two maps: no majority where they differ, so the first decides (not
    // the union, which drew both maps' walls and phantoms), and it is said.
    let two = std::process::Command::new(bin("smokenav"))
        .args(["map", "vote"])
        .args([&a, &b])
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&two.stdout);
    assert!(two.status.success(), "{text}");
    assert!(text.contains("note: two maps vote"), "{text}");
    let fused = smokenav_platform_map::load_map_server(&out.join("map.yaml")).unwrap();
    let first = smokenav_platform_map::load_map_server(&a).unwrap();
    assert_eq!((fused.width, fused.height), (first.width, first.height));
    let differ = fused
        .cells
        .iter()
        .zip(&first.cells)
        .filter(|&(&f, &m)| (f >= 65) != (m >= 65))
        .count();
    assert_eq!(differ, 0, "the two-map vote is the first map");

    // Bad uses: one map, an unreadable one, an unknown rule.
    let refused = |args: &[&std::ffi::OsStr], want: &str| {
        let o = std::process::Command::new(bin("smokenav"))
            .args(["map", "vote"])
            .args(args)
            .arg("--out")
            .arg(dir.path().join("x"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(want), "{want}: {err}");
    };
    refused(&[a.as_os_str()], "2");
    let missing = dir.path().join("nope.yaml");
    refused(&[a.as_os_str(), missing.as_os_str()], "nope.yaml");
    refused(
        &[
            a.as_os_str(),
            b.as_os_str(),
            "--rule".as_ref(),
            "loudest".as_ref(),
        ],
        "unknown rule `loudest`",
    );
}
