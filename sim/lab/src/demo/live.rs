//! The live run: simulator + emulated devices in this process, the real
//! driver, fusion and SLAM processes beside it, supervised like
//! `smokenav.target`: started in dependency order, each awaited until its
//! `health/<role>` topic says it is up, watched while the scenario runs, and
//! stopped (SIGTERM, then SIGKILL after 5 s) at the end or on Ctrl-C. The
//! sensor topics are recorded to MCAP from the bus as they flow.

use super::Say;
use super::recording::create_recorder;
use anyhow::{Context, bail};
use smokenav_platform_bus::{Bus, BusOptions, Subscriber, Waiter, topics};
use smokenav_platform_config::RobotConfig;
use smokenav_platform_map::OccupancyGrid;
use smokenav_platform_recording::{AnyMessageRef, Recorder};
use smokenav_platform_runtime::launch;
use smokenav_shared_types::catalog::topic_names;
use smokenav_shared_types::clock::monotonic_now_ns;
use smokenav_shared_types::{
    FusedScan, Health, HealthState, LaserScan, Odometry, PoseEstimate, SectionSource, SmokeReading,
    SonarRing,
};
use smokenav_sim_link::{
    Progress, RunSummary, SimLink, SimLinkConfig, TruthPublisher, TruthTrack, Until,
};
use smokenav_sim_world::Scenario;
use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, mpsc};
use std::time::{Duration, Instant};

/// How long a process may take to report ready.
const READY_TIMEOUT: Duration = Duration::from_secs(30);
/// How long a process may take to exit after SIGTERM.
const STOP_TIMEOUT: Duration = Duration::from_secs(5);

pub struct LiveOutcome {
    pub recording: PathBuf,
    pub truth: TruthTrack,
    pub truth_map: OccupancyGrid,
    pub sim_s: f64,
    pub interrupted: bool,
}

/// One supervised process.
struct Proc {
    role: String,
    child: std::process::Child,
    log: PathBuf,
}

impl Proc {
    fn spawn(
        bin: &Path,
        role: &str,
        profile: &Path,
        instance: &str,
        logs: &Path,
    ) -> anyhow::Result<Self> {
        let log = logs.join(format!("{role}.log"));
        let file =
            File::create(&log).with_context(|| format!("cannot create {}", log.display()))?;
        let err = file.try_clone().context("cannot share the log file")?;
        let child = launch::command(bin, instance)
            .arg("--config")
            .arg(profile)
            .stdout(file)
            .stderr(err)
            .spawn()
            .with_context(|| format!("cannot start {}", bin.display()))?;
        Ok(Self {
            role: role.to_owned(),
            child,
            log,
        })
    }

    fn pid(&self) -> u32 {
        self.child.id()
    }

    fn exited(&mut self) -> Option<std::process::ExitStatus> {
        self.child.try_wait().ok().flatten()
    }

    /// The end of its log, for error messages.
    fn log_tail(&self) -> String {
        let mut text = String::new();
        if let Ok(mut f) = File::open(&self.log) {
            let len = f.metadata().map(|m| m.len()).unwrap_or(0);
            let _ = f.seek(SeekFrom::Start(len.saturating_sub(2000)));
            let _ = f.read_to_string(&mut text);
        }
        text
    }

