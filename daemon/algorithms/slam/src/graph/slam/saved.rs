//! A saved mapping run, and the two ways to go on from it: keep mapping
//! (`--load-graph`) or localise on it without changing it
//! (`[slam] mode = "localization"`), as slam_toolbox offers.
//!
//! A saved run is two files: `G` is the pose graph as 2D g2o (what `smokenav
//! graph optimize` reads), and `G.scans` beside it carries what the g2o
//! cannot — each node's scan, so the map can be rendered again and matched
//! against — in a versioned text format:
//!
//! ```text
//! SMOKENAV_GRAPH_SCANS 1
//! NODES <n>                      the g2o's vertices are 0..n-1, in order
//! LAST_POSE <x> <y> <θ>          where the run ended (map frame)
//! ROBUST <edge index> …          edges (g2o order) with the robust kernel: loop closures
//! NODE <id> <sx> <sy> <sθ> <p> <b>   the laser's pose on the robot, then
//! P <x> <y> …                    p decimated laser endpoints (robot frame, m)
//! B <x> <y> <flags> …            b beams for the map (robot frame, m; flags: 1 hit, 2 sonar, 4 off the middle of a sonar arc)
//! ```
//!
//! Every number is written at full precision (`f32`/`f64` round-trip), so a
//! graph read back renders the bit-identical map. Lines starting with `#`
//! are comments. Input is distrusted: a missing or unknown record, a count
//! that does not match, a number that is not finite, a line over
//! [`MAX_LINE_BYTES`] is an error naming the file and line.
//!
//! Going on from a saved run, the first scan is placed where the run ended
//! (`[slam] resume_at = "last"`), where it began (`"first"`: a robot that
//! starts every run from its dock), or at [`SlamBackend::set_initial_pose`],
//! and matched against the saved
//! map around it (the loop-closure search window, branch and bound, for up
//! to [`SEARCH_SCANS`] scans until one matches and the next confirms it; an
//! operator's pose given mid-run, [`SlamBackend::relocalize`], starts that
//! search again around it, ± 3σ of what they said); then:
//! - **mapping**: that scan becomes a new node tied to the saved node nearest
//!   it (the last one carrying on, the first from the dock) by a robust edge
//!   (a loose one if the match failed), and mapping goes on as
//!   in one run — later loop closures reach the saved nodes like any others;
//! - **localization**: no node, edge or map cell is added. Each scan moves the
//!   pose by the front end's motion and is then matched against the saved
//!   nodes near it (± the tracker window); a match below the closure score
//!   threshold leaves the pose to the motion (counted).

use super::{GraphParams, GraphSlam, Node};
use crate::backend::{RelocalizeError, SlamBackend, SlamUpdate, StampedPose};
use crate::degeneracy::ScanConstraint;
use crate::graph::g2o;
use crate::graph::pose_graph::{Edge, PoseGraph};
use crate::rbpf::matcher::RobotBeam;
use crate::scan::RangeScan;
use nalgebra::Matrix3;
use smokenav_platform_config::{ResumeAt, SlamSection};
use smokenav_platform_map::OccupancyGrid;
use smokenav_shared_types::Pose2;
use std::fmt::Write as _;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Version of the `.scans` format this code writes and reads.
pub const SCANS_VERSION: u32 = 1;
/// Longest line of a `.scans` file (a node's beams: 682 beams take ~25 kB).
pub const MAX_LINE_BYTES: usize = 1 << 20;
/// Most endpoints or beams of one node.
pub const MAX_NODE_POINTS: usize = 100_000;

#[derive(Debug, thiserror::Error)]
pub enum SavedGraphError {
    #[error("{file}: {source}")]
    G2o {
        file: PathBuf,
        #[source]
        source: g2o::G2oError,
    },
    #[error("{file}: {message}")]
    Io { file: PathBuf, message: String },
    #[error("{file}:{line}: {reason}")]
    Scans {
        file: PathBuf,
        line: usize,
        reason: String,
    },
    #[error("{file}: {reason}")]
    Mismatch { file: PathBuf, reason: String },
}

/// The sidecar of a saved graph `G`: `G.scans`.
pub fn scans_path(g2o: &Path) -> PathBuf {
    let mut s = g2o.as_os_str().to_owned();
    s.push(".scans");
    PathBuf::from(s)
}

fn io_err(file: &Path, e: impl std::fmt::Display) -> SavedGraphError {
    SavedGraphError::Io {
        file: file.to_owned(),
        message: e.to_string(),
    }
}

/// Writes `g`'s graph to `path` (g2o) and its nodes' scans to [`scans_path`].
pub fn save(g: &GraphSlam, path: &Path) -> Result<(), SavedGraphError> {
    let mut text = Vec::new();
    g2o::write(&g.graph, &mut text).map_err(|e| io_err(path, e))?;
    std::fs::write(path, text).map_err(|e| io_err(path, e))?;
    let side = scans_path(path);
    std::fs::write(&side, scans_text(g)).map_err(|e| io_err(&side, e))
}

fn scans_text(g: &GraphSlam) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "SMOKENAV_GRAPH_SCANS {SCANS_VERSION}");
    let _ = writeln!(
        s,
        "# the nodes' scans of the pose graph beside this file (smokenav slam --save-graph)"
    );
    let _ = writeln!(s, "NODES {}", g.nodes.len());
    let last = g.pose().unwrap_or(g.initial);
    let _ = writeln!(s, "LAST_POSE {} {} {}", last.x, last.y, last.theta);
    s.push_str("ROBUST");
    for (i, e) in g.graph.edges().iter().enumerate() {
        if e.robust {
            let _ = write!(s, " {i}");
        }
    }
    s.push('\n');
    for (id, n) in g.nodes.iter().enumerate() {
        let _ = writeln!(
            s,
            "NODE {id} {} {} {} {} {}",
            n.sensor.x,
            n.sensor.y,
            n.sensor.theta,
            n.points.len(),
            n.beams.len()
        );
        s.push('P');
        for (x, y) in &n.points {
            let _ = write!(s, " {x} {y}");
        }
        s.push_str("\nB");
        for b in &n.beams {
            let flags = u8::from(b.hit)
                | (u8::from(b.sonar) << 1)
                | (u8::from(b.arc_flank) << 2)
                | (u8::from(b.smoke_return) << 3);
            let _ = write!(s, " {} {} {flags}", b.x, b.y);
        }
        s.push('\n');
    }
    s
}

