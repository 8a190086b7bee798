//! The SLAM process end to end: a prefix of the MIT CSAIL CARMEN log is
//! replayed through the bus (`base/odom` + `laser/scan`) into the real
//! `smokenav-slam` binary; the poses it publishes on `slam/pose` are compared
//! with GMapping's corrected poses for the same scans, the map on `slam/map`
//! has only 0, 100 and -1 (nav2's static layer), it is saved with `smokenav
//! map save` in all three map_server modes and read back by an independent
//! nav2-semantics reader (PyYAML + Pillow), SIGUSR1 saves into systemd's
//! state directory, and a burst of scans shows the process skipping to the
//! newest instead of queueing.

use smokenav_algorithms_eval::{StampedPose, TrajectoryOptions, evaluate_trajectories};
use smokenav_algorithms_slam::Pose2;
use smokenav_algorithms_slam::carmen::LaserRecord;
use smokenav_platform_bus::{Publisher, Waiter, topics};
use smokenav_platform_config::MountPose;
use smokenav_platform_config::SlamMode;
use smokenav_platform_config::slam::SlamInput;
use smokenav_shared_types::{
    Clock, Health, HealthState, LaserScan, MonotonicClock, Odometry, PoseEstimate,
};
use smokenav_tests::{
    Child, bin, carmen_odometry, csail_prefix, csail_prefix_path, fill_carmen_scan, open_bus,
    profile, python, unique_instance, wait_for, workspace_root,
};
use std::time::{Duration, Instant};

fn publish(
    odom: &mut Publisher<Odometry>,
    scans: &mut Publisher<LaserScan>,
    rec: &LaserRecord,
    stamp_ns: u64,
) -> anyhow::Result<()> {
    odom.publish(&carmen_odometry(rec, stamp_ns))?;
    scans.publish_with(|s: &mut LaserScan| fill_carmen_scan(s, rec, stamp_ns))?;
    Ok(())
}

/// Waits for the pose of the scan stamped `stamp_ns`.
fn pose_for(
    poses: &smokenav_platform_bus::Subscriber<PoseEstimate>,
    waiter: &Waiter,
    stamp_ns: u64,
    timeout: Duration,
) -> anyhow::Result<(PoseEstimate, usize)> {
    let end = Instant::now() + timeout;
    let mut received = 0;
    loop {
        while let Some(p) = poses.receive()? {
            received += 1;
            if p.header.stamp_ns == stamp_ns {
                return Ok((*p, received));
            }
        }
        let now = Instant::now();
        anyhow::ensure!(
            now < end,
            "no slam/pose for the scan stamped {stamp_ns} within {timeout:?}"
        );
        waiter.wait(Some((end - now).min(Duration::from_millis(200))))?;
    }
}

/// Replays the first `n` records of the CSAIL prefix onto `bus` in lock step
/// (each scan's pose back before the next scan goes out) and returns the
/// poses at the log's own stamps.
fn replay_in_lock_step(
    bus: &smokenav_platform_bus::Bus,
    n: usize,
) -> anyhow::Result<Vec<StampedPose>> {
    replay_records(bus, 0..n)
}

/// [`replay_in_lock_step`] of the records in `range` (stamps go on rising
/// from one call to the next: they are the log's offsets from now).
fn replay_records(
    bus: &smokenav_platform_bus::Bus,
    range: std::ops::Range<usize>,
) -> anyhow::Result<Vec<StampedPose>> {
    let mut odom: Publisher<Odometry> = bus.publisher(topics::BASE_ODOM)?;
    let mut scans: Publisher<LaserScan> = bus.publisher(topics::LASER_SCAN)?;
    let poses = bus.subscriber::<PoseEstimate>(topics::SLAM_POSE)?;
    let waiter = Waiter::new()?;
    let _g = waiter.attach(&poses)?;
    let records = csail_prefix();
    let base_ns = MonotonicClock.now_ns();
    let ipc0 = records[0].ipc_timestamp_ns;
    let mut estimate = Vec::new();
    let end = range.end.min(records.len());
    for rec in &records[range.start.min(end)..end] {
        let stamp = base_ns + (rec.ipc_timestamp_ns - ipc0);
        publish(&mut odom, &mut scans, rec, stamp)?;
        let (p, _) = pose_for(&poses, &waiter, stamp, Duration::from_secs(30))?;
        estimate.push(StampedPose::from_ns(
            rec.ipc_timestamp_ns,
            &Pose2::new(p.x, p.y, p.theta),
        ));
    }
    Ok(estimate)
}

