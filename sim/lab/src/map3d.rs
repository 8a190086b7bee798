//! `smokenav-lab map3d`: the 2D/3D fusion comparison on a scenario with
//! obstacles out of the laser's plane. The world runs as fast as the CPU
//! allows; laser scans and sonar echoes go, at the true poses (so the
//! comparison measures mapping, not localisation), into the mapping library
//! with per-sensor maps kept. Per rule (LOP, LIOP, IOP, Bayes) it prints:
//!
//! - the fused 2D grid's error in the laser plane: the share of cells the
//!   map classifies (occupied / free) that the plane's truth classifies
//!   otherwise, beside the laser-only grid's;
//! - the recall of out-of-plane obstacles (segments that do not reach the
//!   laser's height but stand below the robot's top): the share of their
//!   truth cells with an occupied cell within one cell in the projected map,
//!   beside the laser-only grid's.
//!
//! - the projected map's error against the truth of every obstacle below the
//!   robot's top (what the sonar's wide caps cost: ghost cells beside objects);
//!
//! and the octree's memory against a dense 3D grid of the arena. It checks
//! the must-be-true figures and exits non-zero when one fails.

use anyhow::{Context, bail};
use serde::Serialize;
use smokenav_algorithms_mapping::{
    CellClass, FusionRule, Heights, MapParams, MapSet, Mapper, ProbGrid, Rig,
};
use smokenav_platform_map::{FREE, OCCUPIED, OccupancyGrid};
use smokenav_sim_world::laser::{
    URG_AFRT, URG_AMIN, URG_DMAX_MM, URG_DMIN_MM, URG_STEP_TIME_S, URG_STEPS, step_angle,
};
use smokenav_sim_world::{Pose2, Position, Scenario, StepOutput, World};
use std::collections::VecDeque;
use std::path::PathBuf;
use std::time::Duration;

#[derive(clap::Args, Debug)]
pub struct Map3dArgs {
    /// Scenario: a bundled one (heights) or a scenario TOML file.
    #[arg(long, value_name = "FILE|NAME", default_value = "heights")]
    pub scenario: String,
    /// Voxel and cell side, m.
    #[arg(long, value_name = "M", default_value_t = 0.05)]
    pub resolution: f64,
    /// The robot's height, m: obstacles below it are obstacles.
    #[arg(long, value_name = "M", default_value_t = 0.60)]
    pub robot_height: f64,
    /// Write the maps (PNG per rule, the Bayes octree as octree.bt) and report.json here.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// End after this many simulated seconds (default: when the route is done).
    #[arg(long, value_name = "SECONDS")]
    pub duration: Option<f64>,
}

impl Map3dArgs {
    /// The comparison `./demo` adds: the bundled `heights` scenario at 5 cm.
    pub fn demo(out: Option<PathBuf>) -> Self {
        Self {
            scenario: "heights".into(),
            resolution: 0.05,
            robot_height: 0.60,
            out,
            duration: None,
        }
    }
}

#[derive(Debug, Serialize)]
pub struct RuleRow {
    pub rule: String,
    pub plane_error: f64,
    pub plane_classified_cells: usize,
    pub out_of_plane_recall: f64,
    /// The projected map's error against every obstacle below the robot's top.
    pub projected_error: f64,
}

#[derive(Debug, Serialize)]
pub struct Report {
    scenario: String,
    resolution_m: f64,
    laser_height_m: f64,
    sonar_height_m: f64,
    robot_height_m: f64,
    ceiling_m: f64,
    laser_only_plane_error: f64,
    laser_only_out_of_plane_recall: f64,
    out_of_plane_truth_cells: usize,
    rules: Vec<RuleRow>,
    octree_nodes: usize,
    octree_bytes: usize,
    dense_grid_bytes: usize,
    bt_bytes: Option<u64>,
    bt_occupied_leaves: usize,
    /// Lowest and highest corner of the occupied leaves, m.
    occupied_bounds_m: Option<[[f64; 3]; 2]>,
    pub checks: Vec<(String, bool)>,
}

pub fn run(args: Map3dArgs) -> anyhow::Result<()> {
    let report = evaluate(&args)?;
    print!("{}", table(&report));
    if report.checks.iter().any(|(_, ok)| !ok) {
        bail!("a must-be-true figure failed (see FAIL above)");
    }
    Ok(())
}

