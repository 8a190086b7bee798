//! The graph back-end behind [`SlamBackend`]: Karto-style scan matching
//! against a running buffer of recent scans, a node every few decimetres, loop
//! closures verified by branch-and-bound correlative matching, and the pose
//! graph optimised with a Cauchy kernel on the closures.
//!
//! Per scan:
//! 1. The front end ([`FrontEnd`]: correlative, multi-resolution, with an
//!    odometry prior) tracks the scan against the last scans.
//! 2. Once the robot moved `node_distance_m` or turned `node_angle_rad` since
//!    the last node, the scan becomes a node: a vertex at the last node's
//!    optimised pose plus the tracked motion, and an edge carrying that motion.
//!    Other scans are stored as an offset from the last node.
//! 3. A new node looks for a loop closure: the nearest older node (at least
//!    `closure_min_separation` nodes back, within `closure_search_m` of the
//!    current estimate) and its neighbours form a local map; the scan is
//!    matched against it by branch and bound over ± `closure_window_m`,
//!    ± `closure_window_rad` without a prior. Below `closure_min_score` it is
//!    refused; otherwise the edge is added, the graph optimised, and the edge
//!    kept only if its residual after the optimisation is consistent
//!    (`closure_max_chi2`): a closure the rest of the graph contradicts is
//!    taken out again and the previous poses restored. A node that found
//!    nothing while its own estimate is uncertain searches
//!    again, wider (`closure_wide_sigmas`); such a match is added only once
//!    a later node's wide match agrees with it. A closure that moved its
//!    node far (`closure_review`) stays under review for ten nodes: a later
//!    node's far match that contradicts it takes it out again.
//! 4. The map is rendered from the nodes' scans at their optimised poses.
//!
//! Edge covariances come from the matches, not a constant: each tracked
//! scan's covariance (the front end's, from the information its geometry
//! carries, with the prediction's where the scan is degenerate) is
//! propagated along the chain to the next node, so an edge along a
//! featureless corridor is tight across it and loose along it, and a loop
//! closure can stretch the corridor where odometry was wrong. A closure's
//! covariance is its own match's the same way. Edges built from scans that
//! were mostly sonar-painted are widened by `sonar_edge_widening`.
//!
//! The pose each scan reports carries the graph's own uncertainty: the
//! newest node's marginal covariance (its block of the inverse information,
//! [`PoseGraph::marginal_covariance`], after each accepted closure; carried
//! along the odometry edges between closures, which for a chain is exact)
//! composed with the tracked motion since that node. It grows over a blind
//! stretch and shrinks when a closure ties the robot to the known map; the
//! vote's weighted rule and `slam/pose` read it.

use super::pose_graph::{Edge, Information, OptimizeParams, PoseGraph, RobustKernel};
use crate::backend::{SlamBackend, SlamUpdate, StampedPose};
use crate::degeneracy::{DegeneracyParams, ScanConstraint};
use crate::frontend::{FrontEnd, FrontEndParams, MAP_RANGE_MARGIN, Tracked};
use crate::grid::{BeamEnd, LogOddsModel, TiledGrid};
use crate::rbpf::matcher::{MatchParams, PreparedScan, RobotBeam};
use crate::scan::RangeScan;
use nalgebra::{Matrix3, Vector3};
use smokenav_platform_config::SlamSection;
use smokenav_platform_map::OccupancyGrid;
use smokenav_shared_types::Pose2;
use std::sync::Arc;
use std::time::Duration;
use worker::{ClosureWorker, Job, Outcome};

/// A wall the laser confirmed, for [`GraphParams::sonar_behind_wall_margin_m`]:
/// log-odds ≥ 2.5 (p ≥ 0.92; three laser hits net), fixed point. At the
/// published map's 0.65 a single stray laser return would stop every sonar
/// cone through it from clearing it (on the dense-smoke recordings: maps
/// 1–4 mm worse than at 2.5).
const LASER_WALL: i16 = 640;

pub mod saved;
mod worker;

/// Parameters of the graph back-end.
#[derive(Debug, Clone, PartialEq)]
pub struct GraphParams {
    /// Search window of the tracker when the pipeline's front end corrected the odometry, m and rad.
    pub tracker_window_m: f64,
    pub tracker_window_rad: f64,
    pub node_distance_m: f64,
    pub node_angle_rad: f64,
    /// Older nodes within this distance of the new node's estimate are loop candidates, m.
    pub closure_search_m: f64,
    /// Nodes between a candidate and the new node, at least (the recent chain is not a loop).
    pub closure_min_separation: usize,
    /// Nodes either side of the candidate that form its local map.
    pub closure_neighbours: usize,
    /// Separate stretches of the trajectory (runs of nodes within
    /// `closure_search_m`) tried per new node, nearest first: a place passed
    /// several times is tied to each pass, not only to the nearest node.
    pub closure_candidates: usize,
    /// Take the pipeline front end's match of each scan instead of matching
    /// it again with the own tracker (which then only runs when the
    /// pipeline's front end is off). On MIT CSAIL the second match bought
    /// no accuracy once closures tie each pass to the earlier ones.
    pub share_frontend_match: bool,
    pub closure_window_m: f64,
    pub closure_window_rad: f64,
    /// Mean blurred-table value (0–1) a closure match must reach.
    pub closure_min_score: f64,
    /// A closure whose residual eᵀΩe after the optimisation exceeds this is taken out again.
    pub closure_max_chi2: f64,
    /// A closure match is refused as ambiguous when a pose more than this
    /// far from it (m) scores at least `closure_rival_ratio` × its score:
    /// along a corridor, or between repeated shelves, the best peak is no
    /// more likely to be the place than the runner-up.
    pub closure_rival_m: f64,
    pub closure_rival_ratio: f64,
    /// A closure match is refused when fewer than this share (0–1) of the
    /// new node's endpoints, placed at the match, lie where a target node
    /// looked (one of its beams passed through or ended there, within
    /// 0.15 m): a scan of the hall matched against aisle nodes overlaps
    /// them only partly, and its score then comes from the few walls both
    /// happen to share. At 0.6 it refuses 12 of CSAIL's 634 closures that
    /// pass the other checks, and the ATE goes from 0.105 to 0.097 m (the
    /// drifted seeds 1/2/3 from 0.143/0.089/0.118 to 0.114/0.081/0.100 m).
    pub closure_min_overlap: f64,
    /// Add the target map's covariance (where it is degenerate, e.g. nodes
    /// that saw only two aisle walls) to a closure's. Off by default until
    /// measured apart from the overlap check on CSAIL.
    pub closure_map_covariance: bool,
    /// A node whose scan the fusion withheld more than this share of beams
    /// from the laser (smoke) searches for no closure: its remaining laser
    /// view is partial, and on the dense-smoke trial such nodes closed onto
    /// the wrong stretch of a corridor (map error 0.177 m with them, 0.086 m
    /// without). They can still be the target of a later node's closure.
    pub closure_max_withheld: f64,
    /// Try a closure at every n-th new node.
    pub closure_every: usize,
    /// A node whose own search found no closure and whose estimate is
    /// uncertain (this many σ of its marginal beyond the window) searches
    /// again over ± that many σ, up to `closure_wide_max` (m, rad), in the
    /// nearest older stretch that far further out (not the way it just
    /// came); 0 turns it off. The marginal is against the first node, not
    /// the target's: wider than the relative uncertainty, it also reaches
    /// passes the own radius misses (on CSAIL a trigger on the covariance
    /// since the last closure searched 214 nodes and took nothing: ATE
    /// 0.097 m, drifted seeds 0.105/0.077/0.093 m; on the marginal 420 and
    /// 9 confirmed pairs: 0.093 m, 0.081/0.076/0.087 m). Such a match must score
    /// `closure_wide_min_score` and is only taken when a second node within
    /// `WIDE_GROUP_NODES` finds one that agrees with it (the same correction
    /// of the trajectory): one wide match can be a look-alike place.
    pub closure_wide_sigmas: f64,
    pub closure_wide_max: (f64, f64),
    pub closure_wide_min_score: f64,
    /// A closure that moves its node further than this from the estimate
    /// (m, rad) is taken at once but stays under review for
    /// `WIDE_GROUP_NODES` nodes: a later node's match that would move the
    /// graph far again and does not agree with it (the relative pose of the
    /// two nodes, as in the wide search) takes it out. One such match can be
    /// a look-alike: on the dense-smoke trial a scan of a crate seen from the
    /// far side, matched onto the face the older nodes saw, closed 0.6 m off
    /// (score, overlap and residual all passed) and bent the map; the true
    /// closures of the same pass moved their nodes less than 0.22 m. Held
    /// back instead until a second match agreed, a lap's closure at the end
    /// of a run (back at the dock) never went in.
    pub closure_review: (f64, f64),
    /// σ of a node-to-node edge: translation floor (m) plus a share of the step (m/m).
    pub edge_sigma_t: (f64, f64),
    /// σ of a node-to-node edge's rotation: floor (rad) plus a share of the step's turn (rad/rad).
    pub edge_sigma_r: (f64, f64),
    /// σ added to every loop-closure edge's own match covariance, m and rad.
    pub closure_sigma: (f64, f64),
    /// σ of an endpoint's distance to its surface in a closure match, m.
    pub closure_point_sigma_m: f64,
    /// An edge's covariance is multiplied by `1 + this × (share of sonar-painted endpoints)`.
    pub sonar_edge_widening: f64,
    /// The map leaves out sonar echoes more than this behind a laser wall, m; 0 = off.
    pub sonar_behind_wall_margin_m: f64,
    pub optimize: OptimizeParams,
}

impl Default for GraphParams {
    fn default() -> Self {
        Self {
            tracker_window_m: 0.3,
            tracker_window_rad: 0.15,
            node_distance_m: 0.3,
            node_angle_rad: 0.3,
            closure_search_m: 4.0,
            closure_min_separation: 15,
            closure_neighbours: 20,
            closure_candidates: 5,
            share_frontend_match: true,
            closure_window_m: 1.5,
            closure_window_rad: 0.35,
            closure_min_score: 0.45,
            closure_max_chi2: 25.0,
            closure_rival_m: 0.5,
            closure_rival_ratio: 0.9,
            closure_min_overlap: 0.6,
            closure_map_covariance: false,
            closure_max_withheld: 0.3,
            closure_every: 1,
            closure_wide_sigmas: 3.0,
            closure_wide_max: (4.0, 0.7),
            closure_wide_min_score: 0.5,
            closure_review: (0.3, 0.1),
            edge_sigma_t: (0.02, 0.05),
            edge_sigma_r: (0.005, 0.05),
            closure_sigma: (0.1, 0.04),
            closure_point_sigma_m: 0.05,
            sonar_edge_widening: 3.0,
            sonar_behind_wall_margin_m: 0.15,
            optimize: OptimizeParams {
                max_iterations: 30,
                relative_tolerance: 1e-6,
                kernel: RobustKernel::Cauchy(3.0),
                initial_lambda: 1e-5,
            },
        }
    }
}

impl GraphParams {
    /// The defaults with `[slam.graph]`'s keys applied.
    pub fn from_config(cfg: &SlamSection) -> Self {
        let g = &cfg.graph;
        Self {
            node_distance_m: g.node_distance_m,
            node_angle_rad: g.node_angle_rad,
            closure_search_m: g.closure_search_m,
            closure_min_separation: g.closure_min_separation as usize,
            closure_candidates: g.closure_candidates as usize,
            closure_window_m: g.closure_window_m,
            closure_window_rad: g.closure_window_rad,
            closure_min_score: g.closure_min_score,
            closure_max_withheld: g.closure_max_withheld,
            closure_wide_sigmas: g.closure_wide_sigmas,
            closure_wide_max: (g.closure_wide_max_m, g.closure_wide_max_rad),
            closure_wide_min_score: g.closure_wide_min_score,
            closure_review: (g.closure_review_m, g.closure_review_rad),
            sonar_behind_wall_margin_m: g.sonar_behind_wall_m,
            ..Self::default()
        }
    }
}

/// Counters of the graph back-end.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct GraphStats {
    pub scans: u64,
    pub nodes: u64,
    pub closures_tried: u64,
    /// Below the score threshold.
    pub closures_low_score: u64,
    /// Contradicted by the rest of the graph after the optimisation.
    pub closures_inconsistent: u64,
    /// A pose far from the match scored nearly as high.
    pub closures_ambiguous: u64,
    /// Too little of the scan fell on what the target nodes observed.
    pub closures_low_overlap: u64,
    pub closures_accepted: u64,
    /// Wide searches (the estimate uncertain, the own window found nothing),
    /// their matches held for a second one, and those confirmed by it.
    pub closures_wide: u64,
    pub closures_wide_held: u64,
    pub closures_wide_confirmed: u64,
    /// Closures that moved their node far (`closure_review`), and those of
    /// them a later node's far match contradicted: taken out again.
    pub closures_far: u64,
    pub closures_retracted: u64,
    pub optimizations: u64,
    /// Optimisations that failed (the previous poses were kept).
    pub optimization_failures: u64,
    /// Online: closure searches handed to the worker, and their outcomes applied.
    pub closure_jobs: u64,
    pub closure_outcomes_applied: u64,
    /// Online: nodes whose closure search never started (a newer node took
    /// their place while the worker was busy).
    pub closure_nodes_skipped: u64,
    /// Online: nodes added while a job ran, moved by its correction.
    pub closure_nodes_carried: u64,
}

impl GraphStats {
    /// Adds the closure search's counters of `o` (a worker's job).
    fn add_search(&mut self, o: &GraphStats) {
        self.closures_tried += o.closures_tried;
        self.closures_low_score += o.closures_low_score;
        self.closures_inconsistent += o.closures_inconsistent;
        self.closures_ambiguous += o.closures_ambiguous;
        self.closures_low_overlap += o.closures_low_overlap;
        self.closures_accepted += o.closures_accepted;
        self.closures_wide += o.closures_wide;
        self.closures_wide_held += o.closures_wide_held;
        self.closures_wide_confirmed += o.closures_wide_confirmed;
        self.closures_far += o.closures_far;
        self.closures_retracted += o.closures_retracted;
        self.optimizations += o.optimizations;
        self.optimization_failures += o.optimization_failures;
    }
}

