//! A robot driving through smoke, end to end, through the real processes.
//!
//! The simulated world (`tests/data/smoke-front.toml`: the Scout drives up
//! the R3.2 middle bay through a dense smoke cloud) feeds the URG-04LX, Scout
//! and smoke-ADC emulators on real PTYs; the real `smokenav-hokuyo`,
//! `smokenav-scout`, `smokenav-smoke`, `smokenav-fusion` (SmokeNav v2) and
//! `smokenav-slam` processes run over iceoryx2 as on the robot. Against the
//! world's ground truth (true pose at each scan's stamp, ray-cast in the
//! arena) the test checks:
//!
//! - fusion: in every sonar section where the raw laser shows a phantom wall
//!   (the smoke front, metres short of the true walls), the fused scan does
//!   not: it shows the true wall distance (the sonar) or nothing; and the
//!   fusion process reports its sonar usage;
//! - SLAM: the poses on `slam/pose` follow the true trajectory (absolute
//!   trajectory error after the best rigid alignment).

use smokenav_platform_bus::{Bus, Subscriber, Waiter, topics};
use smokenav_shared_types::{
    BeamReading, FusedScan, FusionMethod, Health, HealthState, LaserScan, PoseEstimate,
    SectionSource, SyncState,
};
use smokenav_sim_link::{SimLink, SimLinkConfig, TruthPublisher, TruthTrack, Until};
use smokenav_sim_world::Scenario;
use smokenav_sim_world::geom::{Pose2, Vec2};
use smokenav_tests::{Child, bin, open_bus, unique_instance, wait_for, workspace_root};
use std::collections::HashMap;
use std::time::Duration;

/// Simulated seconds of the run (the cloud is crossed by ~20 s).
const RUN_S: f64 = 28.0;
/// A raw laser range this much shorter than the true wall is the smoke, m.
const PHANTOM_M: f64 = 0.5;
/// Fused and true section medians this close keep the wall distance, m
/// (a sonar's arc across a 25° cone is coarser than a laser).
const KEPT_M: f64 = 0.35;
/// Smoke level at which v2 holds the air alcoholized (μ = 0.5, the paper's "20").
const SMOKE_SENSED: f32 = 20.0;

fn drain<T: smokenav_platform_bus::Message>(sub: &Subscriber<T>, into: &mut Vec<T>) {
    while let Some(m) = sub.receive().unwrap() {
        into.push(*m);
    }
}

