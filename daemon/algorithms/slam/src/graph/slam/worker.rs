//! The online loop-closure worker: the closure search and the optimisation
//! of a new node on a thread of their own, so the scan path never waits for
//! them.
//!
//! One job is in flight at a time. A job is a snapshot of the graph (its
//! vertices and edges) and the nodes' scans (shared, never written after a
//! node is made); the worker runs the very closure search of the inline path
//! ([`GraphSlam::close_loops`]) on its own [`GraphSlam`] holding that snapshot,
//! and returns the closure edges it kept with the optimised poses. The scan
//! path applies them at its next scan (see `GraphSlam::apply_closure_outcome`).
//! While a job runs, a new node waits in a slot of one: a newer node takes
//! the slot and the one it replaces is counted as skipped, so the work stays
//! bounded however slow the optimisation gets.

use super::{GraphSlam, GraphStats, Node};
use crate::graph::pose_graph::{Edge, PoseGraph};
use smokenav_shared_types::Pose2;
use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, sync_channel};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// What the worker gets: node `node`'s closure search over a snapshot.
pub(super) struct Job {
    pub node: usize,
    /// The newest node's marginal covariance when the job started (sizes a wide search).
    pub uncertainty: nalgebra::Matrix3<f64>,
    pub graph: PoseGraph,
    pub nodes: Vec<Arc<Node>>,
}

/// What the worker returns.
pub(super) struct Outcome {
    /// The closure edges kept (empty when none was).
    pub edges: Vec<Edge>,
    /// Earlier closures the search took out again (contradicted by a new far match).
    pub removed: Vec<Edge>,
    /// The optimised poses of the snapshot's nodes, when edges were kept.
    pub poses: Option<Vec<Pose2>>,
    /// The search's counters (closures tried, refused by reason, accepted, optimisations).
    pub stats: GraphStats,
    /// The optimised marginal covariance of the job's node, when edges were kept.
    pub marginal: Option<(usize, nalgebra::Matrix3<f64>)>,
}

/// Latencies kept for the p99 (the last this many jobs).
const LATENCY_WINDOW: usize = 512;

pub(super) struct ClosureWorker {
    jobs: Option<SyncSender<Job>>,
    results: Receiver<Outcome>,
    /// When the job in flight was handed over.
    in_flight: Option<Instant>,
    thread: Option<JoinHandle<()>>,
    /// Job start to applied, ms, of the last [`LATENCY_WINDOW`] jobs.
    latencies: VecDeque<f64>,
    latency_max_ms: f64,
}

impl ClosureWorker {
    /// Starts the thread; `search` is the back-end it searches with (its
    /// graph and nodes are replaced by each job's). With `gate`, a finished
    /// job's outcome waits for a message on it before it is sent (tests hold
    /// an outcome back while the scan path adds nodes).
    pub fn start(mut search: GraphSlam, gate: Option<Receiver<()>>) -> std::io::Result<Self> {
        // Capacity one each way: only one job is ever in flight.
        let (jobs, job_rx) = sync_channel::<Job>(1);
        let (result_tx, results) = sync_channel::<Outcome>(1);
        let thread = std::thread::Builder::new()
            .name("graph-closure".into())
            .spawn(move || {
                while let Ok(job) = job_rx.recv() {
                    search.graph = job.graph;
                    search.nodes = job.nodes;
                    search.stats = GraphStats::default();
                    search.closure_marginal = None;
                    let closed = search.close_loops(job.node, job.uncertainty);
                    let outcome = Outcome {
                        poses: (!closed.added.is_empty()).then(|| search.graph.poses().to_vec()),
                        edges: closed.added,
                        removed: closed.removed,
                        stats: search.stats,
                        marginal: search.closure_marginal.take(),
                    };
                    // The scans are the scan path's: do not hold them between jobs.
                    search.nodes = Vec::new();
                    search.graph = PoseGraph::new();
                    if let Some(g) = &gate {
                        // Bounded: a test that fails while holding it must not hang its drop.
                        let _ = g.recv_timeout(Duration::from_secs(60));
                    }
                    if result_tx.send(outcome).is_err() {
                        break;
                    }
                }
            })?;
        Ok(Self {
            jobs: Some(jobs),
            results,
            in_flight: None,
            thread: Some(thread),
            latencies: VecDeque::with_capacity(LATENCY_WINDOW),
            latency_max_ms: 0.0,
        })
    }

    pub fn idle(&self) -> bool {
        self.in_flight.is_none()
    }

    /// Hands a job over (the caller checked [`Self::idle`]); false if the thread is gone.
    pub fn submit(&mut self, job: Job) -> bool {
        let Some(jobs) = &self.jobs else { return false };
        if jobs.try_send(job).is_err() {
            return false;
        }
        self.in_flight = Some(Instant::now());
        true
    }

    /// The outcome of the job in flight if it is done (waiting up to
    /// `wait`); `Err` if the thread died.
    pub fn finished(&mut self, wait: Option<Duration>) -> Result<Option<Outcome>, ()> {
        let Some(started) = self.in_flight else {
            return Ok(None);
        };
        let got = match wait {
            None => match self.results.try_recv() {
                Ok(o) => Some(o),
                Err(TryRecvError::Empty) => None,
                Err(TryRecvError::Disconnected) => return Err(()),
            },
            Some(d) => match self.results.recv_timeout(d) {
                Ok(o) => Some(o),
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => None,
                Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => return Err(()),
            },
        };
        if got.is_some() {
            self.in_flight = None;
            let ms = started.elapsed().as_secs_f64() * 1e3;
            if self.latencies.len() == LATENCY_WINDOW {
                self.latencies.pop_front();
            }
            self.latencies.push_back(ms);
            self.latency_max_ms = self.latency_max_ms.max(ms);
        }
        Ok(got)
    }

    /// Job start to applied, ms: the largest so far and the p99 of the last jobs.
    pub fn latency_ms(&self) -> (f64, f64) {
        if self.latencies.is_empty() {
            return (0.0, 0.0);
        }
        let mut v: Vec<f64> = self.latencies.iter().copied().collect();
        v.sort_unstable_by(f64::total_cmp);
        let i = ((0.99 * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
        (self.latency_max_ms, v[i])
    }
}

impl Drop for ClosureWorker {
    fn drop(&mut self) {
        // Closing the job channel ends the thread's loop after its current job.
        self.jobs = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
