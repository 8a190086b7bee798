//! `[slam.vote]`: the vote over several SLAM back-ends (SLAMfusion,
//! Fernandes & Alexandre): each member maps from the same scans and
//! odometry on its own thread, the members' maps are aligned to the first
//! member's and every cell is set by a vote over occupied / free / unknown.
//!
//! ```toml
//! [slam]
//! backend = "vote"
//! [slam.vote]
//! members = ["graph", "rbpf", "fuzzy"]   # the first is the reference frame;
//!                                        # add "projected" to map out of the laser plane
//! rule = "majority"                      # or "weighted", "consensus", "majority-reference",
//!                                        # "corroborated", "corroborated-reference"
//! agree_radius_m = 0.1                   # consensus: walls this close are one wall
//! max_residual_m = 0.15                  # alignment residual above it: flagged, left out
//! local_residual_m = 0.018               # residual above it: re-aligned block by block too
//! local_block_m = 2.0                    # those blocks' side
//! local_shift_cells = 1                  # and their largest shift
//! ```

use crate::slam::SlamBackendKind;
use crate::validate::{Validate, Validator};
use serde::{Deserialize, Serialize};

/// How the members' cells are combined.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum VoteRule {
    /// The paper's rule: the state most members agree on (more than half);
    /// no majority → occupied (with only two members voting, one out, the
    /// first of them decides instead: two votes that differ are never a
    /// majority, and "occupied" drew both maps' walls). The default: on the bundled dense-smoke trial
    /// (SmokeNav v2, `smokenav-lab demo --fast --seeds 1`) majority 0.113 m
    /// map error against weighted 0.626 m, clean twin 0.034 against 0.039 m.
    #[default]
    #[serde(rename = "majority")]
    Majority,
    /// Each member's vote weighted by its certainty for that cell, its pose
    /// covariance and (for occupied/free) how little of the region was seen
    /// only by sonar; ties → occupied. Worse where a member's covariance claims more than its map
    /// is worth (the fuzzy member in smoke carries the vote).
    #[serde(rename = "weighted")]
    Weighted,
    /// The paper's majority over walls within `agree_radius_m` of each other,
    /// on the geometry of the member whose walls the others confirm most: a
    /// wall copied a cell or two apart by two members is one wall, not two.
    #[serde(rename = "consensus")]
    Consensus,
    /// The paper's majority; without one, the reference member's state
    /// (the next member's in order while the reference is out) instead of occupied: the
    /// members' copies of a wall a cell apart are not all drawn.
    #[serde(rename = "majority-reference")]
    MajorityReference,
    /// The paper's majority; without one, a wall only where another member
    /// has a wall within a cell of it (the paper's reason for "doubt is a
    /// wall": disagreements lie on a wall's border), else free if any
    /// member saw free space there, else unknown. One member's lone wall —
    /// a phantom or a wall it drew off — is not drawn. With two voting, the
    /// first decides, as under `majority`. At or below its best member in
    /// 12 of 15 dense-smoke runs and 7 of 9 clean ones, the paper's
    /// majority in 7 and 7 (the README's vote table; the shipped profiles'
    /// rule until `corroborated-reference`).
    #[serde(rename = "corroborated")]
    Corroborated,
    /// The paper's majority; without one, the reference member's state (as
    /// `majority-reference`, the next member's in order while the reference
    /// is out), except that a reference wall no other member
    /// has a wall within a cell of is not drawn (free if any member saw
    /// free space there, else unknown): the reference's geometry where the
    /// members split, without its lone walls. The shipped profiles' rule:
    /// over eleven dense-smoke recordings × three seeds at or below its
    /// best member in 26 of 33 runs (`corroborated` 24), on the five
    /// `./demo` recordings in 15 of 15 (11), and in the clean twins in 7
    /// of 9 (6) (the README's vote tables).
    #[serde(rename = "corroborated-reference")]
    CorroboratedReference,
}

impl VoteRule {
    pub fn as_str(self) -> &'static str {
        match self {
            VoteRule::Majority => "majority",
            VoteRule::Weighted => "weighted",
            VoteRule::Consensus => "consensus",
            VoteRule::MajorityReference => "majority-reference",
            VoteRule::Corroborated => "corroborated",
            VoteRule::CorroboratedReference => "corroborated-reference",
        }
    }

    /// Every rule, the default first.
    pub const ALL: [VoteRule; 6] = [
        VoteRule::Majority,
        VoteRule::Weighted,
        VoteRule::Consensus,
        VoteRule::MajorityReference,
        VoteRule::Corroborated,
        VoteRule::CorroboratedReference,
    ];

    /// The rule named `name` (`majority`, `weighted`, `consensus`,
    /// `majority-reference`, `corroborated`, `corroborated-reference`).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|r| r.as_str() == name)
    }
}

