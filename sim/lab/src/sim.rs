//! `smokenav-lab sim SCENARIO`: the smoky world feeding emulated devices on
//! pseudo-terminals, so the real drivers (or a user's own tools) connect to a
//! simulated robot. Prints where each device is, writes a robot profile that
//! points the drivers there, publishes the true pose on `sim/truth`, and
//! writes the true map and trajectory when the scenario ends (or on Ctrl-C).

use anyhow::{Context, bail};
use smokenav_platform_bus::{Bus, BusOptions};
use smokenav_sim_link::{SimLink, SimLinkConfig, TRUTH_TOPIC, TruthPublisher, Until};
use smokenav_sim_world::Scenario;
use std::path::PathBuf;
use std::time::{Duration, Instant};

#[derive(clap::Args, Debug)]
pub struct SimArgs {
    /// Scenario: a bundled one (mrl-clean, r32-light-puff, r32-dense-crossing, corridor, aisles) or a scenario TOML file.
    pub scenario: String,
    /// Where to write the robot profile that points the drivers at the emulated devices
    /// (default: OUT/robot.toml).
    #[arg(long, value_name = "FILE")]
    pub profile_out: Option<PathBuf>,
    /// The simulator's random seed (sensor noise, odometry error, the smoke's
    /// turbulence) instead of the scenario's `seed`.
    #[arg(long, value_name = "N")]
    pub sim_seed: Option<u64>,
    /// Simulated seconds per real second (the devices keep their real rates).
    #[arg(long, value_name = "X", default_value_t = 1.0)]
    pub speed: f64,
    /// Folder for the ground truth (truth.yaml + truth.pgm, truth.txt) and the profile.
    #[arg(long, value_name = "DIR", default_value = "smokenav-sim-out")]
    pub out: PathBuf,
    /// Folder for the devices' stable symlinks (default: a fresh folder under the temp dir).
    #[arg(long, value_name = "DIR")]
    pub dev_dir: Option<PathBuf>,
    /// Bus instance for `sim/truth` and the profile (default: SMOKENAV_INSTANCE, else the scenario's robot profile).
    #[arg(long)]
    pub instance: Option<String>,
    /// Start the world after this many seconds (the devices idle until then: time to start the drivers).
    #[arg(long, value_name = "SECONDS", default_value_t = 0.0)]
    pub delay: f64,
    /// End after this many simulated seconds (default: the scenario's duration).
    #[arg(long, value_name = "SECONDS")]
    pub duration: Option<f64>,
    /// Trajectory file: `plain` (truth.txt) or `tum` (also truth.tum, for `evo_ape tum`).
    #[arg(long, value_enum, default_value_t = crate::demo::TrajectoryFiles::Plain)]
    pub format: crate::demo::TrajectoryFiles,
}

/// A bundled scenario or a scenario file, with the simulator's seed
/// `sim_seed` instead of its own when given (`--sim-seed`).
pub(crate) fn load_scenario(spec: &str, sim_seed: Option<u64>) -> anyhow::Result<Scenario> {
    let mut scenario =
        Scenario::builtin_or_file(spec).with_context(|| format!("cannot load scenario {spec}"))?;
    if let Some(seed) = sim_seed {
        scenario.seed = seed;
    }
    Ok(scenario)
}

