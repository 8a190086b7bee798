//! The vote back-end beside its members (SLAMfusion, seed 004): the
//! recording through SmokeNav v2 fusion, then one SLAM run with
//! `backend = "vote"` in lockstep (every member sees every scan, as offline
//! `smokenav slam --backend vote`), each member's map and the fused one
//! scored against the ground truth. Every rule is scored on the same run:
//! the other rules re-vote the same aligned member maps.

use super::compare::{self, Emitted};
use super::recording::SensorLog;
use smokenav_algorithms_slam::vote::VoteSlam;
use smokenav_platform_config::{RobotConfig, SlamBackendKind, VoteRule};
use smokenav_platform_map::OccupancyGrid;
use smokenav_shared_types::FusionMethod;
use smokenav_sim_link::TruthTrack;

/// One map of the vote run.
#[derive(Debug, Clone, serde::Serialize)]
pub struct VoteRow {
    /// `rbpf`, `graph`, `fuzzy`, or `vote (weighted)` / `vote (majority)`.
    pub name: String,
    pub map_error_m: Option<f64>,
    /// The fused trajectory's ATE (the vote rows; members: not kept).
    pub ate_m: Option<f64>,
    /// A member's alignment residual to the reference member, m.
    pub residual_m: Option<f64>,
    /// A member's health in the vote (`in`, `out (…)`).
    pub health: String,
}

/// The vote run of one scenario.
#[derive(Debug, Clone, serde::Serialize)]
pub struct VoteComparison {
    pub scenario: String,
    /// The profile's rule (the first vote row).
    pub rule: String,
    pub rows: Vec<VoteRow>,
    /// The lowest member map error and the configured rule's map error.
    pub best_member_m: Option<f64>,
    pub vote_m: Option<f64>,
}

impl VoteComparison {
    /// Seed 004's claim on this run: the vote's map error ≤ the best member's.
    pub fn vote_not_worse(&self) -> Option<bool> {
        Some(self.vote_m? <= self.best_member_m?)
    }
}

/// Runs the vote over `log` (fused with SmokeNav v2) and scores every map.
pub fn run(
    scenario: &str,
    log: &SensorLog,
    profile: &RobotConfig,
    truth: &TruthTrack,
    truth_map: &OccupancyGrid,
) -> anyhow::Result<VoteComparison> {
    let (fused, _): (Vec<Emitted>, f64) = compare::fuse(log, profile, FusionMethod::V2)?;
    let mut p = profile.clone();
    p.slam.backend = SlamBackendKind::Vote;
    p.slam.vote.lockstep = true;
    let slam = compare::replay_slam(log, &p, &fused);
    let mut trajectory = slam.trajectory();
    trajectory.dedup_by_key(|q| q.stamp_ns);
    let fused_map = slam.map();
    let vote = slam
        .backend()
        .as_any()
        .downcast_ref::<VoteSlam>()
        .ok_or_else(|| anyhow::anyhow!("backend = \"vote\" did not make a vote"))?;
    let rule = p.slam.vote.rule;
    let others: Vec<(VoteRule, Option<OccupancyGrid>)> = VoteRule::ALL
        .into_iter()
        .filter(|&r| r != rule)
        .map(|r| (r, vote.map_with_rule(r)))
        .collect();
    let st = vote.status();
    let err =
        |m: Option<&OccupancyGrid>| compare::score_map(truth_map, m).ok().map(|r| r.knn_error_m);
    let mut rows: Vec<VoteRow> = st
        .members
        .iter()
        .map(|m| VoteRow {
            name: m.name.to_string(),
            map_error_m: err(m.map.as_ref().map(|(g, _)| g.as_ref())),
            ate_m: None,
            residual_m: m.alignment.map(|a| a.residual_m),
            health: m.health.to_string(),
        })
        .collect();
    let best_member_m = rows
        .iter()
        .filter_map(|r| r.map_error_m)
        .min_by(f64::total_cmp);
    let ate = compare::score_trajectory(truth, &trajectory)
        .ok()
        .map(|r| r.ate_m.rmse);
    let vote_m = err(fused_map.as_ref());
    rows.push(VoteRow {
        name: format!("vote ({})", rule.as_str()),
        map_error_m: vote_m,
        ate_m: ate,
        residual_m: None,
        health: format!("pose from {}", st.pose_member.unwrap_or("-")),
    });
    for (other, map) in &others {
        rows.push(VoteRow {
            name: format!("vote ({})", other.as_str()),
            map_error_m: err(map.as_ref()),
            ate_m: ate,
            residual_m: None,
            health: "same members, other rule".into(),
        });
    }
    Ok(VoteComparison {
        scenario: scenario.to_string(),
        rule: rule.as_str().to_string(),
        rows,
        best_member_m,
        vote_m,
    })
}

fn m(v: Option<f64>) -> String {
    v.map_or("—".into(), |x| format!("{x:.3} m"))
}

/// The verdict's figures: to a tenth of a millimetre, so a near tie reads as what it is.
fn m4(v: Option<f64>) -> String {
    v.map_or("—".into(), |x| format!("{x:.4} m"))
}

/// The members beside the vote, one table per scenario.
pub fn table(runs: &[VoteComparison]) -> String {
    let mut out = String::new();
    for c in runs {
        out.push_str(&format!(
            "\n| vote back-end, {} (SmokeNav v2, one seed) | map error | ATE | alignment residual | in the vote |\n|---|---|---|---|---|\n",
            c.scenario
        ));
        for r in &c.rows {
            out.push_str(&format!(
                "| {} | {} | {} | {} | {} |\n",
                r.name,
                m(r.map_error_m),
                m(r.ate_m),
                m(r.residual_m),
                r.health
            ));
        }
        out.push_str(&match c.vote_not_worse() {
            Some(true) => format!(
                "vote ({}) ≤ best member: yes ({} ≤ {})\n",
                c.rule,
                m4(c.vote_m),
                m4(c.best_member_m)
            ),
            Some(false) => format!(
                "vote ({}) ≤ best member: no ({} > {})\n",
                c.rule,
                m4(c.vote_m),
                m4(c.best_member_m)
            ),
            None => "vote ≤ best member: not scored\n".into(),
        });
    }
    out
}
