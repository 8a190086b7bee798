//! SLAM fusion by voting (SLAMfusion, Fernandes & Alexandre): several
//! back-ends map from the same scans and odometry, their maps are aligned to
//! one of them and every cell is set by a vote (`[slam] backend = "vote"`,
//! `[slam.vote]`).
//!
//! The paper ran GMapping, Karto and RTAB-Map as separate ROS nodes and fused
//! their maps offline on a GPU (25 s per batch). On one robot every member
//! sees the same odometry frame, so here it runs online on a CPU:
//!
//! - **Members** ([`member`]): each back-end of `[slam.vote] members` runs on
//!   its own thread behind a bounded queue. The pipeline's thread hands every
//!   scan (one shared copy, from a small pool) and every held-back odometry
//!   to each queue without waiting; a member whose queue is full drops the
//!   job and counts it. A member that panics is out for good; one busy with a
//!   scan for longer than `stall_timeout_s` is out while it stays so; the vote
//!   goes on with the rest, and [`VoteSlam::status`] names who is out.
//! - **Alignment** ([`align`]): the first member's map is the frame. Each
//!   other member's map is aligned to it by a coarse-to-fine search over
//!   (x, y, θ) around the shared odometry frame — and, while its last
//!   alignment fits, around that with a quarter of the window: one search per
//!   update, warm-started — only when its `map_revision` or the reference's
//!   changed. The residual (robust: RMS distance of the nearest 80 % of its
//!   walls to the reference's) is reported; a member above `max_residual_m`
//!   is flagged in health and left out of the vote, and its next search
//!   spans the whole window again.
//! - **Vote** ([`rule`]): per cell of the reference's grid over occupied /
//!   free / unknown, the paper's majority (no majority → occupied; with two
//!   members left, the first of them decides), one of its variants that
//!   break a three-way split otherwise, or the weighted variant. Recomputed
//!   every `fuse_period_s` on a thread of its own (online) or when the map
//!   is asked for (lockstep).
//! - **Fused pose**: the pose of the member whose map agrees best with the
//!   vote (share of its known cells with the fused state; before the first
//!   vote, the reference member), taken into the reference frame by its
//!   alignment and carried forward by the odometry since the scan it last
//!   used (so a member a few scans behind does not hold the pose back). Its
//!   covariance is that member's. The trajectory offline is that member's,
//!   aligned.
//!
//! Offline (`lockstep`), each scan is handed to every member and waited for
//! (members still run in parallel): nothing is dropped and a run is
//! reproducible.

pub mod align;
pub mod local;
pub mod member;
pub mod rule;

use crate::backend::{BackendOptions, SlamBackend, SlamUpdate, StampedPose, from_config};
use crate::frontend::Tracked;
use crate::graph::saved::SavedGraphError;
use crate::scan::{BeamKind, RangeScan};
use align::{Alignment, DistanceField, SearchWindow, align_with, wall_points};
use member::{Job, Member, MemberFault, WorkerConfig};
use nalgebra::Matrix3;
use rule::{
    CellState, Consensus, WeightedVote, corroborated_doubt, majority_or,
    reference_corroborated_doubt, strict_majority, weighted,
};
use smokenav_platform_config::{SlamSection, VoteRule, VoteSection};
use smokenav_platform_map::OccupancyGrid;
use smokenav_shared_types::Pose2;
use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Why a member does not vote.
#[derive(Debug, Clone, PartialEq)]
pub enum MemberHealth {
    /// Voting.
    In,
    /// Its thread panicked (message).
    Panicked(String),
    /// Busy with one job for longer than the stall timeout (that timeout), s.
    Stalled(f64),
    /// Its alignment residual is above `max_residual_m`, m.
    Misaligned(f64),
    /// No map yet.
    NoMap,
}

impl MemberHealth {
    pub fn is_out(&self) -> bool {
        !matches!(self, MemberHealth::In | MemberHealth::NoMap)
    }
}

impl std::fmt::Display for MemberHealth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MemberHealth::In => write!(f, "in"),
            MemberHealth::Panicked(m) => write!(f, "out (panicked: {m})"),
            MemberHealth::Stalled(s) => write!(f, "out (stalled: one job over {s:.1} s)"),
            MemberHealth::Misaligned(r) => write!(f, "out (alignment residual {r:.3} m)"),
            MemberHealth::NoMap => write!(f, "no map yet"),
        }
    }
}

/// One member as the vote sees it.
#[derive(Debug, Clone)]
pub struct MemberStatus {
    pub name: &'static str,
    pub health: MemberHealth,
    /// Jobs dropped because its queue was full.
    pub drops: u64,
    /// Its last alignment to the reference (the reference: identity, 0).
    pub alignment: Option<Alignment>,
    /// Its last exported map and that map's revision.
    pub map: Option<(Arc<OccupancyGrid>, u64)>,
    /// Share of its known cells whose state is the vote's, at the last vote.
    pub agreement: Option<f64>,
    /// Blocks of its map re-aligned locally at the last vote (`local_residual_m`).
    pub local_blocks: u32,
}