pub fn run(args: SimArgs) -> anyhow::Result<()> {
    if std::env::var_os("RUST_LOG").is_some() {
        smokenav_platform_runtime::init_logging("sim");
    }
    if !(args.speed.is_finite() && args.speed > 0.0 && args.speed <= 100.0) {
        bail!("--speed must be within (0, 100], got {}", args.speed);
    }
    if !(args.delay.is_finite() && (0.0..=3600.0).contains(&args.delay)) {
        bail!("--delay must be within [0, 3600] s, got {}", args.delay);
    }
    let shutdown = smokenav_platform_runtime::Shutdown::install()
        .context("cannot install the signal handlers")?;
    let scenario = load_scenario(&args.scenario, args.sim_seed)?;
    let instance = args
        .instance
        .clone()
        .or_else(|| std::env::var("SMOKENAV_INSTANCE").ok())
        .unwrap_or_else(|| scenario.profile.robot.instance.clone());
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let (dev_dir, temporary) = match &args.dev_dir {
        Some(d) => (d.clone(), false),
        None => (
            std::env::temp_dir().join(format!("smokenav-sim-{}", std::process::id())),
            true,
        ),
    };
    let root = scenario.profile.bus.root_path.clone();
    let duration = args
        .duration
        .map_or(scenario.duration_s, |d| d.min(scenario.duration_s));
    let mut cfg = SimLinkConfig::new(scenario, &dev_dir);
    cfg.speed = args.speed;
    let mut link = SimLink::start(cfg)?;

    let d = link.devices();
    let pty = |p: &Option<PathBuf>| {
        p.as_ref()
            .map_or(String::new(), |p| format!(" → {}", p.display()))
    };
    let s = link.scenario();
    println!(
        "scenario {}: {} ({duration} s, seed {})",
        s.name, s.description, s.seed
    );
    println!(
        "laser: {}{}   (URG-04LX, SCIP 2.0)",
        d.laser,
        pty(&d.laser_pty)
    );
    println!(
        "base:  {}{}   ({}{})",
        d.base,
        pty(&d.base_pty),
        match d.platform {
            smokenav_platform_config::Platform::Pioneer => "Pioneer 3-DX, ARCOS",
            smokenav_platform_config::Platform::Scout => "Nomad Scout, Nomadic direct protocol",
        },
        if link.driven_by_commands() {
            "; base/cmd_vel drives the robot"
        } else {
            "; the scenario's route drives the robot"
        }
    );
    println!(
        "smoke: {}{}   (MQ303A on a {}-bit ADC board)",
        d.smoke,
        pty(&d.smoke_pty),
        s.adc_bits
    );
    let profile = args
        .profile_out
        .clone()
        .unwrap_or_else(|| args.out.join("robot.toml"));
    link.write_profile(&profile, Some(&instance))
        .with_context(|| format!("cannot write {}", profile.display()))?;
    println!(
        "profile: {}   (smokenav-hokuyo / smokenav-{} / smokenav-smoke --config it)",
        profile.display(),
        d.platform.driver_role()
    );
    println!(
        "truth: bus topic {TRUTH_TOPIC} (instance {instance}); truth.yaml/.pgm and truth.txt in {} at the end",
        args.out.display()
    );

    let bus = Bus::open(&BusOptions::new(&instance, "sim").with_root_path(root))?;
    let mut publisher = TruthPublisher::new(&bus)?;
    if args.delay > 0.0 {
        println!("the world starts in {} s …", args.delay);
        let end = Instant::now() + Duration::from_secs_f64(args.delay);
        while Instant::now() < end && !shutdown.requested() {
            std::thread::sleep((end - Instant::now()).min(Duration::from_millis(100)));
        }
    }
    let until = args.duration.map_or(Until::ScenarioEnd, Until::SimSeconds);
    let mut last = Instant::now();
    let mut publish_error = None;
    let summary = link.run(
        until,
        &|| shutdown.requested(),
        &mut |sample, host| {
            if let Err(e) = publisher.publish(sample, host) {
                publish_error.get_or_insert(e);
            }
        },
        &mut |p| {
            if last.elapsed() >= Duration::from_secs(5) {
                last = Instant::now();
                let cmd = p.commanded.map_or(String::new(), |(v, w)| {
                    format!("  cmd {v:.2} m/s {:.0}°/s", w.to_degrees())
                });
                println!(
                    "t {:>6.1}/{:.0} s  truth ({:.2}, {:.2}, {:.0}°)  smoke at the robot {:.3} g/m³{cmd}",
                    p.sim_s,
                    p.duration_s,
                    p.truth.x,
                    p.truth.y,
                    p.truth.theta.to_degrees(),
                    p.smoke_gpm3
                );
            }
        },
    );
    if let Some(e) = publish_error {
        eprintln!("warning: publishing {TRUTH_TOPIC} failed: {e}");
    }
    let (map, traj) = link.write_truth(&args.out)?;
    if args.format == crate::demo::TrajectoryFiles::Tum {
        crate::demo::write_tum_copies(&args.out)?;
    }
    println!(
        "{} after {:.1} s of the scenario ({:.1} s wall); {} laser scans fed",
        if summary.stopped { "stopped" } else { "done" },
        summary.sim_s,
        summary.wall.as_secs_f64(),
        summary.laser.fed
    );
    println!(
        "true map: {}\ntrue trajectory: {}",
        map.display(),
        traj.display()
    );
    drop(link);
    if temporary {
        let _ = std::fs::remove_dir_all(&dev_dir);
    }
    Ok(())
}
