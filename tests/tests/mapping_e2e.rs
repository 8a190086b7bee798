//! The mapping process end to end: the bundled `heights` scenario (two
//! table tops, a low crate and a person lying on the floor, all out of the
//! laser's plane) is stepped here and its laser and sonar go onto the bus as
//! the drivers would publish them (the drivers' own cores, `DirectDrivers`),
//! with the true pose of each scan on `slam/pose` in the scan's stamp — the
//! SLAM process's accuracy is its own test's business, and true poses let
//! the map be checked cell by cell against the arena. The REAL
//! `smokenav-mapping` binary maps them; `mapping/projected` must mark the
//! out-of-plane obstacles' cells and arrive at ≥ 1 Hz, `mapping/voxels` must
//! carry the 3D voxels (some under the laser plane), and SIGUSR1 must write
//! an `octree.bt` that OctoMap's `bt2vrml` reads, into the profile's
//! `[mapping] map_dir`; and `smokenav map save --config` must write that
//! octree beside the 2D map (`bt2vrml` reads the copy too).
//!
//! `./test` installs `octomap-tools`; run alone as someone other than root
//! without it, the `.bt` is checked by our own reader only (and says so).

use smokenav_algorithms_mapping::{ClampLogOdds, Clamping, Octree};
use smokenav_platform_bus::{Publisher, Waiter, topics};
use smokenav_platform_map::OCCUPIED;
use smokenav_shared_types::{
    Header, Health, LaserScan, MapInfo, Odometry, PoseEstimate, SonarRing, VoxelCloud,
};
use smokenav_sim_link::{DirectDrivers, DirectMessage};
use smokenav_sim_world::{Pose2, Position, Scenario, StepOutput, World};
use smokenav_tests::{Child, bin, open_bus, unique_instance, wait_for};
use std::collections::VecDeque;
use std::process::Command;
use std::time::{Duration, Instant};

/// Simulated seconds per wall-clock second.
const SPEED: f64 = 4.0;
/// The stamps' origin (any host time would do; the process only compares them).
const T0_NS: u64 = 1_000_000_000;
/// Heights the mapper assumes (its defaults; the scenario's are the same).
const LASER_M: f64 = 0.40;
const ROBOT_M: f64 = 0.60;

/// A received occupancy grid.
struct Grid {
    info: MapInfo,
    cells: Vec<i8>,
}

impl Grid {
    fn occupied_near(&self, x: f64, y: f64) -> bool {
        let r = self.info.resolution as f64;
        (-1..=1).any(|dy| {
            (-1..=1).any(|dx| {
                let cx = ((x + dx as f64 * r - self.info.origin_x) / r).floor();
                let cy = ((y + dy as f64 * r - self.info.origin_y) / r).floor();
                cx >= 0.0
                    && cy >= 0.0
                    && (cx as u32) < self.info.width
                    && (cy as u32) < self.info.height
                    && self.cells[cy as usize * self.info.width as usize + cx as usize] > 50
            })
        })
    }

    /// Centres of the cells over 50.
    fn occupied_points(&self) -> Vec<(f64, f64)> {
        let (w, r) = (self.info.width as usize, self.info.resolution as f64);
        (0..self.cells.len())
            .filter(|&i| self.cells[i] > 50)
            .map(|i| {
                (
                    self.info.origin_x + ((i % w) as f64 + 0.5) * r,
                    self.info.origin_y + ((i / w) as f64 + 0.5) * r,
                )
            })
            .collect()
    }

    fn recall(&self, cells: &[(f64, f64)]) -> f64 {
        cells
            .iter()
            .filter(|&&(x, y)| self.occupied_near(x, y))
            .count() as f64
            / cells.len().max(1) as f64
    }
}

/// The true pose nearest in time to `t_ns` (sim time).
fn pose_at(history: &VecDeque<(u64, Pose2)>, t_ns: u64) -> Pose2 {
    history
        .iter()
        .min_by_key(|(t, _)| t.abs_diff(t_ns))
        .map(|(_, p)| *p)
        .expect("a truth sample")
}