/// The vote's state, for health and the member map topics.
#[derive(Debug, Clone, Default)]
pub struct VoteStatus {
    pub members: Vec<MemberStatus>,
    /// Fused updates done.
    pub fuses: u64,
    /// Time of the last fused update (alignment + vote), ms.
    pub last_fuse_ms: f64,
    /// The member the fused pose comes from.
    pub pose_member: Option<&'static str>,
    /// Cells of the last vote set occupied by the members that map in
    /// height (obstacles out of the laser plane) over the others' vote.
    pub out_of_plane_cells: u64,
}

/// What one fused update produced.
#[derive(Debug, Clone, Default)]
struct FusedOut {
    map: Option<Arc<OccupancyGrid>>,
    revision: u64,
    fuses: u64,
    fuse_ms: f64,
    /// Per member: alignment, agreement.
    alignments: Vec<Option<Alignment>>,
    agreement: Vec<Option<f64>>,
    misaligned: Vec<bool>,
    /// Per member: blocks re-aligned locally in the last update.
    local_blocks: Vec<u32>,
    /// Members that voted in the laser plane in the last update.
    plane_voters: usize,
    pose_member: Option<usize>,
    /// Cells the members mapping in height made occupied over the others' vote.
    out_of_plane_cells: u64,
}

/// Evidence per 1 m block of the fused frame: laser and sonar endpoints.
#[derive(Debug, Clone, Default)]
struct SonarShare {
    blocks: HashMap<(i32, i32), (u32, u32)>,
}

/// Blocks kept (1 m each): 1 km², beyond which new blocks are not counted.
const MAX_SONAR_BLOCKS: usize = 1_000_000;

impl SonarShare {
    fn add(&mut self, scan: &RangeScan, robot: &Pose2) {
        let sensor = robot.compose(&scan.sensor_pose);
        let (s, c) = sensor.theta.sin_cos();
        for b in &scan.beams {
            let Some(r) = b.range else { continue };
            let (a, r) = (f64::from(b.angle), f64::from(r));
            let (lx, ly) = (r * a.cos(), r * a.sin());
            let (x, y) = (sensor.x + c * lx - s * ly, sensor.y + s * lx + c * ly);
            if !(x.is_finite() && y.is_finite()) {
                continue;
            }
            let key = (x.floor() as i32, y.floor() as i32);
            if self.blocks.len() >= MAX_SONAR_BLOCKS && !self.blocks.contains_key(&key) {
                continue;
            }
            let e = self.blocks.entry(key).or_default();
            match b.kind {
                BeamKind::Laser => e.0 = e.0.saturating_add(1),
                BeamKind::Sonar => e.1 = e.1.saturating_add(1),
            }
        }
    }

    fn share(&self, x: f64, y: f64) -> f64 {
        match self.blocks.get(&(x.floor() as i32, y.floor() as i32)) {
            Some(&(l, s)) if l + s > 0 => f64::from(s) / f64::from(l + s),
            _ => 0.0,
        }
    }
}

/// The member inputs of one fused update.
struct FuseInput {
    map: Option<(Arc<OccupancyGrid>, u64)>,
    /// Obstacles out of the laser plane, on `map`'s grid (the projected map).
    below: Option<Arc<OccupancyGrid>>,
    /// Out for a reason other than its alignment.
    out: bool,
    /// Pose weight from its covariance.
    weight: f64,
}

/// Alignment and vote state, kept between fused updates.
struct Fuser {
    p: VoteParams,
    field: DistanceField,
    field_revision: Option<u64>,
    aligned_at: Vec<Option<(u64, u64)>>,
    points: Vec<(f64, f64)>,
    scratch: Vec<f32>,
    out: FusedOut,
    votes: Vec<CellState>,
    wvotes: Vec<WeightedVote>,
    /// Member-major resampled cells, their states and the fused states (scratch).
    values: Vec<i8>,
    states: Vec<CellState>,
    fused_states: Vec<CellState>,
    consensus: Consensus,
}

impl Fuser {
    fn new(p: VoteParams, members: usize) -> Self {
        Self {
            p,
            field: DistanceField::default(),
            field_revision: None,
            aligned_at: vec![None; members],
            points: Vec::new(),
            scratch: Vec::new(),
            out: FusedOut {
                alignments: vec![None; members],
                agreement: vec![None; members],
                misaligned: vec![false; members],
                local_blocks: vec![0; members],
                ..FusedOut::default()
            },
            votes: Vec::with_capacity(members),
            wvotes: Vec::with_capacity(members),
            values: Vec::new(),
            states: Vec::new(),
            fused_states: Vec::new(),
            consensus: Consensus::default(),
        }
    }

