//! One member of the vote: a back-end on its own thread, fed through a
//! bounded queue. The thread that feeds it never waits (except in lockstep,
//! where it waits up to the stall timeout): a full queue drops the job and
//! counts it. A panic inside the back-end is caught and ends the member; a job
//! that takes longer than the stall timeout marks it stalled.

use crate::backend::{SlamBackend, SlamUpdate, StampedPose};
use crate::frontend::Tracked;
use crate::graph::saved::SavedGraphError;
use crate::scan::RangeScan;
use smokenav_platform_config::SlamBackendKind;
use smokenav_platform_map::OccupancyGrid;
use smokenav_shared_types::Pose2;
use std::panic::AssertUnwindSafe;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// A fault injected into one member, for tests of the vote's resilience
/// (`SMOKENAV_TEST_VOTE_FAULT=member:stall|panic:after_scans` on `smokenav-slam`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MemberFault {
    pub member: SlamBackendKind,
    pub kind: FaultKind,
    /// Scans the member processes normally first.
    pub after_scans: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultKind {
    /// The member hangs inside a scan (until the vote is dropped).
    Stall,
    /// The member panics inside a scan.
    Panic,
}

impl std::str::FromStr for MemberFault {
    type Err = String;
    /// `graph:stall:40`, `fuzzy:panic:10`.
    fn from_str(s: &str) -> Result<Self, String> {
        let parts: Vec<&str> = s.split(':').collect();
        let [m, k, n] = parts[..] else {
            return Err(format!(
                "expected member:stall|panic:after_scans, got {s:?}"
            ));
        };
        let member = match m {
            "rbpf" => SlamBackendKind::Rbpf,
            "graph" => SlamBackendKind::Graph,
            "fuzzy" => SlamBackendKind::Fuzzy,
            other => return Err(format!("unknown member {other:?} in {s:?}")),
        };
        let kind = match k {
            "stall" => FaultKind::Stall,
            "panic" => FaultKind::Panic,
            other => return Err(format!("unknown fault {other:?} in {s:?} (stall or panic)")),
        };
        let after_scans = n
            .parse()
            .map_err(|_| format!("after_scans {n:?} in {s:?} is not a count"))?;
        Ok(Self {
            member,
            kind,
            after_scans,
        })
    }
}

pub(crate) enum Job {
    /// A scan, its corrected odometry and the pipeline's front-end match of
    /// it (handed to the member's `frontend_match` first: the graph takes it
    /// instead of matching the scan again).
    Process(Arc<RangeScan>, Pose2, Option<Tracked>),
    Predict(u64, Pose2, Option<Tracked>),
    /// Export the map now (lockstep: before a fused update).
    Export,
    Trajectory(SyncSender<Vec<StampedPose>>),
    InitialPose(Pose2),
    /// Save the member's pose graph there ([`SlamBackend::save_graph`]).
    SaveGraph(PathBuf, SyncSender<Option<Result<(), SavedGraphError>>>),
}

/// What the member's thread shares with the vote.
#[derive(Default)]
pub(crate) struct MemberState {
    /// The member's last update and the (corrected) odometry it was given with.
    pub update: Option<(SlamUpdate, Pose2)>,
    /// The back-end's `map_revision` after its last job.
    pub revision: u64,
    /// The last exported map and the revision it was exported at.
    pub map: Option<(Arc<OccupancyGrid>, u64)>,
    /// Its obstacles out of the laser plane, exported with `map` (a member
    /// that maps in height; see [`SlamBackend::out_of_plane_map`]).
    pub below: Option<Arc<OccupancyGrid>>,
    /// Why the thread ended, if it panicked.
    pub panicked: Option<String>,
    /// Jobs finished.
    pub done: u64,
}

pub(crate) struct Shared {
    pub state: Mutex<MemberState>,
    pub changed: Condvar,
    /// Milliseconds since `epoch` + 1 at which the current job started; 0 idle.
    pub busy_since_ms: AtomicU64,
    pub reset: AtomicBool,
    pub shutdown: AtomicBool,
    pub epoch: Instant,
}

