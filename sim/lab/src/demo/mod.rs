//! `smokenav-lab demo`: the smoke experiment of SmokeNav (Santos et al. 2015), end to end.
//!
//! 1. Live (unless `--fast`): the simulated world feeds the device emulators
//!    on PTYs (smokenav-simlink); the real driver processes, the fusion
//!    process and the SLAM process run as separate OS processes under a
//!    small supervisor ([`live`]) that waits until each reports ready on its
//!    health topic, prints a one-line status every second and stops them all
//!    at the end or on Ctrl-C; the sensor topics are recorded to MCAP.
//!    `--fast` makes the recording straight from the simulator instead
//!    ([`recording::record_direct`]), as fast as the CPU allows.
//! 2. The recording goes through fusion + SLAM (the libraries, in this
//!    process, deterministic) three ways — laser only, SmokeNav v1, SmokeNav
//!    v2 — and each map and trajectory is scored against the ground truth
//!    ([`compare`]); when the scenario has smoke, its smoke-free twin (the
//!    same scenario without sources) is run the same way as the clean reference.
//! 3. The output folder gets the maps (map_server PGM/YAML, and one PNG with
//!    the ground truth and the three maps side by side), the trajectories, the
//!    recording, a plot of smoke level vs laser spread vs sonar usage, and
//!    `comparison.json`.

mod backends;
mod compare;
mod draw;
mod live;
mod pictures;
mod recording;
mod report;
mod smoke_region;
mod vote;

use anyhow::{Context, bail};
use compare::MethodResult;
use smokenav_platform_config::RobotConfig;
use smokenav_platform_map::OccupancyGrid;
use smokenav_sim_link::{TruthTrack, Until};
use smokenav_sim_world::Scenario;
use std::collections::BTreeMap;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// `--format` of the demo's trajectory files.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum TrajectoryFiles {
    Plain,
    Tum,
}

/// Writes `<name>.tum` beside every `<name>.txt` trajectory under `dir` (truth.txt,
/// trajectories/*.txt): the same poses as TUM lines.
pub(crate) fn write_tum_copies(dir: &Path) -> anyhow::Result<()> {
    let mut files = vec![dir.join("truth.txt")];
    if let Ok(entries) = std::fs::read_dir(dir.join("trajectories")) {
        files.extend(
            entries
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|x| x == "txt")),
        );
    }
    for f in files.into_iter().filter(|f| f.exists()) {
        let poses = smokenav_algorithms_eval::load_trajectory(&f)?;
        let out = f.with_extension("tum");
        std::fs::write(
            &out,
            smokenav_algorithms_eval::format_trajectory_as(
                &poses,
                smokenav_algorithms_eval::TrajectoryFormat::Tum,
            ),
        )
        .with_context(|| format!("cannot write {}", out.display()))?;
    }
    Ok(())
}

#[derive(clap::Args, Debug)]
pub struct DemoArgs {
    /// Scenario: a bundled one (r32-dense-crossing, r32-light-puff, mrl-clean, corridor, aisles, heights, cables) or a scenario TOML file.
    #[arg(long, value_name = "FILE|NAME", default_value = "r32-dense-crossing")]
    pub scenario: String,
    /// Skip the live run: record straight from the simulator, as fast as possible, then compare.
    #[arg(long)]
    pub fast: bool,
    /// The simulator's random seed (sensor noise, odometry error, the smoke's
    /// turbulence) instead of the scenario's `seed`: the same trial drawn
    /// again. One draw's figures can be far from another's; compare methods
    /// over several.
    #[arg(long, value_name = "N")]
    pub sim_seed: Option<u64>,
    /// Output folder.
    #[arg(long, value_name = "DIR", default_value = "smokenav-demo-out")]
    pub out: PathBuf,
    /// Print the comparison as JSON on stdout (progress goes to stderr).
    #[arg(long)]
    pub json: bool,
    /// End the scenario after this many simulated seconds (default: when the route is done).
    #[arg(long, value_name = "SECONDS")]
    pub duration: Option<f64>,
    /// Particles of every SLAM run (default: the robot profile's `[slam] particles`).
    #[arg(long, value_name = "N")]
    pub particles: Option<usize>,
    /// Do not run the scenario's smoke-free twin (no clean reference).
    #[arg(long)]
    pub no_clean_reference: bool,
    /// SLAM runs per method, each with another random seed; the table shows their mean
    /// (in dense smoke one run's map error varies by 10–20 % with the seed alone).
    #[arg(long, value_name = "N", default_value_t = 3)]
    pub seeds: usize,
    /// Trajectory files: `plain` (`timestamp x y theta`) or `tum` (also writes
    /// truth.tum and trajectories/*.tum, `t x y z qx qy qz qw`, for `evo_ape tum`).
    #[arg(long, value_enum, default_value_t = TrajectoryFiles::Plain)]
    pub format: TrajectoryFiles,
    /// Skip the 2D/3D occupancy comparison per fusion rule (LOP, LIOP, IOP,
    /// Bayes) on the `heights` scenario (`smokenav-lab map3d`, into OUT/map3d).
    #[arg(long)]
    pub no_map3d: bool,
    /// Skip the vote back-end's run (the profile's members, e.g. rbpf, graph, fuzzy, projected, and the
    /// fused map, scored side by side on the trial and its clean twin).
    #[arg(long)]
    pub no_vote: bool,
    /// Run only the profile's `[slam] backend`, not also the other of `rbpf` and
    /// `graph` over the same fused scans.
    #[arg(long)]
    pub no_backend_comparison: bool,
}

