//! `smokenav eval`: how far an estimated map (and trajectory) is from the
//! ground truth: the k-nearest-neighbour map error of SmokeNav (Santos et al.
//! 2015) in both directions, the pixel error of SLAMfusion (Fernandes &
//! Alexandre), ATE/RPE, and the relations metric against a published
//! relations file (Kümmerle et al. 2009). Text for people, `--json` for scripts.

use crate::slam::{RELATIONS_MAX_GAP_S, relations_line};
use anyhow::Context;
use clap::Args;
use serde::Serialize;
use smokenav_algorithms_eval::{
    ErrorClass, MapOptions, MapReport, RelationsReport, TrajectoryOptions, TrajectoryReport,
    error_picture, evaluate_relations, load_relations, load_trajectory,
    map::{NOT_A_WALL_CELLS, ON_WALL_CELLS},
};
use smokenav_platform_map::OccupancyGrid;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// Ground-truth map (map_server YAML), e.g. the one the simulator writes.
    #[arg(long, value_name = "GT.yaml", requires = "map")]
    pub truth_map: Option<PathBuf>,
    /// Estimated map (map_server YAML) to score.
    #[arg(long, value_name = "EST.yaml", requires = "truth_map")]
    pub map: Option<PathBuf>,
    /// Ground-truth trajectory: `timestamp x y theta` lines.
    #[arg(long, value_name = "T.txt", requires = "trajectory")]
    pub truth_trajectory: Option<PathBuf>,
    /// Estimated trajectory: `timestamp x y theta` lines (or TUM's eight columns).
    #[arg(long, value_name = "E.txt")]
    pub trajectory: Option<PathBuf>,
    /// Relations file of the SLAM benchmark (Kümmerle et al. 2009; `t1 t2 x
    /// y z roll pitch yaw` per line) to score `--trajectory`'s relative motions against.
    #[arg(long, value_name = "R.relations", requires = "trajectory")]
    pub relations: Option<PathBuf>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    /// Compare the maps (and trajectories) in their own frames: no best-fit alignment.
    #[arg(long)]
    pub no_align: bool,
    /// Time step of the relative pose error, s.
    #[arg(long, default_value_t = 1.0, value_name = "S")]
    pub rpe_delta: f64,
    /// Also draw where the map's error lies, in the ground truth's frame, as
    /// a PNG: estimated walls black where they belong, red when off their
    /// place (up to 6 cells), magenta where the building has none (phantom);
    /// ground-truth walls pale green beside an estimated one, light blue
    /// where the estimate draws them off their place, blue where it lacks
    /// them (missing); the estimate's free space white, unknown grey.
    #[arg(long, value_name = "OUT.png", requires = "map")]
    pub error_image: Option<PathBuf>,
}

#[derive(Serialize)]
struct MapSection<'a> {
    truth: &'a PathBuf,
    estimate: &'a PathBuf,
    #[serde(flatten)]
    report: &'a MapReport,
}

#[derive(Serialize)]
struct TrajectorySection<'a> {
    truth: &'a PathBuf,
    estimate: &'a PathBuf,
    #[serde(flatten)]
    report: &'a TrajectoryReport,
}

#[derive(Serialize)]
struct RelationsSection<'a> {
    relations_file: &'a PathBuf,
    estimate: &'a PathBuf,
    #[serde(flatten)]
    report: &'a RelationsReport,
}

#[derive(Serialize)]
struct Output<'a> {
    #[serde(skip_serializing_if = "Option::is_none")]
    map: Option<MapSection<'a>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    trajectory: Option<TrajectorySection<'a>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    relations: Option<RelationsSection<'a>>,
    /// Where `--error-image` was written.
    #[serde(skip_serializing_if = "Option::is_none")]
    error_image: Option<&'a PathBuf>,
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    print!("{}", evaluate(&args)?);
    Ok(())
}

