//! The comparison as a table, as JSON, and as files.

use super::Comparison;
use super::compare::MethodResult;
use anyhow::Context;
use serde_json::{Value, json};
use std::fmt::Write as _;
use std::path::Path;

fn method_label(m: &MethodResult) -> &'static str {
    m.method.as_str()
}

pub(super) fn num(v: Option<f64>) -> Value {
    match v {
        Some(x) if x.is_finite() => json!((x * 1e4).round() / 1e4),
        _ => Value::Null,
    }
}

fn methods_json(c: &Comparison) -> Value {
    let mut m = serde_json::Map::new();
    for r in &c.results {
        let mut o = serde_json::Map::new();
        o.insert("map_error_m".into(), num(r.map_error_m()));
        o.insert("ate_m".into(), num(r.ate_m()));
        o.insert("sonar_usage".into(), num(Some(r.sonar_usage)));
        if let Ok(map) = &r.map_report {
            o.insert(
                "map_truth_to_estimate_m".into(),
                num(Some(map.truth_to_map.mean_m)),
            );
            o.insert(
                "map_estimate_to_truth_m".into(),
                num(Some(map.map_to_truth.mean_m)),
            );
            o.insert("pixel_rms".into(), num(Some(map.pixel_rms)));
        } else if let Err(e) = &r.map_report {
            o.insert("map_error".into(), json!(e));
        }
        if let Err(e) = &r.trajectory_report {
            o.insert("trajectory_error".into(), json!(e));
        }
        o.insert("scans".into(), json!(r.scans));
        if let Some(w) = &r.fuzzy_walls {
            o.insert("fuzzy_walls".into(), json!(w));
        }
        if let Some(v) = &r.laser_verdict {
            let mut j = json!(v);
            if let Some(obj) = j.as_object_mut() {
                obj.insert("smoke_kept_share".into(), num(v.smoke_kept_share()));
                obj.insert("clean_withheld_share".into(), num(v.clean_withheld_share()));
            }
            o.insert("laser_verdict".into(), j);
        }
        if let Some(m) = r.same_slam_input_as {
            o.insert("same_slam_input_as".into(), json!(m.as_str()));
        }
        if r.runs.len() > 1 {
            o.insert(
                "map_error_m_runs".into(),
                Value::Array(r.runs.iter().map(|x| num(x.0)).collect()),
            );
            o.insert(
                "ate_m_runs".into(),
                Value::Array(r.runs.iter().map(|x| num(x.1)).collect()),
            );
        }
        m.insert(method_label(r).into(), Value::Object(o));
    }
    Value::Object(m)
}

/// `{"scenario": …, "methods": {"laser-only": {"map_error_m": …, "ate_m": …, "sonar_usage": …}, …}, "clean_reference": …}`
pub fn json_value(main: &Comparison, clean: Option<&Comparison>) -> Value {
    let mut v = json!({
        "scenario": main.scenario,
        "sim_seed": main.sim_seed,
        "slam_seeds": main.seeds,
        "duration_s": (main.sim_s * 10.0).round() / 10.0,
        "scans": main.scans,
        "methods": methods_json(main),
        "slam_backend": main.backend.as_str(),
    });
    if !main.other_backends.is_empty()
        && let Some(obj) = v.as_object_mut()
    {
        obj.insert("backends".into(), super::backends::json_value(main, clean));
    }
    if let (Some(c), Some(obj)) = (clean, v.as_object_mut()) {
        obj.insert(
            "clean_reference".into(),
            json!({ "scenario": c.scenario, "methods": methods_json(c) }),
        );
    }
    v
}

fn cell(v: Option<f64>, unit: &str) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{x:.3} {unit}"),
        _ => "—".into(),
    }
}

