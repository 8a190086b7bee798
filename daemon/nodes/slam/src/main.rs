//! `smokenav-slam`: the SLAM library as a process.
//!
//! Subscribes to `fusion/scan` (or `laser/scan`, per `[slam] input` or
//! `--input`) and `base/odom` and hands every message to the SLAM pipeline
//! of `smokenav-algorithms-slam` (odometry pairing and resets, the smoke
//! noise model, the front end, the motion filter, the back-end of `[slam]
//! backend` or `--backend`), the very pipeline `smokenav-lab`'s offline
//! comparison runs; publishes a `PoseEstimate` on `slam/pose` for every scan
//! the pipeline turned into an update and the back-end's map at `[slam]
//! map_rate_hz`: thresholded to 0/100/-1 on `slam/map` (what nav2's static
//! layer and `map_server` tools expect) and as occupancy probability 0..100
//! on `slam/map_probability`. The particle filter's and the graph's maps
//! (the graph's re-drawn from every node) are drawn on a thread of their
//! own and published as each comes back, so the scans never wait for one;
//! health's `map_draw_ms`, `map_export_ms` (the loop's own share) and
//! `map_exports_late` say what maps cost. A map over `[slam] max_map_cells`
//! is not published nor saved (`maps_refused`, health degraded naming it):
//! a pose gone astray must not grow every subscriber's shared memory to
//! gigabytes. When it falls behind the pipeline keeps the
//! newest scan and counts the others as skipped: nothing queues without bound
//! (the bus keeps at most 32 scans per subscriber and overwrites the oldest).
//! SIGUSR1 writes the current map to `--map-dir` as map.pgm + map.yaml +
//! map.png (`smokenav map save DIR` saves the published map from anywhere)
//! and, with the graph back-end (or the vote's graph member), the pose graph
//! as graph.g2o + graph.g2o.scans
//! (what `--load-graph` continues or localises on, and `smokenav graph
//! optimize` reads);
//! the folder defaults to `$SMOKENAV_MAP_DIR`, else systemd's
//! `$STATE_DIRECTORY/maps` (the unit's `StateDirectory=`), else `./maps`.
//!
//! With `[slam] backend = "vote"` the map on `slam/map` is the members'
//! vote, each member's own map goes on `slam/vote/<member>` at the same
//! rate, and health turns degraded naming any member that is out (panicked,
//! stalled, or aligned with a residual above `[slam.vote] max_residual_m`).
//! For tests only, `SMOKENAV_TEST_VOTE_FAULT=member:stall|panic:after_scans`
//! makes one member hang or panic after that many scans.
//!
//! ```text
//! smokenav-slam --config robot.toml [--input fused|laser] [--backend rbpf] [--map-dir DIR]
//! ```

mod renderer;

use anyhow::Context;
use clap::Parser;
use renderer::MapRenderer;
use smokenav_algorithms_slam::backend::footprint_radius;
use smokenav_algorithms_slam::graph::{GraphParams, ResumedGraph, saved};
use smokenav_algorithms_slam::pipeline::{PipelineStats, vote_aware_footprint};
use smokenav_algorithms_slam::projected::SensorRig;
use smokenav_algorithms_slam::rbpf::Rbpf;
use smokenav_algorithms_slam::vote::VoteSlam;
use smokenav_algorithms_slam::vote::member::MemberFault;
use smokenav_algorithms_slam::{BackendOptions, Pose2, SlamPipeline, SlamUpdate};
use smokenav_platform_bus::{Publisher, Subscriber, WaitOutcome, Waiter, topics};
use smokenav_platform_config::{ResumeAt, SlamBackendKind, SlamInput, SlamMode};
use smokenav_platform_map::OccupancyGrid;
use smokenav_platform_runtime::{CommonArgs, Process};
use smokenav_shared_types::HealthState;
use smokenav_shared_types::{
    Clock, FusedScan, Header, LaserScan, MapInfo, MonotonicClock, Odometry, PoseEstimate,
};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(
    version,
    about = "SLAM: scans and odometry in, slam/pose and slam/map out"
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// Scan topic, overriding `[slam] input`: fused (fusion/scan) or laser (laser/scan).
    #[arg(long, value_enum)]
    input: Option<SlamInput>,
    /// SLAM back-end, overriding `[slam] backend`.
    #[arg(long, value_enum)]
    backend: Option<SlamBackendKind>,
    /// Folder SIGUSR1 writes the map to [default: $STATE_DIRECTORY/maps under systemd, else ./maps].
    #[arg(long, value_name = "DIR", env = "SMOKENAV_MAP_DIR")]
    map_dir: Option<PathBuf>,
    /// Number of particles, overriding `[slam] particles`.
    #[arg(long)]
    particles: Option<usize>,
    /// A graph saved by `smokenav slam --save-graph G` (G and G.scans): keep
    /// mapping from it, or with `--localization` only track the robot on its map.
    #[arg(long, value_name = "G")]
    load_graph: Option<PathBuf>,
    /// Localise on `--load-graph`'s map without changing it (as `[slam] mode = "localization"`).
    #[arg(long)]
    localization: bool,
    /// Where `--load-graph`'s run starts: `last` (where it ended) or `first`
    /// (where it began: a robot back at its dock). Overrides `[slam] resume_at`.
    #[arg(long, value_enum, value_name = "WHERE")]
    resume_at: Option<ResumeAt>,
}