/// Runs the evaluation and renders it as the command prints it.
pub fn evaluate(args: &EvalArgs) -> anyhow::Result<String> {
    anyhow::ensure!(
        args.rpe_delta.is_finite() && args.rpe_delta > 0.0,
        "--rpe-delta must be a positive number of seconds, got {}",
        args.rpe_delta
    );
    anyhow::ensure!(
        args.truth_map.is_some() || args.truth_trajectory.is_some() || args.relations.is_some(),
        "nothing to score: give --truth-map with --map, --truth-trajectory with --trajectory, or --relations with --trajectory"
    );
    anyhow::ensure!(
        args.trajectory.is_none() || args.truth_trajectory.is_some() || args.relations.is_some(),
        "--trajectory is scored against --truth-trajectory or --relations: give one"
    );
    let map_opts = MapOptions {
        align: !args.no_align,
        ..Default::default()
    };
    let map = match (&args.truth_map, &args.map) {
        (Some(t), Some(m)) => Some((
            t,
            m,
            smokenav_algorithms_eval::evaluate_map_files(t, m, &map_opts)
                .context("cannot evaluate the map")?,
        )),
        _ => None,
    };
    if let (Some(out), Some((t, m, report))) = (&args.error_image, &map) {
        write_error_image(t, m, report, map_opts.occupied_threshold, out)?;
    }
    let relations = match (&args.relations, &args.trajectory) {
        (Some(r), Some(e)) => {
            let rel = load_relations(r).context("bad relations file")?;
            let est = load_trajectory(e).context("bad trajectory file")?;
            let report = evaluate_relations(&est, &rel, RELATIONS_MAX_GAP_S)
                .with_context(|| format!("{} against {}", e.display(), r.display()))?;
            Some((r, e, report))
        }
        _ => None,
    };
    let traj = match (&args.truth_trajectory, &args.trajectory) {
        (Some(t), Some(e)) => {
            let opts = TrajectoryOptions {
                align: !args.no_align,
                rpe_delta_s: args.rpe_delta,
                ..Default::default()
            };
            Some((
                t,
                e,
                smokenav_algorithms_eval::evaluate_trajectory_files(t, e, &opts)
                    .context("cannot evaluate the trajectory")?,
            ))
        }
        _ => None,
    };
    if args.json {
        let out = Output {
            map: map.as_ref().map(|(t, m, r)| MapSection {
                truth: t,
                estimate: m,
                report: r,
            }),
            relations: relations.as_ref().map(|(f, e, r)| RelationsSection {
                relations_file: f,
                estimate: e,
                report: r,
            }),
            trajectory: traj.as_ref().map(|(t, e, r)| TrajectorySection {
                truth: t,
                estimate: e,
                report: r,
            }),
            error_image: args.error_image.as_ref().filter(|_| map.is_some()),
        };
        return Ok(serde_json::to_string(&out)? + "\n");
    }
    let mut s = String::new();
    if let Some((truth, est, m)) = &map {
        map_text(&mut s, truth, est, m, args.no_align);
        if let Some(out) = &args.error_image {
            let _ = writeln!(s, "  error image   {}", out.display());
        }
    }
    if let Some((t, e, r)) = &traj {
        let _ = writeln!(
            s,
            "trajectory {} against {} ({} poses paired)",
            e.display(),
            t.display(),
            r.pairs
        );
        let _ = writeln!(
            s,
            "  alignment     dx {:+.3} m  dy {:+.3} m  dθ {:+.2}°",
            r.align_dx_m, r.align_dy_m, r.align_dtheta_deg
        );
        let _ = writeln!(
            s,
            "  ATE           rmse {:.4} m  mean {:.4}  median {:.4}  max {:.4};  heading rmse {:.2}°",
            r.ate_m.rmse, r.ate_m.mean, r.ate_m.median, r.ate_m.max, r.ate_heading_deg.rmse
        );
        let _ = writeln!(
            s,
            "  RPE ({} s)   translation rmse {:.4} m  max {:.4};  rotation rmse {:.3}°  max {:.3}°  ({} pairs)",
            r.rpe_delta_s,
            r.rpe_translation_m.rmse,
            r.rpe_translation_m.max,
            r.rpe_rotation_deg.rmse,
            r.rpe_rotation_deg.max,
            r.rpe_pairs
        );
        let _ = writeln!(
            s,
            "  relations     translation {:.4} ± {:.4} m;  rotation {:.3} ± {:.3}°  ({} relations, Kümmerle et al. 2009)",
            r.relations_translation_m.mean,
            r.relations_translation_m.std,
            r.relations_rotation_deg.mean,
            r.relations_rotation_deg.std,
            r.relations
        );
    }
    if let Some((f, e, r)) = &relations {
        let _ = writeln!(
            s,
            "relations {} against {} (Kümmerle et al. 2009)\n  {}",
            e.display(),
            f.display(),
            relations_line(r)
        );
    }
    Ok(s)
}