    /// One fused update; false when there is nothing to do (no reference map,
    /// or no map changed since the last update).
    fn fuse(&mut self, inputs: &[FuseInput], sonar: &SonarShare, force: bool) -> bool {
        let t0 = Instant::now();
        let Some((reference, ref_rev)) = inputs[0].map.clone() else {
            return false;
        };
        let unchanged = self.field_revision == Some(ref_rev)
            && inputs.iter().enumerate().all(|(i, m)| {
                m.map.is_none()
                    || m.out
                    || self.aligned_at[i].is_some_and(|(r, rr)| {
                        Some(r) == m.map.as_ref().map(|x| x.1) && rr == ref_rev
                    })
            });
        if unchanged && !force && self.out.map.is_some() {
            return false;
        }
        if self.field_revision != Some(ref_rev) {
            self.field
                .rebuild(&reference, self.p.section.align_truncation_m);
            self.field_revision = Some(ref_rev);
        }
        self.out.alignments[0] = Some(Alignment {
            transform: Pose2::default(),
            residual_m: 0.0,
            points: 0,
            evaluations: 0,
        });
        self.aligned_at[0] = Some((ref_rev, ref_rev));
        let s = &self.p.section;
        for (i, m) in inputs.iter().enumerate().skip(1) {
            let Some((grid, rev)) = &m.map else { continue };
            if m.out || self.aligned_at[i] == Some((*rev, ref_rev)) {
                continue;
            }
            wall_points(grid, s.align_max_points as usize, &mut self.points);
            if self.points.is_empty() {
                continue;
            }
            let full = SearchWindow {
                center: Pose2::default(),
                window_m: s.align_window_m,
                window_rad: s.align_window_rad,
            };
            // One search per update: around the last alignment with a quarter
            // of the window while it fits, over the whole window when it did
            // not (or the first time). A member that stays above the threshold
            // is flagged every update and costs one wide search each.
            let win = match self.out.alignments[i] {
                Some(prev) if prev.residual_m <= s.max_residual_m => SearchWindow {
                    center: prev.transform,
                    window_m: s.align_window_m / 4.0,
                    window_rad: s.align_window_rad / 4.0,
                },
                _ => full,
            };
            let a = align_with(&self.field, &self.points, &win, &mut self.scratch);
            self.out.alignments[i] = Some(a);
            self.aligned_at[i] = Some((*rev, ref_rev));
        }
        // Who votes: members in, with a map, aligned within the threshold.
        let mut voters: Vec<(usize, &OccupancyGrid, Pose2, f64)> = Vec::new();
        let mut below: Vec<(usize, &OccupancyGrid)> = Vec::new();
        for (i, m) in inputs.iter().enumerate() {
            let Some((grid, _)) = &m.map else { continue };
            let a = self.out.alignments[i];
            let misaligned = a.is_some_and(|a| a.residual_m > s.max_residual_m);
            self.out.misaligned[i] = misaligned;
            if m.out || misaligned {
                continue;
            }
            let Some(a) = a else { continue };
            // Reference point → member point: the inverse of member → reference.
            voters.push((i, grid.as_ref(), a.transform.inverse(), m.weight));
            if let Some(b) = &m.below
                && (b.width, b.height, b.origin) == (grid.width, grid.height, grid.origin)
            {
                below.push((voters.len() - 1, b.as_ref()));
            }
        }
        if voters.is_empty() {
            return false;
        }
        let mut fused = match self.out.map.take() {
            Some(prev) if prev.width == reference.width && prev.height == reference.height => {
                Arc::try_unwrap(prev).unwrap_or_else(|a| (*a).clone())
            }
            _ => OccupancyGrid::new(
                reference.width,
                reference.height,
                reference.resolution,
                reference.origin,
            ),
        };
        fused.origin = reference.origin;
        fused.resolution = reference.resolution;
        let mut agree = vec![(0u64, 0u64); inputs.len()];
        let (w, h, res) = (reference.width, reference.height, reference.resolution);
        let (ox, oy) = (reference.origin[0], reference.origin[1]);
        let rule = s.rule;
        // Per member: reference cell centre → member cell, as an affine map in cells.
        let maps: Vec<(usize, &OccupancyGrid, [f64; 6], f64)> = voters
            .iter()
            .map(|&(i, g, t, wgt)| {
                let (sn, cs) = t.theta.sin_cos();
                // member = R·p + t, p = (ox + (x+.5)res, oy + (y+.5)res); in member cells.
                let inv = 1.0 / g.resolution;
                let a = [
                    cs * res * inv,
                    -sn * res * inv,
                    (cs * (ox + 0.5 * res) - sn * (oy + 0.5 * res) + t.x - g.origin[0]) * inv,
                    sn * res * inv,
                    cs * res * inv,
                    (sn * (ox + 0.5 * res) + cs * (oy + 0.5 * res) + t.y - g.origin[1]) * inv,
                ];
                (i, g, a, wgt)
            })
            .collect();
        // A member that maps in height votes out of the laser plane only: in
        // it, its map is the same laser at another member's poses (the
        // graph's), no evidence of its own. Unless no other member is left.
        let height: Vec<([f64; 6], &OccupancyGrid)> =
            below.iter().map(|&(k, b)| (maps[k].2, b)).collect();
        let maps: Vec<(usize, &OccupancyGrid, [f64; 6], f64)> = if height.len() < maps.len() {
            maps.into_iter()
                .enumerate()
                .filter(|(k, _)| !below.iter().any(|b| b.0 == *k))
                .map(|(_, m)| m)
                .collect()
        } else {
            maps
        };
        // Every member's cell for every reference cell, member-major, then the vote.
        let (n, k_n) = (w * h, maps.len());
        self.out.plane_voters = k_n;
        self.values.clear();
        self.values.resize(k_n * n, -1);
        for (k, (_, g, a, _)) in maps.iter().enumerate() {
            let layer = &mut self.values[k * n..(k + 1) * n];
            for y in 0..h {
                for x in 0..w {
                    layer[y * w + x] = local::sample(g, a, x as f64, y as f64, 0, 0);
                }
            }
        }
        // Members the rigid transform leaves apart: block by block onto the
        // first voter's walls.
        let block = (s.local_block_m / res).round().max(1.0) as usize;
        let shift = i64::from(s.local_shift_cells);
        self.out.local_blocks.iter_mut().for_each(|b| *b = 0);
        if k_n > 1 {
            let (first, rest) = self.values.split_at_mut(n);
            for (k, layer) in rest.chunks_mut(n).enumerate() {
                let (i, g, a, _) = maps[k + 1];
                let residual = self.out.alignments[i].map_or(0.0, |al| al.residual_m);
                if residual > s.local_residual_m {
                    self.out.local_blocks[i] =
                        local::realign_blocks(layer, first, (w, h), g, &a, block, shift);
                }
            }
        }
        self.states.clear();
        self.states
            .extend(self.values.iter().map(|&v| CellState::of(v)));
        self.fused_states.clear();
        self.fused_states.resize(n, CellState::Unknown);
        match rule {
            VoteRule::Majority | VoteRule::MajorityReference => {
                // Without a majority: occupied (the paper), or the state of
                // the first member voting (the reference while it is in; it
                // is never misaligned, at identity). With two left (one out)
                // every cell they differ on lacks a majority, so the paper's
                // rule would draw the union, every wall twice a cell or two
                // apart: then the first one's state decides under either rule.
                let decider = (rule == VoteRule::MajorityReference || k_n == 2).then_some(0);
                for i in 0..n {
                    self.votes.clear();
                    self.votes.extend((0..k_n).map(|k| self.states[k * n + i]));
                    let fallback = decider.map_or(CellState::Occupied, |k| self.states[k * n + i]);
                    self.fused_states[i] = majority_or(&self.votes, fallback);
                }
            }
            VoteRule::Corroborated | VoteRule::CorroboratedReference => {
                for i in 0..n {
                    self.votes.clear();
                    self.votes.extend((0..k_n).map(|k| self.states[k * n + i]));
                    self.fused_states[i] = match strict_majority(&self.votes) {
                        Some(s) => s,
                        // Two voting: the first decides, as under the majority.
                        None if k_n == 2 => self.states[i],
                        None if rule == VoteRule::Corroborated => {
                            corroborated_doubt(&self.states, k_n, w, h, i)
                        }
                        None => reference_corroborated_doubt(&self.states, k_n, w, h, i),
                    };
                }
            }
            VoteRule::Weighted => {
                let block = &mut (None::<(i32, i32)>, 0.0f64);
                for i in 0..n {
                    self.wvotes.clear();
                    self.wvotes.extend((0..k_n).map(|k| WeightedVote {
                        value: self.values[k * n + i],
                        weight: maps[k].3,
                    }));
                    // The share is per 1 m block: looked up when the block changes.
                    let (fx, fy) = ((i % w) as f64, (i / w) as f64);
                    let (cx, cy) = (ox + (fx + 0.5) * res, oy + (fy + 0.5) * res);
                    let key = (cx.floor() as i32, cy.floor() as i32);
                    if block.0 != Some(key) {
                        *block = (Some(key), sonar.share(cx, cy));
                    }
                    self.fused_states[i] = weighted(&self.wvotes, block.1);
                }
            }
            VoteRule::Consensus => {
                let radius = (s.agree_radius_m / res).round().max(0.0) as usize;
                self.consensus
                    .vote(&self.states, k_n, w, h, radius, &mut self.fused_states);
            }
        }
        // Below and above the laser plane the laser-plane members abstain
        // (their "free" there is the laser passing over the obstacle): the
        // members that map in height decide, by majority among themselves.
        let mut out_of_plane = 0u64;
        if !height.is_empty() {
            for y in 0..h {
                let fy = y as f64;
                for x in 0..w {
                    let fx = x as f64;
                    let seen = height
                        .iter()
                        .filter(|&&(a, b)| {
                            CellState::of(local::sample(b, &a, fx, fy, 0, 0)) == CellState::Occupied
                        })
                        .count();
                    if 2 * seen > height.len()
                        && self.fused_states[y * w + x] != CellState::Occupied
                    {
                        self.fused_states[y * w + x] = CellState::Occupied;
                        out_of_plane += 1;
                    }
                }
            }
        }
        self.out.out_of_plane_cells = out_of_plane;
        for (i, state) in self.fused_states.iter().enumerate() {
            fused.cells[i] = state.value();
            for (k, m) in maps.iter().enumerate() {
                let sv = self.states[k * n + i];
                if sv != CellState::Unknown {
                    let e = &mut agree[m.0];
                    e.1 += 1;
                    e.0 += u64::from(sv == *state);
                }
            }
        }
        for (i, a) in agree.iter().enumerate() {
            self.out.agreement[i] = (a.1 > 0).then(|| a.0 as f64 / a.1 as f64);
        }
        // The fused pose's member: best agreement, ties to list order.
        self.out.pose_member = voters.iter().map(|v| v.0).max_by(|&a, &b| {
            let (x, y) = (
                self.out.agreement[a].unwrap_or(0.0),
                self.out.agreement[b].unwrap_or(0.0),
            );
            x.partial_cmp(&y)
                .unwrap_or(std::cmp::Ordering::Equal)
                .then(b.cmp(&a))
        });
        self.out.map = Some(Arc::new(fused));
        self.out.revision += 1;
        self.out.fuses += 1;
        self.out.fuse_ms = t0.elapsed().as_secs_f64() * 1e3;
        true
    }
}

