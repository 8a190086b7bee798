//! The end-to-end test kit.
//!
//! Tests here run the real binaries as separate OS processes over real
//! iceoryx2 shared memory (and real PTYs, via the device emulators). This
//! crate's library gives them:
//!
//! - [`bin`]: the path of a workspace binary, built on first use so a plain
//!   `cargo test` never runs a stale one;
//! - [`unique_instance`]: a bus instance name no other test (or robot) uses;
//! - [`Child`]: a spawned process that is killed when the test ends, with its
//!   output captured for the failure message;
//! - [`profile`]: a robot profile based on a shipped one, modified and written
//!   to a temporary file;
//! - [`wait_for`]: receive messages of a topic until a predicate holds or a timeout passes;
//! - [`csail_prefix`], [`fill_carmen_scan`], [`carmen_odometry`]: the real
//!   robot log the SLAM tests replay, as bus messages; [`pose_for_scan`]:
//!   the SLAM process's answer to one of them.

use anyhow::{Context, bail};
use smokenav_algorithms_slam::carmen::{CarmenReader, LaserRecord, Record};
use smokenav_platform_bus::{
    Bus, BusOptions, Message, Publisher, Subscriber, Topic, Waiter, topics,
};
use smokenav_platform_config::RobotConfig;
use smokenav_shared_types::{
    BeamReading, FusedScan, Header, Health, LaserScan, Odometry, PoseEstimate,
};
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::mpsc;
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

/// The workspace root.
pub fn workspace_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ has a parent")
        .to_owned()
}

/// Where cargo put this test's binaries (`target/<profile>/`).
fn target_profile_dir() -> PathBuf {
    // The test executable lives in target/<profile>/deps/.
    let exe = std::env::current_exe().expect("current_exe");
    exe.parent()
        .and_then(Path::parent)
        .expect("test binary in target/<profile>/deps")
        .to_owned()
}

static BUILT: OnceLock<Result<(), String>> = OnceLock::new();

/// Path of the workspace binary `name` (e.g. `smokenav-hokuyo`). The first call
/// in a test process runs `cargo build --bins` for the workspace, so tests
/// always run the current code; later calls are free.
pub fn bin(name: &str) -> PathBuf {
    let built = BUILT.get_or_init(|| {
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let mut cmd = Command::new(cargo);
        cmd.current_dir(workspace_root())
            .args(["build", "--workspace", "--bins", "--quiet"]);
        if target_profile_dir().ends_with("release") {
            cmd.arg("--release");
        }
        match cmd.status() {
            Ok(s) if s.success() => Ok(()),
            Ok(s) => Err(format!("cargo build --bins failed: {s}")),
            Err(e) => Err(format!("cannot run cargo: {e}")),
        }
    });
    if let Err(e) = built {
        panic!("{e}");
    }
    let path = target_profile_dir().join(name);
    assert!(path.exists(), "binary {} was not built", path.display());
    path
}

/// A bus instance name unique to this test run and process.
pub fn unique_instance(test: &str) -> String {
    static COUNTER: AtomicU32 = AtomicU32::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let mut name: String = test
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .take(20)
        .collect();
    name.push_str(&format!("_{}_{n}", std::process::id()));
    name
}

/// Opens the bus for `instance` in this (test) process.
pub fn open_bus(instance: &str) -> Bus {
    Bus::open(&BusOptions::new(instance, "test")).expect("open bus")
}