/// Pixels per cell of the error image: a building's map at 5 cm is a few
/// hundred cells across, too small to read at one pixel each; a large
/// one stays at one pixel a cell.
fn error_image_scale(width: usize, height: usize) -> u32 {
    (800 / width.max(height).max(1)).clamp(1, 4) as u32
}

/// Draws `--error-image`: the maps loaded again (the report keeps no grids).
fn write_error_image(
    truth: &Path,
    est: &Path,
    report: &MapReport,
    occupied_threshold: i8,
    out: &Path,
) -> anyhow::Result<()> {
    let t = smokenav_platform_map::load_map_server(truth)
        .with_context(|| format!("cannot read {}", truth.display()))?;
    let e = smokenav_platform_map::load_map_server(est)
        .with_context(|| format!("cannot read {}", est.display()))?;
    error_image_png(&t, &e, report, occupied_threshold, out)
}

/// Writes where `est`'s error against `truth` lies (`report`'s alignment)
/// as a PNG, in the truth's frame (`smokenav eval --error-image`,
/// `smokenav slam`'s `errors.png`).
pub(crate) fn error_image_png(
    truth: &OccupancyGrid,
    est: &OccupancyGrid,
    report: &MapReport,
    occupied_threshold: i8,
    out: &Path,
) -> anyhow::Result<()> {
    let pic = error_picture(truth, est, &report.alignment, occupied_threshold)
        .context("cannot draw the error image")?;
    let k = error_image_scale(pic.width, pic.height);
    let (w, h) = (pic.width as u32, pic.height as u32);
    let img = image::RgbImage::from_fn(w * k, h * k, |x, y| {
        // Image rows run top down, the picture's bottom up.
        let (cx, cy) = ((x / k) as usize, (h - 1 - y / k) as usize);
        image::Rgb(pic.get(cx, cy).unwrap_or(ErrorClass::Unknown).rgb())
    });
    img.save_with_format(out, image::ImageFormat::Png)
        .with_context(|| format!("cannot write the error image {}", out.display()))
}