/// Maps the scenario, scores every rule and (with `out`) writes the maps and report.json.
pub fn evaluate(args: &Map3dArgs) -> anyhow::Result<Report> {
    let scenario = Scenario::builtin_or_file(&args.scenario)?;
    let name = scenario.name.clone();
    let heights = Heights {
        laser_m: scenario.laser.height_m,
        sonar_m: scenario.sonar.height_m,
        robot_m: args.robot_height,
    };
    let rig = Rig::from_config(&scenario.profile, &heights);
    let (lo, hi) = scenario.arena.wall_extent();
    let params = MapParams {
        resolution: args.resolution,
        heights,
        grid_origin: [lo.x - 0.5, lo.y - 0.5],
        grid_size_m: [hi.x - lo.x + 1.0, hi.y - lo.y + 1.0],
        ..MapParams::default()
    };
    let mut mapper = Mapper::new(rig, params, MapSet::Comparison)?;
    let arena = scenario.arena.clone();
    let start = scenario.start.position();
    let duration_ns = args.duration.map(|s| (s * 1e9) as u64);
    let mut world = World::new(scenario)?;

    // True poses of the last 300 ms, every 10 ms: a scan is reported when
    // its turn ends, 100 ms after its first step.
    let mut out = StepOutput::default();
    let mut history: VecDeque<(u64, Pose2)> = VecDeque::with_capacity(32);
    history.push_back((world.time_ns(), world.truth_pose()));
    let (mut scans, mut echoes) = (0usize, 0usize);
    let mut beams: Vec<(f64, Option<f64>)> = Vec::with_capacity(URG_STEPS);
    let laser_mount = mapper.rig().laser.pose;
    while !world.is_finished()
        && !world.route_done()
        && duration_ns.is_none_or(|d| world.time_ns() < d)
    {
        world.step_into(Duration::from_millis(10), &mut out);
        if history.len() == 30 {
            history.pop_front();
        }
        history.push_back((world.time_ns(), world.truth_pose()));
        for frame in &out.laser {
            // Each beam at its own step's time, re-expressed from the laser's
            // pose at mid-turn (de-skewed, as a consumer of a moving scanner must).
            let step_ns = |s: u32| frame.t_ns + (s as f64 * URG_STEP_TIME_S * 1e9) as u64;
            let mid = pose_at(&history, step_ns(URG_AFRT)).compose(&laser_mount);
            beams.clear();
            beams.extend(frame.ranges_mm.iter().enumerate().map(|(i, &mm)| {
                let step = URG_AMIN + i as u32;
                let a = step_angle(step);
                if !(URG_DMIN_MM..=URG_DMAX_MM).contains(&mm) {
                    return (a, None);
                }
                let r = mm as f64 / 1000.0;
                let l = pose_at(&history, step_ns(step)).compose(&laser_mount);
                let (ex, ey) = (l.x + r * (l.theta + a).cos(), l.y + r * (l.theta + a).sin());
                let (dx, dy) = (ex - mid.x, ey - mid.y);
                (dy.atan2(dx) - mid.theta, Some(dx.hypot(dy)))
            }));
            let base = mid.compose(&laser_mount.inverse());
            mapper.insert_laser(&base, beams.iter().copied());
            scans += 1;
        }
        for s in out.sonar.iter().filter(|s| !s.saturated) {
            mapper.insert_sonar(&pose_at(&history, s.t_ns), [(s.index, s.range_m)]);
            echoes += 1;
        }
        out.clear();
    }
    eprintln!(
        "{name}: {:.1} s simulated, {scans} scans, {echoes} sonar echoes mapped",
        world.time_ns() as f64 / 1e9
    );

    let res = args.resolution;
    let plane_truth = arena.truth_map_where(res, start, |s| s.spans(heights.laser_m));
    let out_of_plane = arena.truth_map_where(res, start, |s| {
        !s.spans(heights.laser_m) && s.z[0] < heights.robot_m
    });
    let below_top = arena.truth_map_where(res, start, |s| s.z[0] < heights.robot_m);
    let oop_cells: Vec<(f64, f64)> = out_of_plane.occupied_points(OCCUPIED);
    if oop_cells.is_empty() {
        bail!("scenario {name} has no obstacles out of the laser plane below the robot's height");
    }
    let laser = mapper.laser_grid().context("laser grid")?;
    let laser_err = plane_error(&laser, &plane_truth);
    let laser_recall = recall(&laser, &oop_cells);
    let mut rows = Vec::new();
    for rule in FusionRule::ALL {
        let fused = mapper.fused_grid(rule).context("fused grid")?;
        let projected = mapper.projected(rule).context("projection")?;
        let (e, n) = plane_error(&fused, &plane_truth);
        rows.push(RuleRow {
            rule: rule.name().into(),
            plane_error: e,
            plane_classified_cells: n,
            out_of_plane_recall: recall(&projected, &oop_cells),
            projected_error: plane_error(&projected, &below_top).0,
        });
        if let Some(dir) = &args.out {
            std::fs::create_dir_all(dir).with_context(|| dir.display().to_string())?;
            for (what, g) in [("plane", &fused), ("projected", &projected)] {
                let p = dir.join(format!("{}-{what}.png", rule.name().to_lowercase()));
                g.to_occupancy_grid().save_png(&p)?;
            }
        }
    }
    let tree = mapper.octree();
    let dense = mapper.dense_grid_bytes([lo.x, lo.y], [hi.x, hi.y]);
    let mut bt_bytes = None;
    let mut bt_occupied = 0;
    if let Some(dir) = &args.out {
        laser
            .to_occupancy_grid()
            .save_png(&dir.join("laser-only-plane.png"))?;
        let path = dir.join("octree.bt");
        let mut f = std::io::BufWriter::new(
            std::fs::File::create(&path).with_context(|| path.display().to_string())?,
        );
        let stats = tree.write_bt(&mut f)?;
        std::io::Write::flush(&mut f)?;
        bt_occupied = stats.occupied_leaves;
        bt_bytes = Some(std::fs::metadata(&path)?.len());
    }

    let bayes = rows
        .iter()
        .find(|r| r.rule == "Bayes")
        .context("Bayes row")?;
    let checks = vec![
        (
            format!(
                "projected (Bayes) finds ≥ 80 % of out-of-plane obstacle cells: {:.1} %",
                bayes.out_of_plane_recall * 100.0
            ),
            bayes.out_of_plane_recall >= 0.8,
        ),
        (
            format!("laser-only 2D finds ≤ 10 %: {:.1} %", laser_recall * 100.0),
            laser_recall <= 0.10,
        ),
        (
            format!(
                "fused (Bayes) 2D error in the laser plane within 10 % of laser-only: {:.2} % vs {:.2} %",
                bayes.plane_error * 100.0,
                laser_err.0 * 100.0
            ),
            bayes.plane_error <= laser_err.0 * 1.10,
        ),
        (
            format!(
                "octree smaller than the dense grid: {} < {dense} bytes",
                tree.memory_bytes()
            ),
            tree.memory_bytes() < dense,
        ),
    ];
    let report = Report {
        scenario: name,
        resolution_m: res,
        laser_height_m: heights.laser_m,
        sonar_height_m: heights.sonar_m,
        robot_height_m: heights.robot_m,
        ceiling_m: mapper.params().ceiling_m,
        laser_only_plane_error: laser_err.0,
        laser_only_out_of_plane_recall: laser_recall,
        out_of_plane_truth_cells: oop_cells.len(),
        rules: rows,
        octree_nodes: tree.node_count(),
        octree_bytes: tree.memory_bytes(),
        dense_grid_bytes: dense,
        bt_bytes,
        bt_occupied_leaves: bt_occupied,
        occupied_bounds_m: occupied_bounds(tree),
        checks,
    };
    if let Some(dir) = &args.out {
        std::fs::write(
            dir.join("report.json"),
            serde_json::to_string_pretty(&report)?,
        )?;
    }
    Ok(report)
}