/// Reads lines of a `.scans` file, skipping comments, with their numbers.
struct Lines<R> {
    input: R,
    file: PathBuf,
    line: usize,
    buf: Vec<u8>,
}

impl<R: BufRead> Lines<R> {
    fn err(&self, reason: impl Into<String>) -> SavedGraphError {
        SavedGraphError::Scans {
            file: self.file.clone(),
            line: self.line,
            reason: reason.into(),
        }
    }

    /// The next record's fields; `None` at the end of the file.
    fn next(&mut self) -> Result<Option<Vec<String>>, SavedGraphError> {
        loop {
            self.buf.clear();
            self.line += 1;
            let input: &mut R = &mut self.input;
            let n = std::io::Read::take(input, MAX_LINE_BYTES as u64 + 1)
                .read_until(b'\n', &mut self.buf)
                .map_err(|e| self.err(format!("read error: {e}")))?;
            if n == 0 {
                return Ok(None);
            }
            if self.buf.len() > MAX_LINE_BYTES {
                return Err(self.err(format!("longer than {MAX_LINE_BYTES} bytes")));
            }
            let text = std::str::from_utf8(&self.buf).map_err(|_| self.err("not UTF-8"))?;
            let text = text.trim();
            if text.is_empty() || text.starts_with('#') {
                continue;
            }
            return Ok(Some(text.split_whitespace().map(str::to_owned).collect()));
        }
    }

    /// The next record, which must be `tag` with `fields` fields after it (any number if `None`).
    fn expect(&mut self, tag: &str, fields: Option<usize>) -> Result<Vec<String>, SavedGraphError> {
        let Some(mut f) = self.next()? else {
            return Err(self.err(format!("the file ends where a {tag} record was expected")));
        };
        if f[0] != tag {
            return Err(self.err(format!("expected a {tag} record, got {:?}", f[0])));
        }
        f.remove(0);
        if let Some(n) = fields
            && f.len() != n
        {
            return Err(self.err(format!(
                "{tag} expects {n} fields after the tag, got {}",
                f.len()
            )));
        }
        Ok(f)
    }

    fn num<T: std::str::FromStr + Copy>(
        &self,
        f: &[String],
        i: usize,
        what: &str,
        finite: impl Fn(T) -> bool,
    ) -> Result<T, SavedGraphError> {
        match f[i].parse::<T>() {
            Ok(v) if finite(v) => Ok(v),
            _ => Err(self.err(format!(
                "field {} ({what}) is not a valid number: {:?}",
                i + 1,
                f[i]
            ))),
        }
    }
}

/// What a `.scans` file holds.
struct SavedScans {
    last_pose: Pose2,
    robust: Vec<usize>,
    nodes: Vec<Node>,
}

fn read_scans<R: BufRead>(input: R, file: &Path) -> Result<SavedScans, SavedGraphError> {
    let mut l = Lines {
        input,
        file: file.to_owned(),
        line: 0,
        buf: Vec::new(),
    };
    let v = l.expect("SMOKENAV_GRAPH_SCANS", Some(1))?;
    if v[0] != SCANS_VERSION.to_string() {
        return Err(l.err(format!(
            "version {} is not supported (this smokenav reads version {SCANS_VERSION})",
            v[0]
        )));
    }
    let f = l.expect("NODES", Some(1))?;
    let n: usize = l.num(&f, 0, "node count", |v: usize| v <= g2o::MAX_VERTICES)?;
    let f = l.expect("LAST_POSE", Some(3))?;
    let fin = |v: f64| v.is_finite();
    let last_pose = Pose2::new(
        l.num(&f, 0, "x", fin)?,
        l.num(&f, 1, "y", fin)?,
        l.num(&f, 2, "theta", fin)?,
    );
    let f = l.expect("ROBUST", None)?;
    let robust = (0..f.len())
        .map(|i| l.num(&f, i, "edge index", |_: usize| true))
        .collect::<Result<Vec<_>, _>>()?;
    let mut nodes = Vec::with_capacity(n.min(100_000));
    for id in 0..n {
        let f = l.expect("NODE", Some(6))?;
        let got: usize = l.num(&f, 0, "node id", |_: usize| true)?;
        if got != id {
            return Err(l.err(format!("node {got} where node {id} was expected")));
        }
        let sensor = Pose2::new(
            l.num(&f, 1, "sensor x", fin)?,
            l.num(&f, 2, "sensor y", fin)?,
            l.num(&f, 3, "sensor theta", fin)?,
        );
        let cap = |v: usize| v <= MAX_NODE_POINTS;
        let np: usize = l.num(&f, 4, "endpoint count", cap)?;
        let nb: usize = l.num(&f, 5, "beam count", cap)?;
        let f = l.expect("P", Some(2 * np))?;
        let fin32 = |v: f32| v.is_finite();
        let points = (0..np)
            .map(|i| {
                Ok((
                    l.num(&f, 2 * i, "x", fin32)?,
                    l.num(&f, 2 * i + 1, "y", fin32)?,
                ))
            })
            .collect::<Result<Vec<_>, SavedGraphError>>()?;
        let f = l.expect("B", Some(3 * nb))?;
        let beams = (0..nb)
            .map(|i| {
                let flags: u8 = l.num(&f, 3 * i + 2, "flags", |v: u8| v <= 15)?;
                Ok(RobotBeam {
                    x: l.num(&f, 3 * i, "x", fin)?,
                    y: l.num(&f, 3 * i + 1, "y", fin)?,
                    hit: flags & 1 != 0,
                    sonar: flags & 2 != 0,
                    arc_flank: flags & 4 != 0,
                    smoke_return: flags & 8 != 0,
                })
            })
            .collect::<Result<Vec<_>, SavedGraphError>>()?;
        nodes.push(Node::new(points, beams, sensor, 0.0));
    }
    if l.next()?.is_some() {
        return Err(l.err(format!("more records after the {n} nodes NODES announced")));
    }
    Ok(SavedScans {
        last_pose,
        robust,
        nodes,
    })
}