/// Where progress messages go: stderr with `--json` (stdout is for the JSON), else stdout.
pub(crate) struct Say {
    json: bool,
}

impl Say {
    pub fn line(&self, s: &str) {
        if self.json {
            eprintln!("{s}");
        } else {
            println!("{s}");
        }
    }

    /// A status line that overwrites itself on a terminal.
    pub fn status(&self, s: &str) {
        let tty = if self.json {
            std::io::stderr().is_terminal()
        } else {
            std::io::stdout().is_terminal()
        };
        match (self.json, tty) {
            (true, true) => eprint!("\r\x1b[2K{s}"),
            (true, false) => eprintln!("{s}"),
            (false, true) => {
                print!("\r\x1b[2K{s}");
                let _ = std::io::Write::flush(&mut std::io::stdout());
            }
            (false, false) => println!("{s}"),
        }
    }

    pub fn end_status(&self) {
        let tty = if self.json {
            std::io::stderr().is_terminal()
        } else {
            std::io::stdout().is_terminal()
        };
        if tty {
            self.line("");
        }
    }
}

/// The results of one scenario: truth and the three methods.
pub(crate) struct Comparison {
    pub scenario: String,
    pub description: String,
    /// The simulator's seed the scenario ran with.
    pub sim_seed: u64,
    pub sim_s: f64,
    pub scans: usize,
    pub truth: TruthTrack,
    pub truth_map: OccupancyGrid,
    pub results: Vec<MethodResult>,
    /// Smoke sources: (x, y, radius), m, in the truth's frame.
    pub smoke_sources: Vec<(f64, f64, f64)>,
    /// SmokeNav v1's smoke thresholds (SMOKE_MIN, SMOKE_MAX_UP, SMOKE_MAX_DOWN).
    pub smoke_thresholds: [f64; 3],
    /// SLAM runs per method.
    pub seeds: usize,
    /// Share of laser beams the smoke changed, % over time (s since the first
    /// scan): each scan against the same scan of the smoke-free twin.
    pub laser_damage: Vec<(f64, f64)>,
    /// The profile's SLAM back-end (the one `results` come from).
    pub backend: smokenav_platform_config::SlamBackendKind,
    /// The other back-ends over the same fused scans ([`backends`]).
    pub other_backends: Vec<backends::BackendRun>,
    /// Where the smoke was, on the truth map's grid ([`smoke_region`]; `None` without smoke).
    pub smoke_region: Option<OccupancyGrid>,
}

/// The profile the drivers (and the offline runs) use for `scenario`.
fn demo_profile(scenario: &Scenario, particles: Option<usize>) -> RobotConfig {
    let mut p = scenario.profile.clone();
    if !scenario.smoke_sensor.cold_start {
        p.smoke.warmup_s = 0.0;
    }
    if let Some(n) = particles {
        p.slam.particles = n;
    }
    // The sensors' heights and what the base drives over are the world's
    // facts here (what the projected vote member maps in 3D with).
    p.mapping.laser_height_m = scenario.laser.height_m;
    p.mapping.sonar_height_m = scenario.sonar.height_m;
    p.mapping.climb_height_m = p
        .mapping
        .climb_height_m
        .max(scenario.odometry.climb_height_m);
    p
}