/// Longest wait on the bus, so signals and the map timer are served promptly.
const POLL: Duration = Duration::from_millis(50);

fn main() -> ExitCode {
    let args = Args::parse();
    smokenav_platform_runtime::main("slam", &args.common, |p| run(p, &args))
}

enum Scans {
    Fused(Subscriber<FusedScan>),
    Laser(Subscriber<LaserScan>),
}

impl Scans {
    /// Hands every scan that arrived to the pipeline (which keeps the newest).
    fn drain(&self, pipeline: &mut SlamPipeline) -> anyhow::Result<()> {
        match self {
            Scans::Fused(s) => {
                while let Some(f) = s.receive()? {
                    pipeline.push_fused(&f);
                }
            }
            Scans::Laser(s) => {
                while let Some(l) = s.receive()? {
                    pipeline.push_laser(&l);
                }
            }
        }
        Ok(())
    }

    fn lost(&self) -> u64 {
        match self {
            Scans::Fused(s) => s.stats().lost,
            Scans::Laser(s) => s.stats().lost,
        }
    }

    fn topic(&self) -> &'static str {
        match self {
            Scans::Fused(_) => smokenav_shared_types::catalog::topic_names::FUSION_SCAN,
            Scans::Laser(_) => smokenav_shared_types::catalog::topic_names::LASER_SCAN,
        }
    }
}

/// Counters surfaced as health metrics (the pipeline keeps its own).
#[derive(Default)]
struct Counters {
    processed: u64,
    publish_errors: u64,
    maps_published: u64,
    maps_saved: u64,
    /// Wall cells the footprint cleared in the last map exported.
    footprint_cleared: u64,
    /// Wall time the SLAM loop spent on the last map export (drawn in
    /// place, thresholded, published): the scans wait meanwhile.
    map_export: Duration,
    /// Wall time the last map took to draw, on the loop or on the
    /// renderer's thread ([`renderer::MapRenderer`]).
    map_draw: Duration,
    /// Exports, or drawings on the renderer's thread, that took longer than
    /// a scan period ([`SCAN_PERIOD`]).
    map_exports_late: u64,
    /// Maps not published for being over `[slam] max_map_cells`.
    maps_refused: u64,
}

/// Why a map may not go out: it is over `[slam] max_map_cells`.
fn oversized(grid: &OccupancyGrid, max_cells: usize) -> Option<String> {
    too_large((grid.width, grid.height), grid.resolution, "", max_cells)
}

/// Why a map of `size` cells (or, with `at_least` = "at least ", of no
/// fewer) may not go out.
fn too_large(
    (width, height): (usize, usize),
    resolution: f64,
    at_least: &str,
    max_cells: usize,
) -> Option<String> {
    (width.saturating_mul(height) > max_cells).then(|| {
        format!(
            "slam/map not published: the map is {at_least}{width} × {height} cells ({:.0} m × {:.0} m), over [slam] max_map_cells {max_cells} (a pose gone astray? see slam/pose)",
            width as f64 * resolution,
            height as f64 * resolution
        )
    })
}

/// A map just drawn, unless it is over `max_cells`: then none, counted,
/// and the reason kept for health until a map within it is drawn (the map
/// before it is not published again either: it is no longer the map).
fn take_map(
    drawn: Option<(OccupancyGrid, usize)>,
    max_cells: usize,
    counters: &mut Counters,
    refused: &mut Option<String>,
) -> Option<OccupancyGrid> {
    let (map, cleared) = drawn?;
    if let Some(why) = oversized(&map, max_cells) {
        return refuse(why, counters, refused);
    }
    counters.footprint_cleared = cleared as u64;
    *refused = None;
    Some(map)
}

/// A map refused for `why`: counted, the reason kept for health; no map.
fn refuse(
    why: String,
    counters: &mut Counters,
    refused: &mut Option<String>,
) -> Option<OccupancyGrid> {
    counters.maps_refused += 1;
    *refused = Some(why);
    None
}

/// The laser's scan period at 10 Hz: a map export longer than this holds up a scan.
const SCAN_PERIOD: Duration = Duration::from_millis(100);

fn map_info(grid: &OccupancyGrid, stamp_ns: u64) -> MapInfo {
    MapInfo {
        header: Header::new(stamp_ns, 0, "map"),
        resolution: grid.resolution as f32,
        width: grid.width as u32,
        height: grid.height as u32,
        _reserved: 0,
        origin_x: grid.origin[0],
        origin_y: grid.origin[1],
        origin_theta: grid.origin[2],
    }
}