/// The cells of the newest map on `topic`, waiting up to 10 s for one.
fn newest_map(
    bus: &smokenav_platform_bus::Bus,
    topic: smokenav_platform_bus::Topic<smokenav_shared_types::MapInfo>,
) -> anyhow::Result<Vec<i8>> {
    let sub = bus.map_subscriber(topic.clone())?;
    let waiter = Waiter::new()?;
    let _g = waiter.attach(&sub)?;
    let end = Instant::now() + Duration::from_secs(10);
    loop {
        let mut newest = None;
        while let Some(s) = sub.receive()? {
            newest = Some(s.payload().to_vec());
        }
        if let Some(cells) = newest {
            return Ok(cells);
        }
        let now = Instant::now();
        anyhow::ensure!(now < end, "no map on {} within 10 s", topic.name());
        waiter.wait(Some(end - now))?;
    }
}

/// The map at `yaml` as nav2's map_io reads it (tests/python/nav2_map.py).
fn nav2_load(yaml: &std::path::Path) -> anyhow::Result<serde_json::Value> {
    let script = workspace_root().join("tests/python/nav2_map.py");
    let out = std::process::Command::new(python())
        .arg(&script)
        .arg(yaml)
        .output()?;
    anyhow::ensure!(
        out.status.success(),
        "nav2_map.py {}: {}",
        yaml.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    Ok(serde_json::from_slice(&out.stdout)?)
}

#[test]
fn slam_process_tracks_a_replayed_csail_prefix_and_saves_its_map() -> anyhow::Result<()> {
    let instance = unique_instance("slam_e2e");
    let dir = tempfile::tempdir()?;
    let cfg = profile(dir.path(), "pioneer-3dx.toml", |c| {
        c.slam.input = SlamInput::Laser;
        // Few particles keep a debug build in step with the replay.
        c.slam.particles = 10;
        c.slam.map_rate_hz = 2.0;
        // The CARMEN laser pose is the robot pose.
        c.laser.mount = MountPose {
            x: 0.0,
            y: 0.0,
            yaw_deg: 0.0,
        };
    });
    // No --map-dir: the process must save where systemd's StateDirectory= points.
    let state_dir = dir.path().join("state");
    let sig_dir = state_dir.join("maps");
    let mut slam = Child::spawn_env(
        &bin("smokenav-slam"),
        &["--config", cfg.to_str().unwrap()],
        &instance,
        &[("STATE_DIRECTORY", state_dir.to_str().unwrap())],
    )?;
    slam.wait_for_line("particles on laser/scan", Duration::from_secs(30))?;

    let bus = open_bus(&instance);
    let mut odom: Publisher<Odometry> = bus.publisher(topics::BASE_ODOM)?;
    let mut scans: Publisher<LaserScan> = bus.publisher(topics::LASER_SCAN)?;
    let poses = bus.subscriber::<PoseEstimate>(topics::SLAM_POSE)?;
    let waiter = Waiter::new()?;
    let _g = waiter.attach(&poses)?;

    // Replay in lock step: each scan's pose comes back before the next scan goes out.
    let records = csail_prefix();
    assert_eq!(records.len(), 200);
    let base_ns = MonotonicClock.now_ns();
    let ipc0 = records[0].ipc_timestamp_ns;
    let mut estimate = Vec::new();
    for rec in &records {
        let stamp = base_ns + (rec.ipc_timestamp_ns - ipc0);
        publish(&mut odom, &mut scans, rec, stamp)?;
        let (p, _) = pose_for(&poses, &waiter, stamp, Duration::from_secs(30))
            .map_err(|e| anyhow::anyhow!("{e}; smokenav-slam said:\n{}", slam.output()))?;
        assert_eq!(p.particles, 10);
        assert!(p.n_eff > 0.0 && p.n_eff <= 10.0);
        assert_eq!(p.header.frame_id.as_str(), "map");
        estimate.push(StampedPose::from_ns(
            rec.ipc_timestamp_ns,
            &Pose2::new(p.x, p.y, p.theta),
        ));
    }
    let reference = smokenav_algorithms_eval::load_trajectory(
        &workspace_root().join("daemon/algorithms/slam/tests/data/csail-reference-poses.txt"),
    )?;
    // The reference poses sit at some of the log's stamps: paired by stamp.
    let ate = evaluate_trajectories(&reference, &estimate, &TrajectoryOptions::same_stamp())?;
    eprintln!("slam_e2e: ATE of the online poses over the first 200 CSAIL scans: {ate:?}");
    // The first 200 scans hold 30 reference poses; the raw odometry is metres off.
    assert_eq!(ate.pairs, 30);
    assert!(ate.ate_m.rmse < 0.15, "{ate:?}");

    // The map published on slam/map, saved by the CLI from the bus.
    let saved = dir.path().join("saved");
    let out = std::process::Command::new(bin("smokenav"))
        .args([
            "map",
            "save",
            saved.to_str().unwrap(),
            "--instance",
            &instance,
            "--timeout-s",
            "10",
        ])
        .output()?;
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let map = smokenav_platform_map::load_map_server(&saved.join("map.yaml"))?;
    assert_eq!(map.resolution, 0.05);
    let occupied = map
        .cells
        .iter()
        .filter(|&&c| c == smokenav_platform_map::OCCUPIED)
        .count();
    let free = map
        .cells
        .iter()
        .filter(|&&c| c == smokenav_platform_map::FREE)
        .count();
    assert!(
        occupied > 500 && free > 10 * occupied,
        "{occupied} occupied, {free} free cells"
    );
    assert!(saved.join("map.png").exists());

    // The live maps, read through the bus: slam/map is nav2-ready, the
    // probabilities travel on their own topic. The replay is over, so every
    // map published from now on is the same one.
    let live = newest_map(&bus, topics::SLAM_MAP)?;
    let probability = newest_map(&bus, topics::SLAM_MAP_PROBABILITY)?;
    assert_eq!(live.len(), probability.len());
    assert!(
        live.iter().all(|c| [-1, 0, 100].contains(c)),
        "slam/map carries values other than -1/0/100"
    );
    assert!(
        probability.iter().any(|&c| c > 0 && c < 100),
        "slam/map_probability carries no probabilities"
    );
    let mut expected = Vec::new();
    smokenav_platform_map::trinary_cells_into(
        &smokenav_platform_map::OccupancyGrid {
            cells: probability.clone(),
            ..map.clone()
        },
        &mut expected,
    );
    assert_eq!(live, expected);

    // Each mode, saved by the CLI and read by the independent nav2 reader.
    for mode in ["trinary", "scale", "raw"] {
        let out_dir = dir.path().join(format!("saved-{mode}"));
        let out = std::process::Command::new(bin("smokenav"))
            .args(["map", "save", "--mode", mode, "--instance", &instance])
            .arg(&out_dir)
            .output()?;
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let nav2 = nav2_load(&out_dir.join("map.yaml"))?;
        assert_eq!(nav2["mode"], mode);
        assert_eq!(
            nav2["negate_text"], "0",
            "ROS 1 map_server reads negate as an integer"
        );
        assert_eq!(nav2["width"].as_u64(), Some(map.width as u64));
        assert_eq!(nav2["resolution"].as_f64(), Some(0.05));
        let cells: Vec<i8> = serde_json::from_value(nav2["cells"].clone())?;
        // What the loader here reads must be what nav2 reads, cell for cell.
        let ours = smokenav_platform_map::load_map_server(&out_dir.join("map.yaml"))?;
        assert_eq!(
            ours.cells, cells,
            "{mode}: smokenav and nav2 semantics disagree"
        );
        match mode {
            "trinary" => assert_eq!(cells, live, "trinary map differs from slam/map"),
            "raw" => assert_eq!(
                cells, probability,
                "raw map differs from slam/map_probability"
            ),
            _ => {
                for (&p, &c) in probability.iter().zip(&cells) {
                    match p {
                        -1 => assert_eq!(c, -1),
                        p if p >= 66 => assert_eq!(c, 100, "{p}"),
                        p if p <= 19 => assert_eq!(c, 0, "{p}"),
                        _ => {}
                    }
                }
            }
        }
    }
    // Health says what the exports cost the loop (the scans wait meanwhile).
    slam_health_until(&bus, &slam, |h| {
        h.metric("map_export_ms").is_some_and(|m| m > 0.0) && h.metric("map_exports_late").is_some()
    })?;
    let sub = bus.map_subscriber(topics::SLAM_MAP)?;
    let _m = waiter.attach(&sub)?;

    // SIGUSR1 makes the process write its own map.
    slam.signal(nix::sys::signal::Signal::SIGUSR1);
    slam.wait_for_line("map saved", Duration::from_secs(10))?;
    let own = smokenav_platform_map::load_map_server(&sig_dir.join("map.yaml"))?;
    assert!(
        own.cells
            .iter()
            .filter(|&&c| c == smokenav_platform_map::OCCUPIED)
            .count()
            >= occupied / 2
    );
    assert!(sig_dir.join("map.pgm").exists() && sig_dir.join("map.png").exists());

    // A burst of 30 scans at once: the process takes the newest and counts the rest as skipped.
    let last = records.last().unwrap();
    let burst_base = MonotonicClock.now_ns();
    let mut last_stamp = 0;
    for k in 0..30u64 {
        last_stamp = burst_base + k * 1_000_000;
        publish(&mut odom, &mut scans, last, last_stamp)?;
    }
    let (p, received) = pose_for(&poses, &waiter, last_stamp, Duration::from_secs(30))?;
    assert!(p.scans_skipped > 0, "{p:?}");
    assert!(received < 30, "{received} poses for 30 scans sent at once");
    assert!(p.processing_us > 0);

    let status = slam.terminate(Duration::from_secs(10))?;
    assert!(status.success(), "{status:?}");
    // Its log went to a pipe: plain text, no colour codes.
    assert!(!slam.output().contains('\x1b'), "ANSI codes in a piped log");
    Ok(())
}

/// With `backend = "fuzzy"` the process publishes the combined fuzzy map on
/// `slam/map_fuzzy` (confidence 0–100, 30 = unknown) beside `slam/map`, and
/// `smokenav map save` writes it as fuzzy.pgm + fuzzy.yaml (raw) and
/// fuzzy.png. The nav2 map's walls are the fuzzy map's obstacle evidence,
/// not its confidence thresholded at 0.65 (which left walls seen from more
/// than ~1.5 m out: the "faint walls" of saved fuzzy maps).
#[test]
fn fuzzy_slam_process_publishes_its_confidence_map_and_map_save_writes_it() -> anyhow::Result<()> {
    let instance = unique_instance("slam_e2e_fuzzy");
    let dir = tempfile::tempdir()?;
    let cfg = profile(dir.path(), "pioneer-3dx.toml", |c| {
        c.slam.input = SlamInput::Laser;
        c.slam.backend = smokenav_platform_config::SlamBackendKind::Fuzzy;
        c.slam.map_rate_hz = 2.0;
        c.laser.mount = MountPose {
            x: 0.0,
            y: 0.0,
            yaw_deg: 0.0,
        };
    });
    let mut slam = Child::spawn(
        &bin("smokenav-slam"),
        &[
            "--config",
            cfg.to_str().unwrap(),
            "--map-dir",
            dir.path().join("sig").to_str().unwrap(),
        ],
        &instance,
    )?;
    slam.wait_for_line("fuzzy on laser/scan", Duration::from_secs(30))?;
    let bus = open_bus(&instance);
    replay_in_lock_step(&bus, 40)?;
    let live_fuzzy = newest_map(&bus, topics::SLAM_MAP_FUZZY)?;
    let live_nav = newest_map(&bus, topics::SLAM_MAP)?;
    assert_eq!(live_fuzzy.len(), live_nav.len());
    // Eq. 7's floor: every cell a reading reached is ≥ 30 or free-ish below it.
    assert!(live_fuzzy.contains(&30), "no unknown-level cells");
    let confident = live_fuzzy.iter().filter(|&&c| c >= 65).count();
    let nav_occupied = live_nav.iter().filter(|&&c| c == 100).count();
    eprintln!(
        "slam_e2e fuzzy: {confident} cells ≥ 0.65 confidence, {nav_occupied} occupied in slam/map"
    );
    assert!(confident > 0);
    // The walls seen only from afar are in the nav2 map too (312 against
    // 166; 584 before the walls' flanks went to unknown).
    assert!(
        2 * nav_occupied > 3 * confident,
        "{nav_occupied} vs {confident}"
    );

    let saved = dir.path().join("saved");
    let out = std::process::Command::new(bin("smokenav"))
        .args([
            "map",
            "save",
            saved.to_str().unwrap(),
            "--instance",
            &instance,
        ])
        .args(["--timeout-s", "10"])
        .output()?;
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{said}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(said.contains("saved the fuzzy confidence map"), "{said}");
    let fuzzy = smokenav_platform_map::load_map_server(&saved.join("fuzzy.yaml"))?;
    // Raw mode: the saved pixels are the published confidences, cell for cell.
    assert_eq!(fuzzy.cells, newest_map(&bus, topics::SLAM_MAP_FUZZY)?);
    assert!(saved.join("fuzzy.pgm").exists() && saved.join("fuzzy.png").exists());
    assert!(saved.join("map.yaml").exists());
    let status = slam.terminate(Duration::from_secs(10))?;
    assert!(status.success(), "{status:?}");
    Ok(())
}

/// Waits up to 10 s for a `health/slam` report of `slam`'s process that `done` accepts.
fn slam_health_until(
    bus: &smokenav_platform_bus::Bus,
    slam: &Child,
    done: impl Fn(&Health) -> bool,
) -> anyhow::Result<()> {
    let pid = slam.pid();
    wait_for::<Health>(bus, topics::health("slam"), Duration::from_secs(10), |h| {
        h.pid == pid && done(h)
    })
    .map(|_| ())
    .map_err(|e| anyhow::anyhow!("{e}\n{}", slam.output()))
}

/// A Pioneer profile in `dir` for the CSAIL replay (laser scans, the laser
/// at the robot's centre) with the graph back-end in `mode`, loading `graph`
/// if given (`[slam] load_graph`).
fn graph_profile(
    dir: &std::path::Path,
    mode: SlamMode,
    graph: Option<std::path::PathBuf>,
) -> anyhow::Result<std::path::PathBuf> {
    std::fs::create_dir_all(dir)?;
    Ok(profile(dir, "pioneer-3dx.toml", |c| {
        c.slam.input = SlamInput::Laser;
        c.slam.backend = smokenav_platform_config::SlamBackendKind::Graph;
        c.slam.mode = mode;
        c.slam.load_graph = graph;
        c.laser.mount = MountPose {
            x: 0.0,
            y: 0.0,
            yaw_deg: 0.0,
        };
    }))
}

/// Localisation in the SLAM process: a graph saved offline by `smokenav slam
/// --save-graph` is loaded with `--load-graph G --localization`, the same scans
/// replayed over the bus are tracked on it (close to the reference poses), and
/// a profile that asks for localisation without a graph is refused at start
/// instead of quietly mapping from scratch.
#[test]
fn slam_process_localizes_on_a_saved_graph_and_refuses_localization_without_one()
-> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let log = csail_prefix_path();
    let graph = dir.path().join("csail.g2o");
    let out = std::process::Command::new(bin("smokenav"))
        .args([
            "slam",
            "--carmen",
            log.to_str().unwrap(),
            "--backend",
            "graph",
        ])
        .args(["--save-graph", graph.to_str().unwrap()])
        .args(["--out", dir.path().join("offline").to_str().unwrap()])
        .arg("--reference")
        .arg(workspace_root().join("daemon/algorithms/slam/tests/data/csail-reference-poses.txt"))
        .output()?;
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The report scores the run against the reference: ATE, RPE and the
    // relations metric (Kümmerle et al. 2009) over the 30 reference poses.
    let report = String::from_utf8_lossy(&out.stdout);
    let line = report
        .lines()
        .find(|l| l.starts_with("ATE trajectory"))
        .unwrap_or_else(|| panic!("no ATE line in:\n{report}"));
    assert!(
        line.contains("30 poses matched") && line.contains("relations ") && line.contains("(29)"),
        "{line}"
    );

    let cfg = graph_profile(dir.path(), SlamMode::Localization, None)?;
    let map_dir = dir.path().join("maps");
    let map_dir = map_dir.to_str().unwrap();

    // No graph: refused, naming the way out.
    let mut refused = Child::spawn(
        &bin("smokenav-slam"),
        &["--config", cfg.to_str().unwrap(), "--map-dir", map_dir],
        &unique_instance("slam_loc_refused"),
    )?;
    let status = refused.wait_exit(Duration::from_secs(30))?;
    assert!(!status.success(), "localisation without a graph started");
    assert!(
        refused.output().contains("give --load-graph"),
        "{}",
        refused.output()
    );

    // The robot maps live with the graph back-end and SIGUSR1 saves the
    // pose graph beside the map: what the localising run below loads.
    let mapping_cfg = graph_profile(&dir.path().join("mapping"), SlamMode::Mapping, None)?;
    let live_maps = dir.path().join("live-maps");
    let instance = unique_instance("slam_live_graph");
    let mut mapping = Child::spawn(
        &bin("smokenav-slam"),
        &[
            "--config",
            mapping_cfg.to_str().unwrap(),
            "--map-dir",
            live_maps.to_str().unwrap(),
        ],
        &instance,
    )?;
    mapping.wait_for_line("graph on laser/scan", Duration::from_secs(30))?;
    let bus = open_bus(&instance);
    let mapped = replay_in_lock_step(&bus, usize::MAX)?;
    // The graph's map is drawn on its own thread and published from there.
    let cells = newest_map(&bus, topics::SLAM_MAP)?;
    assert!(cells.iter().filter(|&&c| c == 100).count() > 500);
    slam_health_until(&bus, &mapping, |h| {
        h.metric("map_draw_ms").is_some_and(|m| m > 0.0)
    })?;
    // An operator's pose is refused while mapping (it would tear the map):
    // the command says it was not taken, the process's log says why.
    let out = std::process::Command::new(bin("smokenav"))
        .args([
            "initial-pose",
            "--instance",
            &instance,
            "--wait",
            "3",
            "1",
            "2",
            "90",
        ])
        .output()?;
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && said.contains("mapping"), "{said}");
    mapping.wait_for_line("initial pose refused", Duration::from_secs(10))?;
    mapping.signal(nix::sys::signal::Signal::SIGUSR1);
    mapping.wait_for_line("map saved", Duration::from_secs(10))?;
    mapping.terminate(Duration::from_secs(10))?;
    let graph = live_maps.join("graph.g2o");
    let vertices = std::fs::read_to_string(&graph)?
        .lines()
        .filter(|l| l.starts_with("VERTEX_SE2"))
        .count();
    assert!(vertices > 30, "{vertices} nodes in the live run's graph");
    assert!(live_maps.join("graph.g2o.scans").exists());

    let instance = unique_instance("slam_loc");
    let mut slam = Child::spawn(
        &bin("smokenav-slam"),
        &[
            "--config",
            cfg.to_str().unwrap(),
            "--map-dir",
            map_dir,
            "--load-graph",
            graph.to_str().unwrap(),
            // The same scans again: the robot is back where the saved run began.
            "--resume-at",
            "first",
        ],
        &instance,
    )?;
    slam.wait_for_line("localizing on", Duration::from_secs(30))?;
    let bus = open_bus(&instance);
    let estimate = replay_in_lock_step(&bus, usize::MAX)?;
    // Tracked on the map, not only carried by the odometry: health counts
    // the scans matched to the saved map (placed at the run's end, none were).
    slam_health_until(&bus, &slam, |h| {
        h.metric("localization_matched").is_some_and(|m| m >= 150.0)
    })?;
    slam.terminate(Duration::from_secs(10))?;

    // The same replay with the robot placed where the saved run ended (the
    // default), metres from where the scans are: nothing matches, and
    // health says the localisation is lost rather than staying OK.
    // The graph named by the profile alone (`[slam] load_graph`), as a service would.
    let lost_cfg = graph_profile(
        &dir.path().join("lost"),
        SlamMode::Localization,
        Some(graph.clone()),
    )?;
    let instance = unique_instance("slam_loc_lost");
    let mut lost = Child::spawn(
        &bin("smokenav-slam"),
        &["--config", lost_cfg.to_str().unwrap(), "--map-dir", map_dir],
        &instance,
    )?;
    lost.wait_for_line("localizing on", Duration::from_secs(30))?;
    let bus_lost = open_bus(&instance);
    const FOUND_AT: usize = 80;
    replay_records(&bus_lost, 0..FOUND_AT)?;
    slam_health_until(&bus_lost, &lost, |h| {
        h.state() == HealthState::Degraded
            && h.last_error
                .as_str()
                .contains("localization: over 30 scans")
    })?;
    // The operator says where the robot is (as RViz's 2D Pose Estimate
    // would), 0.3 m and 6° off where the mapping run had it: from there
    // it is tracked on the saved map again, in the map's own frame.
    let at = Pose2::new(
        mapped[FOUND_AT].x,
        mapped[FOUND_AT].y,
        mapped[FOUND_AT].theta,
    );
    let said = at.compose(&Pose2::new(0.3, -0.2, 0.1));
    let out = std::process::Command::new(bin("smokenav"))
        .args([
            "initial-pose",
            "--instance",
            &instance,
            "--rad",
            "--wait",
            "10",
        ])
        .args([said.x, said.y, said.theta].map(|v| v.to_string()))
        .output()?;
    let said_back = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && said_back.contains("taken"),
        "{said_back}\n{}",
        lost.output()
    );
    let found = replay_records(&bus_lost, FOUND_AT..usize::MAX)?;
    let off: Vec<f64> = found
        .iter()
        .zip(&mapped[FOUND_AT..])
        .map(|(f, m)| (f.x - m.x).hypot(f.y - m.y))
        .collect();
    let near = off.iter().filter(|&&d| d < 0.15).count();
    // The first is the operator's pose: its match waits for the next scan's.
    eprintln!(
        "slam_e2e: found again from the operator's pose: {near} of {} poses within 0.15 m of the mapping run's, worst {:.3} m after the first",
        off.len(),
        off[1..].iter().copied().fold(0.0, f64::max)
    );
    assert!(near * 10 >= off.len() * 9, "{off:?}");
    slam_health_until(&bus_lost, &lost, |h| {
        h.state() == HealthState::Ok && h.metric("localization_poses_given") == Some(1.0)
    })?;
    assert!(
        lost.output().contains("initial pose taken"),
        "{}",
        lost.output()
    );
    lost.terminate(Duration::from_secs(10))?;
    let reference = smokenav_algorithms_eval::load_trajectory(
        &workspace_root().join("daemon/algorithms/slam/tests/data/csail-reference-poses.txt"),
    )?;
    let ate = evaluate_trajectories(&reference, &estimate, &TrajectoryOptions::same_stamp())?;
    eprintln!("slam_e2e: localisation on the saved graph, ATE over 200 CSAIL scans: {ate:?}");
    assert_eq!(ate.pairs, 30);
    assert!(ate.ate_m.rmse < 0.15, "{ate:?}");
    Ok(())
}