/// The same scenario without smoke (`None` when it has none).
fn clean_twin(scenario: &Scenario) -> Option<Scenario> {
    if scenario.sources.is_empty() && scenario.patches.is_empty() {
        return None;
    }
    let mut twin = scenario.clone();
    twin.sources.clear();
    twin.patches.clear();
    twin.name = format!("{} (no smoke)", scenario.name);
    twin.description = format!("{}, without smoke", scenario.description);
    Some(twin)
}

fn threads() -> usize {
    std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(3)
}

fn metadata(scenario: &Scenario, mode: &str) -> BTreeMap<String, String> {
    let mut m = BTreeMap::new();
    m.insert("scenario".into(), scenario.name.clone());
    m.insert("description".into(), scenario.description.clone());
    m.insert("seed".into(), scenario.seed.to_string());
    m.insert("recorded_by".into(), format!("smokenav-lab demo ({mode})"));
    m
}

/// Records `scenario` straight from the simulator into `dir` and compares the methods.
fn fast_comparison(
    scenario: &Scenario,
    profile: &RobotConfig,
    until: Until,
    dir: &Path,
    seeds: usize,
    other_backends: bool,
    say: &Say,
) -> anyhow::Result<Comparison> {
    let rec_path = dir.join("recording.mcap");
    let t = Instant::now();
    let run = recording::record_direct(
        scenario.clone(),
        profile,
        until,
        &rec_path,
        &metadata(scenario, "simulated recording"),
    )?;
    say.line(&format!(
        "  recorded {:.1} s of {} from the simulator in {:.1} s ({} messages): {}",
        run.sim_s,
        scenario.name,
        t.elapsed().as_secs_f64(),
        run.messages,
        rec_path.display()
    ));
    compare_recording(
        scenario,
        profile,
        &rec_path,
        run.truth,
        run.truth_map,
        run.sim_s,
        dir,
        seeds,
        other_backends,
        say,
    )
}

#[allow(clippy::too_many_arguments)]
fn compare_recording(
    scenario: &Scenario,
    profile: &RobotConfig,
    rec_path: &Path,
    truth: TruthTrack,
    truth_map: OccupancyGrid,
    sim_s: f64,
    dir: &Path,
    seeds: usize,
    other_backends: bool,
    say: &Say,
) -> anyhow::Result<Comparison> {
    smokenav_platform_map::save_map_server(&truth_map, dir, "truth")?;
    truth
        .write(&dir.join("truth.txt"))
        .with_context(|| format!("cannot write {}", dir.join("truth.txt").display()))?;
    let log = recording::SensorLog::read(rec_path)?;
    let t = Instant::now();
    say.line(&format!(
        "  fusion + SLAM ({} particles{}) over {} scans: laser-only, v1, v2 …",
        profile.slam.particles,
        if seeds > 1 {
            format!(", {seeds} seeds each")
        } else {
            String::new()
        },
        log.lasers.len()
    ));
    let smoke = smoke_region::smoke_region(
        scenario,
        &truth,
        &truth_map,
        f64::from(smokenav_sim_world::laser::URG_DMAX_MM) * 1e-3,
    )?;
    let results = compare::run_all(
        &log,
        profile,
        &truth,
        &truth_map,
        smoke.as_ref(),
        threads(),
        seeds,
    )?;
    say.line(&format!("  done in {:.1} s", t.elapsed().as_secs_f64()));
    let other_backends = if other_backends {
        let names: Vec<&str> = backends::others(profile)
            .iter()
            .map(|b| b.as_str())
            .collect();
        let t = Instant::now();
        say.line(&format!(
            "  the same fused scans through SLAM back-end {} …",
            names.join(", ")
        ));
        let runs = backends::run(
            &log,
            profile,
            &truth,
            &truth_map,
            smoke.as_ref(),
            threads(),
            seeds,
        )?;
        say.line(&format!("  done in {:.1} s", t.elapsed().as_secs_f64()));
        runs
    } else {
        Vec::new()
    };
    let c = Comparison {
        scenario: scenario.name.clone(),
        description: scenario.description.clone(),
        sim_seed: scenario.seed,
        sim_s,
        scans: log.lasers.len(),
        truth,
        truth_map,
        results,
        smoke_sources: scenario
            .sources
            .iter()
            .map(|s| (s.position.x, s.position.y, s.radius_m))
            .collect(),
        smoke_thresholds: [
            profile.fusion.v1.smoke_min,
            profile.fusion.v1.smoke_max_up,
            profile.fusion.v1.smoke_max_down,
        ],
        seeds,
        laser_damage: Vec::new(),
        backend: profile.slam.backend,
        other_backends,
        smoke_region: smoke,
    };
    report::write_files(&c, dir)?;
    Ok(c)
}