/// Where maps are saved when `--map-dir` and `$SMOKENAV_MAP_DIR` are not given:
/// the unit's state directory (systemd sets `$STATE_DIRECTORY`; everything
/// else is read-only under `ProtectSystem=strict`), else `./maps`.
fn default_map_dir(state_directory: Option<std::ffi::OsString>) -> PathBuf {
    state_directory
        .filter(|d| !d.is_empty())
        // systemd joins several directories with ':'; the first is ours.
        .map(|d| {
            let first = d
                .to_string_lossy()
                .split(':')
                .next()
                .unwrap_or("")
                .to_owned();
            PathBuf::from(first).join("maps")
        })
        .unwrap_or_else(|| PathBuf::from("maps"))
}

/// Why `dir` (or, if it does not exist yet, the folder it would be made in)
/// looks unwritable, if it does: a read-only file system (`ProtectSystem=`)
/// or a folder marked read-only.
fn unwritable(dir: &Path) -> Option<String> {
    let existing = dir.ancestors().find(|a| a.exists())?;
    match std::fs::metadata(existing) {
        Ok(m) if !m.is_dir() => Some(format!("{} is not a folder", existing.display())),
        Ok(m) if m.permissions().readonly() => Some(format!("{} is read-only", existing.display())),
        Ok(_) => None,
        Err(e) => Some(format!("{}: {e}", existing.display())),
    }
}

fn save_map(grid: &OccupancyGrid, fuzzy: Option<&OccupancyGrid>, dir: &Path) -> anyhow::Result<()> {
    smokenav_platform_map::save_map_server(grid, dir, "map")?;
    grid.save_png(&dir.join("map.png"))?;
    if let Some(f) = fuzzy {
        smokenav_platform_map::save_fuzzy(f, dir)?;
    }
    Ok(())
}

/// With a pose graph (the graph back-end, mapping, continued or localising,
/// or the vote's graph member): the graph and its nodes' scans as
/// `dir/graph.g2o` + `.scans`, so the run can be continued or localised on
/// (`--load-graph`). Written beside, then renamed over the last save: a
/// reader never sees half a graph.
fn save_graph(pipeline: &SlamPipeline, dir: &Path) -> anyhow::Result<()> {
    let (tmp, path) = (dir.join("graph.g2o.tmp"), dir.join("graph.g2o"));
    match pipeline.backend().save_graph(&tmp) {
        None => return Ok(()),
        Some(saved) => saved?,
    }
    let scans = saved::scans_path(&path);
    std::fs::rename(saved::scans_path(&tmp), &scans)
        .with_context(|| format!("cannot write {}", scans.display()))?;
    std::fs::rename(&tmp, &path).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}