impl Shared {
    pub fn lock(&self) -> MutexGuard<'_, MemberState> {
        // A panic is caught before it can poison the lock; recover anyway.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn now_ms(&self) -> u64 {
        self.epoch.elapsed().as_millis() as u64 + 1
    }

    /// How long the current job has been running, if one is.
    pub fn busy_for(&self) -> Option<Duration> {
        match self.busy_since_ms.load(Ordering::Acquire) {
            0 => None,
            t => Some(Duration::from_millis(self.now_ms().saturating_sub(t))),
        }
    }
}

pub(crate) struct Member {
    pub name: &'static str,
    tx: Option<SyncSender<Job>>,
    pub shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
    /// Jobs handed over (not dropped).
    sent: AtomicU64,
    /// Jobs dropped because the queue was full.
    drops: AtomicU64,
    /// Lockstep: the member missed the stall timeout and is fed no more.
    given_up: AtomicBool,
}

pub(crate) struct WorkerConfig {
    pub queue: usize,
    pub export_period: Duration,
    pub fault: Option<MemberFault>,
    /// [`BackendOptions::footprint_m`](crate::backend::BackendOptions::footprint_m).
    pub footprint_m: f64,
}

impl Member {
    pub fn spawn(backend: Box<dyn SlamBackend>, cfg: WorkerConfig) -> std::io::Result<Self> {
        let name = backend.name();
        let (tx, rx) = std::sync::mpsc::sync_channel(cfg.queue);
        let shared = Arc::new(Shared {
            state: Mutex::new(MemberState::default()),
            changed: Condvar::new(),
            busy_since_ms: AtomicU64::new(0),
            reset: AtomicBool::new(false),
            shutdown: AtomicBool::new(false),
            epoch: Instant::now(),
        });
        let s = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name(format!("vote-{name}"))
            .spawn(move || worker(backend, rx, &s, &cfg))?;
        Ok(Self {
            name,
            tx: Some(tx),
            shared,
            thread: Some(thread),
            sent: AtomicU64::new(0),
            drops: AtomicU64::new(0),
            given_up: AtomicBool::new(false),
        })
    }

    /// Queues a job without waiting; false (and counted) when the queue is full.
    pub fn offer(&self, job: Job) -> bool {
        let Some(tx) = &self.tx else { return false };
        match tx.try_send(job) {
            Ok(()) => {
                self.sent.fetch_add(1, Ordering::AcqRel);
                true
            }
            Err(TrySendError::Full(_)) => {
                self.drops.fetch_add(1, Ordering::AcqRel);
                false
            }
            // The thread ended (panicked): its state says why.
            Err(TrySendError::Disconnected(_)) => false,
        }
    }

    /// Lockstep: queues a job, waiting up to `timeout` for room.
    pub fn send_within(&self, job: Job, timeout: Duration) -> bool {
        let deadline = Instant::now() + timeout;
        let mut job = job;
        loop {
            let Some(tx) = &self.tx else { return false };
            match tx.try_send(job) {
                Ok(()) => {
                    self.sent.fetch_add(1, Ordering::AcqRel);
                    return true;
                }
                Err(TrySendError::Disconnected(_)) => return false,
                Err(TrySendError::Full(j)) => {
                    if Instant::now() >= deadline {
                        self.drops.fetch_add(1, Ordering::AcqRel);
                        return false;
                    }
                    job = j;
                    let st = self.shared.lock();
                    let _ = self
                        .shared
                        .changed
                        .wait_timeout(st, Duration::from_millis(20));
                }
            }
        }
    }

    /// Lockstep: waits until every job sent is done (or the member ended), up to `timeout`.
    pub fn wait_idle(&self, timeout: Duration) -> bool {
        let deadline = Instant::now() + timeout;
        let mut st = self.shared.lock();
        loop {
            if st.done >= self.sent.load(Ordering::Acquire) || st.panicked.is_some() {
                return true;
            }
            let now = Instant::now();
            if now >= deadline {
                return false;
            }
            st = self
                .shared
                .changed
                .wait_timeout(st, deadline - now)
                .map(|(g, _)| g)
                .unwrap_or_else(|e| e.into_inner().0);
        }
    }

    pub fn drops(&self) -> u64 {
        self.drops.load(Ordering::Acquire)
    }