/// The alignment and vote alone, over maps given by the caller (benches,
/// tools): what one fused update of [`VoteSlam`] does.
pub struct MapVote {
    fuser: Fuser,
    sonar: SonarShare,
}

impl MapVote {
    pub fn new(section: &VoteSection, members: usize) -> Self {
        Self {
            fuser: Fuser::new(
                VoteParams {
                    section: section.clone(),
                    fault: None,
                },
                members,
            ),
            sonar: SonarShare::default(),
        }
    }

    /// One fused update over `(map, revision)` per member, the first the
    /// reference; a member whose revision changed is re-aligned.
    pub fn update(&mut self, maps: &[(Arc<OccupancyGrid>, u64)]) -> Option<Arc<OccupancyGrid>> {
        let inputs: Vec<FuseInput> = maps
            .iter()
            .map(|m| FuseInput {
                map: Some(m.clone()),
                below: None,
                out: false,
                weight: 1.0,
            })
            .collect();
        self.fuser.fuse(&inputs, &self.sonar, true);
        self.fuser.out.map.clone()
    }

    /// Votes with `rule` from the next update on; maps whose revisions did
    /// not change keep their alignment (a re-vote of the same maps is the
    /// vote alone).
    pub fn set_rule(&mut self, rule: VoteRule) {
        self.fuser.p.section.rule = rule;
    }