struct Node {
    /// Decimated laser endpoints in the robot frame.
    points: Vec<(f32, f32)>,
    /// Beams for the map, robot frame.
    beams: Vec<RobotBeam>,
    sensor: Pose2,
    /// Share of its scan's beams the fusion withheld from the laser (smoke).
    withheld_share: f64,
    /// The beams as (bearing, range) from the sensor, by bearing: what the
    /// node saw, for the closure overlap test.
    view: Vec<(f32, f32)>,
}

/// What the graph's map is drawn from, taken in a moment: the nodes
/// shared, their optimised poses copied. Drawn on the caller's thread
/// ([`SlamBackend::map`]) or on another ([`SlamBackend::map_job`]).
struct MapSources {
    nodes: Vec<Arc<Node>>,
    poses: Vec<Pose2>,
    resolution: f64,
    model: LogOddsModel,
    sonar_model: LogOddsModel,
    sonar_behind_wall_margin_m: f64,
}

impl MapSources {
    fn draw(&self) -> OccupancyGrid {
        let mut grid = TiledGrid::new(self.resolution);
        let mut ends = Vec::new();
        // The laser first, from every node; then the sonar, except echoes
        // from behind a wall the laser drew: a sonar meeting a wall
        // obliquely hears no echo from it (specular reflection) and reports a
        // farther surface heard along another path, and a pose off in a blind
        // stretch puts an echo behind the wall too. Either would draw a wall
        // where the laser saw free space beyond a wall, and clear the wall.
        let mut laser: Option<TiledGrid> = None;
        for sonar in [false, true] {
            if sonar && self.sonar_behind_wall_margin_m > 0.0 {
                laser = Some(grid.clone());
            }
            for (node, pose) in self.nodes.iter().zip(&self.poses) {
                let sensor = pose.compose(&node.sensor);
                let (s, c) = pose.theta.sin_cos();
                ends.clear();
                ends.extend(
                    node.beams
                        .iter()
                        .filter(|b| b.sonar == sonar)
                        .map(|b| BeamEnd {
                            ex: pose.x + c * b.x - s * b.y,
                            ey: pose.y + s * b.x + c * b.y,
                            hit: b.hit && !b.arc_flank && !b.smoke_return,
                        })
                        .map(|e| match &laser {
                            // Up to the wall, cone clear; no echo drawn.
                            Some(l) => match l.wall_before(
                                (sensor.x, sensor.y),
                                (e.ex, e.ey),
                                LASER_WALL,
                                self.sonar_behind_wall_margin_m,
                            ) {
                                Some(d) => {
                                    let (vx, vy) = (e.ex - sensor.x, e.ey - sensor.y);
                                    let k = ((d - self.resolution) / vx.hypot(vy)).max(0.0);
                                    BeamEnd {
                                        ex: sensor.x + k * vx,
                                        ey: sensor.y + k * vy,
                                        hit: false,
                                    }
                                }
                                None => e,
                            },
                            None => e,
                        }),
                );
                let model = if sonar {
                    &self.sonar_model
                } else {
                    &self.model
                };
                grid.integrate(&sensor, &ends, model);
            }
        }
        grid.to_occupancy_grid()
    }
}

impl Node {
    fn new(
        points: Vec<(f32, f32)>,
        beams: Vec<RobotBeam>,
        sensor: Pose2,
        withheld_share: f64,
    ) -> Self {
        let from_sensor = sensor.inverse();
        let mut view: Vec<(f32, f32)> = beams
            .iter()
            .map(|b| {
                let e = from_sensor.compose(&Pose2::new(b.x, b.y, 0.0));
                (e.y.atan2(e.x) as f32, e.x.hypot(e.y) as f32)
            })
            .filter(|(a, r)| a.is_finite() && r.is_finite())
            .collect();
        view.sort_by(|a, b| a.0.total_cmp(&b.0));
        Self {
            points,
            beams,
            sensor,
            withheld_share,
            view,
        }
    }

    /// The transform from the map frame into the node's sensor frame, the node at `pose`.
    fn sensor_from_map(&self, pose: &Pose2) -> Pose2 {
        pose.compose(&self.sensor).inverse()
    }

    /// The node saw the point `(x, y)` (map frame; `from_map` from
    /// [`Self::sensor_from_map`]): one of its beams within `tolerance_m` of
    /// it sideways reached at least as far, less `tolerance_m` (it passed
    /// through the point or ended there).
    fn saw(&self, from_map: &Pose2, x: f64, y: f64, tolerance_m: f64) -> bool {
        let p = from_map.compose(&Pose2::new(x, y, 0.0));
        let d = p.x.hypot(p.y);
        if !d.is_finite() {
            return false;
        }
        if d <= tolerance_m {
            return true;
        }
        let bearing = p.y.atan2(p.x);
        let half = (tolerance_m / d).min(std::f64::consts::PI);
        let lo = self.view.partition_point(|b| (b.0 as f64) < bearing - half);
        self.view[lo..]
            .iter()
            .take_while(|b| (b.0 as f64) <= bearing + half)
            .any(|b| b.1 as f64 >= d - tolerance_m)
    }
}

pub struct GraphSlam {
    /// What it was built from (the closure worker's own back-end is built the same).
    cfg: SlamSection,
    p: GraphParams,
    mp: MatchParams,
    model: LogOddsModel,
    sonar_model: LogOddsModel,
    resolution: f64,
    min_laser_points: usize,
    tracker: FrontEnd,
    closer: FrontEnd,
    prepared: PreparedScan,
    graph: PoseGraph,
    /// Shared with the closure worker's snapshots (a node never changes once made).
    nodes: Vec<Arc<Node>>,
    /// Front-end pose of the last node.
    last_node_tracked: Pose2,
    /// Every scan: stamp, node and offset from it.
    scans: Vec<(u64, usize, Pose2)>,
    stats: GraphStats,
    world: Vec<Vec<(f32, f32)>>,
    /// Where the first node goes (the pipeline's initial pose).
    initial: Pose2,
    /// Odometry and tracked pose of the last scan, for scans the motion
    /// filter held back (they move the estimate by odometry only).
    last_odom: Option<Pose2>,
    last_tracked: Pose2,
    /// Bumped by every change of the exported map (a node, an optimisation).
    revision: u64,
    /// Covariance of the tracked motion since the last node (its frame).
    since_node_cov: Matrix3<f64>,
    /// Sum of the sonar shares of the scans since the last node, and their number.
    since_node_sonar: (f64, u32),
    /// Marginal covariance of the newest node (map frame): exact after an
    /// optimisation, carried along the odometry edges between optimisations.
    newest_cov: Matrix3<f64>,
    /// Covariance of the odometry edge into each node (zero for the first
    /// and for loaded nodes): carries an optimisation's marginal to the nodes
    /// added while it ran.
    chain_cov: Vec<Matrix3<f64>>,
    /// Set by a successful [`Self::close_loops`]: the optimised marginal of its node.
    closure_marginal: Option<(usize, Matrix3<f64>)>,
    degeneracy: DegeneracyParams,
    /// The pipeline front end's match of the scan about to come (used
    /// instead of the own tracker's: the scan is matched once).
    shared: Option<Tracked>,
    /// Scratch of the closure tests: cells of the new node's endpoints at
    /// the match, and map points in the new node's frame.
    near_scan: CellSet,
    map_points: Vec<(f64, f64)>,
    /// Scratch of the overlap test: each target node's sensor frame.
    sensor_frames: Vec<Pose2>,
    /// Online: the thread the closure search and optimisation run on (inline when `None`).
    worker: Option<ClosureWorker>,
    /// Online: the newest node waiting for the worker.
    pending_closure: Option<usize>,
    /// Wide closures waiting for a second node to agree: (node, edge).
    wide_held: std::collections::VecDeque<(usize, Edge)>,
    /// Far closures still under review: (node, edge).
    provisional: std::collections::VecDeque<(usize, Edge)>,
}

/// What one closure search changed in the graph (the worker hands it to the scan path).
#[derive(Debug, Default)]
struct Closed {
    /// Closure edges it kept (empty when none was).
    added: Vec<Edge>,
    /// Earlier closures it took out again (contradicted by a new far match).
    removed: Vec<Edge>,
}

/// A closure match of node `n` (`held`) and one of node `k` (`edge`)
/// agree: `n` is at least `WIDE_GROUP_MIN_NODES` back (a different view),
/// and the relative pose of `n` and `k` the two matches imply is within
/// `WIDE_AGREE_*` of the one the chain between them (a few metres of
/// tracking) says.
fn pair_agrees(poses: &[Pose2], (n, held): &(usize, Edge), k: usize, edge: &Edge) -> bool {
    if n + WIDE_GROUP_MIN_NODES > k {
        return false;
    }
    let implied = |e: &Edge| poses[e.from].compose(&e.measurement);
    let by_matches = implied(held).between(&implied(edge));
    let by_chain = poses[*n].between(&poses[k]);
    let d = by_chain.between(&by_matches);
    d.translation_norm() <= WIDE_AGREE_M + WIDE_AGREE_SHARE * by_chain.translation_norm()
        && d.theta.abs() <= WIDE_AGREE_RAD
}

/// Covariance of `a ⊕ b` from those of `a` (`ca`) and of `b` in `a`'s frame (`cb`).
fn compose_covariance(a: &Pose2, ca: &Matrix3<f64>, b: &Pose2, cb: &Matrix3<f64>) -> Matrix3<f64> {
    let (s, c) = a.theta.sin_cos();
    let ja = Matrix3::new(
        1.0,
        0.0,
        -(s * b.x + c * b.y),
        0.0,
        1.0,
        c * b.x - s * b.y,
        0.0,
        0.0,
        1.0,
    );
    let jb = Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
    ja * ca * ja.transpose() + jb * cb * jb.transpose()
}

/// The information of covariance `cov` plus the floors `(σ_t, σ_r)`; `None` if not positive definite.
fn information_of(cov: &Matrix3<f64>, floor: (f64, f64)) -> Option<Information> {
    let c = cov
        + Matrix3::from_diagonal(&Vector3::new(
            floor.0 * floor.0,
            floor.0 * floor.0,
            floor.1 * floor.1,
        ));
    let c = 0.5 * (c + c.transpose());
    let inv = c.cholesky()?.inverse();
    let info: Information = std::array::from_fn(|r| std::array::from_fn(|k| inv[(r, k)]));
    info.iter().flatten().all(|v| v.is_finite()).then_some(info)
}

fn diagonal(sigma_t: f64, sigma_r: f64) -> Information {
    let (it, ir) = (1.0 / (sigma_t * sigma_t), 1.0 / (sigma_r * sigma_r));
    [[it, 0.0, 0.0], [0.0, it, 0.0], [0.0, 0.0, ir]]
}

/// A set of cells over a bounding box, for the overlap tests of a closure
/// (buffers reused between closures).
#[derive(Debug, Default)]
struct CellSet {
    cell: f64,
    x0: i32,
    y0: i32,
    w: i32,
    h: i32,
    on: Vec<bool>,
}

impl CellSet {
    /// Empties the set and sizes it to hold `(x0, y0)–(x1, y1)`, m.
    fn reset(&mut self, cell: f64, lo: (f64, f64), hi: (f64, f64)) {
        self.cell = cell;
        self.x0 = (lo.0 / cell).floor() as i32 - 1;
        self.y0 = (lo.1 / cell).floor() as i32 - 1;
        self.w = ((hi.0 / cell).floor() as i32 + 2 - self.x0).max(1);
        self.h = ((hi.1 / cell).floor() as i32 + 2 - self.y0).max(1);
        self.on.clear();
        self.on.resize((self.w * self.h) as usize, false);
    }

    fn index(&self, x: f64, y: f64) -> Option<usize> {
        // Saturating: a point far off (or a set never sized) is outside, not an overflow.
        let ix = ((x / self.cell).floor() as i32).saturating_sub(self.x0);
        let iy = ((y / self.cell).floor() as i32).saturating_sub(self.y0);
        ((0..self.w).contains(&ix) && (0..self.h).contains(&iy))
            .then(|| (iy * self.w + ix) as usize)
    }

    fn insert(&mut self, x: f64, y: f64) {
        if let Some(i) = self.index(x, y) {
            self.on[i] = true;
        }
    }

    /// The cell of (x, y) or one of its 8 neighbours is in the set (a match
    /// is good to about a cell; an endpoint a cell behind a seen wall counts).
    fn near(&self, x: f64, y: f64) -> bool {
        let ix = ((x / self.cell).floor() as i32).saturating_sub(self.x0);
        let iy = ((y / self.cell).floor() as i32).saturating_sub(self.y0);
        (-1..=1).any(|dy| {
            (-1..=1).any(|dx| {
                let (cx, cy) = (ix.saturating_add(dx), iy.saturating_add(dy));
                (0..self.w).contains(&cx)
                    && (0..self.h).contains(&cy)
                    && self.on[(cy * self.w + cx) as usize]
            })
        })
    }
}

/// Cell of the scan's endpoints kept for the closure map covariance, m:
/// coarse enough that a match a few centimetres off still lands in place.
const OVERLAP_CELL_M: f64 = 0.1;
/// How far sideways of a target node's beam, and short of its end, a
/// closure's endpoint still counts as seen by that node, m (a match is good
/// to about a cell of `OVERLAP_CELL_M`).
const OVERLAP_TOLERANCE_M: f64 = 0.15;
/// A wide match waits this many nodes for a second one to agree.
const WIDE_GROUP_NODES: usize = 10;
/// … from a node at least this many nodes on (a different view).
const WIDE_GROUP_MIN_NODES: usize = 2;
/// Two wide matches agree when the relative pose they imply for their
/// nodes is within this of the chain's, m (plus a share of the distance) and rad.
const WIDE_AGREE_M: f64 = 0.1;
const WIDE_AGREE_SHARE: f64 = 0.05;
const WIDE_AGREE_RAD: f64 = 0.05;
/// Wide matches held at most.
const WIDE_HELD_MAX: usize = 8;

impl GraphSlam {
    /// The nodes and their poses now, for drawing the map.
    fn map_sources(&self) -> MapSources {
        MapSources {
            nodes: self.nodes.clone(),
            poses: self.graph.poses().to_vec(),
            resolution: self.resolution,
            model: self.model,
            sonar_model: self.sonar_model,
            sonar_behind_wall_margin_m: self.p.sonar_behind_wall_margin_m,
        }
    }

