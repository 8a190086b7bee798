//! `smokenav map vote`: SLAMfusion's vote (seed 004) over saved maps, as the
//! paper ran it: maps made apart (by several back-ends, runs or robots) are
//! aligned to the first and every cell is voted. The same alignment and rules
//! as the SLAM process's `backend = "vote"`; with `--truth-map`, every map and
//! every rule is scored, so rules can be compared on one set of maps.

use anyhow::Context;
use smokenav_algorithms_slam::vote::MapVote;
use smokenav_platform_config::{RobotConfig, VoteRule, VoteSection};
use smokenav_platform_map::OccupancyGrid;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// What `map vote` was asked.
pub struct VoteArgs {
    pub maps: Vec<PathBuf>,
    pub rule: Option<VoteRule>,
    pub config: Option<PathBuf>,
    pub truth_map: Option<PathBuf>,
    pub out: PathBuf,
}

fn load(path: &Path) -> anyhow::Result<OccupancyGrid> {
    smokenav_platform_map::load_map_server(path)
        .with_context(|| format!("cannot read the map {}", path.display()))
}

pub fn run(a: VoteArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        (2..=8).contains(&a.maps.len()),
        "give 2 to 8 maps to vote over, got {}",
        a.maps.len()
    );
    let section = match &a.config {
        Some(p) => {
            RobotConfig::load(p)
                .with_context(|| format!("cannot load {}", p.display()))?
                .slam
                .vote
        }
        None => VoteSection::default(),
    };
    let rule = a.rule.unwrap_or(section.rule);
    let maps: Vec<Arc<OccupancyGrid>> = a
        .maps
        .iter()
        .map(|p| load(p).map(Arc::new))
        .collect::<anyhow::Result<_>>()?;
    let truth = a.truth_map.as_deref().map(load).transpose()?;
    let mut s = section.clone();
    s.rule = rule;
    let mut v = MapVote::new(&s, maps.len());
    // One revision each: re-votes under the other rules reuse the alignment.
    let input: Vec<(Arc<OccupancyGrid>, u64)> = maps.iter().map(|m| (Arc::clone(m), 1)).collect();
    let fused = v
        .update(&input)
        .context("no map to vote: the reference (first) map has no walls")?;
    let name = |p: &Path| p.display().to_string();
    println!(
        "vote ({}) of {} maps on the grid of {} ({}×{} at {} m), {:.1} ms",
        rule.as_str(),
        maps.len(),
        name(&a.maps[0]),
        fused.width,
        fused.height,
        fused.resolution,
        v.last_ms()
    );
    let score = |m: &OccupancyGrid| {
        truth.as_ref().map(|t| {
            match smokenav_algorithms_eval::evaluate_maps(
                t,
                m,
                &smokenav_algorithms_eval::MapOptions::default(),
            ) {
                Ok(r) => format!(
                    "; map error k-NN {:.4} m, pixel RMS {:.3}",
                    r.knn_error_m, r.pixel_rms
                ),
                Err(e) => format!("; not comparable: {e}"),
            }
        })
    };
    for (i, (p, m)) in a.maps.iter().zip(&maps).enumerate() {
        let al = match v.alignments().get(i).copied().flatten() {
            Some(al) => {
                let flag = if al.residual_m > section.max_residual_m {
                    format!(
                        " — above max_residual_m {}: left out",
                        section.max_residual_m
                    )
                } else {
                    String::new()
                };
                format!(
                    "aligned ({:+.3}, {:+.3}) m {:+.2}°, residual {:.3} m{flag}",
                    al.transform.x,
                    al.transform.y,
                    al.transform.theta.to_degrees(),
                    al.residual_m
                )
            }
            None => "not aligned (no walls)".into(),
        };
        println!("  member {}: {al}{}", name(p), score(m).unwrap_or_default());
    }
    if v.voters() == 2
        && matches!(
            rule,
            VoteRule::Majority
                | VoteRule::MajorityReference
                | VoteRule::Corroborated
                | VoteRule::CorroboratedReference
        )
    {
        println!(
            "  note: two maps vote; where they differ neither is a majority and the first one voting decides, so the vote is that map: give three or more"
        );
    }
    if let Some(s) = score(&fused) {
        println!("  vote ({}, chosen){s}", rule.as_str());
        for other in VoteRule::ALL.into_iter().filter(|&r| r != rule) {
            v.set_rule(other);
            if let Some(m) = v.update(&input) {
                println!(
                    "  vote ({}){}",
                    other.as_str(),
                    score(&m).unwrap_or_default()
                );
            }
        }
    }
    smokenav_platform_map::save_map_server(&fused, &a.out, "map")?;
    fused.save_png(&a.out.join("map.png"))?;
    println!("wrote {}", a.out.join("map.yaml").display());
    Ok(())
}