    pub fn alignments(&self) -> &[Option<Alignment>] {
        &self.fuser.out.alignments
    }

    /// Maps that voted in the last update (those aligned within `max_residual_m`).
    pub fn voters(&self) -> usize {
        self.fuser.out.plane_voters
    }

    /// Time of the last update (alignment + vote), ms.
    pub fn last_ms(&self) -> f64 {
        self.fuser.out.fuse_ms
    }
}

/// Everything the vote needs beyond the members' own `[slam]` keys.
#[derive(Debug, Clone)]
pub struct VoteParams {
    pub section: VoteSection,
    pub fault: Option<MemberFault>,
}

/// The vote over several back-ends, itself a [`SlamBackend`].
pub struct VoteSlam {
    p: VoteParams,
    members: Vec<Member>,
    fuser: Arc<Mutex<Fuser>>,
    /// The last fused update, copied out of `fuser` (which a fuse holds for its whole run).
    published: Arc<Mutex<FusedOut>>,
    sonar: Arc<Mutex<SonarShare>>,
    fuse_thread: Option<JoinHandle<()>>,
    shutdown: Arc<AtomicBool>,
    pool: Vec<Arc<RangeScan>>,
    pool_misses: u64,
    initial: Pose2,
    first_odom: Option<Pose2>,
    pose: Option<Pose2>,
    last: Option<SlamUpdate>,
    /// The pipeline's front-end match of the next scan, forwarded with its job.
    tracked: Option<Tracked>,
}

/// Scans kept for reuse: each member holds at most its queue's worth.
const POOL_SLACK: usize = 2;

/// The pose weight of a member from its covariance: 1 for a pose known to a
/// few cm, falling as its position variance grows (0.5 at σ = 0.1 m).
fn pose_weight(u: Option<&SlamUpdate>) -> f64 {
    match u {
        Some(u) => {
            let var = (u.covariance[(0, 0)] + u.covariance[(1, 1)]).max(0.0);
            if var.is_finite() {
                1.0 / (1.0 + var / 0.02)
            } else {
                0.1
            }
        }
        None => 1.0,
    }
}

impl VoteSlam {
    /// The members of `cfg.vote` with `cfg`'s other keys, on their threads.
    pub fn new(
        cfg: &SlamSection,
        opts: &BackendOptions,
        fault: Option<MemberFault>,
    ) -> std::io::Result<Self> {
        let p = VoteParams {
            section: cfg.vote.clone(),
            fault,
        };
        let s = &p.section;
        let export_period = Duration::from_secs_f64(s.fuse_period_s);
        let mut members = Vec::new();
        for &kind in &s.members {
            let mut member_cfg = cfg.clone();
            member_cfg.backend = kind;
            let backend = from_config(&member_cfg, opts);
            members.push(Member::spawn(
                backend,
                WorkerConfig {
                    queue: s.queue as usize,
                    // Lockstep exports on request only.
                    export_period: if s.lockstep {
                        Duration::from_secs(3600)
                    } else {
                        export_period
                    },
                    fault,
                    footprint_m: opts.footprint_m,
                },
            )?);
        }
        let fuser = Arc::new(Mutex::new(Fuser::new(p.clone(), members.len())));
        let sonar = Arc::new(Mutex::new(SonarShare::default()));
        let shutdown = Arc::new(AtomicBool::new(false));
        let published = Arc::new(Mutex::new(FusedOut::default()));
        let mut v = Self {
            p,
            members,
            fuser,
            published,
            sonar,
            fuse_thread: None,
            shutdown,
            pool: Vec::new(),
            pool_misses: 0,
            initial: Pose2::default(),
            first_odom: None,
            pose: None,
            last: None,
            tracked: None,
        };
        if !v.p.section.lockstep {
            v.fuse_thread = Some(v.spawn_fuser(export_period)?);
        }
        Ok(v)
    }