/// Receives `topic` until `done` returns true for a message, or `timeout`.
/// Returns every message received (copied out of shared memory).
pub fn wait_for<T: Message>(
    bus: &Bus,
    topic: Topic<T>,
    timeout: Duration,
    mut done: impl FnMut(&T) -> bool,
) -> anyhow::Result<Vec<T>> {
    let sub = bus.subscriber(topic.clone())?;
    let waiter = Waiter::new()?;
    let _g = waiter.attach(&sub)?;
    let end = Instant::now() + timeout;
    let mut got = Vec::new();
    loop {
        while let Some(s) = sub.receive()? {
            let msg: T = *s;
            let finished = done(&msg);
            got.push(msg);
            if finished {
                return Ok(got);
            }
        }
        let now = Instant::now();
        if now >= end {
            bail!(
                "timed out after {timeout:?} waiting on {topic} ({} messages received)",
                got.len()
            );
        }
        waiter.wait(Some((end - now).min(Duration::from_millis(200))))?;
    }
}

/// A child process killed (SIGKILL) when dropped; stdout and stderr are
/// collected in the background and shown if the test fails.
pub struct Child {
    pub name: String,
    child: std::process::Child,
    output: std::sync::Arc<Mutex<String>>,
    lines: mpsc::Receiver<String>,
}

impl Child {
    /// Spawns `program` with `args` as [`smokenav_platform_runtime::launch::command`]
    /// prepares it (`SMOKENAV_INSTANCE=instance`, `RUST_LOG`, no `NOTIFY_SOCKET`).
    pub fn spawn(program: &Path, args: &[&str], instance: &str) -> anyhow::Result<Self> {
        Self::spawn_env(program, args, instance, &[])
    }

    pub fn spawn_env(
        program: &Path,
        args: &[&str],
        instance: &str,
        env: &[(&str, &str)],
    ) -> anyhow::Result<Self> {
        let mut cmd = smokenav_platform_runtime::launch::command(program, instance);
        cmd.args(args).stdout(Stdio::piped()).stderr(Stdio::piped());
        for (k, v) in env {
            cmd.env(k, v);
        }
        let mut child = cmd
            .spawn()
            .with_context(|| format!("cannot start {}", program.display()))?;
        let output = std::sync::Arc::new(Mutex::new(String::new()));
        let (tx, lines) = mpsc::channel();
        let name = program
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        for stream in [
            child
                .stdout
                .take()
                .map(|s| Box::new(s) as Box<dyn Read + Send>),
            child
                .stderr
                .take()
                .map(|s| Box::new(s) as Box<dyn Read + Send>),
        ]
        .into_iter()
        .flatten()
        {
            let output = output.clone();
            let tx = tx.clone();
            std::thread::spawn(move || {
                for line in BufReader::new(stream).lines().map_while(Result::ok) {
                    if let Ok(mut o) = output.lock() {
                        o.push_str(&line);
                        o.push('\n');
                    }
                    let _ = tx.send(line);
                }
            });
        }
        Ok(Self {
            name,
            child,
            output,
            lines,
        })
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Everything the process printed so far.
    pub fn output(&self) -> String {
        self.output.lock().map(|o| o.clone()).unwrap_or_default()
    }

    /// Waits for an output line containing `needle`; returns that line.
    pub fn wait_for_line(&self, needle: &str, timeout: Duration) -> anyhow::Result<String> {
        let end = Instant::now() + timeout;
        loop {
            let left = end.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(line) if line.contains(needle) => return Ok(line),
                Ok(_) => {}
                Err(_) => bail!(
                    "{}: no line containing {needle:?} within {timeout:?}; output:\n{}",
                    self.name,
                    self.output()
                ),
            }
        }
    }

    /// Sends a signal (e.g. SIGTERM for a clean stop, SIGKILL for a crash).
    pub fn signal(&self, sig: nix::sys::signal::Signal) {
        let _ = nix::sys::signal::kill(nix::unistd::Pid::from_raw(self.child.id() as i32), sig);
    }

