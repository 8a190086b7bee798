//! One fused map update of the vote back-end (alignment of two members to
//! the reference + the per-cell vote) on a 40 m × 40 m map at 5 cm
//! (800 × 800 cells), three members: the reference and two copies moved by a
//! few centimetres and a degree (as drift and a loop closure leave them),
//! each with its own missing and phantom cells. Every update re-aligns both
//! members (their revisions change, as online after each export), the first
//! over the whole window, the rest around the last alignment.
//!
//! `cargo bench -p smokenav-algorithms-slam --bench vote_fuse` — on one core
//! (the bench is single-threaded); SLAMfusion (Fernandes & Alexandre) took
//! 25 s per batch on a GeForce GTX TITAN X.

use smokenav_algorithms_slam::vote::MapVote;
use smokenav_platform_config::{VoteRule, VoteSection};
use smokenav_platform_map::OccupancyGrid;
use smokenav_shared_types::Pose2;
use std::sync::Arc;
use std::time::Instant;

/// A building floor: outer walls, corridors, rooms with doors, pillars.
fn walls() -> Vec<(f64, f64, f64, f64)> {
    let mut w = vec![
        (-19.0, -19.0, 19.0, -19.0),
        (19.0, -19.0, 19.0, 19.0),
        (19.0, 19.0, -19.0, 19.0),
        (-19.0, 19.0, -19.0, -19.0),
    ];
    for k in -3..=3 {
        let y = k as f64 * 5.0;
        // Corridor walls with door gaps every 4 m.
        let mut x = -18.0;
        while x < 18.0 {
            w.push((x, y, x + 3.0, y));
            x += 4.0;
        }
        w.push((k as f64 * 5.0 + 1.0, -18.0, k as f64 * 5.0 + 1.0, -15.0));
    }
    for i in 0..12 {
        let (x, y) = (-16.0 + 3.0 * i as f64, 2.5 + (i % 3) as f64);
        w.push((x, y, x + 0.4, y));
        w.push((x + 0.4, y, x + 0.4, y + 0.4));
    }
    w
}

/// The walls drawn into a 40 m map (free space around them), moved by `t`,
/// with every `drop_every`-th wall cell missing and phantom cells sprinkled.
fn member_map(t: Pose2, drop_every: usize, phantom_seed: u64) -> OccupancyGrid {
    let res = 0.05;
    let mut g = OccupancyGrid::new(800, 800, res, [-20.0, -20.0, 0.0]);
    for c in g.cells.iter_mut() {
        *c = 0;
    }
    let (s, c) = t.theta.sin_cos();
    let mut n = 0usize;
    for (x0, y0, x1, y1) in walls() {
        let steps = ((x1 - x0).hypot(y1 - y0) / (res / 2.0)).ceil() as usize;
        for i in 0..=steps {
            let f = i as f64 / steps as f64;
            let (x, y) = (x0 + f * (x1 - x0), y0 + f * (y1 - y0));
            let (wx, wy) = (c * x - s * y + t.x, s * x + c * y + t.y);
            n += 1;
            if drop_every > 0 && n.is_multiple_of(drop_every) {
                continue;
            }
            if let Some((cx, cy)) = g.world_to_cell(wx, wy) {
                g.set(cx, cy, 100);
            }
        }
    }
    let mut r = phantom_seed;
    for _ in 0..2000 {
        r = r
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let i = (r >> 33) as usize % g.cells.len();
        g.cells[i] = 100;
    }
    g
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    let i = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len()) - 1;
    sorted[i]
}

fn main() {
    let reference = Arc::new(member_map(Pose2::default(), 0, 1));
    let a = Arc::new(member_map(Pose2::new(0.07, -0.04, 0.012), 7, 2));
    let b = Arc::new(member_map(Pose2::new(-0.05, 0.09, -0.015), 5, 3));
    // Local re-alignment off, then on for every member (its worst case: the
    // default gate re-aligns only members whose rigid residual is high).
    for (rule, local) in [
        (VoteRule::Majority, false),
        (VoteRule::Majority, true),
        (VoteRule::Weighted, false),
        (VoteRule::Corroborated, true),
        (VoteRule::CorroboratedReference, true),
    ] {
        let section = VoteSection {
            rule,
            local_residual_m: if local { 0.0 } else { 10.0 },
            ..VoteSection::default()
        };
        let mut vote = MapVote::new(&section, 3);
        let mut times = Vec::new();
        let mut first = 0.0;
        for rev in 0..40u64 {
            let t0 = Instant::now();
            let fused = vote.update(&[
                (Arc::clone(&reference), rev),
                (Arc::clone(&a), rev),
                (Arc::clone(&b), rev),
            ]);
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            assert!(fused.is_some());
            if rev == 0 {
                first = ms;
            } else {
                times.push(ms);
            }
        }
        times.sort_by(f64::total_cmp);
        let al = vote.alignments();
        let res: Vec<String> = al
            .iter()
            .skip(1)
            .map(|a| {
                a.map(|a| {
                    format!(
                        "({:+.3}, {:+.3}, {:+.2}°) residual {:.3} m",
                        a.transform.x,
                        a.transform.y,
                        a.transform.theta.to_degrees(),
                        a.residual_m
                    )
                })
                .unwrap_or_default()
            })
            .collect();
        println!(
            "vote_fuse {:<12} local re-alignment {:<3} 800×800 cells (40 m × 40 m at 5 cm), 3 members: first update {:.1} ms (full window); then p50 {:.1} ms, p99 {:.1} ms, max {:.1} ms over {} updates  | SLAMfusion GPU: 25 000 ms per batch",
            rule.as_str(),
            if local { "on" } else { "off" },
            first,
            percentile(&times, 0.5),
            percentile(&times, 0.99),
            times.last().copied().unwrap_or(0.0),
            times.len()
        );
        println!("  alignments found: {}", res.join("; "));
        println!("  (expected inverses of (+0.070, −0.040, +0.69°) and (−0.050, +0.090, −0.86°))");
    }
}
