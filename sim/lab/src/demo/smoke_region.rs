//! Where the smoke was, for the fuzzy map's "no confident phantom wall
//! where the smoke was" (issue #17): the cells the scenario's smoke covered
//! while the robot was near enough for its laser to see them.
//!
//! The smoke field does not depend on the robot, so it is replayed on its
//! own from the scenario (the world's own field, same steps) beside the true
//! track; live and `--fast` runs get the same region.

use smokenav_platform_map::OccupancyGrid;
use smokenav_sim_link::TruthTrack;
use smokenav_sim_world::Scenario;
use smokenav_sim_world::world::SMOKE_FIELD_PERIOD_NS;

/// Extinction at or above which a cell counts as smoke, 1/m (0.0115 g/m³ at
/// 8.7 m²/g): a beam crossing a metre of it loses a tenth of its power each
/// way, where the simulated URG starts to return from the smoke.
pub const SMOKE_EXTINCTION_PER_M: f64 = 0.1;

/// The region is sampled at the laser's rate.
const LOOK_PERIOD_NS: u64 = 100_000_000;

/// A mask on the grid of `like` (the truth map): 100 where smoke of at least
/// [`SMOKE_EXTINCTION_PER_M`] lay within `range_m` of the robot at some
/// moment of `truth`, 0 elsewhere. `None` when the scenario has no smoke.
///
/// Within range, not in line of sight: the region errs on the large side, so
/// a phantom the smoke made is not missed by it.
pub fn smoke_region(
    scenario: &Scenario,
    truth: &TruthTrack,
    like: &OccupancyGrid,
    range_m: f64,
) -> anyhow::Result<Option<OccupancyGrid>> {
    if scenario.sources.is_empty() && scenario.patches.is_empty() {
        return Ok(None);
    }
    let mut field = scenario.smoke_field()?;
    let (origin, h, cols, rows) = field.grid();
    let dense_gpm3 = SMOKE_EXTINCTION_PER_M / field.params().mass_extinction_m2pg;
    let mut seen = vec![false; cols * rows];
    let samples = truth.samples();
    let Some(t0) = samples.first().map(|s| s.t_ns) else {
        return Ok(None);
    };
    // The world advances the field once per period, at the period's end.
    let period = SMOKE_FIELD_PERIOD_NS;
    let mut advanced_to = 0u64;
    let mut next_look = 0u64;
    let reach = (range_m / h).ceil() as i64;
    for s in samples {
        let t = s.t_ns.saturating_sub(t0);
        if t < next_look {
            continue;
        }
        next_look = t + LOOK_PERIOD_NS;
        while advanced_to + period <= t {
            field.advance(advanced_to as f64 * 1e-9, period as f64 * 1e-9);
            advanced_to += period;
        }
        if field.is_clear() {
            continue;
        }
        let (px, py) = (s.pose.x, s.pose.y);
        let cx = ((px - origin.x) / h).floor() as i64;
        let cy = ((py - origin.y) / h).floor() as i64;
        for gy in (cy - reach).max(0)..=(cy + reach).min(rows as i64 - 1) {
            for gx in (cx - reach).max(0)..=(cx + reach).min(cols as i64 - 1) {
                let (x, y) = (gx as usize, gy as usize);
                let i = y * cols + x;
                if seen[i] || field.cell(x, y) < dense_gpm3 {
                    continue;
                }
                let (wx, wy) = (
                    origin.x + (x as f64 + 0.5) * h,
                    origin.y + (y as f64 + 0.5) * h,
                );
                seen[i] = (wx - px).hypot(wy - py) <= range_m;
            }
        }
    }
    let mut mask = like.clone();
    for (i, v) in mask.cells.iter_mut().enumerate() {
        let (wx, wy) = (
            like.origin[0] + ((i % like.width) as f64 + 0.5) * like.resolution,
            like.origin[1] + ((i / like.width) as f64 + 0.5) * like.resolution,
        );
        let x = ((wx - origin.x) / h).floor();
        let y = ((wy - origin.y) / h).floor();
        let inside = x >= 0.0 && y >= 0.0 && (x as usize) < cols && (y as usize) < rows;
        *v = if inside && seen[y as usize * cols + x as usize] {
            100
        } else {
            0
        };
    }
    Ok(Some(mask))
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_shared_types::Pose2;

    fn track(points: &[(f64, f64)], seconds_each: f64) -> TruthTrack {
        let mut t = TruthTrack::default();
        let mut ns = 5_000_000_000u64;
        for &(x, y) in points {
            for _ in 0..(seconds_each * 10.0) as usize {
                t.push(ns, Pose2::new(x, y, 0.0), 0.0);
                ns += 100_000_000;
            }
        }
        t
    }

    #[test]
    fn the_region_is_the_smoke_within_laser_range_of_the_robot() {
        let scenario = Scenario::builtin("r32-dense-crossing").unwrap();
        let source = scenario.sources[0].position;
        let like = OccupancyGrid::new(300, 240, 0.05, [-0.5, -0.5, 0.0]);
        let at = |m: &OccupancyGrid, x: f64, y: f64| {
            let (cx, cy) = m.world_to_cell(x, y).unwrap();
            m.get(cx, cy).unwrap()
        };
        // Parked 2 m from the source while it injects: its surroundings are smoke.
        let near = track(&[(source.x - 2.0, source.y)], 30.0);
        let m = smoke_region(&scenario, &near, &like, 5.6).unwrap().unwrap();
        assert_eq!(at(&m, source.x, source.y), 100);
        // Far from the source, beyond the robot's range: never in the region.
        assert_eq!(at(&m, 13.5, 1.0), 0);
        // The same smoke out of the laser's reach is not in the region.
        let short = smoke_region(&scenario, &near, &like, 1.0).unwrap().unwrap();
        assert_eq!(at(&short, source.x, source.y), 0);
        let mut clean = scenario.clone();
        clean.sources.clear();
        assert!(smoke_region(&clean, &near, &like, 5.6).unwrap().is_none());
    }
}