    pub fn new(cfg: &SlamSection, p: GraphParams) -> Self {
        let fe = |window_m: f64, window_rad: f64| {
            FrontEnd::new(FrontEndParams {
                resolution: cfg.resolution_m,
                window_m,
                window_rad,
                max_scans: cfg.frontend_scans as usize,
                map_range_margin_m: MAP_RANGE_MARGIN,
                square_after_blind_m: cfg.square_after_blind_m,
                // Its scans come without the ring's readings.
                side_wall_window_m: 0.0,
            })
        };
        // Behind the pipeline's front end the odometry is corrected already:
        // the tracker only refines it, over a narrower (cheaper) window.
        let (tw, tr) = if cfg.frontend {
            (
                p.tracker_window_m.min(cfg.frontend_window_m),
                p.tracker_window_rad.min(cfg.frontend_window_rad),
            )
        } else {
            (cfg.frontend_window_m, cfg.frontend_window_rad)
        };
        Self {
            cfg: cfg.clone(),
            p,
            mp: MatchParams::from_config(cfg),
            model: LogOddsModel::new(cfg.hit_logodds, cfg.miss_logodds, cfg.max_logodds),
            sonar_model: LogOddsModel::new(
                cfg.sonar_hit_logodds,
                cfg.miss_logodds,
                cfg.max_logodds,
            ),
            resolution: cfg.resolution_m,
            min_laser_points: cfg.min_match_laser_points as usize,
            tracker: fe(tw, tr),
            closer: fe(cfg.frontend_window_m, cfg.frontend_window_rad),
            prepared: PreparedScan::default(),
            graph: PoseGraph::new(),
            nodes: Vec::new(),
            last_node_tracked: Pose2::default(),
            scans: Vec::new(),
            stats: GraphStats::default(),
            world: Vec::new(),
            initial: Pose2::default(),
            last_odom: None,
            last_tracked: Pose2::default(),
            revision: 0,
            since_node_cov: Matrix3::zeros(),
            since_node_sonar: (0.0, 0),
            newest_cov: Matrix3::zeros(),
            chain_cov: Vec::new(),
            closure_marginal: None,
            degeneracy: DegeneracyParams::default(),
            shared: None,
            near_scan: CellSet::default(),
            map_points: Vec::new(),
            sensor_frames: Vec::new(),
            worker: None,
            pending_closure: None,
            wide_held: std::collections::VecDeque::new(),
            provisional: std::collections::VecDeque::new(),
        }
    }

    /// Runs the loop-closure search and optimisation of each new node on a
    /// thread of its own (the SLAM process), or inline (`false`: offline
    /// runs, deterministic). If the thread cannot be started it stays inline.
    pub fn set_online(&mut self, online: bool) {
        self.set_online_gated(online, None);
    }

    fn set_online_gated(&mut self, online: bool, gate: Option<std::sync::mpsc::Receiver<()>>) {
        if !online {
            self.worker = None;
            self.pending_closure = None;
            return;
        }
        if self.worker.is_some() {
            return;
        }
        // The same settings as this back-end, its own scratch and matcher.
        let search = GraphSlam::new(&self.cfg, self.p.clone());
        match ClosureWorker::start(search, gate) {
            Ok(w) => self.worker = Some(w),
            Err(e) => tracing::warn!("loop closures stay inline: cannot start their thread: {e}"),
        }
    }

    pub fn is_online(&self) -> bool {
        self.worker.is_some()
    }

    /// Online: the time from handing a closure job to the worker to applying
    /// its outcome, ms: the largest and the p99 of the last jobs.
    pub fn closure_latency_ms(&self) -> (f64, f64) {
        self.worker
            .as_ref()
            .map_or((0.0, 0.0), ClosureWorker::latency_ms)
    }

    /// Online: waits for the job in flight and any node waiting for the
    /// worker, and applies their outcomes (the end of a run, tests).
    pub fn finish_closures(&mut self) {
        loop {
            self.apply_closure_outcome(Some(Duration::from_secs(600)));
            let idle = self.worker.as_ref().is_none_or(ClosureWorker::idle);
            if idle && !self.start_pending_closure() {
                break;
            }
        }
    }

    /// Online: applies the outcome of the job in flight if it is done
    /// (waiting up to `wait`): adds its closure edges, sets the optimised
    /// poses of the snapshot's nodes 0..=m and carries every node added
    /// since by the same correction (new_m ⊕ old_m⁻¹ ⊕ old_i).
    fn apply_closure_outcome(&mut self, wait: Option<Duration>) {
        let Some(w) = &mut self.worker else { return };
        let outcome = match w.finished(wait) {
            Ok(Some(o)) => o,
            Ok(None) => return,
            Err(()) => {
                tracing::error!(
                    "the loop-closure thread died: loop closures run inline from now on"
                );
                self.worker = None;
                return;
            }
        };
        self.apply_outcome(outcome);
    }

    fn apply_outcome(&mut self, outcome: Outcome) {
        self.stats.add_search(&outcome.stats);
        self.stats.closure_outcomes_applied += 1;
        let Some(poses) = outcome.poses else { return };
        let Some(m) = poses.len().checked_sub(1).filter(|&m| m < self.graph.len()) else {
            return;
        };
        for e in &outcome.removed {
            self.graph.remove_edge(e);
        }
        for e in outcome.edges {
            self.graph.add_edge(e);
        }
        let (old_m, new_m) = (self.graph.poses()[m], poses[m]);
        for (i, p) in poses.into_iter().enumerate() {
            self.graph.set_pose(i, p);
        }
        for i in m + 1..self.graph.len() {
            let carried = new_m.compose(&old_m.between(&self.graph.poses()[i]));
            self.graph.set_pose(i, carried);
            self.stats.closure_nodes_carried += 1;
        }
        if let Some((j, c)) = outcome.marginal.filter(|&(j, _)| j <= m) {
            self.newest_cov = self.carry_marginal(j, c);
        }
        self.revision += 1;
    }

    /// Online: hands the waiting node to the worker if it is idle; true if a job started.
    fn start_pending_closure(&mut self) -> bool {
        let Some(w) = &mut self.worker else {
            return false;
        };
        if !w.idle() {
            return false;
        }
        let Some(node) = self.pending_closure.take() else {
            return false;
        };
        let job = Job {
            node,
            // The waiting node is the newest one (a newer node takes its
            // slot), or a few nodes back with `closure_every` > 1.
            uncertainty: self.newest_cov,
            graph: self.graph.snapshot(),
            nodes: self.nodes.clone(),
        };
        if !w.submit(job) {
            tracing::error!(
                "the loop-closure thread is gone: loop closures run inline from now on"
            );
            self.worker = None;
            self.close_loops(node, self.newest_cov);
            return false;
        }
        self.stats.closure_jobs += 1;
        true
    }

    pub fn stats(&self) -> GraphStats {
        self.stats
    }

    pub fn graph(&self) -> &PoseGraph {
        &self.graph
    }

    fn add_node(&mut self, pose: Pose2, withheld_share: f64) -> usize {
        let points = self
            .prepared
            .points
            .iter()
            .filter(|p| p.from_laser)
            .map(|p| (p.hx as f32, p.hy as f32))
            .collect();
        self.nodes.push(Arc::new(Node::new(
            points,
            self.prepared.beams.clone(),
            self.prepared.sensor,
            withheld_share,
        )));
        self.stats.nodes += 1;
        self.revision += 1;
        let id = self.graph.len() as u64;
        // The odometry edge's covariance is set when that edge is made.
        self.chain_cov
            .resize(self.graph.len() + 1, Matrix3::zeros());
        self.graph.add_vertex(id, pose)
    }

    /// Looks for loop closures of node `k`: one candidate per separate
    /// stretch of the older trajectory near its estimate (up to
    /// `closure_candidates`, nearest first), each verified by matching; the
    /// verified edges are added together and the graph optimised once. An
    /// edge the optimised graph contradicts is taken out again (the others
    /// are kept and re-optimised). Returns the number of closures kept.
    fn close_loops(&mut self, k: usize, uncertainty: Matrix3<f64>) -> Closed {
        if k < self.p.closure_min_separation
            || self.nodes[k].points.len() < self.min_laser_points
            || self.nodes[k].withheld_share > self.p.closure_max_withheld
        {
            return Closed::default();
        }
        let last = k - self.p.closure_min_separation;
        let own = self.own_window();
        let mut edges = Vec::new();
        for j in self.candidate_runs(k, last, self.p.closure_search_m, false) {
            self.stats.closures_tried += 1;
            // Refusals are counted by the reason, in verify_closure.
            edges.extend(self.verify_closure(j, k, last, own));
        }
        if edges.is_empty() {
            edges = self.wide_closure(k, last, &uncertainty);
        }
        if edges.is_empty() {
            return Closed::default();
        }
        let before = self.graph.poses().to_vec();
        let far: Vec<bool> = edges.iter().map(|e| self.moves_far(k, e)).collect();
        let retracted = self.review_provisional(k, &edges, &far);
        let mut kept = edges.clone();
        for round in 0..2 {
            for e in &kept {
                self.graph.add_edge(*e);
            }
            self.stats.optimizations += 1;
            self.revision += 1;
            let result = self.graph.optimize(&self.p.optimize);
            let consistent: Vec<Edge> = kept
                .iter()
                .copied()
                .filter(|e| self.graph.edge_chi2(e) <= self.p.closure_max_chi2)
                .collect();
            if result.is_ok() && consistent.len() == kept.len() {
                self.stats.closures_accepted += kept.len() as u64;
                self.stats.closures_retracted += retracted.len() as u64;
                for (e, &far) in edges.iter().zip(&far) {
                    if far && kept.contains(e) {
                        self.stats.closures_far += 1;
                        self.provisional.push_back((k, *e));
                    }
                }
                self.closure_marginal = self.exact_marginal(k).map(|c| (k, c));
                return Closed {
                    added: kept,
                    removed: retracted.into_iter().map(|(_, e)| e).collect(),
                };
            }
            for _ in &kept {
                self.graph.pop_edge();
            }
            for (i, p) in before.iter().enumerate() {
                self.graph.set_pose(i, *p);
            }
            if result.is_err() {
                self.stats.optimization_failures += 1;
                break;
            }
            self.stats.closures_inconsistent += (kept.len() - consistent.len()) as u64;
            kept = consistent;
            // Only the edges the first optimisation agreed with get a second one.
            if kept.is_empty() || round == 1 {
                break;
            }
        }
        if !kept.is_empty() {
            // The second optimisation disagreed again: none of them is trusted.
            self.stats.closures_inconsistent += kept.len() as u64;
        }
        // Nothing new went in: what was under review stays, as it was.
        for (n, e) in retracted.iter().rev() {
            self.graph.add_edge(*e);
            self.provisional.push_front((*n, *e));
        }
        Closed::default()
    }

    /// The closure `edge` of node `k` would move it further than `closure_review`.
    fn moves_far(&self, k: usize, edge: &Edge) -> bool {
        let poses = self.graph.poses();
        self.is_far(&poses[k].between(&poses[edge.from].compose(&edge.measurement)))
    }

    /// A correction `moved` beyond `closure_review`.
    fn is_far(&self, moved: &Pose2) -> bool {
        let (m, rad) = self.p.closure_review;
        moved.translation_norm() > m || moved.theta.abs() > rad
    }

    /// Reviews the far closures of the last `WIDE_GROUP_NODES` nodes against
    /// node `k`'s new matches (`far`: which of them would move it far): one
    /// a new match agrees with is settled, one a new far match contradicts is
    /// taken out of the graph (and returned with its node, to be put back if
    /// nothing new goes in). Older ones are settled.
    fn review_provisional(&mut self, k: usize, edges: &[Edge], far: &[bool]) -> Vec<(usize, Edge)> {
        while self
            .provisional
            .front()
            .is_some_and(|(n, _)| n + WIDE_GROUP_NODES < k || *n >= k)
        {
            self.provisional.pop_front();
        }
        let mut out = Vec::new();
        let poses = self.graph.poses();
        self.provisional.retain(|held| {
            if edges.iter().any(|e| pair_agrees(poses, held, k, e)) {
                return false;
            }
            let contradicted = held.0 + WIDE_GROUP_MIN_NODES <= k
                && edges
                    .iter()
                    .zip(far)
                    .any(|(e, &f)| f && !pair_agrees(poses, held, k, e));
            if contradicted {
                out.push(*held);
            }
            !contradicted
        });
        out.retain(|(_, e)| self.graph.remove_edge(e));
        out
    }

    /// Older nodes (up to `last`) within `radius` of node `k`'s estimate:
    /// the nearest node of each run of consecutive ones, nearest run first,
    /// at most `closure_candidates`. With `skip_recent`, not the run that
    /// reaches `last`: the robot's own way there, tied to it by the chain.
    fn candidate_runs(&self, k: usize, last: usize, radius: f64, skip_recent: bool) -> Vec<usize> {
        let here = self.graph.poses()[k];
        let mut candidates: Vec<(usize, f64)> = Vec::new();
        let mut run: Option<(usize, f64)> = None;
        for (j, x) in self.graph.poses().iter().enumerate().take(last + 1) {
            let d = (x.x - here.x).hypot(x.y - here.y);
            if d <= radius {
                if run.is_none_or(|(_, bd)| d < bd) {
                    run = Some((j, d));
                }
            } else if let Some(r) = run.take() {
                candidates.push(r);
            }
        }
        if !skip_recent {
            candidates.extend(run);
        }
        candidates.sort_by(|a, b| a.1.total_cmp(&b.1));
        candidates.truncate(self.p.closure_candidates.max(1));
        candidates.into_iter().map(|(j, _)| j).collect()
    }

    /// The closure search's own window and score threshold.
    fn own_window(&self) -> (f64, f64, f64) {
        (
            self.p.closure_window_m,
            self.p.closure_window_rad,
            self.p.closure_min_score,
        )
    }