fn run(p: &mut Process, args: &Args) -> anyhow::Result<()> {
    let mut cfg = p.config.slam.clone();
    if let Some(n) = args.particles {
        anyhow::ensure!(
            (1..=1000).contains(&n),
            "--particles must be 1–1000, got {n}"
        );
        cfg.particles = n;
    }
    // `--load-graph` over the profile's `[slam] load_graph`; either means the graph back-end.
    if let Some(g) = &args.load_graph {
        cfg.load_graph = Some(g.clone());
    }
    if let Some(b) = args.backend {
        cfg.backend = b;
    } else if cfg.load_graph.is_some() {
        cfg.backend = SlamBackendKind::Graph;
    }
    if args.localization {
        cfg.mode = SlamMode::Localization;
    }
    if let Some(at) = args.resume_at {
        cfg.resume_at = at;
    }
    // Checked before the bus is touched: a profile asking to localise must
    // not quietly start a fresh map instead.
    anyhow::ensure!(
        cfg.load_graph.is_none() || cfg.backend == SlamBackendKind::Graph,
        "--load-graph needs the graph back-end, not backend {}",
        cfg.backend.as_str()
    );
    anyhow::ensure!(
        cfg.mode == SlamMode::Mapping || cfg.load_graph.is_some(),
        "[slam] mode = \"localization\" tracks the robot on a saved map: give --load-graph G or [slam] load_graph (saved with SIGUSR1 or smokenav slam --save-graph)"
    );
    let resumed = match &cfg.load_graph {
        Some(g) => Some(
            saved::load(&cfg, GraphParams::from_config(&cfg), g)
                .with_context(|| format!("cannot load the saved graph {}", g.display()))?,
        ),
        None => None,
    };
    let input = args.input.unwrap_or(cfg.input);
    let m = &p.config.laser.mount;
    let mount = Pose2::new(m.x, m.y, m.yaw_rad());
    let map_dir = args
        .map_dir
        .clone()
        .unwrap_or_else(|| default_map_dir(std::env::var_os("STATE_DIRECTORY")));
    // Said now, not at the first SIGUSR1 (the folder is made on the first save).
    if let Some(why) = unwritable(&map_dir) {
        tracing::warn!("maps cannot be saved to {}: {why}", map_dir.display());
    }
    let save_requested = Arc::new(AtomicBool::new(false));
    signal_hook::flag::register(signal_hook::consts::SIGUSR1, Arc::clone(&save_requested))
        .context("cannot install the SIGUSR1 handler")?;

    let scans = match input {
        SlamInput::Fused => Scans::Fused(p.bus.subscriber::<FusedScan>(topics::FUSION_SCAN)?),
        SlamInput::Laser => Scans::Laser(p.bus.subscriber::<LaserScan>(topics::LASER_SCAN)?),
    };
    let odom_sub = p.bus.subscriber::<Odometry>(topics::BASE_ODOM)?;
    let given_poses = p
        .bus
        .subscriber::<PoseEstimate>(topics::SLAM_INITIAL_POSE)?;
    let mut poses: Publisher<PoseEstimate> = p.bus.publisher(topics::SLAM_POSE)?;
    let mut maps = p.bus.map_publisher(topics::SLAM_MAP)?;
    let mut probability_maps = p.bus.map_publisher(topics::SLAM_MAP_PROBABILITY)?;
    // Only a back-end with a confidence map (fuzzy) offers slam/map_fuzzy.
    let mut fuzzy_maps = match cfg.backend {
        SlamBackendKind::Fuzzy => Some(p.bus.map_publisher(topics::SLAM_MAP_FUZZY)?),
        _ => None,
    };
    let mut fuzzy: Option<OccupancyGrid> = None;
    // The thresholded cells, reused from map to map.
    let mut trinary: Vec<i8> = Vec::new();
    let waiter = Waiter::new()?;
    let _attached = match &scans {
        Scans::Fused(s) => [
            waiter.attach(s)?,
            waiter.attach(&odom_sub)?,
            waiter.attach(&given_poses)?,
        ],
        Scans::Laser(s) => [
            waiter.attach(s)?,
            waiter.attach(&odom_sub)?,
            waiter.attach(&given_poses)?,
        ],
    };

    let footprint_m = footprint_radius(&cfg, p.config.robot.radius_m);
    let mut pipeline = if cfg.backend == SlamBackendKind::Vote {
        // Online the members run free: a slow one drops scans, none waits for another.
        cfg.vote.lockstep = false;
        let fault = match std::env::var("SMOKENAV_TEST_VOTE_FAULT") {
            Ok(v) if !v.is_empty() => Some(
                v.parse::<MemberFault>()
                    .map_err(|e| anyhow::anyhow!("SMOKENAV_TEST_VOTE_FAULT: {e}"))?,
            ),
            _ => None,
        };
        if let Some(f) = fault {
            tracing::warn!("test fault injected: {f:?}");
        }
        let opts = BackendOptions {
            sensors: Some(Arc::new(SensorRig::from_config(&p.config))),
            footprint_m,
            ..BackendOptions::default()
        };
        let vote =
            VoteSlam::new(&cfg, &opts, fault).context("cannot start the vote's member threads")?;
        SlamPipeline::new(&cfg, Box::new(vote))
    } else if let Some(mut run) = resumed {
        // Localisation adds no node: no closure to run beside it.
        run.slam.set_online(cfg.mode == SlamMode::Mapping);
        SlamPipeline::new(
            &cfg,
            Box::new(ResumedGraph::new(
                run,
                cfg.mode == SlamMode::Localization,
                false,
            )),
        )
    } else {
        // The scan path never waits for the graph's loop closures.
        SlamPipeline::from_config(
            &cfg,
            &BackendOptions {
                online: true,
                sensors: Some(Arc::new(SensorRig::from_config(&p.config))),
                footprint_m,
                ..BackendOptions::default()
            },
        )
    }
    .with_sensor_pose(mount)
    .with_footprint(vote_aware_footprint(&cfg, footprint_m))
    .with_robot(&p.config);
    let mut member_maps = Vec::new();
    if cfg.backend == SlamBackendKind::Vote {
        for m in &cfg.vote.members {
            let topic = match m {
                SlamBackendKind::Rbpf => topics::SLAM_VOTE_RBPF,
                SlamBackendKind::Graph => topics::SLAM_VOTE_GRAPH,
                SlamBackendKind::Fuzzy => topics::SLAM_VOTE_FUZZY,
                SlamBackendKind::Projected => topics::SLAM_VOTE_PROJECTED,
                SlamBackendKind::Vote => continue,
            };
            member_maps.push((m.as_str(), p.bus.map_publisher(topic)?));
        }
    }
    let mut flagged = false;
    let mut last_update: Option<SlamUpdate> = None;
    let mut map: Option<OccupancyGrid> = None;
    // Why the last map drawn was not published (over `[slam] max_map_cells`).
    let mut map_refused: Option<String> = None;
    let mut last_map_revision = None;
    let mut counters = Counters::default();
    let mut renderer = MapRenderer::start().context("cannot start the map drawing thread")?;
    let map_period = Duration::from_secs_f64(1.0 / cfg.map_rate_hz);
    let mut next_map = Instant::now() + map_period;
    let clock = MonotonicClock;
    let rate = p.health.add_rate("pose_hz", Some(10.0));
    // Only the particle filter has particles to speak of.
    let mut backend = match cfg.backend {
        SlamBackendKind::Rbpf => format!("rbpf with {} particles", cfg.particles),
        _ => pipeline.backend().name().to_string(),
    };
    if let Some(g) = &cfg.load_graph {
        let what = match cfg.mode {
            SlamMode::Localization => "localizing on",
            SlamMode::Mapping => "continuing",
        };
        backend = format!("{backend} {what} {}", g.display());
    }
    let threads = match pipeline.backend().as_any().downcast_ref::<Rbpf>() {
        Some(rbpf) if rbpf.threads() == 1 => ", particles matched on 1 thread".to_string(),
        Some(rbpf) => format!(", particles matched on {} threads", rbpf.threads()),
        None => String::new(),
    };
    p.ready(&format!(
        "{backend} on {} + {}, map every {:.1} s{threads}",
        scans.topic(),
        topics::BASE_ODOM,
        map_period.as_secs_f64()
    ));

    while !p.shutdown_requested() {
        if waiter.wait(Some(POLL))? == WaitOutcome::Shutdown {
            break;
        }
        while let Some(o) = odom_sub.receive()? {
            pipeline.push_odom(&o);
        }
        // Before the scans: the pose is where the robot is now.
        while let Some(given) = given_poses.receive()? {
            take_given_pose(&mut pipeline, &given);
        }
        scans.drain(&mut pipeline)?;
        let t0 = Instant::now();
        if let Some(update) = pipeline.poll(clock.now_ns()) {
            let took = t0.elapsed();
            counters.processed += 1;
            p.health.record_latency(took);
            let skipped = pipeline.stats().superseded + scans.lost();
            let covariance = update.covariance_row_major();
            let published = poses.publish_with(|e: &mut PoseEstimate| {
                e.header = Header::new(update.stamp_ns, 0, "map");
                e.x = update.pose.x;
                e.y = update.pose.y;
                e.theta = update.pose.theta;
                e.covariance = covariance;
                e.n_eff = update.n_eff as f32;
                e.particles = update.particles as u32;
                e.scans_skipped = skipped;
                e.processing_us = took.as_micros().min(u32::MAX as u128) as u32;
            });
            match published {
                Ok(_) => p.health.mark(rate),
                Err(e) => {
                    counters.publish_errors += 1;
                    p.health.error(&format!("cannot publish slam/pose: {e}"));
                }
            }
            last_update = Some(update);
        }
        // A map drawn on the renderer's thread is published as soon as it is back.
        let drawn = match renderer.finished() {
            Ok(d) => d,
            Err(e) => {
                p.health.error(e);
                None
            }
        };
        let fresh = drawn.is_some();
        if let Some(d) = drawn {
            counters.map_draw = d.took;
            counters.map_exports_late += u64::from(d.took > SCAN_PERIOD);
            map = take_map(d.map, cfg.max_map_cells, &mut counters, &mut map_refused);
            last_map_revision = Some(d.revision);
        }
        let now = Instant::now();
        let save = save_requested.swap(false, Ordering::Relaxed);
        let due = now >= next_map;
        if due || save || fresh {
            let export_start = Instant::now();
            // Exporting the map copies it: only when it changed since the last export.
            let revision = pipeline.map_revision();
            // A map asked of the renderer now is published when it is back,
            // not the one before it now as well.
            let mut asked = false;
            if last_map_revision != Some(revision) {
                // A map the back-end can have drawn elsewhere is drawn on the
                // renderer's thread (a save waits for its own), asked for
                // when due and the renderer is free; until it is back the
                // last one stands. The renderer is only ever busy, and a
                // map only ever fresh, with such a back-end.
                let elsewhere = !save && renderer.alive();
                if !elsewhere || (due && renderer.idle()) {
                    // A map too large is refused before it is drawn where
                    // its trajectory alone says so: drawing it would take
                    // as much memory as publishing it.
                    let at_least = too_large(
                        pipeline.map_cells_at_least(),
                        cfg.resolution_m,
                        "at least ",
                        cfg.max_map_cells,
                    );
                    if let Some(why) = at_least {
                        map = refuse(why, &mut counters, &mut map_refused);
                        last_map_revision = Some(revision);
                    } else if let Some(job) = elsewhere
                        .then(|| pipeline.map_and_footprint_job())
                        .flatten()
                    {
                        asked = renderer.draw(revision, job);
                    } else {
                        let t0 = Instant::now();
                        map = take_map(
                            pipeline.map_and_footprint(),
                            cfg.max_map_cells,
                            &mut counters,
                            &mut map_refused,
                        );
                        counters.map_draw = t0.elapsed();
                        last_map_revision = Some(revision);
                    }
                }
                if fuzzy_maps.is_some() {
                    fuzzy = pipeline
                        .confidence_map()
                        .filter(|f| oversized(f, cfg.max_map_cells).is_none());
                }
            }
            if let (Some(grid), Some(u)) = (&map, last_update) {
                if (due && !asked) || fresh {
                    let info = map_info(grid, u.stamp_ns);
                    smokenav_platform_map::trinary_cells_into(grid, &mut trinary);
                    match maps.publish(&info, &trinary) {
                        Ok(_) => counters.maps_published += 1,
                        Err(e) => {
                            counters.publish_errors += 1;
                            p.health.error(&format!("cannot publish slam/map: {e}"));
                        }
                    }
                    if let Err(e) = probability_maps.publish(&info, &grid.cells) {
                        counters.publish_errors += 1;
                        p.health
                            .error(&format!("cannot publish slam/map_probability: {e}"));
                    }
                    if let (Some(publisher), Some(f)) = (&mut fuzzy_maps, &fuzzy)
                        && let Err(e) = publisher.publish(&map_info(f, u.stamp_ns), &f.cells)
                    {
                        counters.publish_errors += 1;
                        p.health
                            .error(&format!("cannot publish slam/map_fuzzy: {e}"));
                    }
                }
                if save {
                    match save_map(grid, fuzzy.as_ref(), &map_dir)
                        .and_then(|()| save_graph(&pipeline, &map_dir))
                    {
                        Ok(()) => {
                            counters.maps_saved += 1;
                            tracing::info!("map saved to {}", map_dir.display());
                        }
                        Err(e) => p.health.error(&format!(
                            "cannot save the map to {}: {}",
                            map_dir.display(),
                            smokenav_platform_runtime::error_line(&e)
                        )),
                    }
                }
            }
            if save
                && map.is_none()
                && let Some(why) = &map_refused
            {
                p.health.error(&format!(
                    "cannot save the map to {}: {why}",
                    map_dir.display()
                ));
            }
            if due {
                next_map = now + map_period;
                publish_members(
                    p,
                    &pipeline,
                    &mut member_maps,
                    cfg.max_map_cells,
                    &mut counters,
                );
            }
            // What the scans waited for: a map drawn in place and its publishing.
            let took = export_start.elapsed();
            counters.map_export = took;
            counters.map_exports_late += u64::from(took > SCAN_PERIOD);
        }
        flagged = flag_conditions(
            p,
            &pipeline,
            cfg.max_blind_m,
            map_refused.as_deref(),
            flagged,
        );
        report(p, &pipeline, &counters, &scans);
        p.tick()?;
    }
    Ok(())
}