/// The true pose at host time `t_ns`, interpolated between truth samples.
fn truth_at(track: &TruthTrack, t_ns: u64) -> Option<Pose2> {
    let s = track.samples();
    let i = s.partition_point(|x| x.t_ns < t_ns);
    let (a, b) = (s.get(i.checked_sub(1)?)?, s.get(i)?);
    let span = (b.t_ns - a.t_ns) as f64;
    let u = if span > 0.0 {
        (t_ns - a.t_ns) as f64 / span
    } else {
        0.0
    };
    let dth = (b.pose.theta - a.pose.theta + std::f64::consts::PI)
        .rem_euclid(std::f64::consts::TAU)
        - std::f64::consts::PI;
    Some(Pose2 {
        x: a.pose.x + u * (b.pose.x - a.pose.x),
        y: a.pose.y + u * (b.pose.y - a.pose.y),
        theta: a.pose.theta + u * dth,
    })
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

/// What one phantom section became in the fused scan.
#[derive(Debug, Default)]
struct PhantomTally {
    sections: usize,
    /// Fused median within `KEPT_M` of the true median.
    kept_true_distance: usize,
    /// …of which the sonar supplied the ranges.
    kept_by_sonar: usize,
    /// No range at all (SLAM sees no return there).
    dropped: usize,
    /// Sonar ranges, but off the true median: a 25° cone echoes from the
    /// nearest surface anywhere in it (an oblique wall, a corner).
    coarse_sonar: usize,
    /// The phantom got through: the fused median is the raw laser's.
    passed: usize,
}

#[test]
fn fused_scan_keeps_the_true_walls_through_smoke_and_slam_follows_the_truth() {
    let scenario = Scenario::load(&workspace_root().join("tests/data/smoke-front.toml")).unwrap();
    let arena = scenario.arena.clone();
    let mount = scenario.laser_mount;
    let dir = tempfile::tempdir().unwrap();
    let mut link = SimLink::start(SimLinkConfig::new(scenario, dir.path().join("dev"))).unwrap();
    let instance = unique_instance("smoke_run");
    let mut profile = link.driver_profile(Some(&instance));
    profile.fusion.method = FusionMethod::V2;
    let profile_path = dir.path().join("robot.toml");
    std::fs::write(&profile_path, profile.to_toml()).unwrap();
    let cfg = profile_path.to_string_lossy().into_owned();

    let bus = open_bus(&instance);
    let roles = ["hokuyo", "scout", "smoke", "fusion", "slam"];
    let procs: Vec<Child> = roles
        .iter()
        .map(|role| {
            Child::spawn(
                &bin(&format!("smokenav-{role}")),
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

    let raw_sub: Subscriber<LaserScan> = bus.subscriber(topics::LASER_SCAN).unwrap();
    let fused_sub: Subscriber<FusedScan> = bus.subscriber(topics::FUSION_SCAN).unwrap();
    let pose_sub: Subscriber<PoseEstimate> = bus.subscriber(topics::SLAM_POSE).unwrap();
    let waiter = Waiter::new().unwrap();
    let _g = [
        waiter.attach(&raw_sub).unwrap(),
        waiter.attach(&fused_sub).unwrap(),
        waiter.attach(&pose_sub).unwrap(),
    ];
    let world = {
        let instance = instance.clone();
        std::thread::spawn(move || {
            let bus: Bus = open_bus(&instance);
            let mut truth = TruthPublisher::new(&bus).unwrap();
            let summary = link.run(
                Until::SimSeconds(RUN_S),
                &|| false,
                &mut |sample, host| truth.publish(sample, host).unwrap(),
                &mut |_| {},
            );
            (link, summary)
        })
    };
    let (mut raw, mut fused, mut poses) = (Vec::new(), Vec::new(), Vec::new());
    while !world.is_finished() {
        waiter.wait(Some(Duration::from_millis(50))).unwrap();
        drain(&raw_sub, &mut raw);
        drain(&fused_sub, &mut fused);
        drain(&pose_sub, &mut poses);
    }
    let (link, summary) = world.join().unwrap();
    assert!(summary.sim_s >= RUN_S - 0.01, "{summary:?}");
    // SLAM may still be working through the last scans.
    let until = std::time::Instant::now() + Duration::from_secs(5);
    while std::time::Instant::now() < until {
        waiter.wait(Some(Duration::from_millis(100))).unwrap();
        drain(&raw_sub, &mut raw);
        drain(&fused_sub, &mut fused);
        drain(&pose_sub, &mut poses);
    }
    let health = |role: &str| {
        wait_for::<Health>(&bus, topics::health(role), Duration::from_secs(5), |_| true)
            .unwrap()
            .pop()
            .unwrap()
    };
    let fusion_health = health("fusion");
    let slam_health = health("slam");
    for p in &procs {
        assert!(
            p.output().lines().all(|l| !l.contains("panicked")),
            "{}",
            p.output()
        );
    }
    let truth = link.truth();

    // --- Fusion: phantom sections of the raw laser vs the fused scan. ---
    let raw_by_stamp: HashMap<u64, &LaserScan> =
        raw.iter().map(|s| (s.header.stamp_ns, s)).collect();
    // Phantom sections while the smoke sensor already reads smoke, and before:
    // the laser sees the cloud from metres away, the sensor only where it is.
    let mut tally = PhantomTally::default();
    let mut unsensed = PhantomTally::default();
    let mut complete = 0;
    for f in fused
        .iter()
        .filter(|f| f.sync_state() == SyncState::Complete)
    {
        complete += 1;
        let Some(laser) = raw_by_stamp.get(&f.scan.header.stamp_ns) else {
            continue;
        };
        let Some(robot) = truth_at(truth, f.scan.header.stamp_ns) else {
            continue;
        };
        let origin = Vec2::new(
            robot.x + mount.x * robot.theta.cos() - mount.y * robot.theta.sin(),
            robot.y + mount.x * robot.theta.sin() + mount.y * robot.theta.cos(),
        );
        let true_range = |i: usize| {
            let a = robot.theta + mount.theta + f64::from(laser.angle(i));
            arena
                .cast(origin, Vec2::from_angle(a), 5.6)
                .map(|h| h.distance)
        };
        for d in f.sections() {
            let beams = d.first_beam as usize..d.end_beam as usize;
            let (mut valid, mut phantom) = (0usize, 0usize);
            let (mut raw_r, mut true_r, mut fused_r) = (Vec::new(), Vec::new(), Vec::new());
            for i in beams.clone() {
                let Some(t) = true_range(i) else { continue };
                true_r.push(t);
                if let BeamReading::Range(r) = laser.beam(i) {
                    valid += 1;
                    raw_r.push(f64::from(r));
                    if f64::from(r) < t - PHANTOM_M {
                        phantom += 1;
                    }
                }
                if let BeamReading::Range(r) = f.scan.beam(i) {
                    fused_r.push(f64::from(r));
                }
            }
            // A phantom wall: most of a section's laser ranges well short of the walls.
            if valid < 10 || phantom * 10 < valid * 6 {
                continue;
            }
            let tally = if f.smoke_level >= SMOKE_SENSED {
                &mut tally
            } else {
                &mut unsensed
            };
            tally.sections += 1;
            let t = median(true_r).unwrap();
            match median(fused_r) {
                None => tally.dropped += 1,
                Some(m) if (m - t).abs() <= KEPT_M => {
                    tally.kept_true_distance += 1;
                    if d.source() == SectionSource::Sonar {
                        tally.kept_by_sonar += 1;
                    }
                }
                Some(m) => {
                    let r = median(raw_r).unwrap_or(f64::NAN);
                    if (m - r).abs() <= KEPT_M || d.source() != SectionSource::Sonar {
                        tally.passed += 1;
                        if f.smoke_level >= SMOKE_SENSED {
                            eprintln!(
                                "phantom through: stamp {} smoke {:.0} section of sonar {} \
                                 ({:?}): raw median {r:.2} fused {m:.2} true {t:.2}",
                                f.scan.header.stamp_ns,
                                f.smoke_level,
                                d.sonar_index,
                                d.source(),
                            );
                        }
                    } else {
                        tally.coarse_sonar += 1;
                    }
                }
            }
        }
    }
    let usage = fusion_health.metric("sonar_usage").unwrap();
    // The speck filter drops laser beams: health must say how many.
    let specks = fusion_health
        .metric("speck_beams")
        .expect("health/fusion reports speck_beams");
    // So does keeping the laser beams the sonar vouches for.
    let vouched = fusion_health
        .metric("vouched_beams")
        .expect("health/fusion reports vouched_beams");
    eprintln!(
        "fusion: {complete} complete fused scans; raw phantom sections {}: true distance kept {} \
         ({} by the sonar), dropped {}, coarse sonar arc {}, phantom through {}; before the \
         smoke sensor read smoke: {unsensed:?}; sonar usage {:.1} %; {specks} speck beams dropped, {vouched} vouched for by the sonar",
        tally.sections,
        tally.kept_true_distance,
        tally.kept_by_sonar,
        tally.dropped,
        tally.coarse_sonar,
        tally.passed,
        usage * 100.0
    );
    assert!(
        complete >= 200,
        "{complete} complete fused scans in {RUN_S} s"
    );
    assert!(
        tally.sections >= 50,
        "the scenario shows the laser a phantom wall: {tally:?}"
    );
    assert!(
        tally.passed * 20 <= tally.sections,
        "at most 5 % of phantom sections reach SLAM: {tally:?}"
    );
    assert!(
        tally.kept_by_sonar * 3 >= tally.sections,
        "the sonar gives back the true wall in at least a third of them: {tally:?}"
    );
    assert!(
        usage > 0.1 && usage < 0.9,
        "sonar usage reported by the fusion process: {usage}"
    );

    // --- SLAM: its poses against the truth. ---
    let to_eval = |t_ns: u64, x: f64, y: f64, theta: f64| smokenav_algorithms_eval::StampedPose {
        t: t_ns as f64 * 1e-9,
        x,
        y,
        theta,
    };
    let truth_poses: Vec<_> = truth
        .samples()
        .iter()
        .map(|s| to_eval(s.t_ns, s.pose.x, s.pose.y, s.pose.theta))
        .collect();
    let est: Vec<_> = poses
        .iter()
        .map(|p| to_eval(p.header.stamp_ns, p.x, p.y, p.theta))
        .collect();
    let report = smokenav_algorithms_eval::evaluate_trajectories(
        &truth_poses,
        &est,
        &smokenav_algorithms_eval::TrajectoryOptions::default(),
    )
    .unwrap();
    let processed = slam_health.metric("scans_processed").unwrap_or(0.0);
    let skipped = slam_health.metric("scans_skipped").unwrap_or(0.0);
    // The Hokuyo driver's time between beams reached the SLAM process, and
    // the base's odometry ran: the sweeps were deskewed.
    let deskewed = slam_health.metric("scans_deskewed").unwrap_or(0.0);
    // The laser maps the smoke front ahead as a wall, then the robot drives
    // through it blind: the footprint takes that wall out of the map.
    let footprint = slam_health.metric("footprint_cleared").unwrap_or(0.0);
    eprintln!("slam: the footprint cleared {footprint} wall cells of the last map");
    assert!(
        footprint > 0.0,
        "no phantom wall cleared from the robot's path"
    );
    assert!(
        deskewed > 0.5 * processed,
        "{deskewed} of {processed} scans deskewed"
    );
    eprintln!(
        "slam: {} poses ({processed} scans processed, {skipped} skipped as superseded); \
         ATE RMS {:.3} m, max {:.3} m over {} poses; travelled {:.1} m",
        poses.len(),
        report.ate_m.rmse,
        report.ate_m.max,
        report.pairs,
        truth
            .samples()
            .windows(2)
            .map(|w| (w[1].pose.x - w[0].pose.x).hypot(w[1].pose.y - w[0].pose.y))
            .sum::<f64>()
    );
    assert!(
        poses.len() >= 60,
        "{} poses from the SLAM process",
        poses.len()
    );
    // Offline on the same scenario (`smokenav demo --fast --scenario
    // tests/data/smoke-front.toml`) laser-only SLAM is off by 1.4 m RMS.
    assert!(
        report.ate_m.rmse < 0.5,
        "SLAM through smoke: ATE RMS {:.3} m",
        report.ate_m.rmse
    );
    // The particle filter reports the scans it only weighed because the
    // fusion withheld much of them from the laser (the smoke's edge).
    let withheld = slam_health.metric("withheld_updates").unwrap_or(0.0);
    let updates = slam_health.metric("updates").unwrap_or(0.0);
    assert!(
        withheld > 0.0 && withheld < updates,
        "{withheld} of {updates} updates mostly withheld from the laser"
    );
}