    /// The wide search of node `k` (see `closure_wide_sigmas`): the closure
    /// edges to add, two that agree or none. A match no later node confirms
    /// within [`WIDE_GROUP_NODES`] is forgotten.
    fn wide_closure(&mut self, k: usize, last: usize, uncertainty: &Matrix3<f64>) -> Vec<Edge> {
        while self
            .wide_held
            .front()
            .is_some_and(|(n, _)| n + WIDE_GROUP_NODES < k || *n >= k)
        {
            self.wide_held.pop_front();
        }
        let n = self.p.closure_wide_sigmas;
        let xy = uncertainty
            .fixed_view::<2, 2>(0, 0)
            .symmetric_eigenvalues()
            .max();
        let (sxy, sth) = (xy.max(0.0).sqrt(), uncertainty[(2, 2)].max(0.0).sqrt());
        let wide_m = (n * sxy).min(self.p.closure_wide_max.0);
        let wide_rad = (n * sth).min(self.p.closure_wide_max.1);
        // A search radius of 0 turns loop closure off, the wide search too.
        if n <= 0.0
            || self.p.closure_search_m <= 0.0
            || !(wide_m.is_finite() && wide_rad.is_finite())
            || (wide_m <= self.p.closure_window_m && wide_rad <= self.p.closure_window_rad)
        {
            return Vec::new();
        }
        self.stats.closures_wide += 1;
        let window = (
            wide_m.max(self.p.closure_window_m),
            wide_rad.max(self.p.closure_window_rad),
            self.p.closure_wide_min_score,
        );
        // The nearest stretch only: on CSAIL the others cost 0.5 CPU-s and
        // changed no figure (ATE 0.093 m, drifted seeds 0.081/0.076/0.087 m).
        let Some(&j) = self
            .candidate_runs(k, last, self.p.closure_search_m + window.0, true)
            .first()
        else {
            return Vec::new();
        };
        self.stats.closures_tried += 1;
        let Some(edge) = self.verify_closure(j, k, last, window) else {
            return Vec::new();
        };
        let poses = self.graph.poses();
        match self
            .wide_held
            .iter()
            .rposition(|held| pair_agrees(poses, held, k, &edge))
            .and_then(|i| self.wide_held.remove(i))
        {
            Some((_, first)) => {
                self.stats.closures_wide_confirmed += 1;
                vec![first, edge]
            }
            None => {
                if self.wide_held.len() == WIDE_HELD_MAX {
                    self.wide_held.pop_front();
                }
                self.wide_held.push_back((k, edge));
                self.stats.closures_wide_held += 1;
                Vec::new()
            }
        }
    }

    /// The laser endpoints of nodes `lo..=hi` in the map frame, one slot per node.
    fn fill_world(&mut self, lo: usize, hi: usize) {
        let poses = self.graph.poses();
        self.world.resize_with(hi + 1 - lo, Vec::new);
        for (slot, n) in self.world.iter_mut().zip(lo..=hi) {
            let x = poses[n];
            let (s, c) = x.theta.sin_cos();
            slot.clear();
            slot.extend(self.nodes[n].points.iter().map(|&(px, py)| {
                let (px, py) = (px as f64, py as f64);
                (
                    (x.x + c * px - s * py) as f32,
                    (x.y + s * px + c * py) as f32,
                )
            }));
        }
    }

    /// Matches node `k` against the local map around older node `j` (its
    /// neighbours up to node `last`): the closure edge j → k, if the match
    /// reaches `closure_min_score`.
    fn verify_closure(
        &mut self,
        j: usize,
        k: usize,
        last: usize,
        (window_m, window_rad, min_score): (f64, f64, f64),
    ) -> Option<Edge> {
        let here = self.graph.poses()[k];
        let lo = j.saturating_sub(self.p.closure_neighbours);
        let hi = (j + self.p.closure_neighbours).min(last);
        self.fill_world(lo, hi);
        let map: Vec<&[(f32, f32)]> = self.world.iter().map(|v| v.as_slice()).collect();
        let Some((matched, score, rival)) = self.closer.match_against(
            &map,
            self.nodes[k]
                .points
                .iter()
                .map(|&(x, y)| (x as f64, y as f64)),
            &here,
            window_m,
            window_rad,
            Some((self.p.closure_rival_m, self.p.closure_rival_ratio)),
        ) else {
            self.stats.closures_low_score += 1;
            return None;
        };
        if score < min_score {
            self.stats.closures_low_score += 1;
            return None;
        }
        // A match that would move its node far (`closure_review`) is as
        // unsure as one of the wide search, and must score as high: in the
        // dense-smoke trial's last corner a node mid-turn, a quarter of its
        // scan withheld, matched the aisle before at 0.46 and moved 0.6 m
        // along it.
        if self.is_far(&here.between(&matched))
            && score < self.p.closure_wide_min_score.max(min_score)
        {
            self.stats.closures_low_score += 1;
            return None;
        }
        if rival > 0.0 {
            self.stats.closures_ambiguous += 1;
            return None;
        }
        // The map covariance reads the scan's cells the overlap test leaves.
        if (self.p.closure_min_overlap > 0.0 || self.p.closure_map_covariance)
            && self.overlap(k, lo, hi, &matched) < self.p.closure_min_overlap
        {
            self.stats.closures_low_overlap += 1;
            return None;
        }
        let in_k = self.closure_covariance(k, lo, hi, &matched, (window_m, window_rad));
        // Rotated into the frame of node j, where the measurement is expressed.
        let measurement = self.graph.poses()[j].between(&matched);
        let (sn, cs) = measurement.theta.sin_cos();
        let rot = Matrix3::new(cs, -sn, 0.0, sn, cs, 0.0, 0.0, 0.0, 1.0);
        let cov = rot * in_k * rot.transpose();
        let information = information_of(&cov, self.p.closure_sigma)
            .unwrap_or_else(|| diagonal(self.p.closure_sigma.0, self.p.closure_sigma.1));
        Some(Edge {
            from: j,
            to: k,
            measurement,
            information,
            robust: true,
        })
    }

    /// The covariance of a closure match of node `k` at `matched` against
    /// nodes `lo..=hi` ([`Self::fill_world`] and [`Self::overlap`] done), in
    /// node k's frame: its scan's information plus the target map's (where
    /// either is degenerate, the search window: a uniform spread over ± w
    /// has variance w²/3). The two add: the match is only as good as the
    /// weaker of the point sets in each direction.
    fn closure_covariance(
        &mut self,
        k: usize,
        lo: usize,
        hi: usize,
        matched: &Pose2,
        (wt, wr): (f64, f64),
    ) -> Matrix3<f64> {
        let constraint = ScanConstraint::from_points(
            &self.nodes[k]
                .points
                .iter()
                .map(|&(x, y)| (x as f64, y as f64))
                .collect::<Vec<_>>(),
        );
        let window = Matrix3::from_diagonal(&(Vector3::new(wt * wt, wt * wt, wr * wr) / 3.0));
        let sigma = self.p.closure_point_sigma_m;
        let scan = constraint.covariance(sigma * sigma, &window, 1.0, &self.degeneracy);
        if self.p.closure_map_covariance {
            scan + self.map_covariance(lo, hi, matched, constraint.normals, &window)
        } else {
            scan
        }
    }

    /// The share (0–1) of node `k`'s endpoints, placed at `matched`, that
    /// fall on cells nodes `lo..=hi` observed (a beam passed through or
    /// ended there). Also leaves those endpoints' cells in `near_scan`.
    fn overlap(&mut self, k: usize, lo: usize, hi: usize, matched: &Pose2) -> f64 {
        let poses = self.graph.poses();
        let points = &self.nodes[k].points;
        let (s, c) = matched.theta.sin_cos();
        let world = |&(px, py): &(f32, f32)| {
            let (px, py) = (px as f64, py as f64);
            (matched.x + c * px - s * py, matched.y + s * px + c * py)
        };
        let (mut min, mut max) = ((f64::MAX, f64::MAX), (f64::MIN, f64::MIN));
        for (x, y) in points.iter().map(world) {
            min = (min.0.min(x), min.1.min(y));
            max = (max.0.max(x), max.1.max(y));
        }
        self.near_scan.reset(OVERLAP_CELL_M, min, max);
        // Each target node's sensor frame once, not once per endpoint.
        self.sensor_frames.clear();
        self.sensor_frames.extend(
            poses[lo..=hi]
                .iter()
                .zip(&self.nodes[lo..=hi])
                .map(|(pose, node)| node.sensor_from_map(pose)),
        );
        let mut inside = 0usize;
        for (x, y) in points.iter().map(world) {
            self.near_scan.insert(x, y);
            let seen = self
                .sensor_frames
                .iter()
                .zip(&self.nodes[lo..=hi])
                .any(|(from_map, node)| node.saw(from_map, x, y, OVERLAP_TOLERANCE_M));
            inside += usize::from(seen);
        }
        inside as f64 / points.len().max(1) as f64
    }

    /// The covariance (node `k`'s frame, at `matched`) of a closure's match
    /// from the target map's side: what the map points of nodes `lo..=hi`
    /// that lie where the scan has endpoints constrain (after
    /// [`Self::overlap`], which leaves those cells in `near_scan`). A scan
    /// that sees the rack end matched against nodes that saw only the two
    /// aisle walls there is fixed across the aisle, not along it. The map's
    /// information is rescaled to the scan's `normals` (each node sees the
    /// same walls again: their count says nothing about the geometry).
    fn map_covariance(
        &mut self,
        lo: usize,
        hi: usize,
        matched: &Pose2,
        normals: usize,
        window: &Matrix3<f64>,
    ) -> Matrix3<f64> {
        let mut info = Matrix3::zeros();
        let mut count = 0usize;
        let to_k = matched.inverse();
        for slot in &self.world[..=hi - lo] {
            self.map_points.clear();
            // The node's points (world frame, scan order) where the scan has
            // endpoints, into the frame of node k at the match.
            self.map_points.extend(
                slot.iter()
                    .map(|&(x, y)| (x as f64, y as f64))
                    .filter(|&(x, y)| self.near_scan.near(x, y))
                    .map(|(x, y)| {
                        let p = to_k.compose(&Pose2::new(x, y, 0.0));
                        (p.x, p.y)
                    }),
            );
            let c = ScanConstraint::from_points(&self.map_points);
            info += c.information;
            count += c.normals;
        }
        let scale = normals as f64 / count.max(1) as f64;
        let map = ScanConstraint::from_information(info * scale, normals.min(count));
        let sigma = self.p.closure_point_sigma_m;
        map.covariance(sigma * sigma, window, 1.0, &self.degeneracy)
    }

    fn pose_of_scan(&self, node: usize, offset: &Pose2) -> Pose2 {
        self.graph.poses()[node].compose(offset)
    }

    /// Adds the edge from the previous node to the newest one and carries
    /// the newest node's marginal along it.
    fn add_chain_edge(&mut self, edge: Edge) {
        let cov = Matrix3::from_fn(|r, c| edge.information[r][c])
            .try_inverse()
            .unwrap_or_else(Matrix3::zeros);
        self.newest_cov = compose_covariance(
            &self.graph.poses()[edge.from],
            &self.newest_cov,
            &edge.measurement,
            &cov,
        );
        self.chain_cov[edge.to] = cov;
        self.graph.add_edge(edge);
    }

    /// Covariance of the latest scan's pose: the newest node's marginal
    /// carried by the tracked motion since it. Zero before the first node.
    fn scan_covariance(&self) -> Matrix3<f64> {
        match self.scans.last() {
            Some(&(_, n, rel)) if n + 1 == self.nodes.len() => compose_covariance(
                &self.graph.poses()[n],
                &self.newest_cov,
                &rel,
                &self.since_node_cov,
            ),
            _ => Matrix3::zeros(),
        }
    }

    /// The newest node's marginal from node `m`'s (`cov`), carried along
    /// the odometry edges of the nodes after it.
    fn carry_marginal(&self, m: usize, cov: Matrix3<f64>) -> Matrix3<f64> {
        let poses = self.graph.poses();
        (m + 1..poses.len()).fold(cov, |c, i| {
            let step = poses[i - 1].between(&poses[i]);
            let edge = self
                .chain_cov
                .get(i)
                .copied()
                .unwrap_or_else(Matrix3::zeros);
            compose_covariance(&poses[i - 1], &c, &step, &edge)
        })
    }

    /// The exact marginal of node `k` from the graph as it stands (`None`
    /// if the graph cannot be factorised: the carried estimate stays).
    fn exact_marginal(&mut self, k: usize) -> Option<Matrix3<f64>> {
        match self.graph.marginal_covariance(k, &self.p.optimize.kernel) {
            Ok(c) => Some(Matrix3::from_fn(|r, col| c[r][col])),
            Err(e) => {
                tracing::debug!(node = k, error = %e, "no marginal covariance");
                None
            }
        }
    }

    fn update(&self, stamp_ns: u64, pose: Pose2, processed: bool) -> SlamUpdate {
        SlamUpdate {
            stamp_ns,
            pose,
            covariance: self.scan_covariance(),
            n_eff: 1.0,
            particles: 1,
            processed,
            resampled: false,
        }
    }
}