/// `[slam.vote]`: every key optional, unknown keys rejected.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VoteSection {
    /// The back-ends that vote (2–3 distinct, not `vote`); the first one's map
    /// is the frame the others are aligned to and the fused map's geometry.
    /// The default puts the graph first: it draws no random numbers, so the
    /// frame does not move with the particle filter's seed. Over 18 offline
    /// runs (three dense-smoke recordings, 4 seeds; two clean twins, 3) the
    /// majority was at or below its best member 10 times this way, 6 with
    /// the RBPF first; lower in clean air (0.031 / 0.032 against 0.033 /
    /// 0.034 m), the same within 0.004 m in smoke.
    pub members: Vec<SlamBackendKind>,
    /// `majority` (the paper's, default), `weighted`, `consensus`,
    /// `majority-reference`, `corroborated` or `corroborated-reference`.
    pub rule: VoteRule,
    /// `consensus`: two members' walls this close (a square window) are the
    /// same wall, m.
    pub agree_radius_m: f64,
    /// A member whose alignment residual (RMS distance of the nearest 80 % of
    /// its wall cells to the reference's walls, truncated at
    /// `align_truncation_m`) is above this is flagged in health and left out
    /// of the vote, m.
    pub max_residual_m: f64,
    /// Translational search window of the alignment around the shared
    /// odometry frame (or the last alignment), ± m.
    pub align_window_m: f64,
    /// Rotational search window of the alignment, ± rad.
    pub align_window_rad: f64,
    /// Wall distances beyond this count as this much in the alignment score, m.
    pub align_truncation_m: f64,
    /// At most this many wall cells of a member are matched (evenly thinned).
    pub align_max_points: u32,
    /// A member whose alignment residual is above this is re-aligned block by
    /// block after the rigid alignment (`local_block_m` squares, each shifted
    /// by up to `local_shift_cells` where that lays more of its walls on the
    /// reference's): one rigid transform cannot undo two members' different
    /// loop corrections or drift. 0 = every member, a value above
    /// `max_residual_m` = never, m.
    pub local_residual_m: f64,
    /// Side of the blocks of the local re-alignment, m.
    pub local_block_m: f64,
    /// Largest shift of a block in the local re-alignment, cells of the member's map.
    pub local_shift_cells: u32,
    /// Scans (and odometry updates) a member's queue holds; a full queue drops
    /// the newest and counts it.
    pub queue: u32,
    /// A member busy with one scan for longer than this is out (stalled), s.
    pub stall_timeout_s: f64,
    /// How often members export their maps and the vote is recomputed, s.
    pub fuse_period_s: f64,
    /// Every member finishes each scan before the next one (offline runs:
    /// reproducible, nothing dropped); `smokenav slam` sets it.
    pub lockstep: bool,
}

impl Default for VoteSection {
    fn default() -> Self {
        Self {
            members: vec![
                SlamBackendKind::Graph,
                SlamBackendKind::Rbpf,
                SlamBackendKind::Fuzzy,
            ],
            rule: VoteRule::Majority,
            agree_radius_m: 0.1,
            max_residual_m: 0.15,
            align_window_m: 0.5,
            align_window_rad: 0.1,
            align_truncation_m: 0.5,
            align_max_points: 3000,
            local_residual_m: 0.018,
            local_block_m: 2.0,
            local_shift_cells: 1,
            queue: 8,
            stall_timeout_s: 5.0,
            fuse_period_s: 0.5,
            lockstep: false,
        }
    }
}

impl Validate for VoteSection {
    fn validate(&self, key: &str, v: &mut Validator) {
        let k = |name: &str| format!("{key}.{name}");
        // `projected` votes only out of the laser plane: beside 2–3 that map it.
        let in_plane = self
            .members
            .iter()
            .filter(|m| **m != SlamBackendKind::Projected)
            .count();
        if !(2..=3).contains(&in_plane) {
            v.fail(
                k("members"),
                format!(
                    "must name 2–3 back-ends that map the laser plane (and `projected` beside them if wanted), got {in_plane}"
                ),
            );
        }
        if self.members.first() == Some(&SlamBackendKind::Projected) {
            v.fail(
                k("members"),
                "`projected` cannot come first: the first member is the reference frame, and it votes only out of the laser plane",
            );
        }
        for (i, m) in self.members.iter().enumerate() {
            if *m == SlamBackendKind::Vote {
                v.fail(k("members"), "a vote cannot be a member of itself");
            } else if self.members[..i].contains(m) {
                v.fail(k("members"), format!("{} is named twice", m.as_str()));
            }
        }
        v.within(&k("agree_radius_m"), self.agree_radius_m, 0.0, 1.0);
        v.within(&k("max_residual_m"), self.max_residual_m, 0.001, 10.0);
        v.within(&k("align_window_m"), self.align_window_m, 0.0, 10.0);
        v.within(&k("align_window_rad"), self.align_window_rad, 0.0, 3.2);
        v.within(
            &k("align_truncation_m"),
            self.align_truncation_m,
            0.01,
            10.0,
        );
        v.within(&k("local_residual_m"), self.local_residual_m, 0.0, 10.0);
        v.within(&k("local_block_m"), self.local_block_m, 0.1, 100.0);
        if self.local_shift_cells > 10 {
            v.fail(
                k("local_shift_cells"),
                format!("must be 0–10, got {}", self.local_shift_cells),
            );
        }
        if !(10..=1_000_000).contains(&self.align_max_points) {
            v.fail(
                k("align_max_points"),
                format!("must be 10–1000000, got {}", self.align_max_points),
            );
        }
        if !(1..=1024).contains(&self.queue) {
            v.fail(k("queue"), format!("must be 1–1024, got {}", self.queue));
        }
        v.within(&k("stall_timeout_s"), self.stall_timeout_s, 0.01, 3600.0);
        v.within(&k("fuse_period_s"), self.fuse_period_s, 0.01, 60.0);
    }
}