/// The comparison as text: per rule, then the octree, then PASS/FAIL per figure.
pub fn table(r: &Report) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{}: laser plane {:.2} m, sonar {:.2} m, robot top {:.2} m, {} m cells",
        r.scenario, r.laser_height_m, r.sonar_height_m, r.robot_height_m, r.resolution_m
    );
    let _ = writeln!(
        s,
        "{:<12} {:>18} {:>22} {:>18}",
        "map", "2D error (plane)", "out-of-plane recall", "projected error"
    );
    let _ = writeln!(
        s,
        "{:<12} {:>17.2}% {:>21.1}% {:>18}",
        "laser only",
        r.laser_only_plane_error * 100.0,
        r.laser_only_out_of_plane_recall * 100.0,
        "-"
    );
    for row in &r.rules {
        let _ = writeln!(
            s,
            "{:<12} {:>17.2}% {:>21.1}% {:>17.2}%",
            row.rule,
            row.plane_error * 100.0,
            row.out_of_plane_recall * 100.0,
            row.projected_error * 100.0
        );
    }
    let _ = writeln!(
        s,
        "octree: {} nodes, {:.1} KiB; dense 3D grid of the arena (f32, floor to {:.1} m): {:.1} KiB; {:.1}× smaller",
        r.octree_nodes,
        r.octree_bytes as f64 / 1024.0,
        r.ceiling_m,
        r.dense_grid_bytes as f64 / 1024.0,
        r.dense_grid_bytes as f64 / r.octree_bytes.max(1) as f64
    );
    if let Some(b) = r.bt_bytes {
        let _ = writeln!(
            s,
            "octree.bt: {b} bytes, {} occupied leaves",
            r.bt_occupied_leaves
        );
    }
    for (what, ok) in &r.checks {
        let _ = writeln!(s, "{} {what}", if *ok { "PASS" } else { "FAIL" });
    }
    s
}