/// A saved run read back: the graph back-end as it ended, where it ended and
/// where it began (its first node, as optimised).
pub struct SavedRun {
    pub slam: GraphSlam,
    pub last_pose: Pose2,
    pub first_pose: Pose2,
}

/// Reads `path` (g2o) and its `.scans` sidecar into a graph back-end with `cfg`'s and `params`' settings.
pub fn load(
    cfg: &SlamSection,
    params: GraphParams,
    path: &Path,
) -> Result<SavedRun, SavedGraphError> {
    let file = std::fs::File::open(path).map_err(|e| io_err(path, e))?;
    let read = g2o::read(BufReader::new(file)).map_err(|source| SavedGraphError::G2o {
        file: path.to_owned(),
        source,
    })?;
    let side = scans_path(path);
    let file = std::fs::File::open(&side).map_err(|e| {
        io_err(
            &side,
            format!("{e} (a saved graph needs the nodes' scans beside it; smokenav slam --save-graph writes both)"),
        )
    })?;
    let saved = read_scans(BufReader::new(file), &side)?;
    let mismatch = |reason: String| SavedGraphError::Mismatch {
        file: side.clone(),
        reason,
    };
    if saved.nodes.len() != read.len() {
        return Err(mismatch(format!(
            "{} nodes, but {} has {} vertices",
            saved.nodes.len(),
            path.display(),
            read.len()
        )));
    }
    if let Some((i, id)) = read
        .ids()
        .iter()
        .enumerate()
        .find(|&(i, &id)| id != i as u64)
    {
        return Err(SavedGraphError::Mismatch {
            file: path.to_owned(),
            reason: format!(
                "vertex {id} is the {}-th vertex: a saved run's vertices are 0..n-1 in order",
                i + 1
            ),
        });
    }
    if let Some(&e) = saved.robust.iter().find(|&&e| e >= read.edges().len()) {
        return Err(mismatch(format!(
            "ROBUST names edge {e}, but {} has {} edges",
            path.display(),
            read.edges().len()
        )));
    }
    // The graph again, with the robust kernel where the run had it (g2o has no such field).
    let mut graph = PoseGraph::new();
    for (i, p) in read.poses().iter().enumerate() {
        graph.add_vertex(i as u64, *p);
        graph.set_fixed(i, read.is_fixed(i));
    }
    for (i, e) in read.edges().iter().enumerate() {
        graph.add_edge(Edge {
            robust: saved.robust.contains(&i),
            ..*e
        });
    }
    let mut slam = GraphSlam::new(cfg, params);
    slam.stats.nodes = saved.nodes.len() as u64;
    slam.nodes = saved.nodes.into_iter().map(Arc::new).collect();
    slam.graph = graph;
    slam.revision = 1;
    if let Some(last) = slam.graph.len().checked_sub(1) {
        slam.newest_cov = slam.exact_marginal(last).unwrap_or_else(Matrix3::zeros);
    }
    // Where the run ended, also for a save of the graph before any new scan.
    slam.initial = saved.last_pose;
    let first_pose = slam
        .graph
        .poses()
        .first()
        .copied()
        .unwrap_or(saved.last_pose);
    Ok(SavedRun {
        slam,
        last_pose: saved.last_pose,
        first_pose,
    })
}

/// Counters of localisation on a saved map.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LocalizationStats {
    pub scans: u64,
    /// Scans matched against the saved map (the pose is the match).
    pub matched: u64,
    /// Scans whose match was refused or impossible (the pose follows the motion).
    pub unmatched: u64,
    /// Unmatched scans since the last matched one: a long run of them is a
    /// robot lost on the map (or started at the wrong end, `resume_at`).
    pub unmatched_streak: u64,
    /// Poses an operator gave ([`SlamBackend::relocalize`]).
    pub relocalized: u64,
}

/// Scans in a row that matched nothing on the saved map before a localising
/// run says it is lost (3 s at 10 Hz: a doorway or a crowd passes).
pub const LOST_AFTER_SCANS: u64 = 30;

/// The graph back-end going on from a saved run ([`load`]): mapping on, or localising only.
pub struct ResumedGraph {
    inner: GraphSlam,
    localization: bool,
    /// Where the first scan is placed before it is matched.
    start: Pose2,
    started: bool,
    keep_trajectory: bool,
    // Localisation state.
    pose: Option<Pose2>,
    last_odom: Option<Pose2>,
    trajectory: Vec<StampedPose>,
    loc: LocalizationStats,
    /// Map-frame endpoints of the saved nodes near the scan (reused).
    local: Vec<Vec<(f32, f32)>>,
    /// The window (m, rad) scans are matched in after the start or an
    /// operator's pose, and how many scans more it is searched while none
    /// matches ([`SEARCH_SCANS`]).
    searching: Option<((f64, f64), u32)>,
    /// An operator's pose for the next scan ([`SlamBackend::relocalize`]).
    given: Option<Pose2>,
    /// A wide search's match, taken only once the next scan matches where
    /// the motion since carries it: one scan alone matched a wrong place
    /// metres off (the CSAIL prefix localised from its far end, 0.61 m ATE
    /// from 2 such scans).
    candidate: Option<Pose2>,
}