#[test]
fn mapping_process_maps_out_of_plane_obstacles_and_saves_its_octree() -> anyhow::Result<()> {
    let scenario = Scenario::builtin("heights")?;
    let arena = scenario.arena.clone();
    let start = scenario.start.position();
    let mut cfg = scenario.profile.clone();
    cfg.mapping.size_m = 24.0;
    cfg.mapping.publish_rate_hz = 2.0;
    let dir = tempfile::tempdir()?;
    let bt_dir = dir.path().join("octree");
    // The save folder from the profile (no --map-dir), so `map save --config` finds it.
    cfg.mapping.map_dir = Some(bt_dir.to_str().unwrap().into());
    let profile = dir.path().join("robot.toml");
    std::fs::write(&profile, cfg.to_toml())?;

    let instance = unique_instance("mapping_e2e");
    let mut mapping = Child::spawn(
        &bin("smokenav-mapping"),
        &["--config", profile.to_str().unwrap()],
        &instance,
    )?;
    mapping.wait_for_line("Bayes maps at 0.05 m", Duration::from_secs(30))?;

    let bus = open_bus(&instance);
    let mut scans: Publisher<LaserScan> = bus.publisher(topics::LASER_SCAN)?;
    let mut rings: Publisher<SonarRing> = bus.publisher(topics::BASE_SONAR)?;
    let mut poses: Publisher<PoseEstimate> = bus.publisher(topics::SLAM_POSE)?;
    let mut odometry: Publisher<Odometry> = bus.publisher(topics::BASE_ODOM)?;
    let projected_sub = bus.map_subscriber(topics::MAPPING_PROJECTED)?;
    let grid_sub = bus.map_subscriber(topics::MAPPING_GRID)?;
    let voxel_sub = bus.subscriber::<VoxelCloud>(topics::MAPPING_VOXELS)?;
    let waiter = Waiter::new()?;
    let _g = waiter.attach(&projected_sub)?;

    let mut drivers = DirectDrivers::new(&scenario.profile, T0_NS)?;
    let mut world = World::new(scenario)?;
    let mut out = StepOutput::default();
    let mut history: VecDeque<(u64, Pose2)> = VecDeque::with_capacity(64);
    let mut arrivals: Vec<Instant> = Vec::new();
    let mut projected: Option<Grid> = None;
    let mut grid: Option<Grid> = None;
    let mut last_voxels: Option<Box<VoxelCloud>> = None;
    let (mut sent_scans, mut last_scan_stamp) = (0u64, 0u64);
    let drain = |projected: &mut Option<Grid>,
                 grid: &mut Option<Grid>,
                 last_voxels: &mut Option<Box<VoxelCloud>>,
                 arrivals: &mut Vec<Instant>|
     -> anyhow::Result<()> {
        while let Some(m) = projected_sub.receive()? {
            arrivals.push(Instant::now());
            *projected = Some(Grid {
                info: *m.user_header(),
                cells: m.payload().to_vec(),
            });
        }
        while let Some(m) = grid_sub.receive()? {
            *grid = Some(Grid {
                info: *m.user_header(),
                cells: m.payload().to_vec(),
            });
        }
        while let Some(v) = voxel_sub.receive()? {
            *last_voxels = Some(Box::new(*v));
        }
        Ok(())
    };

    let wall0 = Instant::now();
    while !world.is_finished() && !world.route_done() {
        out.clear();
        world.step_into(Duration::from_millis(20), &mut out);
        for t in &out.truth {
            if history.len() == history.capacity() {
                history.pop_front();
            }
            history.push_back((t.t_ns, t.pose));
        }
        let mut err = None;
        drivers.convert(&out, |_, msg| {
            let r = match &msg {
                DirectMessage::Laser(s) => {
                    // The pose at the scan's stamp, its first beam: SLAM's
                    // convention, as it deskews the sweep to that instant.
                    let sim_ns = s.header.stamp_ns - T0_NS;
                    let p = pose_at(&history, sim_ns);
                    last_scan_stamp = s.header.stamp_ns;
                    sent_scans += 1;
                    scans.publish(s).and_then(|_| {
                        poses.publish_with(|e| {
                            e.header = Header::new(s.header.stamp_ns, 0, "map");
                            (e.x, e.y, e.theta) = (p.x, p.y, p.theta);
                        })
                    })
                }
                DirectMessage::Sonar(r) => rings.publish(r),
                DirectMessage::Odometry(o) => odometry.publish(o),
                _ => Ok(0),
            };
            if let Err(e) = r {
                err = Some(e);
            }
        });
        if let Some(e) = err {
            return Err(e.into());
        }
        drain(&mut projected, &mut grid, &mut last_voxels, &mut arrivals)?;
        // Paced at SPEED × real time, so the process sees the devices' rates.
        let due = wall0 + Duration::from_secs_f64(world.time_ns() as f64 / 1e9 / SPEED);
        if let Some(d) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(d);
        }
    }
    let wall = wall0.elapsed();
    assert!(sent_scans > 1000, "{sent_scans} scans");

    // The maps that include the last scan.
    let end = Instant::now() + Duration::from_secs(20);
    while projected
        .as_ref()
        .is_none_or(|g| g.info.header.stamp_ns < last_scan_stamp)
        || last_voxels
            .as_ref()
            .is_none_or(|v| v.header.stamp_ns < last_scan_stamp)
    {
        anyhow::ensure!(
            Instant::now() < end,
            "no map of the last scan within 20 s:\n{}",
            mapping.output()
        );
        waiter.wait(Some(Duration::from_millis(200)))?;
        drain(&mut projected, &mut grid, &mut last_voxels, &mut arrivals)?;
    }
    let projected = projected.unwrap();
    let grid = grid.expect("a fused grid");
    let voxels = last_voxels.unwrap();

    // ≥ 1 Hz: over the run, and no gap of more than a second and a half.
    let rate = (arrivals.len() - 1) as f64
        / arrivals
            .last()
            .unwrap()
            .duration_since(arrivals[0])
            .as_secs_f64();
    let max_gap = arrivals
        .windows(2)
        .map(|w| w[1] - w[0])
        .max()
        .unwrap_or_default();
    eprintln!(
        "mapping_e2e: {sent_scans} scans in {wall:.1?}; mapping/projected {} maps at {rate:.2} Hz, longest gap {max_gap:.2?}",
        arrivals.len()
    );
    assert!(rate >= 1.0, "mapping/projected at {rate:.2} Hz");
    assert!(max_gap < Duration::from_millis(1500), "gap of {max_gap:?}");

    // The obstacles under the robot's top that the laser plane misses.
    let res = projected.info.resolution as f64;
    assert!((res - 0.05).abs() < 1e-6);
    let oop = arena.truth_map_where(res, start, |s| !s.spans(LASER_M) && s.z[0] < ROBOT_M);
    let oop_cells = oop.occupied_points(OCCUPIED);
    assert!(oop_cells.len() > 100, "{} cells", oop_cells.len());
    let walls = arena.truth_map_where(res, start, |s| s.spans(LASER_M));
    let wall_cells = walls.occupied_points(OCCUPIED);
    let (p_recall, g_recall) = (projected.recall(&oop_cells), grid.recall(&oop_cells));
    let p_walls = projected.recall(&wall_cells);
    eprintln!(
        "mapping_e2e: out-of-plane recall {p_recall:.3} projected, {g_recall:.3} fused laser-plane grid; walls {p_walls:.3} projected"
    );
    assert!(p_recall >= 0.8, "projected map found {p_recall:.3}");
    // The same obstacles in the fused grid of the laser plane: height is what finds them.
    assert!(g_recall <= 0.1, "the laser-plane grid found {g_recall:.3}");
    assert!(
        p_walls >= 0.8,
        "projected map found {p_walls:.3} of the walls"
    );
    // Every sweep deskewed by the odometry (the robot turns at every
    // waypoint). How many of the fused grid's walls lie on the arena's is
    // printed, not checked: sonar arcs in the laser plane dominate it (this
    // run: 0.449 of 2841 cells without deskewing, 0.485 of 2719 with).
    let occupied = grid.occupied_points();
    let near = occupied
        .iter()
        .filter(|&&(x, y)| {
            wall_cells
                .iter()
                .any(|&(wx, wy)| (wx - x).hypot(wy - y) <= 1.5 * res)
        })
        .count();
    let precision = near as f64 / occupied.len().max(1) as f64;
    let health = wait_for::<Health>(
        &bus,
        topics::health("mapping"),
        Duration::from_secs(5),
        |h| h.metric("scans_mapped").is_some_and(|n| n > 0.0),
    )?
    .pop()
    .expect("a health report");
    let mapped = health.metric("scans_mapped").unwrap_or(0.0);
    let deskewed = health.metric("scans_deskewed").unwrap_or(0.0);
    eprintln!(
        "mapping_e2e: {deskewed} of {mapped} scans deskewed; {:.3} of the laser-plane grid's {} wall cells within 1.5 cells of a wall",
        precision,
        occupied.len()
    );
    assert!(
        deskewed > 0.9 * mapped,
        "{deskewed} of {mapped} mapped scans deskewed"
    );

    // The voxels: 3D, some under the laser plane (the sonar's out-of-plane obstacles).
    assert!(voxels.len() > 1000, "{} voxels", voxels.len());
    // An overfull cloud is thinned evenly: voxels all over the arena, not one corner.
    let (lo, hi) = voxels
        .points()
        .iter()
        .fold(([f32::MAX; 2], [f32::MIN; 2]), |(lo, hi), p| {
            (
                [lo[0].min(p[0]), lo[1].min(p[1])],
                [hi[0].max(p[0]), hi[1].max(p[1])],
            )
        });
    assert!(
        lo[0] < 0.5 && lo[1] < 0.5 && hi[0] > 8.5 && hi[1] > 7.5,
        "{lo:?} … {hi:?}"
    );
    assert_eq!(voxels.header.frame_id.as_str(), "map");
    assert!((voxels.resolution - 0.05).abs() < 1e-6);
    let low = voxels
        .points()
        .iter()
        .filter(|p| (p[2] as f64) < LASER_M - 0.1)
        .count();
    let in_plane = voxels
        .points()
        .iter()
        .filter(|p| ((p[2] as f64) - LASER_M).abs() < res)
        .count();
    eprintln!(
        "mapping_e2e: {} voxels ({} truncated), {low} under the laser plane, {in_plane} in it",
        voxels.len(),
        voxels.truncated
    );
    assert!(
        low > 100 && in_plane > 100,
        "{low} low, {in_plane} in plane"
    );
    assert!(voxels.points().iter().all(|p| p[2] >= 0.0 && p[2] <= 2.0));

    // SIGUSR1: the octree as .bt.
    mapping.signal(nix::sys::signal::Signal::SIGUSR1);
    mapping.wait_for_line("octree saved", Duration::from_secs(20))?;
    let bt = bt_dir.join("octree.bt");
    let clamp = ClampLogOdds::from(Clamping::default());
    let tree = Octree::read_bt(
        &mut std::io::BufReader::new(std::fs::File::open(&bt)?),
        clamp,
    )?;
    let mut occupied = 0usize;
    tree.for_each_leaf(|l| occupied += usize::from(l.logodds > 0.0));
    assert!(occupied > 1000, "{occupied} occupied leaves");
    if smokenav_tests::ensure_octomap_tools() {
        let run = Command::new("bt2vrml").arg(&bt).output()?;
        assert!(
            run.status.success(),
            "bt2vrml: {}{}",
            String::from_utf8_lossy(&run.stdout),
            String::from_utf8_lossy(&run.stderr)
        );
        let wrl = std::fs::read_to_string(bt_dir.join("octree.bt.wrl"))?;
        let boxes = wrl.matches("Transform { translation ").count();
        assert_eq!(boxes, occupied, "bt2vrml reads every occupied leaf");
    } else {
        eprintln!(
            "bt2vrml (octomap-tools) missing and not root: the .bt was read back by our reader only"
        );
    }

    // `smokenav map save`: SLAM's 2D map (a stand-in here, latched on
    // slam/map) and the mapping process's octree, fresh, beside it.
    let mut slam_map = bus.map_publisher(topics::SLAM_MAP)?;
    let info = MapInfo {
        header: Header::new(last_scan_stamp, 0, "map"),
        resolution: 0.05,
        width: 4,
        height: 2,
        ..Default::default()
    };
    let out_dir = dir.path().join("saved");
    let mut child = Command::new(bin("smokenav"))
        .args([
            "map",
            "save",
            out_dir.to_str().unwrap(),
            "--timeout-s",
            "30",
        ])
        .args(["--config", profile.to_str().unwrap()])
        .env("SMOKENAV_INSTANCE", &instance)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()?;
    // Republished as SLAM does (iceoryx2 hands a late joiner the history on the next send).
    while child.try_wait()?.is_none() {
        slam_map.publish(&info, &[0, 100, -1, 0, 0, 0, 100, -1])?;
        std::thread::sleep(Duration::from_millis(200));
    }
    let run = child.wait_with_output()?;
    let said = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "map save: {said}{}",
        String::from_utf8_lossy(&run.stderr)
    );
    eprintln!("mapping_e2e: map save said: {said}");
    assert!(said.contains("saved the 3D map"), "{said}");
    assert!(out_dir.join("map.yaml").exists());
    let saved = out_dir.join("octree.bt");
    let copy = Octree::read_bt(
        &mut std::io::BufReader::new(std::fs::File::open(&saved)?),
        clamp,
    )?;
    let mut copy_occupied = 0usize;
    copy.for_each_leaf(|l| copy_occupied += usize::from(l.logodds > 0.0));
    // Saved after the SIGUSR1 one, with no new scans: the same tree.
    assert_eq!(copy_occupied, occupied);
    assert!(
        said.contains(&format!("({occupied} occupied leaves")),
        "{said}"
    );
    if smokenav_tests::ensure_octomap_tools() {
        let run = Command::new("bt2vrml").arg(&saved).output()?;
        assert!(run.status.success(), "bt2vrml of the saved copy");
        let wrl = std::fs::read_to_string(out_dir.join("octree.bt.wrl"))?;
        assert_eq!(wrl.matches("Transform { translation ").count(), occupied);
    }

    let status = mapping.terminate(Duration::from_secs(10))?;
    assert!(status.success(), "{status:?}\n{}", mapping.output());
    Ok(())
}