impl SlamBackend for GraphSlam {
    fn name(&self) -> &'static str {
        "graph"
    }

    fn predict(&mut self, stamp_ns: u64, odom: &Pose2) -> SlamUpdate {
        self.apply_closure_outcome(None);
        self.start_pending_closure();
        let (Some(last_odom), Some(&(_, node, _))) = (self.last_odom, self.scans.last()) else {
            return self.update(stamp_ns, self.initial, false);
        };
        if !odom.is_finite() {
            return self.update(stamp_ns, self.pose().unwrap_or(self.initial), false);
        }
        // Move the tracked pose by the odometry since the last scan; the
        // scan is stored as an offset from its node like any other.
        let step = last_odom.between(odom);
        let tracked = self.last_tracked.compose(&step);
        // Odometry only: the edge floor's share of the step, per step.
        let (st, sr) = (
            self.p.edge_sigma_t.1 * step.translation_norm(),
            self.p.edge_sigma_r.1 * step.theta.abs(),
        );
        let step_cov = match self.shared.take() {
            Some(t) => t.covariance,
            None => Matrix3::from_diagonal(&Vector3::new(st * st, st * st, sr * sr)),
        };
        let since = self.last_node_tracked.between(&self.last_tracked);
        self.since_node_cov = compose_covariance(&since, &self.since_node_cov, &step, &step_cov);
        self.last_odom = Some(*odom);
        self.last_tracked = tracked;
        let rel = self.last_node_tracked.between(&tracked);
        self.scans.push((stamp_ns, node, rel));
        self.update(stamp_ns, self.pose_of_scan(node, &rel), false)
    }

    fn frontend_match(&mut self, tracked: &Tracked) {
        if self.p.share_frontend_match {
            self.shared = Some(*tracked);
        }
    }

    fn odometry_reset(&mut self) {
        self.tracker.odometry_reset();
        self.last_odom = None;
    }

    fn set_initial_pose(&mut self, pose: Pose2) {
        if self.nodes.is_empty() {
            self.initial = pose;
        }
    }

    fn map_revision(&self) -> u64 {
        self.revision
    }

    fn metrics(&self, emit: &mut dyn FnMut(&'static str, f64)) {
        let s = &self.stats;
        emit("graph_nodes", s.nodes as f64);
        emit("loop_closures_tried", s.closures_tried as f64);
        emit("loop_closures_accepted", s.closures_accepted as f64);
        emit("loop_closures_low_score", s.closures_low_score as f64);
        emit("loop_closures_inconsistent", s.closures_inconsistent as f64);
        // Far closures went in under review; a later far match that
        // contradicted one took it out again.
        emit("loop_closures_far", s.closures_far as f64);
        emit("loop_closures_retracted", s.closures_retracted as f64);
        emit("loop_closures_ambiguous", s.closures_ambiguous as f64);
        emit("loop_closures_low_overlap", s.closures_low_overlap as f64);
        // Wide matches a second node confirmed (each adds two closures).
        emit(
            "loop_closures_wide_confirmed",
            s.closures_wide_confirmed as f64,
        );
        emit("graph_optimizations", s.optimizations as f64);
        emit(
            "graph_optimization_failures",
            s.optimization_failures as f64,
        );
        // Online only (the p99 is in the stats of benches).
        if self.worker.is_some() {
            emit("loop_closure_nodes_skipped", s.closure_nodes_skipped as f64);
            emit("loop_closure_latency_max_ms", self.closure_latency_ms().0);
        }
    }

    fn save_graph(&self, path: &std::path::Path) -> Option<Result<(), saved::SavedGraphError>> {
        Some(saved::save(self, path))
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn process(&mut self, scan: &RangeScan, odom: &Pose2) -> SlamUpdate {
        self.stats.scans += 1;
        // A finished closure moves the nodes before this scan is placed on them.
        self.apply_closure_outcome(None);
        self.start_pending_closure();
        let stamp_ns = scan.stamp_ns;
        self.prepared.prepare(scan, &self.mp);
        let odom = if odom.is_finite() {
            *odom
        } else {
            Pose2::default()
        };
        // Behind the pipeline's front end the scan was matched already: its
        // pose is `odom`, and its covariance comes with the shared match.
        let t = match self.shared.take() {
            Some(t) => Tracked { pose: odom, ..t },
            None => self.tracker.track(
                self.prepared
                    .points
                    .iter()
                    .filter(|p| p.from_laser)
                    .map(|p| (p.hx, p.hy)),
                &odom,
                stamp_ns,
            ),
        };
        let tracked = t.pose;
        if !self.nodes.is_empty() {
            let since = self.last_node_tracked.between(&self.last_tracked);
            let step = self.last_tracked.between(&tracked);
            self.since_node_cov =
                compose_covariance(&since, &self.since_node_cov, &step, &t.covariance);
        }
        self.since_node_sonar.0 += self.prepared.sonar_share;
        self.since_node_sonar.1 += 1;
        self.last_odom = Some(odom);
        self.last_tracked = tracked;
        if self.nodes.is_empty() {
            let k = self.add_node(self.initial, scan.withheld_share);
            self.last_node_tracked = tracked;
            self.scans.push((stamp_ns, k, Pose2::default()));
            return self.update(stamp_ns, self.initial, true);
        }
        let last = self.nodes.len() - 1;
        let rel = self.last_node_tracked.between(&tracked);
        if rel.translation_norm() < self.p.node_distance_m
            && rel.theta.abs() < self.p.node_angle_rad
        {
            self.scans.push((stamp_ns, last, rel));
            return self.update(stamp_ns, self.pose_of_scan(last, &rel), false);
        }
        let guess = self.graph.poses()[last].compose(&rel);
        let k = self.add_node(guess, scan.withheld_share);
        let d = rel.translation_norm();
        let (sum, n) = self.since_node_sonar;
        let sonar_share = if n > 0 { sum / n as f64 } else { 0.0 };
        let widening = 1.0 + self.p.sonar_edge_widening * sonar_share;
        // The step's own uncertainty (a floor that grows with the step, for
        // the matching error the scans' geometry does not show) plus what the
        // matches along the way measured.
        let floor = (
            self.p.edge_sigma_t.0 + self.p.edge_sigma_t.1 * d,
            self.p.edge_sigma_r.0 + self.p.edge_sigma_r.1 * rel.theta.abs() + 0.01 * d,
        );
        // Sonar-painted scans widen all of it (their matches and the map they leave are coarser).
        let information = information_of(&self.since_node_cov, floor)
            .unwrap_or_else(|| diagonal(floor.0, floor.1))
            .map(|row| row.map(|v| v / widening));
        self.add_chain_edge(Edge {
            from: last,
            to: k,
            measurement: rel,
            information,
            robust: false,
        });
        self.since_node_cov = Matrix3::zeros();
        self.since_node_sonar = (0.0, 0);
        self.last_node_tracked = tracked;
        self.scans.push((stamp_ns, k, Pose2::default()));
        if k.is_multiple_of(self.p.closure_every.max(1)) {
            if self.worker.is_some() {
                if self.pending_closure.replace(k).is_some() {
                    self.stats.closure_nodes_skipped += 1;
                }
                self.start_pending_closure();
            } else {
                self.close_loops(k, self.newest_cov);
                if let Some((m, c)) = self.closure_marginal.take() {
                    self.newest_cov = self.carry_marginal(m, c);
                }
            }
        }
        self.update(stamp_ns, self.graph.poses()[k], true)
    }

    fn pose(&self) -> Option<Pose2> {
        self.scans.last().map(|(_, n, o)| self.pose_of_scan(*n, o))
    }

    fn map(&self) -> Option<OccupancyGrid> {
        (!self.nodes.is_empty()).then(|| self.map_sources().draw())
    }

    fn map_job(&self) -> Option<crate::backend::MapJob> {
        let sources = (!self.nodes.is_empty()).then(|| self.map_sources());
        Some(Box::new(move || sources.map(|s| s.draw())))
    }

    fn trajectory(&self) -> Vec<StampedPose> {
        self.scans
            .iter()
            .map(|(stamp_ns, n, o)| StampedPose {
                stamp_ns: *stamp_ns,
                pose: self.pose_of_scan(*n, o),
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scan::{Beam, BeamKind};

    /// A 14 m × 9 m hall around a 6 m × 3 m block, with pillars and alcoves so
    /// every stretch of the loop sees more than two parallel walls.
    const WALLS: [(f64, f64, f64, f64); 16] = [
        (-7.0, -4.5, 7.0, -4.5),
        (7.0, -4.5, 7.0, 4.5),
        (7.0, 4.5, -7.0, 4.5),
        (-7.0, 4.5, -7.0, -4.5),
        (-3.0, -1.5, 3.0, -1.5),
        (3.0, -1.5, 3.0, 1.5),
        (3.0, 1.5, -3.0, 1.5),
        (-3.0, 1.5, -3.0, -1.5),
        (-1.0, -4.5, -1.0, -3.8),
        (2.0, -4.5, 2.0, -4.0),
        (7.0, 0.0, 6.3, 0.0),
        (1.0, 4.5, 1.0, 3.9),
        (-4.0, 4.5, -4.0, 4.0),
        (-7.0, 1.0, -6.4, 1.0),
        (4.8, -2.6, 5.1, -2.6),
        (-5.1, 2.6, -4.8, 2.9),
    ];

    fn cast(x: f64, y: f64, a: f64) -> Option<f64> {
        cast_in(&WALLS, x, y, a)
    }

    use crate::testkit::cast_in;

    fn scan_at(truth: &Pose2, stamp_ns: u64) -> RangeScan {
        let mut s = RangeScan {
            stamp_ns,
            laser_noise_factor: 1.0,
            ..Default::default()
        };
        for i in 0..361 {
            let a = -std::f64::consts::FRAC_PI_2 + i as f64 * std::f64::consts::PI / 360.0;
            s.beams.push(Beam {
                angle: a as f32,
                range: cast(truth.x, truth.y, truth.theta + a).map(|r| r as f32),
                kind: BeamKind::Laser,
            });
        }
        s
    }

    /// A lap and a quarter round the block (0.25 m per scan, corners in five
    /// steps) with odometry that reads 4 % long and turns 3 % wide, the laser
    /// blind (smoke) on the middle three legs: returns the back-end and the
    /// largest position error on the last leg, where the robot sees the start again.
    fn drive(p: GraphParams) -> (GraphSlam, f64) {
        drive_legs(p, &[10.0, 6.0, 10.0, 6.0, 8.0], &[1, 2, 3])
    }

    /// The defaults, but a blind leg's heading drift stays: the test hall
    /// is square, and turning the heading onto its walls after a blind leg
    /// (`[slam] square_after_blind_m`) would take away the drift these
    /// tests give the loop closure to repair.
    fn drifting() -> SlamSection {
        SlamSection {
            square_after_blind_m: 0.0,
            ..SlamSection::default()
        }
    }

    /// [`drive`] over the given legs, blind on the legs in `blind`; the
    /// worst error is that of the last leg.
    fn drive_legs(p: GraphParams, legs: &[f64], blind: &[usize]) -> (GraphSlam, f64) {
        let (slam, worst, _) = drive_legs_with(
            GraphSlam::new(&drifting(), p),
            legs,
            blind,
            &[],
            &mut |_| {},
        );
        (slam, worst)
    }

    /// [`drive_legs`] with a given back-end, the scans of the legs in
    /// `withheld` marked as mostly withheld from the laser by the fusion
    /// (their laser beams left as they are), calling `after_scan` after each
    /// scan; also returns the truth of every scan (in the frame of the first).
    fn drive_legs_with(
        slam: GraphSlam,
        legs: &[f64],
        blind: &[usize],
        withheld: &[usize],
        after_scan: &mut dyn FnMut(&GraphSlam),
    ) -> (GraphSlam, f64, Vec<Pose2>) {
        drive_legs_odometry(slam, legs, blind, withheld, (1.04, 1.03), after_scan)
    }

    /// [`drive_legs_with`] with odometry reading `scale.0` × the distance
    /// and `scale.1` × the turn.
    fn drive_legs_odometry(
        mut slam: GraphSlam,
        legs: &[f64],
        blind: &[usize],
        withheld: &[usize],
        scale: (f64, f64),
        after_scan: &mut dyn FnMut(&GraphSlam),
    ) -> (GraphSlam, f64, Vec<Pose2>) {
        let mut truths = Vec::new();
        let start = Pose2::new(-5.0, -3.0, 0.0);
        let mut truth = start;
        let mut odom = Pose2::new(3.0, -1.0, 0.4);
        let mut k = 0u64;
        let mut worst = 0.0f64;
        for (leg, &len) in legs.iter().enumerate() {
            let steps = (len / 0.25) as usize;
            let mut moves = vec![Pose2::new(0.25, 0.0, 0.0); steps];
            moves.extend((0..5).map(|_| Pose2::new(0.0, 0.0, std::f64::consts::FRAC_PI_2 / 5.0)));
            for step in moves {
                let mut scan = scan_at(&truth, k * 100_000_000);
                if blind.contains(&leg) {
                    scan.beams.iter_mut().for_each(|b| b.range = None);
                }
                if withheld.contains(&leg) {
                    scan.withheld_share = 0.5;
                }
                let u = slam.process(&scan, &odom);
                after_scan(&slam);
                truths.push(start.between(&truth));
                if leg + 1 == legs.len() && step.x > 0.0 {
                    let t = start.between(&truth);
                    worst = worst.max((u.pose.x - t.x).hypot(u.pose.y - t.y));
                }
                truth = truth.compose(&step);
                odom = odom.compose(&Pose2::new(step.x * scale.0, 0.0, step.theta * scale.1));
                k += 1;
            }
        }
        (slam, worst, truths)
    }

    /// The largest position error on the last (8 m) leg of a drive, as the
    /// graph finally has that leg (after every correction).
    fn last_leg_worst(slam: &GraphSlam, truths: &[Pose2]) -> f64 {
        let traj = slam.trajectory();
        let last_leg = (8.0 / 0.25) as usize + 5;
        traj[traj.len() - last_leg..traj.len() - 5]
            .iter()
            .zip(&truths[truths.len() - last_leg..])
            .map(|(e, t)| (e.pose.x - t.x).hypot(e.pose.y - t.y))
            .fold(0.0f64, f64::max)
    }

    /// Node edges of a straight drive in `walls` (0.1 m per scan, range
    /// 5.6 m; with `sonar_every` = n, all beams but every n-th marked as sonar-painted).
    fn corridor_edges(
        walls: &[(f64, f64, f64, f64)],
        sonar_every: Option<usize>,
        p: GraphParams,
    ) -> Vec<Edge> {
        let mut slam = GraphSlam::new(&SlamSection::default(), p);
        for k in 0..40u64 {
            let truth = Pose2::new(0.1 * k as f64, 0.0, 0.0);
            let mut scan = RangeScan {
                stamp_ns: k * 100_000_000,
                laser_noise_factor: 1.0,
                ..Default::default()
            };
            for i in 0..481 {
                let a = -2.0 + i as f64 * 4.0 / 480.0;
                let r = cast_in(walls, truth.x, truth.y, a).filter(|&r| r < 5.6);
                let sonar = sonar_every.is_some_and(|n| i % n != 0);
                scan.beams.push(Beam {
                    angle: a as f32,
                    range: r.map(|r| r as f32),
                    kind: if sonar {
                        BeamKind::Sonar
                    } else {
                        BeamKind::Laser
                    },
                });
            }
            slam.process(&scan, &Pose2::new(truth.x * 1.01, 0.0, 0.0));
        }
        slam.graph().edges().to_vec()
    }

    /// One sonar section seen from the origin: beams 40°–80° painted at the
    /// range of the echo (a wall at y = 1 m, its nearest point in the cone at
    /// 80°), the rest without a return. Its map under `sonar_arc_middle`.
    fn sonar_arc_map(sonar_arc_middle: f64) -> OccupancyGrid {
        let cfg = SlamSection {
            sonar_hit_logodds: 2.0,
            sonar_arc_middle,
            ..SlamSection::default()
        };
        let mut slam = GraphSlam::new(&cfg, GraphParams::default());
        let r = 1.0 / 80f64.to_radians().sin();
        let mut scan = RangeScan {
            stamp_ns: 1,
            laser_noise_factor: 1.0,
            ..Default::default()
        };
        for deg in -90..=90i32 {
            let arc = (40..=80).contains(&deg);
            scan.beams.push(Beam {
                angle: (deg as f32).to_radians(),
                range: arc.then_some(r as f32),
                kind: if arc {
                    BeamKind::Sonar
                } else {
                    BeamKind::Laser
                },
            });
            scan.arc_offset.push(if arc {
                (deg - 60).abs() as f32 / 20.0
            } else {
                f32::NAN
            });
        }
        slam.process(&scan, &Pose2::default());
        slam.map().expect("one node")
    }

    #[test]
    fn the_map_draws_a_sonar_arc_s_middle_as_a_wall_and_clears_its_whole_cone() {
        let at = |g: &OccupancyGrid, deg: f64, r: f64| {
            let (s, c) = deg.to_radians().sin_cos();
            let (x, y) = g.world_to_cell(r * c, r * s).expect("inside the map");
            g.get(x, y).expect("inside the map")
        };
        let r = 1.0 / 80f64.to_radians().sin();
        let whole = sonar_arc_map(1.0);
        let middle = sonar_arc_map(1.0 / 3.0);
        // The end of the arc at 40° stands 0.35 m in front of the wall.
        assert!(
            at(&whole, 42.0, r) >= 65,
            "the whole arc is drawn: {}",
            at(&whole, 42.0, r)
        );
        assert!(
            at(&middle, 42.0, r) < 65,
            "its end is not: {}",
            at(&middle, 42.0, r)
        );
        // The middle third (53°–67°) is drawn either way.
        assert!(at(&middle, 60.0, r) >= 65);
        // The cone before the arc is seen free (one miss: below even) either
        // way, its ends too.
        for g in [&whole, &middle] {
            assert!((0..50).contains(&at(g, 42.0, r - 0.2)));
            assert!((0..50).contains(&at(g, 60.0, r - 0.2)));
        }
    }

    /// Occupied cells between x = 0.8 and 1.5 m of the map of six nodes
    /// backing away 0.3 m at a time from a wall at x = 3 m, each seeing a
    /// smoke cloud in front of it (|y| ≤ 0.15 m) that the laser returns
    /// from at x = 1.0 or 1.3 m by turns, marked as the sonar contradicting
    /// it (roughness 0.6 m), with `[slam] smoke_return_rough_m` = `rough_m`.
    fn cloud_walls(rough_m: f64) -> usize {
        let cfg = SlamSection {
            smoke_return_rough_m: rough_m,
            ..SlamSection::default()
        };
        let mut slam = GraphSlam::new(&cfg, GraphParams::default());
        for k in 0..6u32 {
            let x0 = -0.3 * f64::from(k);
            let mut scan = RangeScan {
                stamp_ns: 1 + u64::from(k) * 100_000_000,
                laser_noise_factor: 1.0,
                ..Default::default()
            };
            for i in 0..=480 {
                let a = (-60.0 + 0.25 * f64::from(i)).to_radians();
                let cloud_x = if i % 2 == 0 { 1.0 } else { 1.3 };
                let cloud = ((cloud_x - x0) * a.tan()).abs() <= 0.15;
                let range = if cloud { cloud_x - x0 } else { 3.0 - x0 } / a.cos();
                scan.beams.push(Beam {
                    angle: a as f32,
                    range: Some(range as f32),
                    kind: BeamKind::Laser,
                });
                scan.laser_roughness
                    .push(if cloud { 0.6 } else { f32::NAN });
            }
            slam.process(&scan, &Pose2::new(x0, 0.0, 0.0));
        }
        let map = slam.map().expect("nodes");
        let mut walls = 0;
        for cy in 0..map.height {
            for cx in 0..map.width {
                let (x, _) = map.cell_center(cx, cy);
                if (0.8..1.5).contains(&x) && map.get(cx, cy).is_some_and(|v| v >= 65) {
                    walls += 1;
                }
            }
        }
        walls
    }

    #[test]
    fn a_smoke_cloud_the_sonar_contradicts_is_not_drawn_as_a_wall() {
        let drawn = cloud_walls(0.0);
        assert!(drawn >= 8, "drawn when the check is off: {drawn}");
        assert_eq!(cloud_walls(0.15), 0);
        // A threshold above the cloud's roughness draws it.
        assert_eq!(cloud_walls(1.0), drawn);
    }

    /// Six nodes 0.3 m apart along y facing a wall at x = 2 m: the first four
    /// see it with the laser, the last two through smoke with a sonar cone
    /// at 40°–50° whose echo came from 3.5 m, behind the wall (a specular
    /// path). Returns the map and the echo's place from the last node.
    fn echo_behind_wall_map(margin_m: f64) -> (OccupancyGrid, (f64, f64)) {
        let cfg = SlamSection {
            sonar_hit_logodds: 2.0,
            ..SlamSection::default()
        };
        let p = GraphParams {
            sonar_behind_wall_margin_m: margin_m,
            ..GraphParams::default()
        };
        let mut slam = GraphSlam::new(&cfg, p);
        let echo = 3.5;
        for k in 0..6 {
            let y = 0.3 * f64::from(k);
            let smoke = k >= 4;
            let mut scan = RangeScan {
                stamp_ns: 1 + u64::from(k as u32) * 100_000_000,
                laser_noise_factor: 1.0,
                ..Default::default()
            };
            for i in 0..=480 {
                let deg = -60.0 + 0.25 * f64::from(i);
                let sonar = smoke && (40.0..=50.0).contains(&deg);
                scan.beams.push(Beam {
                    angle: (deg as f32).to_radians(),
                    range: Some(if sonar {
                        echo as f32
                    } else {
                        (2.0 / deg.to_radians().cos()) as f32
                    }),
                    kind: if sonar {
                        BeamKind::Sonar
                    } else {
                        BeamKind::Laser
                    },
                });
                scan.arc_offset.push(if sonar {
                    ((deg - 45.0).abs() / 5.0) as f32
                } else {
                    f32::NAN
                });
            }
            slam.process(&scan, &Pose2::new(0.0, y, 0.0));
        }
        let at = 45f64.to_radians();
        (
            slam.map().expect("nodes"),
            (echo * at.cos(), 1.5 + echo * at.sin()),
        )
    }

    #[test]
    fn a_sonar_echo_from_behind_a_laser_wall_is_left_out_and_does_not_clear_the_wall() {
        // Unknown (−1) beyond the map's edge: nothing observed there.
        let cell = |g: &OccupancyGrid, (x, y): (f64, f64)| {
            g.world_to_cell(x, y)
                .and_then(|(cx, cy)| g.get(cx, cy))
                .unwrap_or(-1)
        };
        let (drawn, echo) = echo_behind_wall_map(0.0);
        assert!(
            cell(&drawn, echo) >= 65,
            "without the check the echo is a wall: {}",
            cell(&drawn, echo)
        );
        let (map, echo) = echo_behind_wall_map(0.15);
        assert!(
            cell(&map, echo) < 65,
            "the echo behind the wall is not drawn: {}",
            cell(&map, echo)
        );
        // Where the cone crossed the wall (x = 2, y = 1.5 + 2 ± 0.4) the wall stands.
        for dy in [-0.3, 0.0, 0.3] {
            let w = (2.02, 3.5 + dy);
            assert!(cell(&map, w) >= 65, "wall at {w:?}: {}", cell(&map, w));
        }
        // And the cone before the wall is free.
        assert!((0..50).contains(&cell(&map, (1.5, 3.0))));
    }

    const CORRIDOR: [(f64, f64, f64, f64); 2] =
        [(-30.0, -1.2, 30.0, -1.2), (-30.0, 1.3, 30.0, 1.3)];
    /// The same with a cross wall and pillars ahead and behind, in range.
    const FEATURES: [(f64, f64, f64, f64); 5] = [
        (-30.0, -1.2, 30.0, -1.2),
        (-30.0, 1.3, 30.0, 1.3),
        (7.0, -1.2, 7.0, 1.3),
        (2.0, 1.3, 2.0, 0.9),
        (-1.5, -1.2, -1.5, -0.8),
    ];

    #[test]
    fn edge_covariance_follows_what_the_scans_constrain() {
        let corridor = corridor_edges(&CORRIDOR, None, GraphParams::default());
        let features = corridor_edges(&FEATURES, None, GraphParams::default());
        assert!(corridor.len() >= 8 && features.len() >= 8);
        let along = |e: &Edge| e.information[0][0];
        let across = |e: &Edge| e.information[1][1];
        for e in &corridor {
            // Along a featureless corridor the edge is odometry's; across it, the walls'.
            assert!(across(e) > 2.5 * along(e), "{:?}", e.information);
        }
        let mean =
            |v: &[Edge], f: &dyn Fn(&Edge) -> f64| v.iter().map(f).sum::<f64>() / v.len() as f64;
        assert!(
            mean(&features, &along) > 1.8 * mean(&corridor, &along),
            "features fix the position along the corridor: {} vs {}",
            mean(&features, &along),
            mean(&corridor, &along)
        );
    }

    #[test]
    fn edges_from_mostly_sonar_scans_are_wider() {
        let log_det = |v: &[Edge]| {
            v.iter()
                .map(|e| {
                    Matrix3::from_fn(|r, c| e.information[r][c])
                        .determinant()
                        .ln()
                })
                .sum::<f64>()
                / v.len() as f64
        };
        // Two beams in three painted from sonar cones, with and without the widening.
        let widened = log_det(&corridor_edges(&FEATURES, Some(3), GraphParams::default()));
        let plain = log_det(&corridor_edges(
            &FEATURES,
            Some(3),
            GraphParams {
                sonar_edge_widening: 0.0,
                ..GraphParams::default()
            },
        ));
        // Share 2/3 and widening 3: covariance ×3, information determinant ÷27 (ln 27 ≈ 3.3).
        assert!(widened < plain - 2.0, "{widened} vs {plain}");
    }

    /// A lap whose odometry reads 10 % long and turns 10 % wide comes back
    /// from its three blind legs about 2 m off, past the closure window: the
    /// own search finds nothing there. The estimate is uncertain after the
    /// blind legs, so the wide search looks again; its first match waits, a
    /// later node's agrees, both are added, and from then on the own window
    /// closes the loop node after node. Online too (the worker keeps the
    /// waiting match between its jobs). A match no second node confirms is
    /// never added (searched only every 11th node, none can).
    #[test]
    fn a_return_past_the_window_is_closed_by_the_wide_search_once_two_nodes_agree() {
        let legs = [10.0, 6.0, 10.0, 6.0, 8.0];
        let run = |p: GraphParams, online: bool| {
            let p = GraphParams {
                closure_every: p.closure_every.max(2),
                ..p
            };
            let mut slam = GraphSlam::new(&drifting(), p);
            slam.set_online(online);
            // Online, scans come 5 ms apart (a robot's come 100 ms apart): fed
            // as fast as they are made, the worker skips so many nodes that
            // two wide matches rarely fall within WIDE_GROUP_NODES.
            let mut pace = |_: &GraphSlam| {
                if online {
                    std::thread::sleep(Duration::from_millis(5));
                }
            };
            let (mut slam, _, truths) =
                drive_legs_odometry(slam, &legs, &[1, 2, 3], &[], (1.1, 1.1), &mut pace);
            slam.finish_closures();
            (slam.stats(), last_leg_worst(&slam, &truths))
        };
        let (narrow, narrow_worst) = run(
            GraphParams {
                closure_wide_sigmas: 0.0,
                ..GraphParams::default()
            },
            false,
        );
        let (wide, wide_worst) = run(GraphParams::default(), false);
        eprintln!(
            "last leg: {narrow_worst:.3} m narrow, {wide_worst:.3} m wide\n{narrow:?}\n{wide:?}"
        );
        assert_eq!(narrow.closures_accepted, 0, "{narrow:?}");
        assert!(narrow_worst > 1.0, "{narrow_worst}");
        assert!(wide.closures_wide_held >= 1, "{wide:?}");
        assert!(wide.closures_wide_confirmed >= 1, "{wide:?}");
        assert!(wide.closures_accepted >= 2, "{wide:?}");
        assert!(wide_worst < 0.2, "{wide_worst}");
        // Searched only every 11th node, no second node comes within
        // WIDE_GROUP_NODES of a wide match: it is held, never added alone.
        let (sparse, sparse_worst) = run(
            GraphParams {
                closure_every: WIDE_GROUP_NODES + 1,
                ..GraphParams::default()
            },
            false,
        );
        eprintln!("every 11th node: {sparse_worst:.3} m\n{sparse:?}");
        assert!(sparse.closures_wide_held >= 1, "{sparse:?}");
        assert_eq!(sparse.closures_wide_confirmed, 0, "{sparse:?}");
        assert_eq!(sparse.closures_accepted, 0, "{sparse:?}");
        let (online, online_worst) = run(GraphParams::default(), true);
        eprintln!("online: {online_worst:.3} m\n{online:?}");
        assert!(online.closures_wide_confirmed >= 1, "{online:?}");
        assert!(online_worst < 0.2, "{online_worst}");
    }

    /// A lap (no closure of its own: the chain alone), the graph then bent
    /// by a closure of node `k` onto node 10 that places `k` `offset_m`
    /// further along x than the lap's poses do (taken as `close_loops`
    /// takes a far one): returns the back-end, the poses before the closure
    /// and the closure.
    fn lap_with_a_far_closure(k_back: usize, offset_m: f64) -> (GraphSlam, Vec<Pose2>, Edge) {
        let (mut slam, _) = drive(GraphParams {
            closure_search_m: 0.0,
            ..GraphParams::default()
        });
        let poses = slam.graph.poses().to_vec();
        let k = poses.len() - k_back;
        let placed = Pose2::new(poses[k].x + offset_m, poses[k].y, poses[k].theta);
        let closure = Edge {
            from: 10,
            to: k,
            measurement: poses[10].between(&placed),
            information: diagonal(0.1, 0.04),
            robust: true,
        };
        assert!(slam.moves_far(k, &closure));
        slam.graph.add_edge(closure);
        slam.graph.optimize(&slam.p.optimize).unwrap();
        slam.provisional.push_back((k, closure));
        (slam, poses, closure)
    }

    /// A closure of node `k` onto node 12 placing it `offset_m` along x from
    /// where the lap's own poses put it.
    fn closure_of(poses: &[Pose2], k: usize, offset_m: f64) -> Edge {
        let placed = Pose2::new(poses[k].x + offset_m, poses[k].y, poses[k].theta);
        Edge {
            from: 12,
            to: k,
            measurement: poses[12].between(&placed),
            information: diagonal(0.1, 0.04),
            robust: true,
        }
    }

    #[test]
    fn a_far_closure_a_later_far_match_contradicts_is_taken_out_again() {
        let (mut slam, poses, wrong) = lap_with_a_far_closure(8, 0.6);
        let edges_before = slam.graph.edges().len();
        // Three nodes on, a match that agrees with the lap, not with the
        // bent graph: far from where the wrong closure put the node.
        let k = poses.len() - 5;
        let right = closure_of(&poses, k, 0.0);
        assert!(
            slam.moves_far(k, &right),
            "the wrong closure bent the graph"
        );
        let out = slam.review_provisional(k, &[right], &[true]);
        assert_eq!(out, vec![(poses.len() - 8, wrong)]);
        assert_eq!(slam.graph.edges().len(), edges_before - 1);
        assert!(!slam.graph.edges().contains(&wrong));
        assert!(slam.provisional.is_empty());
    }

    #[test]
    fn a_far_closure_a_later_match_agrees_with_stays() {
        let (mut slam, poses, first) = lap_with_a_far_closure(8, 0.6);
        // Three nodes on, a match that moves the graph the same way.
        let k = poses.len() - 5;
        let second = closure_of(&poses, k, 0.6);
        assert!(slam.review_provisional(k, &[second], &[true]).is_empty());
        assert!(slam.graph.edges().contains(&first));
        assert!(slam.provisional.is_empty(), "settled");
        // A match of the very next node is no second view: nothing is decided.
        let (mut slam, poses, _) = lap_with_a_far_closure(8, 0.6);
        let k = poses.len() - 7;
        let out = slam.review_provisional(k, &[closure_of(&poses, k, 0.0)], &[true]);
        assert!(out.is_empty());
        assert_eq!(slam.provisional.len(), 1);
    }

    #[test]
    fn loop_closure_repairs_the_drift_of_a_lap() {
        let p = GraphParams {
            closure_every: 2,
            ..GraphParams::default()
        };
        let (slam, with) = drive(p.clone());
        let stats = slam.stats();
        assert!(stats.closures_accepted >= 1, "{stats:?}");
        let (_, without) = drive(GraphParams {
            closure_search_m: 0.0,
            ..p
        });
        eprintln!("last leg: {with:.3} m with closures, {without:.3} m without; {stats:?}");
        assert!(without > 0.5, "the blind stretch drifts: {without} m");
        assert!(with < 0.2, "with closures: {with} m");
        // The trajectory has a pose per scan and the map is finite.
        assert_eq!(slam.trajectory().len() as u64, stats.scans);
        assert!(slam.map().is_some());
    }

    /// The map drawn on another thread ([`SlamBackend::map_job`], so the
    /// SLAM process's scans need not wait for it) is the map as it was when
    /// the job was taken, whatever the graph did after (nodes added, a loop
    /// closed).
    #[test]
    fn a_map_job_draws_the_map_as_it_was_when_taken() {
        let p = GraphParams {
            closure_every: 2,
            ..GraphParams::default()
        };
        let mut taken = None;
        let mut k = 0;
        let (slam, _, _) = drive_legs_with(
            GraphSlam::new(&drifting(), p),
            &[10.0, 6.0, 10.0, 6.0, 8.0],
            &[1, 2, 3],
            &[],
            &mut |s| {
                k += 1;
                if k == 60 {
                    taken = Some((s.map_job().unwrap(), s.map().unwrap()));
                }
            },
        );
        let (job, then) = taken.unwrap();
        let drawn = std::thread::spawn(job).join().unwrap().unwrap();
        assert_eq!(
            (drawn.width, drawn.height, drawn.origin),
            (then.width, then.height, then.origin)
        );
        assert!(drawn.cells == then.cells, "the job drew another map");
        assert!(slam.stats().closures_accepted >= 1);
        assert!(
            slam.map().unwrap().cells != drawn.cells,
            "the graph moved on"
        );
        // Before the first scan there is nothing to draw.
        let empty = GraphSlam::new(&drifting(), GraphParams::default());
        assert!(empty.map_job().unwrap()().is_none());
    }

    /// A closure that would move its node far (`closure_review`) must reach
    /// the wide search's score: with that score out of reach the lap's
    /// drift (over 0.5 m) stays, where the defaults repair it.
    #[test]
    fn a_closure_that_moves_its_node_far_must_score_as_a_wide_one() {
        let p = GraphParams {
            closure_every: 2,
            closure_wide_min_score: 1.01,
            ..GraphParams::default()
        };
        let (slam, with) = drive(p);
        let stats = slam.stats();
        assert!(with > 0.5, "far closures refused: {with} m, {stats:?}");
        assert!(stats.closures_low_score >= 1, "{stats:?}");
    }

    /// `[slam.graph]` reaches the back-end: its defaults are the back-end's,
    /// and a section that turns the closure search off (radius 0) leaves the
    /// lap of [`drive`] open where the defaults close it.
    #[test]
    fn the_graph_section_of_the_config_sets_the_closure_search() {
        assert_eq!(
            GraphParams::from_config(&SlamSection::default()),
            GraphParams::default()
        );
        let mut off = drifting();
        off.graph.closure_search_m = 0.0;
        let legs = [10.0, 6.0, 10.0, 6.0, 8.0];
        let lap = |cfg: &SlamSection| {
            let p = GraphParams {
                closure_every: 2,
                ..GraphParams::from_config(cfg)
            };
            let (slam, worst, _) =
                drive_legs_with(GraphSlam::new(cfg, p), &legs, &[1, 2, 3], &[], &mut |_| {});
            (slam.stats(), worst)
        };
        let (on, on_worst) = lap(&drifting());
        let (shut, shut_worst) = lap(&off);
        assert!(on.closures_accepted >= 1, "{on:?}");
        assert_eq!(shut.closures_tried, 0, "{shut:?}");
        assert!(
            shut_worst > 0.5 && on_worst < 0.2,
            "{shut_worst} / {on_worst}"
        );
    }

    /// The lap of [`drive`] with the last leg's scans mostly withheld from
    /// the laser (the fusion saw smoke there): the laser's partial view is not
    /// trusted for a closure, so those nodes search for none.
    #[test]
    fn nodes_mostly_withheld_from_the_laser_search_for_no_closure() {
        let p = GraphParams {
            closure_every: 2,
            ..GraphParams::default()
        };
        let legs = [10.0, 6.0, 10.0, 6.0, 8.0];
        let run = |withheld: &[usize]| {
            let slam = GraphSlam::new(&SlamSection::default(), p.clone());
            drive_legs_with(slam, &legs, &[1, 2, 3], withheld, &mut |_| {})
                .0
                .stats()
        };
        let clear = run(&[]);
        let smoky = run(&[4]);
        eprintln!("clear {clear:?}\nsmoky {smoky:?}");
        assert!(clear.closures_accepted >= 1, "{clear:?}");
        assert!(smoky.closures_tried < clear.closures_tried, "{smoky:?}");
        assert_eq!(smoky.closures_accepted, 0, "{smoky:?}");
    }

    /// The lap of [`drive`] with the closure search on its own thread, each
    /// job's outcome held back until three scans after the job started: the
    /// closure is found as inline, and the nodes the scan path added while
    /// the job ran are moved with the correction, not left at the drifted end.
    #[test]
    fn the_threaded_closure_search_repairs_the_lap_and_carries_the_nodes_added_meanwhile() {
        let p = GraphParams {
            closure_every: 2,
            ..GraphParams::default()
        };
        let (gate, held) = std::sync::mpsc::channel();
        let mut slam = GraphSlam::new(&SlamSection::default(), p);
        slam.set_online_gated(true, Some(held));
        assert!(slam.is_online());
        let (mut scan, mut released) = (0usize, 0usize);
        let mut started_at: Vec<usize> = Vec::new();
        let (mut slam, _, truths) = drive_legs_with(
            slam,
            &[10.0, 6.0, 10.0, 6.0, 8.0],
            &[1, 2, 3],
            &[],
            &mut |s| {
                scan += 1;
                while (started_at.len() as u64) < s.stats().closure_jobs {
                    started_at.push(scan);
                }
                while released < started_at.len() && started_at[released] + 3 <= scan {
                    gate.send(()).unwrap();
                    released += 1;
                }
            },
        );
        // From here on the worker does not wait for the gate.
        drop(gate);
        slam.finish_closures();
        let stats = slam.stats();
        assert!(stats.closure_jobs >= 1, "{stats:?}");
        assert_eq!(stats.closure_outcomes_applied, stats.closure_jobs);
        assert!(stats.closures_accepted >= 1, "{stats:?}");
        assert!(stats.closure_nodes_carried >= 1, "{stats:?}");
        // The last leg, where the robot sees the start again (the trajectory
        // after the last correction): as close to the truth as inline.
        assert_eq!(slam.trajectory().len(), truths.len());
        let worst = last_leg_worst(&slam, &truths);
        eprintln!("last leg after the threaded closures: {worst:.3} m; {stats:?}");
        assert!(worst < 0.2, "with threaded closures: {worst} m");
    }

    /// The pose covariance each scan reports follows the graph's marginals:
    /// it grows over the blind legs, and the first accepted closure shrinks
    /// it, inline at that scan and online once the worker's outcome is applied.
    #[test]
    fn the_reported_covariance_grows_while_blind_and_shrinks_at_a_closure() {
        for online in [false, true] {
            let mut slam = GraphSlam::new(
                &SlamSection::default(),
                GraphParams {
                    closure_every: 2,
                    ..GraphParams::default()
                },
            );
            slam.set_online(online);
            // (position variance, closures accepted and applied so far) per scan.
            let mut seen: Vec<(f64, u64)> = Vec::new();
            let (slam, _, _) = drive_legs_with(
                slam,
                &[10.0, 6.0, 10.0, 6.0, 8.0],
                &[1, 2, 3],
                &[],
                &mut |s| {
                    let c = s.scan_covariance();
                    assert!(
                        c.iter().all(|v| v.is_finite()) && c[(0, 0)] >= 0.0 && c[(1, 1)] >= 0.0,
                        "{c}"
                    );
                    let applied = if online {
                        s.stats()
                            .closure_outcomes_applied
                            .min(s.stats().closures_accepted)
                    } else {
                        s.stats().closures_accepted
                    };
                    seen.push((c[(0, 0)] + c[(1, 1)], applied));
                },
            );
            let stats = slam.stats();
            assert!(stats.closures_accepted >= 1, "{stats:?}");
            let first = seen
                .iter()
                .position(|&(_, n)| n > 0)
                .expect("a closure reaches the reported pose");
            let before = seen[first - 1].0;
            let after = seen[first].0;
            let start = seen[5].0;
            eprintln!(
                "online {online}: variance {start:.5} early, {before:.4} m² before the first closure, {after:.5} after"
            );
            assert!(
                before > 10.0 * start.max(1e-6),
                "grows while blind: {start} → {before}"
            );
            assert!(
                after < 0.5 * before,
                "the closure shrinks it: {before} → {after}"
            );
        }
    }

    /// An outcome for nodes 0..=m applied after the scan path added nodes
    /// m+1..: those keep their pose relative to node m.
    #[test]
    fn an_outcome_moves_the_nodes_added_after_its_snapshot_with_node_m() {
        let mut slam = GraphSlam::new(&SlamSection::default(), GraphParams::default());
        for n in 0..8 {
            slam.prepared
                .prepare(&scan_at(&Pose2::new(0.3 * n as f64, 0.0, 0.0), 0), &slam.mp);
            slam.add_node(
                Pose2::new(0.3 * n as f64, 0.05 * n as f64, 0.01 * n as f64),
                0.0,
            );
        }
        let before = slam.graph.poses().to_vec();
        let revision = slam.revision;
        // The worker's snapshot had nodes 0..=4; its optimisation moved node 4 and turned it.
        let m = 4;
        let poses: Vec<Pose2> = before[..=m]
            .iter()
            .map(|p| Pose2::new(p.x - 0.2, p.y + 0.1, p.theta + 0.05))
            .collect();
        let edge = Edge {
            from: 0,
            to: m,
            measurement: poses[0].between(&poses[m]),
            information: diagonal(0.1, 0.04),
            robust: true,
        };
        let edges = slam.graph.edges().len();
        slam.apply_outcome(Outcome {
            edges: vec![edge],
            removed: Vec::new(),
            poses: Some(poses.clone()),
            stats: GraphStats {
                closures_accepted: 1,
                ..GraphStats::default()
            },
            marginal: None,
        });
        let after = slam.graph.poses();
        assert_eq!(&after[..=m], &poses[..]);
        for i in m + 1..after.len() {
            let (was, is) = (before[m].between(&before[i]), after[m].between(&after[i]));
            assert!(
                (was.x - is.x).abs() < 1e-9
                    && (was.y - is.y).abs() < 1e-9
                    && (was.theta - is.theta).abs() < 1e-9,
                "node {i}: {was:?} from node {m} before, {is:?} after"
            );
            assert!(
                (after[i].x - before[i].x).abs() > 0.1,
                "node {i} was not moved"
            );
        }
        assert_eq!(slam.graph.edges().len(), edges + 1);
        assert!(slam.revision > revision);
        let stats = slam.stats();
        assert_eq!(stats.closures_accepted, 1);
        assert_eq!(stats.closure_nodes_carried, 3);
        // A later job took that closure out again (a far match contradicted
        // it): the scan path's graph loses it too.
        let replaced = Edge { from: 1, ..edge };
        slam.apply_outcome(Outcome {
            edges: vec![replaced],
            removed: vec![edge],
            poses: Some(poses.clone()),
            stats: GraphStats {
                closures_accepted: 1,
                closures_retracted: 1,
                ..GraphStats::default()
            },
            marginal: None,
        });
        assert_eq!(slam.graph.edges().len(), edges + 1);
        assert!(!slam.graph.edges().contains(&edge));
        assert!(slam.graph.edges().contains(&replaced));
        assert_eq!(slam.stats().closures_retracted, 1);
        // Health counts it on its own, not with the closures the graph
        // contradicted when they were added.
        let mut reported = Vec::new();
        slam.metrics(&mut |name, v| {
            if name.starts_with("loop_closures_") {
                reported.push((name, v));
            }
        });
        assert!(
            reported.contains(&("loop_closures_retracted", 1.0)),
            "{reported:?}"
        );
        assert!(
            reported.contains(&("loop_closures_inconsistent", 0.0)),
            "{reported:?}"
        );
    }

    /// A corridor between racks whose uprights repeat every 1.2 m, driven
    /// down and back with exact odometry: on the way back each scan matches
    /// the first pass as well one bay (1.2 m) off as in place, so a closure
    /// taken at the best peak may pull the estimate a bay along. The
    /// ambiguous closures must be refused and the estimate stay on the truth.
    #[test]
    fn closures_between_repeating_racks_are_refused_as_ambiguous() {
        let mut walls = vec![(-30.0, -1.2, 30.0, -1.2), (-30.0, 1.3, 30.0, 1.3)];
        for i in -25..25 {
            let x = 1.2 * i as f64;
            walls.push((x, -1.2, x, -0.9));
            walls.push((x + 0.6, 1.3, x + 0.6, 1.0));
        }
        let run = |p: GraphParams| {
            let mut slam = GraphSlam::new(&SlamSection::default(), p);
            // Down the corridor from x = -6 to 10, turn round, back to x = 2.
            let start = Pose2::new(-6.0, 0.0, 0.0);
            let mut truth = start;
            let mut moves = vec![Pose2::new(0.1, 0.0, 0.0); 160];
            moves.extend([Pose2::new(0.0, 0.0, std::f64::consts::PI / 10.0); 10]);
            moves.extend([Pose2::new(0.1, 0.0, 0.0); 80]);
            let mut first = None;
            let mut worst = 0.0f64;
            for (n, step) in moves.iter().enumerate() {
                let mut scan = RangeScan {
                    stamp_ns: n as u64 * 100_000_000,
                    laser_noise_factor: 1.0,
                    ..Default::default()
                };
                for i in 0..481 {
                    let a = -2.0 + i as f64 * 4.0 / 480.0;
                    let r = cast_in(&walls, truth.x, truth.y, truth.theta + a).filter(|&r| r < 5.6);
                    scan.beams.push(Beam {
                        angle: a as f32,
                        range: r.map(|r| r as f32),
                        kind: BeamKind::Laser,
                    });
                }
                let u = slam.process(&scan, &truth);
                let est = first.get_or_insert(u.pose).between(&u.pose);
                let t = start.between(&truth);
                worst = worst.max((est.x - t.x).hypot(est.y - t.y));
                truth = truth.compose(step);
            }
            (worst, slam.stats())
        };
        let (worst, stats) = run(GraphParams::default());
        assert!(worst < 0.3, "{worst:.2} m off the truth: {stats:?}");
        assert!(stats.closures_ambiguous > 0, "{stats:?}");
        // Without the rival test the same drive takes a false closure.
        let (worst, stats) = run(GraphParams {
            closure_rival_ratio: 2.0,
            ..GraphParams::default()
        });
        assert!(worst > 0.6, "{worst:.2} m off the truth: {stats:?}");
    }

    /// Two and a quarter laps: nodes of the third pass along the first leg
    /// are tied to both earlier passes, not only to the nearest node.
    #[test]
    fn a_place_passed_three_times_is_tied_to_both_earlier_passes() {
        let legs = [10.0, 6.0, 10.0, 6.0, 10.0, 6.0, 10.0, 6.0, 8.0];
        let tied_to_both = |p: GraphParams| {
            let (slam, _) = drive_legs(p, &legs, &[]);
            // Nodes per lap: 32 m at 0.25 m a scan, 4 × 5 turning scans (each a node).
            let lap = slam.graph().len() * 4 / 9;
            let closures: Vec<_> = slam.graph().edges().iter().filter(|e| e.robust).collect();
            (2 * lap..slam.graph().len())
                .filter(|&k| {
                    let from =
                        |pass: usize| closures.iter().any(|e| e.to == k && e.from / lap == pass);
                    from(0) && from(1)
                })
                .count()
        };
        let many = tied_to_both(GraphParams::default());
        let one = tied_to_both(GraphParams {
            closure_candidates: 1,
            ..GraphParams::default()
        });
        assert!(
            many >= 5,
            "{many} nodes of the third pass tied to both earlier passes"
        );
        assert_eq!(one, 0);
    }
    /// A URG-like scan (481 beams over ± 2 rad, 5.6 m) of `walls` from `truth`.
    fn scan_in(walls: &[(f64, f64, f64, f64)], truth: &Pose2) -> RangeScan {
        let mut scan = RangeScan {
            laser_noise_factor: 1.0,
            ..Default::default()
        };
        for i in 0..481 {
            let a = -2.0 + i as f64 * 4.0 / 480.0;
            let r = cast_in(walls, truth.x, truth.y, truth.theta + a).filter(|&r| r < 5.6);
            scan.beams.push(Beam {
                angle: a as f32,
                range: r.map(|r| r as f32),
                kind: BeamKind::Laser,
            });
        }
        scan
    }

    /// A back-end holding, as nodes at their true poses, scans of `target`
    /// every 0.3 m from x = 0 to 6 down the corridor, then one scan of
    /// `candidate` from `at` placed at `guess`: returns it and the node ids
    /// (the one nearest `at`, the last target node, the candidate).
    fn target_and_candidate(
        target: &[(f64, f64, f64, f64)],
        candidate: &[(f64, f64, f64, f64)],
        at: Pose2,
        guess: Pose2,
        p: GraphParams,
    ) -> (GraphSlam, usize, usize, usize) {
        let mut slam = GraphSlam::new(&SlamSection::default(), p);
        for n in 0..=20 {
            let pose = Pose2::new(0.3 * n as f64, 0.0, 0.0);
            slam.prepared.prepare(&scan_in(target, &pose), &slam.mp);
            slam.add_node(pose, 0.0);
        }
        slam.prepared.prepare(&scan_in(candidate, &at), &slam.mp);
        let k = slam.add_node(guess, 0.0);
        let j = (at.x / 0.3).round() as usize;
        (slam, j, k - 1, k)
    }

    /// [`FEATURES`] with a 3 m gap in the upper wall opening into a room
    /// 1.7 m deep that nodes driven down the plain corridor never saw into.
    const ROOM: [(f64, f64, f64, f64); 9] = [
        (-30.0, -1.2, 30.0, -1.2),
        (-30.0, 1.3, 1.0, 1.3),
        (4.0, 1.3, 30.0, 1.3),
        (1.0, 1.3, 1.0, 3.0),
        (1.0, 3.0, 4.0, 3.0),
        (4.0, 3.0, 4.0, 1.3),
        (7.0, -1.2, 7.0, 1.3),
        (2.0, 1.3, 2.0, 0.9),
        (-1.5, -1.2, -1.5, -0.8),
    ];

    /// The map covariance reads the cells the overlap test leaves; with the
    /// overlap threshold off (the default) that test was skipped, and the
    /// closure search read a cell set never sized: an overflow in a debug
    /// build (the SLAM process died), in a release one a closure as wide as
    /// the search window in every direction.
    #[test]
    fn the_map_covariance_works_with_the_overlap_threshold_off() {
        let at = Pose2::new(3.0, 0.0, 0.0);
        let p = GraphParams {
            closure_map_covariance: true,
            closure_min_overlap: 0.0,
            ..GraphParams::default()
        };
        let (mut slam, j, last, k) = target_and_candidate(&FEATURES, &FEATURES, at, at, p);
        let edge = slam
            .verify_closure(j, k, last, slam.own_window())
            .expect("a closure");
        // Nodes that saw the cross wall and the pillars fix it in x and y.
        let (ix, iy) = (edge.information[0][0], edge.information[1][1]);
        assert!(ix > 50.0 && iy > 50.0, "information x {ix}, y {iy}");
    }

    #[test]
    fn a_node_saw_what_its_beams_passed_through_or_ended_on() {
        // One beam straight ahead ending at 4 m, one to the left ending at 2 m;
        // the sensor 0.2 m ahead of the robot, the node at (1, 0) facing +y.
        let beams = vec![
            RobotBeam {
                x: 4.2,
                y: 0.0,
                hit: true,
                sonar: false,
                arc_flank: false,
                smoke_return: false,
            },
            RobotBeam {
                x: 0.2,
                y: 2.0,
                hit: true,
                sonar: false,
                arc_flank: false,
                smoke_return: false,
            },
        ];
        let node = Node::new(Vec::new(), beams, Pose2::new(0.2, 0.0, 0.0), 0.0);
        let pose = node.sensor_from_map(&Pose2::new(1.0, 0.0, std::f64::consts::FRAC_PI_2));
        // Ahead is +y in the map; the sensor is at (1, 0.2).
        assert!(node.saw(&pose, 1.0, 2.2, 0.15), "on the first beam");
        assert!(node.saw(&pose, 1.0, 4.2, 0.15), "at its end");
        assert!(node.saw(&pose, 1.1, 4.1, 0.15), "a little aside of it");
        assert!(!node.saw(&pose, 1.0, 4.6, 0.15), "past its end");
        assert!(!node.saw(&pose, 1.6, 2.2, 0.15), "between the beams");
        // The left beam points to -x in the map.
        assert!(node.saw(&pose, -0.5, 0.2, 0.15), "on the second beam");
        assert!(!node.saw(&pose, -1.5, 0.2, 0.15), "past its end");
        assert!(!node.saw(&pose, 1.0, -2.0, 0.15), "behind the sensor");
        assert!(!node.saw(&pose, f64::NAN, 0.0, 0.15));
    }

    #[test]
    fn a_scan_that_sees_past_what_the_target_nodes_saw_is_refused_for_low_overlap() {
        let at = Pose2::new(3.0, 0.0, 0.0);
        let guess = Pose2::new(3.2, 0.1, 0.02);
        let verify = |candidate: &[(f64, f64, f64, f64)], p: GraphParams| {
            let (mut slam, j, last, k) = target_and_candidate(&FEATURES, candidate, at, guess, p);
            let overlap = {
                let lo = j.saturating_sub(slam.p.closure_neighbours);
                let hi = (j + slam.p.closure_neighbours).min(last);
                slam.fill_world(lo, hi);
                slam.overlap(k, lo, hi, &at)
            };
            let edge = slam.verify_closure(j, k, last, slam.own_window());
            (overlap, edge, slam.stats())
        };
        // The same place: all of the scan falls where the target nodes looked.
        let on = GraphParams {
            closure_min_overlap: 0.75,
            ..GraphParams::default()
        };
        let (overlap, edge, stats) = verify(&FEATURES, on.clone());
        assert!(overlap > 0.95, "{overlap}");
        assert!(edge.is_some(), "{stats:?}");
        // Through the gap into the room: a good match on the corridor, but a
        // third of the scan is on walls the target map knows nothing of.
        let (overlap, edge, stats) = verify(&ROOM, on);
        assert!(overlap < 0.75, "{overlap}");
        assert!(edge.is_none());
        assert_eq!(stats.closures_low_overlap, 1, "{stats:?}");
        // Without the overlap test the score alone lets it through.
        let (_, edge, stats) = verify(
            &ROOM,
            GraphParams {
                closure_min_overlap: 0.0,
                ..GraphParams::default()
            },
        );
        assert!(edge.is_some(), "{stats:?}");
    }

    #[test]
    fn a_closure_against_nodes_that_saw_only_the_aisle_walls_is_wide_along_the_aisle() {
        let at = Pose2::new(3.0, 0.0, 0.0);
        let covariance = |target: &[(f64, f64, f64, f64)]| {
            let p = GraphParams {
                closure_map_covariance: true,
                ..GraphParams::default()
            };
            let (mut slam, _, last, k) = target_and_candidate(target, &FEATURES, at, at, p);
            slam.fill_world(0, last);
            slam.overlap(k, 0, last, &at);
            let scan_only = ScanConstraint::from_points(
                &slam.nodes[k]
                    .points
                    .iter()
                    .map(|&(x, y)| (x as f64, y as f64))
                    .collect::<Vec<_>>(),
            );
            let w = Matrix3::from_diagonal(&Vector3::new(0.75, 0.75, 0.04));
            let scan_only = scan_only.covariance(0.05f64.powi(2), &w, 1.0, &slam.degeneracy);
            (
                slam.closure_covariance(
                    k,
                    0,
                    last,
                    &at,
                    (slam.p.closure_window_m, slam.p.closure_window_rad),
                ),
                scan_only,
            )
        };
        // The scan sees the cross wall and the pillars: alone it fixes x.
        let (against_features, scan_only) = covariance(&FEATURES);
        assert!(scan_only[(0, 0)] < 0.01, "{scan_only}");
        assert!(against_features[(0, 0)] < 0.01, "{against_features}");
        // Nodes that saw only the two walls cannot say where along them it is.
        let (against_corridor, _) = covariance(&CORRIDOR);
        assert!(against_corridor[(0, 0)] > 0.1, "{against_corridor}");
        assert!(against_corridor[(1, 1)] < 0.01, "{against_corridor}");
    }
}