/// How far a wide search's match may be from the next scan's for the two to
/// confirm each other (m, rad): a tracker window's worth.
const CONFIRM_WITHIN: (f64, f64) = (0.15, 0.1);

/// Scans searched in the wide window after the start or an operator's pose
/// (1 s at 10 Hz: a person passing the laser), then the tracker's. Searched
/// wide for as long as the robot stays lost, the CSAIL prefix localised from
/// its far end matched 9 of 200 scans at places 4–8 m off, confirmed scan
/// by scan (a corridor repeats); a robot still lost after this waits for an
/// operator's pose, and health says it is lost.
pub const SEARCH_SCANS: u32 = 10;

/// The widest search around an operator's pose (3σ of what they said,
/// at least the closure window): a branch-and-bound match over ± 3 m and
/// ± 60° of the saved nodes near it stays within a scan period.
pub const MAX_RELOCALIZE_WINDOW: (f64, f64) = (3.0, std::f64::consts::FRAC_PI_3);

impl ResumedGraph {
    /// Starts at the saved run's last or first pose, as its settings'
    /// `resume_at` say (the first scan is matched against the saved map there).
    pub fn new(run: SavedRun, localization: bool, keep_trajectory: bool) -> Self {
        let start = match run.slam.cfg.resume_at {
            ResumeAt::Last => run.last_pose,
            ResumeAt::First => run.first_pose,
        };
        let wide = (run.slam.p.closure_window_m, run.slam.p.closure_window_rad);
        Self {
            inner: run.slam,
            localization,
            start,
            started: false,
            keep_trajectory,
            pose: None,
            last_odom: None,
            trajectory: Vec::new(),
            loc: LocalizationStats::default(),
            local: Vec::new(),
            searching: Some((wide, SEARCH_SCANS)),
            given: None,
            candidate: None,
        }
    }

    pub fn graph_slam(&self) -> &GraphSlam {
        &self.inner
    }

    pub fn localization_stats(&self) -> LocalizationStats {
        self.loc
    }

    /// Matches the prepared scan against the saved nodes within the closure
    /// search radius of `guess` (at most 60, nearest first) over ± `window`:
    /// the pose and its score, if it reaches the closure threshold and no
    /// rival scores nearly as high.
    fn match_saved(&mut self, guess: &Pose2, window: (f64, f64)) -> Option<(Pose2, f64)> {
        let g = &mut self.inner;
        let points: Vec<(f64, f64)> = g
            .prepared
            .points
            .iter()
            .filter(|p| p.from_laser)
            .map(|p| (p.hx, p.hy))
            .collect();
        if points.len() < g.min_laser_points {
            return None;
        }
        let mut near: Vec<(usize, f64)> = g
            .graph
            .poses()
            .iter()
            .enumerate()
            .map(|(i, x)| (i, (x.x - guess.x).hypot(x.y - guess.y)))
            // An operator's wide window reaches nodes past the closure radius.
            .filter(|&(_, d)| d <= g.p.closure_search_m.max(window.0 + 2.0))
            .collect();
        near.sort_by(|a, b| a.1.total_cmp(&b.1));
        near.truncate(60);
        if near.is_empty() {
            return None;
        }
        self.local.resize_with(near.len(), Vec::new);
        for (slot, &(n, _)) in self.local.iter_mut().zip(&near) {
            let x = g.graph.poses()[n];
            let (s, c) = x.theta.sin_cos();
            slot.clear();
            slot.extend(g.nodes[n].points.iter().map(|&(px, py)| {
                let (px, py) = (f64::from(px), f64::from(py));
                (
                    (x.x + c * px - s * py) as f32,
                    (x.y + s * px + c * py) as f32,
                )
            }));
        }
        let map: Vec<&[(f32, f32)]> = self.local.iter().map(|v| v.as_slice()).collect();
        let (pose, score, rival) = g.closer.match_against(
            &map,
            points.iter().copied(),
            guess,
            window.0,
            window.1,
            Some((g.p.closure_rival_m, g.p.closure_rival_ratio)),
        )?;
        if score < g.p.closure_min_score || rival > 0.0 {
            return None;
        }
        // Where the scan does not constrain the pose (along a bare wall) the
        // match may slide: keep the motion's value in those directions.
        let constraint = ScanConstraint::from_points(&points);
        Some((constraint.remap(guess, &pose, &g.degeneracy, None), score))
    }

    /// Mapping on: the first scan becomes a node tied to the last saved node.
    fn first_mapping_scan(&mut self, scan: &RangeScan, odom: &Pose2) -> SlamUpdate {
        let p = &self.inner.p;
        let window = self
            .searching
            .take()
            .map_or((p.closure_window_m, p.closure_window_rad), |(w, _)| w);
        self.inner.prepared.prepare(scan, &self.inner.mp);
        let start = self.start;
        let matched = self.match_saved(&start, window);
        let g = &mut self.inner;
        g.shared = None;
        g.stats.scans += 1;
        let pose = matched.map_or(start, |m| m.0);
        // Tied to the saved node nearest the start: the last one when the
        // run carries on where it ended, the first when it starts from the dock.
        let anchor = g
            .graph
            .poses()
            .iter()
            .enumerate()
            .min_by(|a, b| {
                let d = |p: &Pose2| (p.x - pose.x).hypot(p.y - pose.y);
                d(a.1).total_cmp(&d(b.1)).then(b.0.cmp(&a.0))
            })
            .map(|(i, _)| i);
        // The new node's covariance is carried from its anchor's marginal
        // (load() left the last node's; taken before the node is added,
        // which no edge ties down yet).
        if let Some(anchor) = anchor.filter(|&a| a + 1 != g.graph.len()) {
            g.newest_cov = g.exact_marginal(anchor).unwrap_or_else(Matrix3::zeros);
        }
        let k = g.add_node(pose, 0.0);
        if let Some(anchor) = anchor {
            // A matched start is as sure as a loop closure; an unmatched one is a guess.
            let (st, sr) = if matched.is_some() {
                g.p.closure_sigma
            } else {
                (1.0, 0.5)
            };
            g.add_chain_edge(Edge {
                from: anchor,
                to: k,
                measurement: g.graph.poses()[anchor].between(&pose),
                information: super::diagonal(st, sr),
                robust: true,
            });
        }
        g.last_node_tracked = *odom;
        g.last_tracked = *odom;
        g.last_odom = Some(*odom);
        g.since_node_cov = Matrix3::zeros();
        g.since_node_sonar = (0.0, 0);
        g.scans.push((scan.stamp_ns, k, Pose2::default()));
        g.update(scan.stamp_ns, pose, true)
    }