/// An operator's pose from `slam/initial_pose` (`smokenav initial-pose`,
/// RViz's 2D Pose Estimate through smokenav-zenoh): handed to the
/// back-end, which searches around it (localising) or starts there (before
/// its first scan). A pose in another frame, or one a mapping back-end
/// cannot take, is refused with a warning; nothing else changes.
fn take_given_pose(pipeline: &mut SlamPipeline, given: &PoseEstimate) {
    let frame = given.header.frame_id.as_str();
    if !(frame.is_empty() || frame == "map") {
        tracing::warn!("initial pose refused: it is in frame `{frame}`, SLAM's poses are in `map`");
        return;
    }
    let pose = Pose2::new(given.x, given.y, given.theta);
    let c = &given.covariance;
    // Row-major (x, y, θ): the larger position σ and the heading's.
    let sigma = (c[0].max(c[4]).max(0.0).sqrt(), c[8].max(0.0).sqrt());
    match pipeline.relocalize(pose, sigma) {
        Ok(()) => tracing::info!(
            "initial pose taken: x {:.2} m, y {:.2} m, heading {:.1}° (σ {:.2} m, {:.1}°)",
            pose.x,
            pose.y,
            pose.theta.to_degrees(),
            sigma.0,
            sigma.1.to_degrees()
        ),
        Err(e) => tracing::warn!("initial pose refused: {e}"),
    }
}