    fn spawn_fuser(&self, period: Duration) -> std::io::Result<JoinHandle<()>> {
        let shared: Vec<_> = self.members.iter().map(|m| Arc::clone(&m.shared)).collect();
        let fuser = Arc::clone(&self.fuser);
        let published = Arc::clone(&self.published);
        let sonar = Arc::clone(&self.sonar);
        let shutdown = Arc::clone(&self.shutdown);
        let stall = Duration::from_secs_f64(self.p.section.stall_timeout_s);
        std::thread::Builder::new()
            .name("vote-fuse".into())
            .spawn(move || {
                while !shutdown.load(Ordering::Acquire) {
                    std::thread::sleep(period);
                    let inputs: Vec<FuseInput> = shared
                        .iter()
                        .map(|s| {
                            let st = s.lock();
                            FuseInput {
                                map: st.map.clone(),
                                below: st.below.clone(),
                                out: st.panicked.is_some()
                                    || s.busy_for().is_some_and(|d| d > stall),
                                weight: pose_weight(st.update.as_ref().map(|u| &u.0)),
                            }
                        })
                        .collect();
                    let share = sonar.lock().map(|s| s.clone()).unwrap_or_default();
                    if let Ok(mut f) = fuser.lock()
                        && f.fuse(&inputs, &share, false)
                        && let Ok(mut p) = published.lock()
                    {
                        *p = f.out.clone();
                    }
                }
            })
    }

    fn stall_timeout(&self) -> Duration {
        Duration::from_secs_f64(self.p.section.stall_timeout_s)
    }

    fn health_of(&self, i: usize, fused: &FusedOut) -> MemberHealth {
        let m = &self.members[i];
        let st = m.shared.lock();
        if let Some(msg) = &st.panicked {
            return MemberHealth::Panicked(msg.clone());
        }
        if let Some(d) = m.shared.busy_for()
            && d > self.stall_timeout()
        {
            return MemberHealth::Stalled(self.p.section.stall_timeout_s);
        }
        if m.given_up() {
            return MemberHealth::Stalled(self.p.section.stall_timeout_s);
        }
        if st.map.is_none() {
            return MemberHealth::NoMap;
        }
        if fused.misaligned.get(i).copied().unwrap_or(false) {
            let r = fused.alignments[i]
                .map(|a| a.residual_m)
                .unwrap_or(f64::NAN);
            return MemberHealth::Misaligned(r);
        }
        MemberHealth::In
    }

    /// Reads the last fused update (a brief lock: the fuse itself holds another).
    fn with_fused<R>(&self, f: impl FnOnce(&FusedOut) -> R) -> R {
        match self.published.lock() {
            Ok(p) => f(&p),
            Err(e) => f(&e.into_inner()),
        }
    }

    /// The members and the last fused update.
    pub fn status(&self) -> VoteStatus {
        let fused = self.with_fused(|f| f.clone());
        VoteStatus {
            members: (0..self.members.len())
                .map(|i| {
                    let map = self.members[i].shared.lock().map.clone();
                    MemberStatus {
                        name: self.members[i].name,
                        health: self.health_of(i, &fused),
                        drops: self.members[i].drops(),
                        alignment: fused.alignments.get(i).copied().flatten(),
                        map,
                        agreement: fused.agreement.get(i).copied().flatten(),
                        local_blocks: fused.local_blocks.get(i).copied().unwrap_or(0),
                    }
                })
                .collect(),
            fuses: fused.fuses,
            last_fuse_ms: fused.fuse_ms,
            pose_member: fused.pose_member.map(|i| self.members[i].name),
            out_of_plane_cells: fused.out_of_plane_cells,
        }
    }

    pub fn params(&self) -> &VoteParams {
        &self.p
    }

    /// One fused update now from the members' last exported maps (benches).
    pub fn fuse_now(&self) -> Option<f64> {
        let inputs = self.inputs();
        let share = self.sonar.lock().map(|s| s.clone()).unwrap_or_default();
        let mut f = self.fuser.lock().ok()?;
        if !f.fuse(&inputs, &share, true) {
            return None;
        }
        if let Ok(mut p) = self.published.lock() {
            *p = f.out.clone();
        }
        Some(f.out.fuse_ms)
    }

    /// The fused map the other `rule` makes of the members' current maps
    /// (same alignments; the vote's own rule is restored): the demo and tools
    /// compare both rules on one run.
    pub fn map_with_rule(&self, rule: VoteRule) -> Option<OccupancyGrid> {
        if self.p.section.lockstep {
            self.fuse_lockstep();
        }
        let inputs = self.inputs();
        let share = self.sonar.lock().map(|s| s.clone()).unwrap_or_default();
        let mut f = self.fuser.lock().ok()?;
        let own = f.p.section.rule;
        f.p.section.rule = rule;
        let map = f
            .fuse(&inputs, &share, true)
            .then(|| f.out.map.as_deref().cloned())
            .flatten();
        f.p.section.rule = own;
        f.fuse(&inputs, &share, true);
        map
    }