fn table_rows(s: &mut String, c: &Comparison) {
    let _ = writeln!(
        s,
        "  {:<11} {:>14} {:>12} {:>12} {:>11} {:>12}",
        "method", "map error", "truth→map", "map→truth", "ATE (RMS)", "sonar usage"
    );
    for r in &c.results {
        let (tm, mt) = match &r.map_report {
            Ok(m) => (Some(m.truth_to_map.mean_m), Some(m.map_to_truth.mean_m)),
            Err(_) => (None, None),
        };
        let _ = writeln!(
            s,
            "  {:<11} {:>14} {:>12} {:>12} {:>11} {:>11.1}%",
            method_label(r),
            cell(r.map_error_m(), "m"),
            cell(tm, "m"),
            cell(mt, "m"),
            cell(r.ate_m(), "m"),
            r.sonar_usage * 100.0
        );
    }
    let err = |m| {
        c.results
            .iter()
            .find(|r| r.method == m)
            .and_then(|r| r.map_error_m())
    };
    use smokenav_shared_types::FusionMethod::*;
    if let (Some(l), Some(v1), Some(v2)) = (err(LaserOnly), err(V1), err(V2))
        && l > 0.0
    {
        let _ = writeln!(
            s,
            "  map error relative to laser-only: v1 {:.2}×, v2 {:.2}×",
            v1 / l,
            v2 / l
        );
    }
    laser_verdict_rows(s, c);
    if c.seeds > 1 {
        let _ = writeln!(
            s,
            "  (map error and ATE: mean of {} SLAM seeds; maps, trajectories, truth→map and map→truth: the median seed's run)",
            c.seeds
        );
        for r in &c.results {
            let fmt = |v: Option<f64>| v.map_or("—".into(), |x| format!("{x:.3}"));
            let maps: Vec<String> = r.runs.iter().map(|x| fmt(x.0)).collect();
            let ates: Vec<String> = r.runs.iter().map(|x| fmt(x.1)).collect();
            let _ = writeln!(
                s,
                "  {:<11} map error per seed {} m; ATE {} m",
                method_label(r),
                maps.join(" "),
                ates.join(" ")
            );
        }
    }
    for r in &c.results {
        if let Some(m) = r.same_slam_input_as {
            let _ = writeln!(
                s,
                "  {}: fusion handed SLAM exactly the scans {} did, so the SLAM result is the same",
                method_label(r),
                m.as_str()
            );
        }
        if let Err(e) = &r.map_report {
            let _ = writeln!(s, "  {}: map not scored: {e}", method_label(r));
        }
        if let Err(e) = &r.trajectory_report {
            let _ = writeln!(s, "  {}: trajectory not scored: {e}", method_label(r));
        }
    }
}

/// Against the smoke-free twin: how many of the beams the smoke changed each
/// method handed to SLAM, and how many untouched beams it withheld.
fn laser_verdict_rows(s: &mut String, c: &Comparison) {
    let verdicts: Vec<(&MethodResult, &super::compare::LaserVerdict)> = c
        .results
        .iter()
        .filter_map(|r| r.laser_verdict.as_ref().map(|v| (r, v)))
        .collect();
    let Some((_, first)) = verdicts.first() else {
        return;
    };
    let pct = |x: Option<f64>| x.map_or("—".into(), |x| format!("{:.1} %", x * 100.0));
    let kept: Vec<String> = verdicts
        .iter()
        .map(|(r, v)| format!("{} {}", method_label(r), pct(v.smoke_kept_share())))
        .collect();
    let lost: Vec<String> = verdicts
        .iter()
        .map(|(r, v)| format!("{} {}", method_label(r), pct(v.clean_withheld_share())))
        .collect();
    let _ = writeln!(
        s,
        "  laser beams the smoke changed (vs the smoke-free twin, {} of {} returns): handed to SLAM by {}",
        first.smoke_beams,
        first.smoke_beams + first.clean_beams,
        kept.join(", ")
    );
    let _ = writeln!(
        s,
        "  laser beams the smoke left alone, withheld from SLAM: {}",
        lost.join(", ")
    );
}

/// With the fuzzy back-end: its confidence on true walls by who painted them,
/// and its confident cells away from every true wall, by where they are.
fn fuzzy_rows(s: &mut String, c: &Comparison) {
    for r in &c.results {
        if let Some(w) = &r.fuzzy_walls {
            let smoke = match (w.confident_phantom_cells_in_smoke, w.in_smoke_near_wall) {
                (Some(n), Some(near)) => format!(
                    "{n} in the smoke ({near} of them 0.3–0.6 m off a wall; smoke region {:.1} m²)",
                    w.smoke_region_m2.unwrap_or(0.0)
                ),
                _ => "no smoke".into(),
            };
            let _ = writeln!(
                s,
                "  {:<11} fuzzy map on true walls: laser-seen {:.2} ({} cells), sonar-only {:.2} ({} cells); confident cells ≥ 0.3 m from any wall: {}: {smoke}; in clear air {} 0.3–0.6 m off a wall, {} outside the walls, {} in open space",
                method_label(r),
                w.laser_wall_confidence,
                w.laser_wall_cells,
                w.sonar_only_wall_confidence,
                w.sonar_only_wall_cells,
                w.confident_phantom_cells,
                w.clear_air_near_wall,
                w.clear_air_outside_arena,
                w.clear_air_open_space
            );
        }
    }
}