/// Each member's last exported map on its own topic.
fn publish_members(
    p: &mut Process,
    pipeline: &SlamPipeline,
    publishers: &mut [(&'static str, smokenav_platform_bus::MapPublisher)],
    max_cells: usize,
    counters: &mut Counters,
) {
    let Some(vote) = pipeline.backend().as_any().downcast_ref::<VoteSlam>() else {
        return;
    };
    let stamp = pipeline.last_update().map(|u| u.stamp_ns).unwrap_or(0);
    for m in vote.status().members {
        let Some((grid, _)) = &m.map else { continue };
        if oversized(grid, max_cells).is_some() {
            counters.maps_refused += 1;
            continue;
        }
        let Some((_, publisher)) = publishers.iter_mut().find(|(n, _)| *n == m.name) else {
            continue;
        };
        if let Err(e) = publisher.publish(&map_info(grid, stamp), &grid.cells) {
            counters.publish_errors += 1;
            p.health
                .error(&format!("cannot publish slam/vote/{}: {e}", m.name));
        }
    }
}

/// Degraded, naming the reasons, while the back-end names a condition (a
/// vote member out, a localisation lost), the heading
/// has been odometry's alone for more than `max_blind_m` or the last map
/// was refused (`map_refused`); back to Ok when
/// none holds. Returns whether it is flagged now.
fn flag_conditions(
    p: &mut Process,
    pipeline: &SlamPipeline,
    max_blind_m: f64,
    map_refused: Option<&str>,
    flagged: bool,
) -> bool {
    // The back-end's own first (vote members out, localisation lost).
    let mut reasons: Vec<String> = pipeline.backend().health_condition().into_iter().collect();
    reasons.extend(conditions(&pipeline.stats(), max_blind_m));
    reasons.extend(map_refused.map(str::to_owned));
    if !reasons.is_empty() {
        p.health.error(&reasons.join("; "));
        // Its own state: a low rate publishing Ok as Degraded would otherwise
        // leave it Ok, and the rate's message would replace these reasons.
        if p.health.own_state() == HealthState::Ok {
            p.health.set_state(HealthState::Degraded);
        }
        true
    } else {
        if flagged {
            p.health.clear_error();
            if p.health.own_state() == HealthState::Degraded {
                p.health.set_state(HealthState::Ok);
            }
        }
        false
    }
}

/// Scans in a row without odometry that make the SLAM process degraded:
/// a second of a 10 Hz laser.
const NO_ODOMETRY_SCANS: u64 = 10;

/// Why the pipeline makes the SLAM process degraded: no odometry for
/// [`NO_ODOMETRY_SCANS`] scans in a row; a blind stretch longer than
/// `max_blind_m` (0: never).
fn conditions(stats: &PipelineStats, max_blind_m: f64) -> Vec<String> {
    let mut reasons = Vec::new();
    if stats.no_odometry_in_a_row >= NO_ODOMETRY_SCANS {
        reasons.push(format!(
            "no odometry on base/odom for {NO_ODOMETRY_SCANS}+ scans in a row (is the base driver running?): the poses rest on scan matching alone"
        ));
    }
    if max_blind_m > 0.0 && stats.blind_m > max_blind_m {
        // The limit, not the running figure: the text stays the same while
        // the stretch lasts (a new text is logged again); heading_blind_m has the figure.
        reasons.push(format!(
            "heading from odometry alone for over {max_blind_m:.1} m (the laser blind or unmatched): the map may turn"
        ));
    }
    reasons
}

fn report(p: &mut Process, pipeline: &SlamPipeline, c: &Counters, scans: &Scans) {
    let h = &mut p.health;
    metrics(pipeline, c, scans.lost(), &mut |name, value| {
        h.set_metric(name, value)
    });
}

/// Metrics of `health/slam` besides its rate (`pose_hz`) and a configured
/// `rate_floor`: the pipeline's counters, then the back-end's own.
fn metrics(
    pipeline: &SlamPipeline,
    c: &Counters,
    lost_on_bus: u64,
    emit: &mut dyn FnMut(&'static str, f64),
) {
    let stats = pipeline.stats();
    emit("scans_processed", c.processed as f64);
    emit("scans_skipped", (stats.superseded + lost_on_bus) as f64);
    emit("scans_lost_on_bus", lost_on_bus as f64);
    emit("scans_without_odometry", stats.no_odometry as f64);
    emit("scans_without_ranges", stats.empty_scans as f64);
    emit("scans_held_back", stats.held_back as f64);
    emit("odom_resets", stats.odom_resets as f64);
    // Unflagged jumps no robot drives, taken as resets.
    emit("odom_jumps", stats.odom_jumps as f64);
    emit("odom_out_of_order", stats.odom_out_of_order as f64);
    emit("frontend_fallbacks", stats.frontend_fallbacks as f64);
    emit("frontend_withheld", stats.frontend_withheld as f64);
    emit("heading_blind_m", stats.blind_m);
    emit("heading_blind_deg", stats.blind_rad.to_degrees());
    emit("heading_blind_longest_m", stats.longest_blind_m);
    emit("heading_squared", stats.headings_squared as f64);
    emit("heading_side_wall", stats.side_wall_headings as f64);
    // Zero on a laser without a time between beams: its sweeps stay bent.
    emit("scans_deskewed", stats.deskewed as f64);
    // Scans whose sonar echoes were moved to where the ring heard them ([slam] sonar_age_compensation).
    emit("scans_sonar_compensated", stats.sonar_compensated as f64);
    emit("maps_published", c.maps_published as f64);
    // A large map's export holds up the scans: how long, and how often past a scan period.
    emit("map_export_ms", c.map_export.as_secs_f64() * 1e3);
    emit("map_draw_ms", c.map_draw.as_secs_f64() * 1e3);
    emit("map_exports_late", c.map_exports_late as f64);
    emit("maps_refused", c.maps_refused as f64);
    emit("maps_saved", c.maps_saved as f64);
    // Smoke phantoms in the robot's own path, gone from the map ([slam] clear_footprint).
    emit("footprint_cleared", c.footprint_cleared as f64);
    emit("publish_errors", c.publish_errors as f64);
    // The back-end's own figures (the particle filter's resamples and N_eff).
    pipeline.backend().metrics(emit);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn maps_go_to_the_state_directory_under_systemd() {
        assert_eq!(
            default_map_dir(Some("/var/lib/smokenav".into())),
            PathBuf::from("/var/lib/smokenav/maps")
        );
        assert_eq!(
            default_map_dir(Some("/var/lib/a:/var/lib/b".into())),
            PathBuf::from("/var/lib/a/maps")
        );
        assert_eq!(default_map_dir(None), PathBuf::from("maps"));
        assert_eq!(default_map_dir(Some("".into())), PathBuf::from("maps"));
    }

    #[test]
    fn a_long_blind_stretch_is_named_in_health() {
        let blind = |m: f64| PipelineStats {
            blind_m: m,
            ..PipelineStats::default()
        };
        assert!(conditions(&blind(4.9), 5.0).is_empty());
        let r = conditions(&blind(6.2), 5.0);
        assert_eq!(r.len(), 1);
        assert!(
            r[0].starts_with("heading from odometry alone for over 5.0 m"),
            "{r:?}"
        );
        // The same text while the stretch lasts (the log repeats a new text).
        assert_eq!(conditions(&blind(9.0), 5.0), r);
        assert!(conditions(&blind(60.0), 0.0).is_empty(), "0 never flags");
    }

    #[test]
    fn scans_without_odometry_in_a_row_are_named_in_health() {
        let silent = |n: u64| PipelineStats {
            no_odometry: 50,
            no_odometry_in_a_row: n,
            ..PipelineStats::default()
        };
        assert!(conditions(&silent(9), 0.0).is_empty());
        let r = conditions(&silent(10), 0.0);
        assert_eq!(r.len(), 1);
        assert!(r[0].starts_with("no odometry on base/odom"), "{r:?}");
        assert_eq!(
            conditions(&silent(400), 0.0),
            r,
            "the same text while it lasts"
        );
    }

    /// A health report holds `MAX_METRICS`; one past it is lost. Every
    /// back-end as the process runs it (the graph online, with its closure
    /// thread's figures), with the rate and a configured floor, must fit.
    #[test]
    fn every_backends_health_fits_one_report() {
        use smokenav_platform_config::RobotConfig;
        use smokenav_shared_types::health::MAX_METRICS;
        let config = RobotConfig::builtin("nomad-scout").unwrap();
        for kind in [
            SlamBackendKind::Rbpf,
            SlamBackendKind::Graph,
            SlamBackendKind::Fuzzy,
            SlamBackendKind::Vote,
        ] {
            let mut cfg = config.slam.clone();
            cfg.backend = kind;
            let opts = BackendOptions {
                online: true,
                sensors: Some(Arc::new(SensorRig::from_config(&config))),
                ..BackendOptions::default()
            };
            let pipeline = if kind == SlamBackendKind::Vote {
                cfg.vote.lockstep = false;
                SlamPipeline::new(&cfg, Box::new(VoteSlam::new(&cfg, &opts, None).unwrap()))
            } else {
                SlamPipeline::from_config(&cfg, &opts)
            };
            let mut names = Vec::new();
            metrics(&pipeline, &Counters::default(), 0, &mut |n, _| {
                names.push(n)
            });
            let mut unique = names.clone();
            unique.sort_unstable();
            unique.dedup();
            assert_eq!(
                unique.len(),
                names.len(),
                "{kind:?}: a name twice in {names:?}"
            );
            for n in &names {
                assert!(
                    n.len() <= smokenav_shared_types::health::METRIC_NAME_LEN,
                    "{n}"
                );
            }
            // + pose_hz + rate_floor.
            assert!(
                names.len() + 2 <= MAX_METRICS,
                "{kind:?}: {} metrics and 2 more do not fit {MAX_METRICS}: {names:?}",
                names.len()
            );
        }
    }

    /// A map over the limit is not taken (nor is the one before it kept),
    /// is counted, and its reason names the key until a map within it comes.
    #[test]
    fn a_map_over_the_limit_is_refused_counted_and_named() {
        let mut counters = Counters::default();
        let mut refused = None;
        let grid = |w, h| Some((OccupancyGrid::new(w, h, 0.05, [0.0; 3]), 3));
        assert!(take_map(grid(100, 100), 10_000, &mut counters, &mut refused).is_some());
        assert_eq!((counters.maps_refused, counters.footprint_cleared), (0, 3));
        assert!(take_map(grid(101, 100), 10_000, &mut counters, &mut refused).is_none());
        assert_eq!(counters.maps_refused, 1);
        let why = refused.clone().unwrap();
        assert!(
            why.contains("101 × 100 cells (5 m × 5 m)")
                && why.contains("[slam] max_map_cells 10000"),
            "{why}"
        );
        assert!(take_map(None, 10_000, &mut counters, &mut refused).is_none());
        assert_eq!(
            refused.as_ref(),
            Some(&why),
            "nothing drawn: the reason stands"
        );
        assert!(take_map(grid(50, 50), 10_000, &mut counters, &mut refused).is_some());
        assert!(refused.is_none());
        // A corrupt size cannot overflow the check.
        let huge = OccupancyGrid {
            width: usize::MAX,
            height: 2,
            ..OccupancyGrid::new(1, 1, 0.05, [0.0; 3])
        };
        assert!(oversized(&huge, 1 << 30).is_some());
    }

    #[test]
    fn map_info_carries_the_grid_geometry() {
        let grid = OccupancyGrid::new(7, 5, 0.05, [-8.6, -10.4, 0.0]);
        let info = map_info(&grid, 42);
        assert_eq!((info.width, info.height), (7, 5));
        assert_eq!(info.cell_count(), grid.cells.len());
        assert_eq!((info.origin_x, info.origin_y), (-8.6, -10.4));
        assert_eq!(info.header.stamp_ns, 42);
        assert_eq!(info.header.frame_id.as_str(), "map");
        assert!((info.resolution - 0.05).abs() < 1e-9);
    }
}