    fn inputs(&self) -> Vec<FuseInput> {
        let stall = self.stall_timeout();
        self.members
            .iter()
            .map(|m| {
                let st = m.shared.lock();
                FuseInput {
                    map: st.map.clone(),
                    below: st.below.clone(),
                    out: st.panicked.is_some()
                        || m.given_up()
                        || m.shared.busy_for().is_some_and(|d| d > stall),
                    weight: pose_weight(st.update.as_ref().map(|u| &u.0)),
                }
            })
            .collect()
    }

    /// A pooled copy of `scan` the members share.
    fn shared_scan(&mut self, scan: &RangeScan) -> Arc<RangeScan> {
        for a in &mut self.pool {
            if let Some(s) = Arc::get_mut(a) {
                s.clone_from(scan);
                return Arc::clone(a);
            }
        }
        let cap = self.members.len() * (self.p.section.queue as usize + 1) + POOL_SLACK;
        self.pool_misses += 1;
        let a = Arc::new(scan.clone());
        if self.pool.len() < cap {
            self.pool.push(Arc::clone(&a));
        }
        a
    }

    fn dispatch(&self, make: &mut dyn FnMut() -> Job) {
        let lockstep = self.p.section.lockstep;
        let timeout = self.stall_timeout();
        for m in &self.members {
            if m.given_up() {
                continue;
            }
            if lockstep {
                // Members run in parallel: hand the job to all, then wait for all.
                if !m.send_within(make(), timeout) {
                    self.give_up(m);
                }
            } else {
                m.offer(make());
            }
        }
        if lockstep {
            for m in &self.members {
                if !m.given_up() && !m.wait_idle(timeout) {
                    self.give_up(m);
                }
            }
        }
    }

    fn give_up(&self, m: &Member) {
        if m.shared.lock().panicked.is_none() {
            tracing::warn!(
                "vote member {} did not finish a job within {:.1} s: fed no more",
                m.name,
                self.p.section.stall_timeout_s
            );
        }
        m.give_up();
    }

    /// Lockstep: every member exports its map, then the vote runs here.
    fn fuse_lockstep(&self) {
        let timeout = self.stall_timeout();
        for m in &self.members {
            if m.given_up() {
                continue;
            }
            let exported = m.send_within(Job::Export, timeout) && m.wait_idle(timeout);
            if !exported {
                self.give_up(m);
            }
        }
        let inputs = self.inputs();
        let share = self.sonar.lock().map(|s| s.clone()).unwrap_or_default();
        if let Ok(mut f) = self.fuser.lock()
            && f.fuse(&inputs, &share, false)
            && let Ok(mut p) = self.published.lock()
        {
            *p = f.out.clone();
        }
    }

    /// The fused pose at odometry `odom`.
    fn fused_pose(&self, odom: &Pose2) -> (Pose2, Option<SlamUpdate>) {
        let found = self.with_fused(|fused| {
            let first = fused.pose_member;
            for i in first.into_iter().chain(0..self.members.len()) {
                if self.health_of(i, fused).is_out() {
                    continue;
                }
                let Some(t) = fused
                    .alignments
                    .get(i)
                    .copied()
                    .flatten()
                    .map(|a| a.transform)
                    .or((i == 0).then_some(Pose2::default()))
                else {
                    continue;
                };
                let st = self.members[i].shared.lock();
                if let Some((u, o)) = st.update {
                    let pose = t.compose(&u.pose.compose(&o.between(odom)));
                    return Some((pose, u));
                }
            }
            None
        });
        if let Some((pose, u)) = found {
            return (pose, Some(u));
        }
        let first = self.first_odom.unwrap_or(*odom);
        (self.initial.compose(&first.between(odom)), None)
    }

    fn update(&mut self, stamp_ns: u64, odom: &Pose2, processed: bool) -> SlamUpdate {
        self.first_odom.get_or_insert(*odom);
        let (pose, member) = self.fused_pose(odom);
        self.pose = Some(pose);
        let u = SlamUpdate {
            stamp_ns,
            pose,
            covariance: member
                .map(|u| u.covariance)
                .unwrap_or_else(|| Matrix3::from_diagonal_element(1e-4)),
            n_eff: member.map(|u| u.n_eff).unwrap_or(1.0),
            particles: member.map(|u| u.particles).unwrap_or(1),
            processed,
            resampled: false,
        };
        self.last = Some(u);
        u
    }
}

impl Drop for VoteSlam {
    fn drop(&mut self) {
        self.shutdown.store(true, Ordering::Release);
        if let Some(t) = self.fuse_thread.take() {
            let _ = t.join();
        }
        // Members join their threads in their own Drop.
    }
}