/// `x y confidence place` of every confident phantom cell (truth frame).
fn phantoms_csv(r: &MethodResult) -> String {
    let mut s = String::from(
        "# confident (>= 0.65) fuzzy-map cells more than 0.3 m from every true wall\n# x_m y_m (truth frame) confidence place\n",
    );
    for p in &r.fuzzy_phantoms {
        let _ = writeln!(
            s,
            "{:.3} {:.3} {:.2} {}",
            p.x,
            p.y,
            f64::from(p.confidence) / 100.0,
            p.place.as_str()
        );
    }
    s
}

/// The paper's comparison for people.
pub fn table(main: &Comparison, clean: Option<&Comparison>) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "\n{} — {}: {:.1} s, {} scans",
        main.scenario, main.description, main.sim_s, main.scans
    );
    let _ = writeln!(
        s,
        "map error: the SmokeNav paper's k-NN error, mean of both directions (truth walls → nearest mapped wall, mapped walls → nearest true wall) after best-fit alignment"
    );
    table_rows(&mut s, main);
    fuzzy_rows(&mut s, main);
    if let Some(c) = clean {
        let _ = writeln!(
            s,
            "\nclean reference: {} — same route, same seed, no smoke",
            c.scenario
        );
        table_rows(&mut s, c);
    }
    s.push_str(&super::backends::table(main, clean));
    s
}

fn write(path: &Path, text: &str) -> anyhow::Result<()> {
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

/// Maps (PGM/YAML) and trajectories of one comparison into `dir`.
pub fn write_files(c: &Comparison, dir: &Path) -> anyhow::Result<()> {
    let maps = dir.join("maps");
    let trajectories = dir.join("trajectories");
    for d in [&maps, &trajectories] {
        std::fs::create_dir_all(d).with_context(|| format!("cannot create {}", d.display()))?;
    }
    for r in &c.results {
        let name = method_label(r);
        if let Some(m) = &r.map {
            smokenav_platform_map::save_map_server(m, &maps, name)
                .with_context(|| format!("cannot write the {name} map to {}", maps.display()))?;
        }
        if let Some(f) = &r.confidence_map {
            let stem = format!("{name}-fuzzy");
            smokenav_platform_map::save_map_server_mode(
                f,
                &maps,
                &stem,
                smokenav_platform_map::MapMode::Raw,
            )
            .with_context(|| format!("cannot write the {stem} map to {}", maps.display()))?;
        }
        if r.fuzzy_walls.is_some() {
            write(&maps.join(format!("{name}-phantoms.txt")), &phantoms_csv(r))?;
        }
        write(
            &trajectories.join(format!("{name}.txt")),
            &format!(
                "# timestamp x y theta ({name}, SLAM map frame)\n{}",
                smokenav_algorithms_eval::format_trajectory(
                    &r.trajectory
                        .iter()
                        .map(|p| smokenav_algorithms_eval::StampedPose::from_ns(
                            p.stamp_ns, &p.pose
                        ))
                        .collect::<Vec<_>>()
                )
            ),
        )?;
    }
    Ok(())
}

/// `maps.png`, `errors.png` and `smoke.png` of one comparison into `dir`.
pub fn write_pictures(c: &Comparison, dir: &Path) -> anyhow::Result<()> {
    super::pictures::maps_png(c, &dir.join("maps.png"))?;
    super::pictures::errors_png(c, &dir.join("errors.png"))?;
    if c.results.iter().any(|r| r.confidence_map.is_some()) {
        super::pictures::fuzzy_png(c, &dir.join("fuzzy.png"))?;
    }
    super::pictures::smoke_png(c, &dir.join("smoke.png"))
}

/// `comparison.json` (what `--json` prints).
pub fn write_summary(
    main: &Comparison,
    clean: Option<&Comparison>,
    dir: &Path,
) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(&json_value(main, clean))
        .context("cannot format the comparison")?;
    write(&dir.join("comparison.json"), &(text + "\n"))
}