/// Share of the cells `map` classifies, within the truth's known cells, that
/// the truth classifies otherwise; and how many cells that was.
fn plane_error(map: &ProbGrid, truth: &OccupancyGrid) -> (f64, usize) {
    let (mut wrong, mut n) = (0usize, 0usize);
    for y in 0..truth.height {
        for x in 0..truth.width {
            let t = truth.cells[y * truth.width + x];
            if t != OCCUPIED && t != FREE {
                continue;
            }
            let (wx, wy) = truth.cell_center(x, y);
            let Some(i) = map.geometry.index(wx, wy) else {
                continue;
            };
            let c = map.class(i);
            if c == CellClass::Unknown {
                continue;
            }
            n += 1;
            if (c == CellClass::Occupied) != (t == OCCUPIED) {
                wrong += 1;
            }
        }
    }
    (wrong as f64 / n.max(1) as f64, n)
}

/// Share of `cells` with an occupied map cell within one cell.
fn recall(map: &ProbGrid, cells: &[(f64, f64)]) -> f64 {
    let r = map.geometry.resolution;
    let found = cells
        .iter()
        .filter(|&&(x, y)| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dx| {
                    map.geometry
                        .index(x + dx as f64 * r, y + dy as f64 * r)
                        .is_some_and(|i| map.class(i) == CellClass::Occupied)
                })
            })
        })
        .count();
    found as f64 / cells.len().max(1) as f64
}

/// The box around the occupied leaves (log-odds > 0, as the export decides).
fn occupied_bounds(tree: &smokenav_algorithms_mapping::Octree) -> Option<[[f64; 3]; 2]> {
    let r = tree.resolution();
    let mut b: Option<[[f64; 3]; 2]> = None;
    tree.for_each_leaf(|l| {
        if l.logodds <= 0.0 {
            return;
        }
        let lo: [f64; 3] = std::array::from_fn(|a| tree.coord(l.key[a]) - r / 2.0);
        let hi: [f64; 3] = std::array::from_fn(|a| lo[a] + l.size as f64 * r);
        let bb = b.get_or_insert([lo, hi]);
        for a in 0..3 {
            bb[0][a] = bb[0][a].min(lo[a]);
            bb[1][a] = bb[1][a].max(hi[a]);
        }
    });
    b
}

/// The true pose at `t`, interpolated in the history (clamped to its ends).
fn pose_at(history: &VecDeque<(u64, Pose2)>, t: u64) -> Pose2 {
    let Some(&(_, last)) = history.back() else {
        return Pose2::default();
    };
    let mut before = history[0];
    if t <= before.0 {
        return before.1;
    }
    for &(ti, pi) in history {
        if ti >= t {
            let f = (t - before.0) as f64 / (ti - before.0).max(1) as f64;
            return before.1.interpolate(&pi, f);
        }
        before = (ti, pi);
    }
    last
}