impl SlamBackend for VoteSlam {
    fn name(&self) -> &'static str {
        "vote"
    }

    fn process(&mut self, scan: &RangeScan, odom: &Pose2) -> SlamUpdate {
        let shared = self.shared_scan(scan);
        let o = *odom;
        let t = self.tracked.take();
        self.dispatch(&mut || Job::Process(Arc::clone(&shared), o, t));
        drop(shared);
        let u = self.update(scan.stamp_ns, odom, true);
        if let Ok(mut s) = self.sonar.lock() {
            s.add(scan, &u.pose);
        }
        u
    }

    fn frontend_match(&mut self, tracked: &Tracked) {
        // Goes with the next job to every member (the graph uses it).
        self.tracked = Some(*tracked);
    }

    fn predict(&mut self, stamp_ns: u64, odom: &Pose2) -> SlamUpdate {
        let o = *odom;
        let t = self.tracked.take();
        self.dispatch(&mut || Job::Predict(stamp_ns, o, t));
        self.update(stamp_ns, odom, false)
    }

    fn odometry_reset(&mut self) {
        // Not queued (a full queue must not lose it): the member applies it before its next job.
        for m in &self.members {
            m.request_reset();
        }
        self.first_odom = None;
        if let Some(p) = self.pose {
            self.initial = p;
        }
    }

    fn set_initial_pose(&mut self, pose: Pose2) {
        if self.last.is_none() && pose.is_finite() {
            self.initial = pose;
            // Every member starts there too, so their maps share the frame.
            let timeout = self.stall_timeout();
            for m in &self.members {
                m.send_within(Job::InitialPose(pose), timeout);
            }
        }
    }

    fn pose(&self) -> Option<Pose2> {
        self.pose
    }

    fn map_revision(&self) -> u64 {
        if self.p.section.lockstep {
            // Any member's map changed → the vote would too.
            self.members
                .iter()
                .map(|m| m.shared.lock().revision)
                .fold(0u64, |a, r| a.wrapping_mul(1_000_003).wrapping_add(r))
        } else {
            self.with_fused(|f| f.revision)
        }
    }

    fn map(&self) -> Option<OccupancyGrid> {
        if self.p.section.lockstep {
            self.fuse_lockstep();
        }
        self.with_fused(|f| f.map.as_deref().cloned())
    }

    fn trajectory(&self) -> Vec<StampedPose> {
        if self.p.section.lockstep {
            self.fuse_lockstep();
        }
        let (i, t) = self.with_fused(|f| {
            let i = f.pose_member.unwrap_or(0);
            let t = f
                .alignments
                .get(i)
                .copied()
                .flatten()
                .map(|a| a.transform)
                .unwrap_or_default();
            (i, t)
        });
        let (rtx, rrx) = std::sync::mpsc::sync_channel(1);
        if !self.members[i].send_within(Job::Trajectory(rtx), self.stall_timeout()) {
            return Vec::new();
        }
        rrx.recv_timeout(self.stall_timeout())
            .unwrap_or_default()
            .into_iter()
            .map(|p| StampedPose {
                stamp_ns: p.stamp_ns,
                pose: t.compose(&p.pose),
            })
            .collect()
    }

    fn metrics(&self, emit: &mut dyn FnMut(&'static str, f64)) {
        let st = self.status();
        emit(
            "vote_members_out",
            st.members.iter().filter(|m| m.health.is_out()).count() as f64,
        );
        emit("vote_out_of_plane_cells", st.out_of_plane_cells as f64);
        emit(
            "vote_drops",
            st.members.iter().map(|m| m.drops).sum::<u64>() as f64,
        );
        emit(
            "vote_residual_max_m",
            st.members
                .iter()
                .filter_map(|m| m.alignment.map(|a| a.residual_m))
                .fold(0.0, f64::max),
        );
        emit(
            "vote_local_blocks",
            st.members.iter().map(|m| f64::from(m.local_blocks)).sum(),
        );
        emit("vote_fuse_ms", st.last_fuse_ms);
        emit("vote_fuses", st.fuses as f64);
        for m in &st.members {
            let name = match m.name {
                "rbpf" => "vote_out_rbpf",
                "graph" => "vote_out_graph",
                "fuzzy" => "vote_out_fuzzy",
                _ => continue,
            };
            emit(name, f64::from(u8::from(m.health.is_out())));
        }
    }

    /// The graph member's pose graph, in its own frame (every member starts
    /// at the same pose on the same odometry: the reference's frame but for
    /// the alignment the status reports). Waits up to the stall timeout for
    /// the member's thread; a member that is out cannot save.
    fn save_graph(&self, path: &Path) -> Option<Result<(), SavedGraphError>> {
        let i = self.members.iter().position(|m| m.name == "graph")?;
        let (rtx, rrx) = std::sync::mpsc::sync_channel(1);
        let out = |why: &str| {
            Some(Err(SavedGraphError::Io {
                file: path.to_owned(),
                message: format!("the vote's graph member {why}"),
            }))
        };
        if !self.members[i].send_within(Job::SaveGraph(path.to_owned(), rtx), self.stall_timeout())
        {
            return out("is out or its queue stayed full");
        }
        match rrx.recv_timeout(self.stall_timeout()) {
            Ok(saved) => saved,
            Err(_) => out("did not answer within the stall timeout"),
        }
    }

    /// The members that are out (panicked, stalled, misaligned), as
    /// `vote: member rbpf stalled …; member graph …`.
    fn health_condition(&self) -> Option<String> {
        let st = self.status();
        let out: Vec<String> = st
            .members
            .iter()
            .filter(|m| m.health.is_out())
            .map(|m| format!("member {} {}", m.name, m.health))
            .collect();
        (!out.is_empty()).then(|| format!("vote: {}", out.join("; ")))
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

#[cfg(test)]
mod tests;