    /// One scan (`None`: one the motion filter held back, odometry only).
    fn localize(&mut self, stamp_ns: u64, scan: Option<&RangeScan>, odom: &Pose2) -> SlamUpdate {
        self.inner.shared = None;
        let processed = scan.is_some();
        let moved = match self.last_odom {
            Some(o) if odom.is_finite() => o.between(odom),
            _ => Pose2::default(),
        };
        let guess = match (self.given.take(), self.pose) {
            // Where the operator says the robot is now, not where it was.
            (Some(given), _) => {
                self.candidate = None;
                given
            }
            (None, Some(p)) => p.compose(&moved),
            _ => self.start,
        };
        let candidate = self.candidate.take().map(|c| c.compose(&moved));
        if odom.is_finite() {
            self.last_odom = Some(*odom);
        }
        let pose = if let Some(scan) = scan {
            self.loc.scans += 1;
            self.inner.prepared.prepare(scan, &self.inner.mp);
            let p = &self.inner.p;
            let tracker = (p.tracker_window_m, p.tracker_window_rad);
            // A wide match of the last scan, carried here by the motion:
            // confirmed if this scan matches there too.
            let confirmed = candidate.and_then(|c| {
                let (m, _) = self.match_saved(&c, tracker)?;
                let d = c.between(&m);
                (d.translation_norm() <= CONFIRM_WITHIN.0 && d.theta.abs() <= CONFIRM_WITHIN.1)
                    .then_some(m)
            });
            let matched = match (confirmed, self.searching) {
                (Some(m), _) => Some(m),
                // After the start or an operator's pose the robot may be
                // far from it: the wide window, and a match held until the
                // next scan confirms it.
                (None, Some((wide, left))) => {
                    self.candidate = self.match_saved(&guess, wide).map(|(m, _)| m);
                    // (A match of the last searched scan is still confirmed by the next.)
                    self.searching = (left > 1).then_some((wide, left - 1));
                    None
                }
                (None, None) => self.match_saved(&guess, tracker).map(|(m, _)| m),
            };
            match matched {
                Some(m) => {
                    self.loc.matched += 1;
                    self.loc.unmatched_streak = 0;
                    self.searching = None;
                    m
                }
                None => {
                    self.loc.unmatched += 1;
                    self.loc.unmatched_streak += 1;
                    guess
                }
            }
        } else {
            guess
        };
        self.pose = Some(pose);
        if self.keep_trajectory {
            self.trajectory.push(StampedPose { stamp_ns, pose });
        }
        SlamUpdate {
            // Not estimated while localising (zero: unknown); the inner
            // graph's newest marginal belongs to the saved run's end.
            covariance: Matrix3::zeros(),
            ..self.inner.update(stamp_ns, pose, processed)
        }
    }
}