/// The map section of the text report.
fn map_text(s: &mut String, truth: &Path, est: &Path, m: &MapReport, no_align: bool) {
    let _ = writeln!(
        s,
        "map {} against {} ({} m cells)",
        est.display(),
        truth.display(),
        m.resolution_m
    );
    let a = &m.alignment;
    let _ = writeln!(
        s,
        "  alignment     dx {:+.3} m  dy {:+.3} m  dθ {:+.2}°{}",
        a.dx_m,
        a.dy_m,
        a.dtheta_deg,
        if no_align { " (not searched)" } else { "" }
    );
    let _ = writeln!(
        s,
        "  k-NN error    {:.4} m = {:.2} cells  (SmokeNav paper; mean of both directions)",
        m.knn_error_m, m.knn_error_cells
    );
    for (label, d) in [
        ("  truth → map  ", &m.truth_to_map),
        ("  map → truth  ", &m.map_to_truth),
    ] {
        let _ = writeln!(
            s,
            "{label}mean {:.4} m  rms {:.4}  median {:.4}  max {:.4}  ({} cells)",
            d.mean_m, d.rms_m, d.median_m, d.max_m, d.count
        );
    }
    let _ = writeln!(
        s,
        "  pixel error   {:.3}  (SLAMfusion: √Σ(T−M)² over {} cells; rms {:.4})",
        m.pixel_error, m.pixel_count, m.pixel_rms
    );
    let _ = writeln!(
        s,
        "  where the k-NN error comes from (m of it, cells): on a wall < {ON_WALL_CELLS} cells, \
         misplaced ≤ {NOT_A_WALL_CELLS}, beyond that missing (truth → map) or phantom (map → truth)"
    );
    for (label, far, b) in [
        ("  truth → map  ", "missing", &m.truth_to_map_bands),
        ("  map → truth  ", "phantom", &m.map_to_truth_bands),
    ] {
        let _ = writeln!(
            s,
            "{label}on a wall {:.4} ({})  misplaced {:.4} ({})  {far} {:.4} ({})",
            b.on_wall.knn_share_m,
            b.on_wall.cells,
            b.misplaced.knn_share_m,
            b.misplaced.cells,
            b.far.knn_share_m,
            b.far.cells,
        );
        for g in &b.far_groups {
            let _ = writeln!(
                s,
                "      {far} around ({:.2}, {:.2}) m: {} cell{}, {:.4} m",
                g.x_m,
                g.y_m,
                g.cells,
                if g.cells == 1 { "" } else { "s" },
                g.knn_share_m
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_platform_map::{OCCUPIED, OccupancyGrid, save_map_server};
    use std::path::Path;

    fn room(extra: bool) -> OccupancyGrid {
        let mut g = OccupancyGrid::new(60, 40, 0.05, [0.0, 0.0, 0.0]);
        for x in 0..60 {
            g.set(x, 0, OCCUPIED);
            g.set(x, 39, OCCUPIED);
        }
        for y in 0..40 {
            g.set(0, y, OCCUPIED);
            g.set(59, y, OCCUPIED);
        }
        if extra {
            for x in 20..40 {
                g.set(x, 20, OCCUPIED);
            }
        }
        g
    }

    fn args(dir: &Path, est: &str) -> EvalArgs {
        EvalArgs {
            truth_map: Some(save_map_server(&room(false), dir, "gt").unwrap()),
            map: Some(save_map_server(&room(est == "phantom"), dir, est).unwrap()),
            truth_trajectory: None,
            trajectory: None,
            relations: None,
            json: false,
            no_align: false,
            rpe_delta: 1.0,
            error_image: None,
        }
    }

    #[test]
    fn the_error_image_draws_a_phantom_wall_where_the_estimate_has_it() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("where.png");
        let mut a = args(dir.path(), "phantom");
        a.error_image = Some(out.clone());
        let text = evaluate(&a).unwrap();
        assert!(text.contains("error image"), "{text}");
        let img = image::open(&out).unwrap().to_rgb8();
        // 60 × 40 cells and 20 around them, 4 pixels a cell.
        assert_eq!(img.dimensions(), (400, 320));
        let at = |cx: u32, cy: u32| img.get_pixel((cx + 20) * 4 + 1, (79 - (cy + 20)) * 4 + 1).0;
        assert_eq!(at(30, 20), ErrorClass::Phantom.rgb(), "the extra wall");
        assert_eq!(at(0, 0), ErrorClass::EstimateOnWall.rgb(), "a corner");
        assert_eq!(at(10, 10), ErrorClass::Unknown.rgb(), "never seen");
        assert_eq!(at(70, 10), ErrorClass::Unknown.rgb(), "beside the map");
        a.json = true;
        std::fs::remove_file(&out).unwrap();
        let json: serde_json::Value = serde_json::from_str(&evaluate(&a).unwrap()).unwrap();
        assert_eq!(json["error_image"], out.display().to_string());
        assert!(out.exists(), "written again with --json");
        // Without --map there is nothing to draw.
        use clap::Parser as _;
        let err = crate::Cli::try_parse_from([
            "smokenav",
            "eval",
            "--trajectory",
            "t.txt",
            "--relations",
            "r.relations",
            "--error-image",
            "x.png",
        ])
        .err()
        .expect("--error-image needs --map");
        assert!(err.to_string().contains("--map"), "{err}");
    }

    #[test]
    fn identical_maps_print_zero_error() {
        let dir = tempfile::tempdir().unwrap();
        let text = evaluate(&args(dir.path(), "same")).unwrap();
        assert!(
            text.contains("k-NN error    0.0000 m = 0.00 cells"),
            "{text}"
        );
        assert!(text.contains("pixel error   0.000"), "{text}");
    }

    #[test]
    fn json_carries_both_directions_and_the_trajectory() {
        let dir = tempfile::tempdir().unwrap();
        let mut a = args(dir.path(), "phantom");
        let t = dir.path().join("t.txt");
        let e = dir.path().join("e.txt");
        std::fs::write(&t, "0 0 0 0\n1 1 0 0\n2 2 0 0\n").unwrap();
        std::fs::write(&e, "0 0 0.1 0\n1 1 0.1 0\n2 2 0.1 0\n").unwrap();
        a.truth_trajectory = Some(t);
        a.trajectory = Some(e);
        a.json = true;
        a.no_align = true;
        let v: serde_json::Value = serde_json::from_str(&evaluate(&a).unwrap()).unwrap();
        assert_eq!(v["map"]["truth_to_map"]["max_m"], 0.0);
        // The phantom bar lies 0.95 m from the nearest true wall at its middle.
        assert!(
            v["map"]["map_to_truth"]["max_m"].as_f64().unwrap() > 0.9,
            "{v}"
        );
        assert!(
            (v["trajectory"]["ate_m"]["rmse"].as_f64().unwrap() - 0.1).abs() < 1e-9,
            "{v}"
        );
        assert!(
            v["map"]["estimate"]
                .as_str()
                .unwrap()
                .ends_with("phantom.yaml")
        );
    }

    /// The benchmark's relations need no map and no truth trajectory.
    #[test]
    fn a_trajectory_is_scored_against_a_relations_file_alone() {
        let dir = tempfile::tempdir().unwrap();
        let e = dir.path().join("e.txt");
        let r = dir.path().join("intel.relations");
        // Straight along x at 1 m/s, read 10 % short by the relations.
        std::fs::write(&e, "0 0 0 0\n1 1 0 0\n2 2 0 0\n3 3 0 0\n").unwrap();
        std::fs::write(
            &r,
            "0 1 0.9 0 0 0 0 0\n1 3 1.8 0 0 0 0 0\n2 9 1 0 0 0 0 0\n",
        )
        .unwrap();
        let mut a = args(dir.path(), "same");
        a.truth_map = None;
        a.map = None;
        a.trajectory = Some(e);
        a.relations = Some(r);
        let text = evaluate(&a).unwrap();
        assert!(!text.contains("k-NN"), "{text}");
        assert!(text.contains("translation 0.1500 ± 0.0500 m"), "{text}");
        assert!(
            text.contains("2 relations, 1 outside the trajectory"),
            "{text}"
        );
        a.json = true;
        let v: serde_json::Value = serde_json::from_str(&evaluate(&a).unwrap()).unwrap();
        assert!(v.get("map").is_none(), "{v}");
        assert_eq!(v["relations"]["relations"], 2);
        assert_eq!(v["relations"]["unmatched"], 1);
        assert!((v["relations"]["translation_m"]["mean"].as_f64().unwrap() - 0.15).abs() < 1e-9);
    }

    #[test]
    fn nothing_to_score_is_an_error_that_says_what_to_give() {
        let dir = tempfile::tempdir().unwrap();
        let mut a = args(dir.path(), "same");
        a.truth_map = None;
        a.map = None;
        let e = format!("{:#}", evaluate(&a).unwrap_err());
        assert!(e.contains("nothing to score"), "{e}");
        let t = dir.path().join("e.txt");
        std::fs::write(&t, "0 0 0 0\n1 1 0 0\n").unwrap();
        a.trajectory = Some(t);
        let e = format!("{:#}", evaluate(&a).unwrap_err());
        assert!(e.contains("nothing to score"), "{e}");
        let mut b = args(dir.path(), "same");
        b.trajectory = a.trajectory.clone();
        let e = format!("{:#}", evaluate(&b).unwrap_err());
        assert!(e.contains("--truth-trajectory or --relations"), "{e}");
    }

    #[test]
    fn bad_map_file_error_names_it() {
        let dir = tempfile::tempdir().unwrap();
        let mut a = args(dir.path(), "same");
        a.map = Some(dir.path().join("missing.yaml"));
        let e = format!("{:#}", evaluate(&a).unwrap_err());
        assert!(e.contains("missing.yaml"), "{e}");
    }
}