    /// SIGTERM, then SIGKILL if it has not exited after [`STOP_TIMEOUT`].
    fn stop(&mut self) -> Option<std::process::ExitStatus> {
        launch::stop(&mut self.child, STOP_TIMEOUT).ok()
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if self.exited().is_none() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// A workspace binary next to this one.
fn sibling(name: &str) -> Option<PathBuf> {
    let exe = std::env::current_exe().ok()?;
    let p = exe.parent()?.join(name);
    p.is_file().then_some(p)
}

/// Waits until every process in `procs[from..]` reports `ok` or `degraded` on
/// its health topic (from its own pid).
fn wait_ready(
    bus: &Bus,
    procs: &mut [Proc],
    say: &Say,
    shutdown: &smokenav_platform_runtime::Shutdown,
) -> anyhow::Result<()> {
    let subs: Vec<Subscriber<Health>> = procs
        .iter()
        .map(|p| bus.subscriber(topics::health(&p.role)))
        .collect::<Result<_, _>>()?;
    let waiter = Waiter::new()?;
    let _guards = subs
        .iter()
        .map(|s| waiter.attach(s))
        .collect::<Result<Vec<_>, _>>()?;
    let mut ready = vec![false; procs.len()];
    let start = Instant::now();
    while ready.iter().any(|r| !r) {
        if shutdown.requested() {
            bail!("interrupted while starting the processes");
        }
        for (i, p) in procs.iter_mut().enumerate() {
            while let Some(h) = subs[i].receive()? {
                if ready[i] || h.pid != p.pid() {
                    continue;
                }
                if matches!(h.state(), HealthState::Ok | HealthState::Degraded) {
                    ready[i] = true;
                    say.line(&format!(
                        "  {:<7} ready (pid {}, {}){}",
                        p.role,
                        p.pid(),
                        h.state().as_str(),
                        if h.last_error.is_empty() {
                            String::new()
                        } else {
                            format!(": {}", h.last_error)
                        }
                    ));
                }
            }
            if let Some(status) = p.exited() {
                bail!(
                    "smokenav-{} exited ({status}) before it was ready; end of {}:\n{}",
                    p.role,
                    p.log.display(),
                    p.log_tail()
                );
            }
        }
        if start.elapsed() > READY_TIMEOUT {
            let late: Vec<&str> = procs
                .iter()
                .zip(&ready)
                .filter(|(_, r)| !**r)
                .map(|(p, _)| p.role.as_str())
                .collect();
            bail!(
                "not ready within {READY_TIMEOUT:?}: {} (logs in {})",
                late.join(", "),
                procs[0]
                    .log
                    .parent()
                    .map_or(String::new(), |d| d.display().to_string())
            );
        }
        waiter.wait(Some(Duration::from_millis(100)))?;
    }
    Ok(())
}

/// What the status line shows.
#[derive(Default)]
struct Status {
    smoke: Option<SmokeReading>,
    fused: Option<Box<FusedScan>>,
    pose: Option<PoseEstimate>,
    /// Messages in the current second, per tapped topic.
    counts: [u64; 6],
    rates: [f64; 6],
    window: Option<Instant>,
}

const TAPPED: [&str; 6] = [
    topic_names::LASER_SCAN,
    topic_names::BASE_SONAR,
    topic_names::BASE_ODOM,
    topic_names::SMOKE_LEVEL,
    topic_names::FUSION_SCAN,
    topic_names::SLAM_POSE,
];

impl Status {
    fn roll(&mut self) {
        let now = Instant::now();
        let start = *self.window.get_or_insert(now);
        let dt = now.duration_since(start).as_secs_f64();
        if dt > 0.0 {
            for (r, c) in self.rates.iter_mut().zip(self.counts.iter_mut()) {
                *r = *c as f64 / dt;
                *c = 0;
            }
        }
        self.window = Some(now);
    }

    fn line(&self, p: Option<&Progress>, duration_s: f64) -> String {
        let t = p.map_or(0.0, |p| p.sim_s);
        let smoke = match &self.smoke {
            Some(s) if s.is_ready() => {
                format!("smoke {:>4.0} mV {:<7}", s.level, s.trend().as_str())
            }
            Some(s) => format!("smoke {:<15}", s.state().as_str()),
            None => format!("smoke {:<15}", "—"),
        };
        let fusion = match &self.fused {
            Some(f) => {
                let mut n = [0usize; 4];
                for d in f.sections() {
                    n[d.source() as usize] += 1;
                }
                format!(
                    "fusion {}: laser {:>2} sonar {:>2} both {:>2} neither {:>2}",
                    f.method().as_str(),
                    n[SectionSource::Laser as usize],
                    n[SectionSource::Sonar as usize],
                    n[SectionSource::Both as usize],
                    n[SectionSource::Neither as usize]
                )
            }
            None => "fusion —".into(),
        };
        let slam = match &self.pose {
            Some(q) => format!(
                "SLAM ({:>5.2}, {:>5.2}) {:>4.0}°",
                q.x,
                q.y,
                q.theta.to_degrees()
            ),
            None => "SLAM —".into(),
        };
        let r = &self.rates;
        format!(
            "{t:>5.1}/{duration_s:.0} s | {smoke} | {fusion} | {slam} | Hz scan {:.0} sonar {:.0} odom {:.0} smoke {:.0} fused {:.0} pose {:.0}",
            r[0], r[1], r[2], r[3], r[4], r[5]
        )
    }
}

type SimResult = (SimLink, Option<RunSummary>, Option<String>);

pub fn run(
    scenario: &Scenario,
    profile: &RobotConfig,
    until: Until,
    out: &Path,
    say: &Say,
) -> anyhow::Result<LiveOutcome> {
    let shutdown = smokenav_platform_runtime::Shutdown::install()
        .context("cannot install the signal handlers")?;
    let instance = format!("demo_{}", std::process::id());
    let dev_dir = std::env::temp_dir().join(format!("smokenav-demo-{}", std::process::id()));
    let logs = out.join("logs");
    std::fs::create_dir_all(&logs).with_context(|| format!("cannot create {}", logs.display()))?;

    // The world and its devices.
    let link = SimLink::start(SimLinkConfig::new(scenario.clone(), &dev_dir))?;
    let d = link.devices();
    let show = |p: &Option<PathBuf>| {
        p.as_ref()
            .map_or(String::new(), |p| format!(" → {}", p.display()))
    };
    say.line(&format!("  laser: {}{}", d.laser, show(&d.laser_pty)));
    say.line(&format!(
        "  base:  {}{} ({})",
        d.base,
        show(&d.base_pty),
        d.platform.driver_role()
    ));
    say.line(&format!("  smoke: {}{}", d.smoke, show(&d.smoke_pty)));
    let mut driver_profile = profile.clone();
    driver_profile.laser.port = d.laser.clone();
    driver_profile.base.port = d.base.clone();
    driver_profile.smoke.port = d.smoke.clone();
    driver_profile.smoke.backend = Some(smokenav_platform_config::AdcBackend::Serial);
    driver_profile.robot.instance = instance.clone();
    let profile_path = out.join("robot.toml");
    std::fs::write(&profile_path, driver_profile.to_toml())
        .with_context(|| format!("cannot write {}", profile_path.display()))?;

    // The processes, as smokenav.target would run them.
    let base_role = d.platform.driver_role();
    let need = |name: &str| {
        sibling(name).with_context(|| {
            format!("{name} is not built next to this smokenav-lab binary (run `cargo build --release --workspace --bins`)")
        })
    };
    let drivers = [
        ("hokuyo", need("smokenav-hokuyo")?),
        (base_role, need(&format!("smokenav-{base_role}"))?),
        ("smoke", need("smokenav-smoke")?),
    ];
    let fusion_bin = need("smokenav-fusion")?;
    let slam_bin = sibling("smokenav-slam");

    let bus = Bus::open(
        &BusOptions::new(&instance, "demo").with_root_path(profile.bus.root_path.clone()),
    )?;
    let truth_map = link.world().truth_map();

    // The world runs on its own thread once everything is up.
    let (go_tx, go_rx) = mpsc::channel::<bool>();
    let stop = Arc::new(AtomicBool::new(false));
    let done = Arc::new(AtomicBool::new(false));
    let progress: Arc<Mutex<Option<Progress>>> = Arc::new(Mutex::new(None));
    let sim_thread = {
        let (stop, done, progress) = (stop.clone(), done.clone(), progress.clone());
        let instance = instance.clone();
        let root = profile.bus.root_path.clone();
        let mut link = link;
        std::thread::Builder::new()
            .name("simlink".into())
            .spawn(move || -> SimResult {
                if !matches!(go_rx.recv(), Ok(true)) {
                    done.store(true, Ordering::SeqCst);
                    return (link, None, None);
                }
                let publisher =
                    Bus::open(&BusOptions::new(&instance, "simlink").with_root_path(root))
                        .and_then(|b| TruthPublisher::new(&b).map(|p| (b, p)));
                let (_bus, mut publisher) = match publisher {
                    Ok(x) => x,
                    Err(e) => {
                        done.store(true, Ordering::SeqCst);
                        return (link, None, Some(format!("cannot publish sim/truth: {e}")));
                    }
                };
                let summary = link.run(
                    until,
                    &|| stop.load(Ordering::Relaxed),
                    &mut |s, host| {
                        let _ = publisher.publish(s, host);
                    },
                    &mut |p| {
                        if let Ok(mut g) = progress.lock() {
                            *g = Some(*p);
                        }
                    },
                );
                done.store(true, Ordering::SeqCst);
                (link, Some(summary), None)
            })
            .context("cannot start the simulator thread")?
    };

    let mut procs: Vec<Proc> = Vec::new();
    let started = (|| -> anyhow::Result<()> {
        say.line("  starting the drivers …");
        for (role, bin) in &drivers {
            procs.push(Proc::spawn(bin, role, &profile_path, &instance, &logs)?);
        }
        wait_ready(&bus, &mut procs, say, &shutdown)?;
        procs.push(Proc::spawn(
            &fusion_bin,
            "fusion",
            &profile_path,
            &instance,
            &logs,
        )?);
        let n = procs.len();
        wait_ready(&bus, &mut procs[n - 1..], say, &shutdown)?;
        match &slam_bin {
            Some(bin) => {
                procs.push(Proc::spawn(bin, "slam", &profile_path, &instance, &logs)?);
                let n = procs.len();
                wait_ready(&bus, &mut procs[n - 1..], say, &shutdown)?;
            }
            None => say.line("  slam    not built (no smokenav-slam next to this binary): the live run goes without the SLAM process"),
        }
        Ok(())
    })();
    if let Err(e) = started {
        let _ = go_tx.send(false);
        for p in procs.iter_mut().rev() {
            p.stop();
        }
        let _ = sim_thread.join();
        let _ = std::fs::remove_dir_all(&dev_dir);
        return Err(e);
    }

    // Record and watch while the world runs.
    let rec_path = out.join("recording.mcap");
    let mut meta = super::metadata(scenario, "live run");
    meta.insert("instance".into(), instance.clone());
    let mut rec = create_recorder(&rec_path, &driver_profile, &meta, monotonic_now_ns())?;
    let taps = Taps::new(&bus)?;
    let waiter = Waiter::new()?;
    let _guards = taps.attach(&waiter)?;
    let _ = go_tx.send(true);
    say.line(&format!("  running {} …", scenario.name));
    let mut status = Status::default();
    let mut last_line = Instant::now();
    let mut interrupted = false;
    let mut failure: Option<String> = None;
    let mut finished_at: Option<Instant> = None;
    let mut rec_error: Option<String> = None;
    loop {
        waiter.wait(Some(Duration::from_millis(100)))?;
        // Record from the world's start to its end (the devices idle before and after).
        let window = progress.lock().ok().and_then(|g| {
            g.as_ref().map(|p| {
                let end = done
                    .load(Ordering::SeqCst)
                    .then(|| p.timebase.sim_to_host((p.sim_s * 1e9) as u64));
                (p.timebase.t0_host_ns, end)
            })
        });
        taps.drain(&mut status, &mut rec, window, &mut rec_error)?;
        if last_line.elapsed() >= Duration::from_secs(1) {
            status.roll();
            let p = progress.lock().ok().and_then(|g| *g);
            say.status(&status.line(p.as_ref(), scenario.duration_s));
            last_line = Instant::now();
        }
        if shutdown.requested() {
            interrupted = true;
            stop.store(true, Ordering::SeqCst);
            break;
        }
        for p in procs.iter_mut() {
            if let Some(s) = p.exited() {
                failure = Some(format!(
                    "smokenav-{} exited ({s}) during the run; end of {}:\n{}",
                    p.role,
                    p.log.display(),
                    p.log_tail()
                ));
            }
        }
        if failure.is_some() || rec_error.is_some() {
            stop.store(true, Ordering::SeqCst);
            break;
        }
        if done.load(Ordering::SeqCst) {
            // Let the last messages through the processes.
            let at = *finished_at.get_or_insert_with(Instant::now);
            if at.elapsed() > Duration::from_millis(500) {
                break;
            }
        }
    }
    say.end_status();
    let (link, summary, sim_error) = sim_thread
        .join()
        .map_err(|_| anyhow::anyhow!("the simulator thread panicked"))?;
    say.line("  stopping the processes …");
    for p in procs.iter_mut().rev() {
        let s = p.stop();
        if !interrupted && failure.is_none() && !s.is_some_and(|s| s.success()) {
            say.line(&format!(
                "  warning: smokenav-{} did not exit cleanly ({s:?}); see {}",
                p.role,
                p.log.display()
            ));
        }
    }
    let (_, stats) = rec
        .finish(None)
        .with_context(|| format!("cannot finish {}", rec_path.display()))?;
    let truth = link.truth().clone();
    drop(link);
    let _ = std::fs::remove_dir_all(&dev_dir);
    if let Some(e) = failure.or(sim_error).or(rec_error) {
        bail!(e);
    }
    let sim_s = summary.map_or(0.0, |s| s.sim_s);
    if let Some(s) = summary {
        say.line(&format!(
            "  ran {:.1} s of the scenario in {:.1} s; {} laser scans fed ({} off the sensor's timing, {} without a world frame); {} loop stalls",
            s.sim_s,
            s.wall.as_secs_f64(),
            s.laser.fed,
            s.laser.misaligned,
            s.laser.empty,
            s.overruns
        ));
    }
    say.line(&format!(
        "  recorded {} messages ({:.1} MB): {}",
        stats.messages,
        stats.bytes as f64 / 1e6,
        rec_path.display()
    ));
    Ok(LiveOutcome {
        recording: rec_path,
        truth,
        truth_map,
        sim_s,
        interrupted,
    })
}

/// The recorded topics' subscribers.
struct Taps {
    laser: Subscriber<LaserScan>,
    sonar: Subscriber<SonarRing>,
    odom: Subscriber<Odometry>,
    smoke: Subscriber<SmokeReading>,
    fused: Subscriber<FusedScan>,
    pose: Subscriber<PoseEstimate>,
}

impl Taps {
    fn new(bus: &Bus) -> anyhow::Result<Self> {
        Ok(Self {
            laser: bus.subscriber(topics::LASER_SCAN)?,
            sonar: bus.subscriber(topics::BASE_SONAR)?,
            odom: bus.subscriber(topics::BASE_ODOM)?,
            smoke: bus.subscriber(topics::SMOKE_LEVEL)?,
            fused: bus.subscriber(topics::FUSION_SCAN)?,
            pose: bus.subscriber(topics::SLAM_POSE)?,
        })
    }

    fn attach<'w>(
        &'w self,
        w: &'w Waiter,
    ) -> anyhow::Result<Vec<smokenav_platform_bus::Attachment<'w, 'w>>> {
        Ok(vec![
            w.attach(&self.laser)?,
            w.attach(&self.sonar)?,
            w.attach(&self.odom)?,
            w.attach(&self.smoke)?,
            w.attach(&self.fused)?,
            w.attach(&self.pose)?,
        ])
    }

    /// Records what arrived stamped within `window` (the world's start, and
    /// its end once known) and updates the status.
    fn drain(
        &self,
        st: &mut Status,
        rec: &mut Recorder<BufWriter<File>>,
        window: Option<(u64, Option<u64>)>,
        error: &mut Option<String>,
    ) -> anyhow::Result<()> {
        let inside = |stamp: u64| {
            window.is_some_and(|(t0, end)| stamp >= t0 && end.is_none_or(|e| stamp < e))
        };
        let mut put = |i: usize, stamp: u64, msg: AnyMessageRef| {
            st.counts[i] += 1;
            if inside(stamp)
                && error.is_none()
                && let Err(e) = rec.record(TAPPED[i], msg, monotonic_now_ns())
            {
                *error = Some(format!("recording failed: {e}"));
            }
        };
        while let Some(s) = self.laser.receive()? {
            put(0, s.header.stamp_ns, AnyMessageRef::LaserScan(&s));
        }
        while let Some(s) = self.sonar.receive()? {
            put(1, s.header.stamp_ns, AnyMessageRef::SonarRing(&s));
        }
        while let Some(s) = self.odom.receive()? {
            put(2, s.header.stamp_ns, AnyMessageRef::Odometry(&s));
        }
        while let Some(s) = self.smoke.receive()? {
            put(3, s.header.stamp_ns, AnyMessageRef::SmokeReading(&s));
            st.smoke = Some(*s);
        }
        while let Some(s) = self.fused.receive()? {
            put(4, s.scan.header.stamp_ns, AnyMessageRef::FusedScan(&s));
            st.fused = Some(Box::new(*s));
        }
        while let Some(s) = self.pose.receive()? {
            put(5, s.header.stamp_ns, AnyMessageRef::PoseEstimate(&s));
            st.pose = Some(*s);
        }
        Ok(())
    }
}