impl SlamBackend for ResumedGraph {
    fn name(&self) -> &'static str {
        "graph"
    }

    fn process(&mut self, scan: &RangeScan, odom: &Pose2) -> SlamUpdate {
        let odom_ok = if odom.is_finite() {
            *odom
        } else {
            Pose2::default()
        };
        if self.localization {
            return self.localize(scan.stamp_ns, Some(scan), odom);
        }
        if !self.started {
            self.started = true;
            return self.first_mapping_scan(scan, &odom_ok);
        }
        self.inner.process(scan, odom)
    }

    fn frontend_match(&mut self, tracked: &crate::frontend::Tracked) {
        self.inner.frontend_match(tracked);
    }

    fn predict(&mut self, stamp_ns: u64, odom: &Pose2) -> SlamUpdate {
        if self.localization {
            return self.localize(stamp_ns, None, odom);
        }
        if !self.started {
            // Nothing to move from yet: the start is where the run ended.
            self.inner.shared = None;
            return self.inner.update(stamp_ns, self.start, false);
        }
        self.inner.predict(stamp_ns, odom)
    }

    fn odometry_reset(&mut self) {
        self.inner.odometry_reset();
        self.last_odom = None;
    }

    fn set_initial_pose(&mut self, pose: Pose2) {
        if !self.started && self.pose.is_none() {
            self.start = pose;
        }
    }

    fn relocalize(&mut self, pose: Pose2, sigma: (f64, f64)) -> Result<(), RelocalizeError> {
        if !(pose.is_finite() && sigma.0.is_finite() && sigma.1.is_finite()) {
            return Err(RelocalizeError::NotFinite);
        }
        if !self.localization && self.started {
            return Err(RelocalizeError::Mapping("graph"));
        }
        let p = &self.inner.p;
        let (max_m, max_rad) = MAX_RELOCALIZE_WINDOW;
        self.searching = Some((
            (
                (3.0 * sigma.0.abs()).clamp(p.closure_window_m, max_m),
                (3.0 * sigma.1.abs()).clamp(p.closure_window_rad, max_rad),
            ),
            SEARCH_SCANS,
        ));
        if self.localization && self.pose.is_some() {
            self.given = Some(pose);
        } else {
            self.start = pose;
        }
        self.loc.relocalized += 1;
        Ok(())
    }

    fn pose(&self) -> Option<Pose2> {
        if self.localization {
            self.pose
        } else if self.started {
            self.inner.pose()
        } else {
            None
        }
    }

    fn map_revision(&self) -> u64 {
        self.inner.map_revision()
    }

    fn map(&self) -> Option<OccupancyGrid> {
        self.inner.map()
    }

    fn map_job(&self) -> Option<crate::backend::MapJob> {
        self.inner.map_job()
    }

    fn trajectory(&self) -> Vec<StampedPose> {
        if self.localization {
            self.trajectory.clone()
        } else {
            self.inner.trajectory()
        }
    }

    fn metrics(&self, emit: &mut dyn FnMut(&'static str, f64)) {
        self.inner.metrics(emit);
        if self.localization {
            emit("localization_matched", self.loc.matched as f64);
            emit("localization_unmatched", self.loc.unmatched as f64);
            emit("localization_poses_given", self.loc.relocalized as f64);
        }
    }

    fn health_condition(&self) -> Option<String> {
        (self.localization && self.loc.unmatched_streak >= LOST_AFTER_SCANS).then(|| {
            format!(
                "localization: over {LOST_AFTER_SCANS} scans in a row matched nothing on the saved map (robot lost, or not where [slam] resume_at puts it: give its pose with `smokenav initial-pose` or RViz's 2D Pose Estimate)"
            )
        })
    }

    fn save_graph(&self, path: &Path) -> Option<Result<(), SavedGraphError>> {
        Some(save(&self.inner, path))
    }

    /// The graph back-end itself ([`GraphSlam`]), so tools that read its
    /// graph and counters work on a resumed run too; this wrapper is
    /// reached through [`ResumedGraph::graph_slam`]'s owner.
    fn as_any(&self) -> &dyn std::any::Any {
        self.inner.as_any()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testkit::scan_in;

    /// A 12 m × 7 m hall round a 6 m × 2 m block, with pillars and alcoves
    /// so every leg of the loop sees more than two parallel walls.
    const HALL: [(f64, f64, f64, f64); 13] = [
        (-6.0, -3.5, 6.0, -3.5),
        (6.0, -3.5, 6.0, 3.5),
        (6.0, 3.5, -6.0, 3.5),
        (-6.0, 3.5, -6.0, -3.5),
        (-3.0, -1.0, 3.0, -1.0),
        (3.0, -1.0, 3.0, 1.0),
        (3.0, 1.0, -3.0, 1.0),
        (-3.0, 1.0, -3.0, -1.0),
        (-1.0, -3.5, -1.0, -2.9),
        (2.0, 3.5, 2.0, 3.0),
        (6.0, 0.5, 5.4, 0.5),
        (-6.0, -0.5, -5.5, -0.5),
        (4.2, -2.4, 4.5, -2.1),
    ];
    const START: Pose2 = Pose2 {
        x: -4.5,
        y: -2.2,
        theta: 0.0,
    };

    fn scan_at(truth: &Pose2, stamp_ns: u64) -> RangeScan {
        scan_in(&HALL, 5.6, truth, stamp_ns)
    }

    /// Two laps round the block (0.2 m a scan, corners in five steps) with
    /// odometry 3 % long and 2 % wide in turns: (truth, scan, odometry) per scan.
    fn route() -> Vec<(Pose2, RangeScan, Pose2)> {
        let mut truth = START;
        let mut odom = Pose2::new(1.0, 2.0, 0.3);
        let mut out = Vec::new();
        for len in [9.0, 4.4, 9.0, 4.4].repeat(2) {
            let steps = (len / 0.2_f64).round() as usize;
            let mut moves = vec![Pose2::new(0.2, 0.0, 0.0); steps];
            moves.extend((0..5).map(|_| Pose2::new(0.0, 0.0, std::f64::consts::FRAC_PI_2 / 5.0)));
            for step in moves {
                let k = out.len() as u64;
                out.push((truth, scan_at(&truth, k * 100_000_000), odom));
                truth = truth.compose(&step);
                odom = odom.compose(&Pose2::new(step.x * 1.03, 0.0, step.theta * 1.02));
            }
        }
        out
    }

    fn run(slam: &mut dyn SlamBackend, part: &[(Pose2, RangeScan, Pose2)]) -> Vec<Pose2> {
        part.iter()
            .map(|(_, s, o)| slam.process(s, o).pose)
            .collect()
    }

    /// Largest distance of the estimates from the truth (both from START).
    fn worst_error(est: &[Pose2], part: &[(Pose2, RangeScan, Pose2)]) -> f64 {
        est.iter()
            .zip(part)
            .map(|(e, (t, _, _))| {
                let t = START.between(t);
                (e.x - t.x).hypot(e.y - t.y)
            })
            .fold(0.0, f64::max)
    }

    fn first_half_saved(dir: &Path) -> (PathBuf, Vec<(Pose2, RangeScan, Pose2)>, usize) {
        let r = route();
        let half = r.len() / 2;
        let mut slam = GraphSlam::new(&SlamSection::default(), GraphParams::default());
        run(&mut slam, &r[..half]);
        let path = dir.join("first.g2o");
        save(&slam, &path).unwrap();
        (path, r, half)
    }

    #[test]
    fn a_saved_run_reads_back_to_the_same_graph_and_map_bit_for_bit() {
        let dir = tempfile::tempdir().unwrap();
        let r = route();
        let mut slam = GraphSlam::new(&SlamSection::default(), GraphParams::default());
        run(&mut slam, &r[..r.len() / 2]);
        assert!(
            slam.graph.edges().iter().any(|e| e.robust),
            "a closure to save"
        );
        let path = dir.path().join("run.g2o");
        save(&slam, &path).unwrap();
        let back = load(&SlamSection::default(), GraphParams::default(), &path).unwrap();
        assert_eq!(back.slam.graph.poses(), slam.graph.poses());
        // g2o carries the information's upper triangle (the lower one mirrors it).
        let upper = |e: &Edge| {
            (
                e.from,
                e.to,
                e.measurement,
                e.robust,
                [0, 1, 2, 4, 5, 8].map(|i| e.information[i / 3][i % 3]),
            )
        };
        let edges = |g: &GraphSlam| g.graph.edges().iter().map(upper).collect::<Vec<_>>();
        assert_eq!(edges(&back.slam), edges(&slam));
        assert_eq!(back.last_pose, slam.pose().unwrap());
        assert_eq!(back.slam.map(), slam.map());
        let again = dir.path().join("again.g2o");
        save(&back.slam, &again).unwrap();
        for (a, b) in [(&path, &again), (&scans_path(&path), &scans_path(&again))] {
            assert_eq!(std::fs::read(a).unwrap(), std::fs::read(b).unwrap());
        }
    }

    #[test]
    fn continuing_a_run_split_in_two_halves_matches_the_whole_run() {
        let dir = tempfile::tempdir().unwrap();
        let (path, r, half) = first_half_saved(dir.path());
        let mut whole = GraphSlam::new(&SlamSection::default(), GraphParams::default());
        let all = run(&mut whole, &r);
        let saved = load(&SlamSection::default(), GraphParams::default(), &path).unwrap();
        let nodes_before = saved.slam.nodes.len();
        let mut resumed = ResumedGraph::new(saved, false, true);
        run(&mut resumed, &r[half..]);
        // The final estimates (after every closure) of the second half.
        let second: Vec<Pose2> = resumed.trajectory().iter().map(|p| p.pose).collect();
        let whole_second: Vec<Pose2> = whole.trajectory()[half..].iter().map(|p| p.pose).collect();
        assert_eq!(second.len(), r.len() - half);
        let (e_split, e_whole) = (
            worst_error(&second, &r[half..]),
            worst_error(&whole_second, &r[half..]),
        );
        let apart = second
            .iter()
            .zip(&whole_second)
            .map(|(a, b)| (a.x - b.x).hypot(a.y - b.y))
            .fold(0.0, f64::max);
        let g = resumed.graph_slam();
        eprintln!(
            "second half: worst {e_split:.3} m continued, {e_whole:.3} m in one run, {apart:.3} m apart; whole run {:.3} m; {:?}",
            worst_error(&all, &r),
            g.stats()
        );
        assert!(g.nodes.len() > nodes_before, "mapping went on");
        assert!(
            g.stats().closures_accepted >= 1,
            "the second lap closes onto the saved nodes: {:?}",
            g.stats()
        );
        assert!(
            e_split < 0.15 && apart < 0.15,
            "{e_split} m, {apart} m apart"
        );
    }

    /// `resume_at = "first"`: the first half driven again from its start is
    /// tracked on the saved map (localising) and, mapping, its first node is
    /// tied to the saved run's first node, where it is, not to the last.
    #[test]
    fn a_run_resumed_at_the_first_node_starts_where_the_saved_run_began() {
        let dir = tempfile::tempdir().unwrap();
        let (path, r, half) = first_half_saved(dir.path());
        let cfg = SlamSection {
            resume_at: ResumeAt::First,
            ..SlamSection::default()
        };
        let saved = load(&cfg, GraphParams::default(), &path).unwrap();
        let first = saved.first_pose;
        assert_eq!(first, saved.slam.graph.poses()[0]);
        let mut loc = ResumedGraph::new(saved, true, true);
        let est = run(&mut loc, &r[..half]);
        let worst = worst_error(&est, &r[..half]);
        let s = loc.localization_stats();
        eprintln!("the first half again, from its first node: worst {worst:.3} m; {s:?}");
        assert!(worst < 0.1, "{worst} m off the truth");
        assert!(s.matched as usize > half * 9 / 10, "{s:?}");
        assert_eq!(loc.health_condition(), None);

        let saved = load(&cfg, GraphParams::default(), &path).unwrap();
        let n = saved.slam.graph.len();
        let mut mapping = ResumedGraph::new(saved, false, true);
        run(&mut mapping, &r[..1]);
        let g = mapping.graph_slam();
        let tie = g
            .graph
            .edges()
            .iter()
            .find(|e| e.to == n)
            .expect("the new node's edge");
        let p = g.graph.poses()[n];
        assert!(
            (p.x - first.x).hypot(p.y - first.y) < 0.1,
            "{p:?} vs {first:?}"
        );
        // The hall's first half comes back past its start: the nearest saved
        // node may be a later one, never one far away (the last, on another route).
        let d = |q: &Pose2| (q.x - p.x).hypot(q.y - p.y);
        let nearest = g.graph.poses()[..n]
            .iter()
            .map(d)
            .fold(f64::INFINITY, f64::min);
        assert!(d(&g.graph.poses()[tie.from]) <= nearest + 0.05, "{tie:?}");
    }

    /// A localising robot put on the wrong side of the block is lost (and
    /// says so) until an operator gives its pose, half a metre and 11° off:
    /// from there it is tracked on the saved map again.
    #[test]
    fn a_lost_localization_is_found_again_from_an_operators_pose() {
        let dir = tempfile::tempdir().unwrap();
        let (path, r, half) = first_half_saved(dir.path());
        let saved = load(&SlamSection::default(), GraphParams::default(), &path).unwrap();
        let mut loc = ResumedGraph::new(saved, true, true);
        // The far side of the block, facing the other way.
        loc.set_initial_pose(Pose2::new(0.0, 4.4, std::f64::consts::PI));
        let lost_for = LOST_AFTER_SCANS as usize + 5;
        run(&mut loc, &r[half..half + lost_for]);
        let s = loc.localization_stats();
        assert_eq!(s.matched, 0, "{s:?}");
        assert!(loc.health_condition().is_some(), "{s:?}");

        let from = half + lost_for;
        let truth = START.between(&r[from].0);
        let said = truth.compose(&Pose2::new(0.4, -0.3, 0.2));
        loc.relocalize(said, (0.5, 0.25)).unwrap();
        let est = run(&mut loc, &r[from..]);
        let s = loc.localization_stats();
        // The first scan's match waits for the second to confirm it: until
        // then the pose is the operator's.
        assert_eq!(est[0], said);
        let worst = worst_error(&est[1..], &r[from + 1..]);
        eprintln!("found again from the operator's pose: worst {worst:.3} m; {s:?}");
        assert!(worst < 0.1, "{worst} m off the truth");
        assert_eq!(s.relocalized, 1);
        assert!(s.matched as usize > (r.len() - from) * 9 / 10, "{s:?}");
        assert_eq!(loc.health_condition(), None);
        assert_eq!(
            loc.relocalize(Pose2::new(f64::NAN, 0.0, 0.0), (0.5, 0.2)),
            Err(RelocalizeError::NotFinite)
        );
    }

    /// Mapping takes an operator's pose before its first scan only: later it
    /// would tear the map built so far.
    #[test]
    fn a_mapping_run_takes_an_operators_pose_only_before_its_first_scan() {
        let dir = tempfile::tempdir().unwrap();
        let (path, r, half) = first_half_saved(dir.path());
        let saved = load(&SlamSection::default(), GraphParams::default(), &path).unwrap();
        let mut mapping = ResumedGraph::new(saved, false, true);
        let at = START.between(&r[half].0);
        assert_eq!(mapping.relocalize(at, (0.2, 0.1)), Ok(()));
        run(&mut mapping, &r[half..half + 1]);
        let p = mapping.pose().unwrap();
        assert!((p.x - at.x).hypot(p.y - at.y) < 0.1, "{p:?} vs {at:?}");
        assert_eq!(
            mapping.relocalize(at, (0.2, 0.1)),
            Err(RelocalizeError::Mapping("graph"))
        );
        let mut fresh = GraphSlam::new(&SlamSection::default(), GraphParams::default());
        assert_eq!(
            fresh.relocalize(Pose2::new(1.0, 2.0, 0.5), (0.0, 0.0)),
            Ok(())
        );
        let first = fresh.process(&r[0].1, &r[0].2).pose;
        assert_eq!(first, Pose2::new(1.0, 2.0, 0.5));
        assert!(fresh.relocalize(first, (0.0, 0.0)).is_err());
    }

    #[test]
    fn localization_on_the_first_halfs_graph_tracks_and_leaves_the_map_unchanged() {
        let dir = tempfile::tempdir().unwrap();
        let (path, r, half) = first_half_saved(dir.path());
        let saved = load(&SlamSection::default(), GraphParams::default(), &path).unwrap();
        let map_before = saved.slam.map().unwrap();
        let (poses, edges) = (
            saved.slam.graph.poses().to_vec(),
            saved.slam.graph.edges().to_vec(),
        );
        let mut loc = ResumedGraph::new(saved, true, true);
        let est = run(&mut loc, &r[half..]);
        let worst = worst_error(&est, &r[half..]);
        let s = loc.localization_stats();
        eprintln!("localisation on the first lap's graph: worst {worst:.3} m; {s:?}");
        assert!(worst < 0.1, "{worst} m off the truth");
        assert!(s.matched as usize > (r.len() - half) * 9 / 10, "{s:?}");
        let g = loc.graph_slam();
        assert_eq!(g.graph.poses(), poses.as_slice());
        assert_eq!(g.graph.edges(), edges.as_slice());
        assert_eq!(loc.map().unwrap(), map_before, "the map is bit-equal");
        // And saved again it is the same pair of files.
        let again = dir.path().join("again.g2o");
        save(g, &again).unwrap();
        for (a, b) in [(&path, &again), (&scans_path(&path), &scans_path(&again))] {
            assert_eq!(std::fs::read(a).unwrap(), std::fs::read(b).unwrap());
        }
    }

    #[test]
    fn a_damaged_sidecar_is_reported_with_its_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let (path, _, _) = first_half_saved(dir.path());
        let side = scans_path(&path);
        let good = std::fs::read_to_string(&side).unwrap();
        let load_err = || {
            load(&SlamSection::default(), GraphParams::default(), &path)
                .err()
                .expect("an error")
                .to_string()
        };
        // A number that is not one, on the first endpoint line (line 7).
        let bad = good.replacen("\nP ", "\nP x", 1);
        std::fs::write(&side, &bad).unwrap();
        let e = load_err();
        assert!(e.contains("first.g2o.scans:7:") && e.contains("\"x"), "{e}");
        // Another version.
        std::fs::write(&side, good.replacen("SCANS 1", "SCANS 9", 1)).unwrap();
        let e = load_err();
        assert!(e.contains(":1:") && e.contains("version 9"), "{e}");
        // A node too few.
        let cut = good.rfind("\nNODE ").unwrap();
        std::fs::write(&side, &good[..cut + 1]).unwrap();
        let e = load_err();
        assert!(e.contains("ends where a NODE record was expected"), "{e}");
        // No sidecar at all.
        std::fs::remove_file(&side).unwrap();
        let e = load_err();
        assert!(
            e.contains("first.g2o.scans") && e.contains("--save-graph"),
            "{e}"
        );
    }
}