    pub fn given_up(&self) -> bool {
        self.given_up.load(Ordering::Acquire)
    }

    pub fn give_up(&self) {
        self.given_up.store(true, Ordering::Release);
    }

    pub fn request_reset(&self) {
        self.shared.reset.store(true, Ordering::Release);
    }
}

impl Drop for Member {
    fn drop(&mut self) {
        self.shared.shutdown.store(true, Ordering::Release);
        self.tx = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn panic_message(e: &(dyn std::any::Any + Send)) -> String {
    e.downcast_ref::<&str>()
        .map(|s| (*s).to_owned())
        .or_else(|| e.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "panicked".to_owned())
}

fn worker(
    mut backend: Box<dyn SlamBackend>,
    rx: Receiver<Job>,
    shared: &Shared,
    cfg: &WorkerConfig,
) {
    let mut processed = 0u64;
    let mut last_export: Option<Instant> = None;
    let fault = cfg.fault.filter(|f| backend.name() == f.member.as_str());
    loop {
        let job = match rx.recv_timeout(cfg.export_period) {
            Ok(j) => Some(j),
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => None,
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => break,
        };
        if shared.shutdown.load(Ordering::Acquire) {
            break;
        }
        shared
            .busy_since_ms
            .store(shared.now_ms(), Ordering::Release);
        let force_export = matches!(job, Some(Job::Export));
        let is_job = job.is_some();
        let result = std::panic::catch_unwind(AssertUnwindSafe(|| {
            if shared.reset.swap(false, Ordering::AcqRel) {
                backend.odometry_reset();
            }
            let update = match job {
                Some(Job::Process(scan, odom, tracked)) => {
                    processed += 1;
                    if let Some(f) = fault
                        && processed > f.after_scans
                    {
                        match f.kind {
                            FaultKind::Panic => {
                                panic!("injected fault: {} panics", f.member.as_str())
                            }
                            FaultKind::Stall => {
                                while !shared.shutdown.load(Ordering::Acquire) {
                                    std::thread::sleep(Duration::from_millis(20));
                                }
                            }
                        }
                    }
                    if let Some(t) = &tracked {
                        backend.frontend_match(t);
                    }
                    Some((backend.process(&scan, &odom), odom))
                }
                Some(Job::Predict(stamp, odom, tracked)) => {
                    if let Some(t) = &tracked {
                        backend.frontend_match(t);
                    }
                    Some((backend.predict(stamp, &odom), odom))
                }
                Some(Job::Trajectory(reply)) => {
                    let _ = reply.try_send(backend.trajectory());
                    None
                }
                Some(Job::InitialPose(p)) => {
                    backend.set_initial_pose(p);
                    None
                }
                Some(Job::SaveGraph(path, reply)) => {
                    let _ = reply.try_send(backend.save_graph(&path));
                    None
                }
                Some(Job::Export) | None => None,
            };
            let revision = backend.map_revision();
            let exported = shared.lock().map.as_ref().map(|(_, r)| *r);
            let due = last_export.is_none_or(|t| t.elapsed() >= cfg.export_period);
            let map = (exported != Some(revision) && (due || force_export))
                .then(|| crate::backend::export_map(backend.as_ref(), cfg.footprint_m))
                .flatten()
                .map(|(m, _)| m);
            let below = map.as_ref().and_then(|_| backend.out_of_plane_map());
            (update, revision, map, below)
        }));
        shared.busy_since_ms.store(0, Ordering::Release);
        let mut st = shared.lock();
        match result {
            Ok((update, revision, map, below)) => {
                if let Some(u) = update {
                    st.update = Some(u);
                }
                st.revision = revision;
                if let Some(m) = map {
                    st.map = Some((Arc::new(m), revision));
                    st.below = below.map(Arc::new);
                    last_export = Some(Instant::now());
                }
                // A timeout tick (no job) only exports.
                st.done += u64::from(is_job);
            }
            Err(e) => {
                let msg = panic_message(e.as_ref());
                tracing::error!("vote member {} panicked: {msg}", backend.name());
                st.panicked = Some(msg);
            }
        }
        let ended = st.panicked.is_some();
        drop(st);
        shared.changed.notify_all();
        if ended {
            break;
        }
    }
}