/// How many beams of each scan the smoke changed: the scan against the same
/// scan of the smoke-free twin (same seed ⇒ same noise; the smoke is the only
/// difference), counting beams whose range moved by more than 10 cm or that
/// gained or lost their return. Scans are matched by time since the first.
fn laser_damage(a: &recording::SensorLog, b: &recording::SensorLog) -> Vec<(f64, f64)> {
    let Some(a0) = a.lasers.first().map(|s| s.header.stamp_ns) else {
        return Vec::new();
    };
    let twin = compare::scans_by_tick(b);
    let mut out = Vec::with_capacity(a.lasers.len());
    for s in &a.lasers {
        let k = compare::tick(s.header.stamp_ns, a0);
        let Some(c) = twin.get(&k) else { continue };
        let n = s.len().min(c.len());
        if n == 0 {
            continue;
        }
        let changed = (0..n)
            .filter(|&i| compare::smoke_changed(s.beam(i).range(), c.beam(i).range()))
            .count();
        out.push((k as f64 * 0.1, changed as f64 * 100.0 / n as f64));
    }
    out
}

/// The smoke's damage over time, and each method's [`compare::LaserVerdict`]:
/// the recording fused again with every method (as the comparison did),
/// judged beam by beam against the clean twin's recording.
fn judge_against_twin(
    main: &mut Comparison,
    profile: &RobotConfig,
    smoky: &Path,
    clean: &Path,
) -> anyhow::Result<()> {
    let a = recording::SensorLog::read(smoky)?;
    let b = recording::SensorLog::read(clean)?;
    main.laser_damage = laser_damage(&a, &b);
    for r in &mut main.results {
        let (fused, _) = compare::fuse(&a, profile, r.method)?;
        r.laser_verdict = Some(compare::laser_verdict(&fused, &a, &b));
    }
    Ok(())
}

/// The vote back-end over the trial's recording and its clean twin's.
fn vote_runs(
    main: &Comparison,
    clean: Option<&Comparison>,
    profile: &RobotConfig,
    out: &Path,
    say: &Say,
) -> anyhow::Result<Vec<vote::VoteComparison>> {
    let names: Vec<&str> = profile
        .slam
        .vote
        .members
        .iter()
        .map(|m| m.as_str())
        .collect();
    say.line(&format!(
        "vote back-end ({} and their vote; SmokeNav v2):",
        names.join(", ")
    ));
    let mut runs = vec![(main, out.join("recording.mcap"))];
    if let Some(c) = clean {
        runs.push((c, out.join("clean-reference").join("recording.mcap")));
    }
    let mut votes = Vec::new();
    for (c, rec) in runs {
        let t = Instant::now();
        let log = recording::SensorLog::read(&rec)?;
        votes.push(vote::run(
            &c.scenario,
            &log,
            profile,
            &c.truth,
            &c.truth_map,
        )?);
        say.line(&format!(
            "  {} in {:.1} s",
            c.scenario,
            t.elapsed().as_secs_f64()
        ));
    }
    Ok(votes)
}

pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    if std::env::var_os("RUST_LOG").is_some() {
        smokenav_platform_runtime::init_logging("demo");
    }
    if let Some(d) = args.duration
        && !(d.is_finite() && d > 0.0)
    {
        bail!("--duration must be a positive number of seconds, got {d}");
    }
    if let Some(n) = args.particles
        && !(1..=1000).contains(&n)
    {
        bail!("--particles must be 1–1000, got {n}");
    }
    if !(1..=20).contains(&args.seeds) {
        bail!("--seeds must be 1–20, got {}", args.seeds);
    }
    let say = Say { json: args.json };
    let scenario = crate::sim::load_scenario(&args.scenario, args.sim_seed)?;
    let until = args.duration.map_or(Until::RouteDone, Until::SimSeconds);
    let profile = demo_profile(&scenario, args.particles);
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let started = Instant::now();
    say.line(&format!(
        "smokenav-lab demo: {} — {} ({} s scripted, simulator seed {}{})",
        scenario.name,
        scenario.description,
        scenario.duration_s,
        scenario.seed,
        if args.fast { ", fast" } else { ", live" }
    ));

    let main = if args.fast {
        say.line("recording (straight from the simulator):");
        fast_comparison(
            &scenario,
            &profile,
            until,
            &args.out,
            args.seeds,
            !args.no_backend_comparison,
            &say,
        )?
    } else {
        say.line("live run (simulator → emulated devices → driver, fusion and SLAM processes):");
        let live = live::run(&scenario, &profile, until, &args.out, &say)?;
        if live.interrupted {
            say.line(&format!(
                "interrupted: everything stopped cleanly; the partial recording is {}",
                live.recording.display()
            ));
            return Ok(());
        }
        say.line("comparison (the live recording through fusion + SLAM, in this process):");
        compare_recording(
            &scenario,
            &profile,
            &live.recording,
            live.truth,
            live.truth_map,
            live.sim_s,
            &args.out,
            args.seeds,
            !args.no_backend_comparison,
            &say,
        )?
    };

    let clean = match clean_twin(&scenario) {
        Some(twin) if !args.no_clean_reference => {
            say.line(&format!("clean reference ({}):", twin.name));
            let dir = args.out.join("clean-reference");
            std::fs::create_dir_all(&dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
            Some(fast_comparison(
                &twin,
                &profile,
                until,
                &dir,
                args.seeds,
                !args.no_backend_comparison,
                &say,
            )?)
        }
        _ => None,
    };
    let mut main = main;
    if clean.is_some() {
        judge_against_twin(
            &mut main,
            &profile,
            &args.out.join("recording.mcap"),
            &args.out.join("clean-reference").join("recording.mcap"),
        )?;
    }
    report::write_pictures(&main, &args.out)?;
    if let Some(c) = &clean {
        report::write_pictures(c, &args.out.join("clean-reference"))?;
    }

    report::write_summary(&main, clean.as_ref(), &args.out)?;
    if args.format == TrajectoryFiles::Tum {
        write_tum_copies(&args.out)?;
        if clean.is_some() {
            write_tum_copies(&args.out.join("clean-reference"))?;
        }
    }
    let votes = if args.no_vote {
        Vec::new()
    } else {
        vote_runs(&main, clean.as_ref(), &profile, &args.out, &say)?
    };
    // Mapping, not localisation: true poses on the scenario with obstacles
    // out of the laser's plane (the demo's `--duration` shortens it too).
    let map3d = if args.no_map3d {
        None
    } else {
        say.line("occupancy fusion per rule (heights scenario, true poses):");
        let mut a = crate::map3d::Map3dArgs::demo(Some(args.out.join("map3d")));
        a.duration = args.duration;
        Some(crate::map3d::evaluate(&a)?)
    };
    let mut v = report::json_value(&main, clean.as_ref());
    if let (false, Some(obj)) = (votes.is_empty(), v.as_object_mut()) {
        obj.insert("vote".into(), serde_json::to_value(&votes)?);
        let path = args.out.join("comparison.json");
        std::fs::write(&path, serde_json::to_string_pretty(&v)? + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    if let (Some(r), Some(obj)) = (&map3d, v.as_object_mut()) {
        obj.insert("occupancy_rules".into(), serde_json::to_value(r)?);
        // comparison.json is what --json prints: with the rules too.
        let path = args.out.join("comparison.json");
        std::fs::write(&path, serde_json::to_string_pretty(&v)? + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    if args.json {
        println!("{v}");
    } else {
        print!("{}", report::table(&main, clean.as_ref()));
        if !votes.is_empty() {
            print!("{}", vote::table(&votes));
        }
        if let Some(r) = &map3d {
            print!("\n{}", crate::map3d::table(r));
        }
        println!(
            "\nwrote {} (maps.png, errors.png, smoke.png, maps/, trajectories/, recording.mcap, comparison.json) in {:.0} s",
            args.out.display(),
            started.elapsed().as_secs_f64()
        );
    }
    Ok(())
}