    /// Waits for the process to exit and returns its status.
    pub fn wait_exit(&mut self, timeout: Duration) -> anyhow::Result<std::process::ExitStatus> {
        let end = Instant::now() + timeout;
        loop {
            if let Some(status) = self.child.try_wait()? {
                return Ok(status);
            }
            if Instant::now() >= end {
                bail!(
                    "{} did not exit within {timeout:?}; output:\n{}",
                    self.name,
                    self.output()
                );
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Stops the process with SIGTERM and waits for it.
    pub fn terminate(&mut self, timeout: Duration) -> anyhow::Result<std::process::ExitStatus> {
        self.signal(nix::sys::signal::Signal::SIGTERM);
        self.wait_exit(timeout)
    }

    pub fn is_running(&mut self) -> bool {
        matches!(self.child.try_wait(), Ok(None))
    }
}

impl Drop for Child {
    fn drop(&mut self) {
        if self.is_running() {
            self.signal(nix::sys::signal::Signal::SIGKILL);
            let _ = self.child.wait();
        }
        if std::thread::panicking() {
            eprintln!("--- output of {} ---\n{}", self.name, self.output());
        }
    }
}

/// Loads a shipped profile (e.g. `pioneer-3dx.toml`), lets the test change it,
/// and writes it to a file in `dir`. Returns the file's path.
pub fn profile(dir: &Path, shipped: &str, edit: impl FnOnce(&mut RobotConfig)) -> PathBuf {
    let src = workspace_root().join("config").join(shipped);
    let mut cfg = RobotConfig::load(&src).unwrap_or_else(|e| panic!("{e}"));
    edit(&mut cfg);
    let path = dir.join(format!("test-{shipped}"));
    std::fs::write(&path, cfg.to_toml()).expect("write profile");
    path
}

/// A Python interpreter that has the independent readers the tests check
/// smokenav's files against (`tests/python/requirements.txt`): a virtual
/// environment under `target/`, created and filled by the first test that
/// needs it (other test processes wait on a lock), so `cargo test` alone works
/// on a fresh machine. `SMOKENAV_PYTHON` names another interpreter instead.
/// Panics with the reason when it cannot be set up: these checks are never
/// skipped.
pub fn python() -> PathBuf {
    static PYTHON: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    PYTHON
        .get_or_init(|| {
            if let Ok(p) = std::env::var("SMOKENAV_PYTHON") {
                return Ok(PathBuf::from(p));
            }
            prepare_venv()
        })
        .clone()
        .unwrap_or_else(|e| panic!("{e}"))
}

fn prepare_venv() -> Result<PathBuf, String> {
    let requirements = workspace_root().join("tests/python/requirements.txt");
    let wanted = std::fs::read_to_string(&requirements)
        .map_err(|e| format!("cannot read {}: {e}", requirements.display()))?;
    // target/<profile>/.. is target/, shared by debug and release test runs.
    let target = target_profile_dir()
        .parent()
        .map(Path::to_owned)
        .ok_or("no target folder")?;
    let venv = target.join("python-venv");
    let stamp = venv.join("smokenav-requirements.txt");
    let interpreter = venv.join("bin/python");
    let ready = || std::fs::read_to_string(&stamp).is_ok_and(|s| s == wanted);
    if ready() {
        return Ok(interpreter);
    }
    std::fs::create_dir_all(&target)
        .map_err(|e| format!("cannot create {}: {e}", target.display()))?;
    let lock_path = target.join("python-venv.lock");
    let lock_file = std::fs::File::create(&lock_path)
        .map_err(|e| format!("cannot create {}: {e}", lock_path.display()))?;
    let _lock = nix::fcntl::Flock::lock(lock_file, nix::fcntl::FlockArg::LockExclusive)
        .map_err(|(_, e)| format!("cannot lock {}: {e}", lock_path.display()))?;
    if ready() {
        return Ok(interpreter);
    }
    let base = std::env::var("PYTHON3").unwrap_or_else(|_| "python3".into());
    let run = |cmd: &mut Command, what: &str| -> Result<(), String> {
        let out = cmd
            .output()
            .map_err(|e| format!("{what}: cannot run {:?}: {e}", cmd.get_program()))?;
        if out.status.success() {
            Ok(())
        } else {
            Err(format!(
                "{what} failed ({}):\n{}{}",
                out.status,
                String::from_utf8_lossy(&out.stdout),
                String::from_utf8_lossy(&out.stderr)
            ))
        }
    };
    if !interpreter.exists() {
        run(
            Command::new(&base).args(["-m", "venv"]).arg(&venv),
            &format!(
                "creating the test Python environment {} (Debian: apt-get install python3-venv)",
                venv.display()
            ),
        )?;
    }
    run(
        Command::new(&interpreter)
            .args([
                "-m",
                "pip",
                "install",
                "--quiet",
                "--disable-pip-version-check",
                "-r",
            ])
            .arg(&requirements),
        &format!(
            "installing {} into {}",
            requirements.display(),
            venv.display()
        ),
    )?;
    std::fs::write(&stamp, &wanted)
        .map_err(|e| format!("cannot write {}: {e}", stamp.display()))?;
    Ok(interpreter)
}

fn have_bt2vrml() -> bool {
    std::process::Command::new("sh")
        .args(["-c", "command -v bt2vrml"])
        .output()
        .is_ok_and(|o| o.status.success())
}

/// OctoMap's `bt2vrml` is on the PATH, installed from Debian's
/// `octomap-tools` when missing and running as root (`./test` installs it).
pub fn ensure_octomap_tools() -> bool {
    if have_bt2vrml() {
        return true;
    }
    if !nix::unistd::Uid::effective().is_root() {
        return false;
    }
    let setup = workspace_root().join("tests/setup/machine.sh");
    let st = std::process::Command::new("bash")
        .arg("-c")
        .arg(format!(
            ". '{}' && install_debian_packages octomap-tools",
            setup.display()
        ))
        .status()
        .expect("bash runs");
    st.success() && have_bt2vrml()
}

/// CARMEN max-range readings are 81.91: beyond the scan's `range_max`, i.e. no return.
pub const CARMEN_RANGE_MAX: f32 = 81.9;

/// The MIT CSAIL log's first 200 laser records, a CARMEN file.
pub fn csail_prefix_path() -> PathBuf {
    workspace_root().join("daemon/algorithms/slam/tests/data/csail-prefix-200.clf")
}

/// The first 200 laser records (odometry and scan each) of the MIT CSAIL
/// log: the real robot input the SLAM tests replay.
pub fn csail_prefix() -> Vec<LaserRecord> {
    let path = csail_prefix_path();
    let file = std::fs::File::open(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    CarmenReader::new(BufReader::new(file))
        .filter_map(|r| match r {
            Ok(Record::Laser(l)) => Some(l),
            _ => None,
        })
        .collect()
}

/// `rec`'s scan as the laser driver publishes it, stamped `stamp_ns`
/// (readings at or past [`CARMEN_RANGE_MAX`] are no return).
pub fn fill_carmen_scan(s: &mut LaserScan, rec: &LaserRecord, stamp_ns: u64) {
    s.header = Header::new(stamp_ns, 0, "laser");
    s.angle_min = rec.start_angle as f32;
    s.angle_increment = rec.angular_resolution as f32;
    s.range_min = 0.02;
    s.range_max = CARMEN_RANGE_MAX;
    s.count = rec.ranges.len() as u32;
    s.has_intensities = 0;
    for (i, &r) in rec.ranges.iter().enumerate() {
        let beam = if r > 0.0 && r < CARMEN_RANGE_MAX {
            BeamReading::Range(r)
        } else {
            BeamReading::BeyondMax
        };
        s.set_beam(i, beam);
    }
}

/// `rec`'s odometry as the base driver publishes it, stamped `stamp_ns`.
pub fn carmen_odometry(rec: &LaserRecord, stamp_ns: u64) -> Odometry {
    Odometry {
        header: Header::new(stamp_ns, 0, "odom"),
        x: rec.robot_pose.x,
        y: rec.robot_pose.y,
        theta: rec.robot_pose.theta,
        ..Default::default()
    }
}

/// Waits up to 30 s for the `slam/pose` of the scan stamped `stamp_ns`
/// (`waiter` has `poses` attached); earlier poses are passed over.
pub fn pose_for_scan(
    poses: &Subscriber<PoseEstimate>,
    waiter: &Waiter,
    stamp_ns: u64,
) -> anyhow::Result<PoseEstimate> {
    let end = Instant::now() + Duration::from_secs(30);
    loop {
        while let Some(p) = poses.receive()? {
            if p.header.stamp_ns == stamp_ns {
                return Ok(*p);
            }
        }
        let now = Instant::now();
        anyhow::ensure!(now < end, "no slam/pose for the scan stamped {stamp_ns}");
        waiter.wait(Some((end - now).min(Duration::from_millis(200))))?;
    }
}

/// The next health report of `sub` that `done` accepts, within 15 s.
pub fn health_until(
    sub: &Subscriber<Health>,
    waiter: &Waiter,
    what: &str,
    mut done: impl FnMut(&Health) -> bool,
) -> Health {
    let end = Instant::now() + Duration::from_secs(15);
    let mut last = None;
    loop {
        while let Some(h) = sub.receive().unwrap() {
            let h: Health = *h;
            if done(&h) {
                return h;
            }
            last = Some(h);
        }
        let now = Instant::now();
        assert!(
            now < end,
            "no health report {what}; last: {:?} `{}`",
            last.map(|h| h.state()),
            last.map_or(String::new(), |h| h.last_error.as_str().to_owned())
        );
        waiter
            .wait(Some((end - now).min(Duration::from_millis(200))))
            .unwrap();
    }
}

/// A fused scan at `stamp` with the layout of a laser over ±90° in
/// `beams` beams (0.02–5.6 m) and nothing in it yet: the tests fill its
/// beams, sources and sections.
pub fn half_circle_fused(stamp: u64, beams: usize) -> FusedScan {
    let mut f = FusedScan::default();
    let s = &mut f.scan;
    s.header = Header::new(stamp, 0, "laser");
    s.angle_min = -std::f32::consts::FRAC_PI_2;
    s.angle_increment = std::f32::consts::PI / (beams - 1) as f32;
    s.range_min = 0.02;
    s.range_max = 5.6;
    s.count = beams as u32;
    f
}

/// `smokenav-slam` with the graph back-end on fused scans (the profile at
/// `config` with `[slam] input = "fused"`), and the bus ends a test drives
/// it through.
pub struct FusedSlam {
    pub process: Child,
    pub odom: Publisher<Odometry>,
    pub scans: Publisher<FusedScan>,
    pub poses: Subscriber<PoseEstimate>,
    pub health: Subscriber<Health>,
    _bus: Bus,
}

impl FusedSlam {
    pub fn spawn(config: &Path, instance: &str) -> Self {
        let process = Child::spawn(
            &bin("smokenav-slam"),
            &["--config", config.to_str().unwrap(), "--backend", "graph"],
            instance,
        )
        .unwrap();
        process
            .wait_for_line("graph on fusion/scan", Duration::from_secs(30))
            .unwrap_or_else(|e| panic!("{e}\n{}", process.output()));
        let bus = open_bus(instance);
        Self {
            odom: bus.publisher(topics::BASE_ODOM).unwrap(),
            scans: bus.publisher(topics::FUSION_SCAN).unwrap(),
            poses: bus.subscriber(topics::SLAM_POSE).unwrap(),
            health: bus.subscriber(topics::health("slam")).unwrap(),
            process,
            _bus: bus,
        }
    }

    /// Stops the process; it must exit cleanly.
    pub fn terminate(mut self) {
        let status = self.process.terminate(Duration::from_secs(10)).unwrap();
        assert!(status.success(), "{status:?}\n{}", self.process.output());
    }
}
