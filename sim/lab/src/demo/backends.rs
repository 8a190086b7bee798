//! The same fused recording through the other SLAM back-end(s), so the demo
//! table shows the particle filter and the pose graph side by side.
//!
//! The profile's `[slam] backend` is the main comparison ([`super::compare`]);
//! this runs each of `rbpf` and `graph` the profile does not name over the
//! very same fusion output, scored the same way. The pose graph draws no
//! random numbers (its result does not depend on `[slam] seed`), so it runs
//! once per method; the particle filter runs once per seed.

use super::Comparison;
use super::compare::{self, MethodResult};
use super::recording::SensorLog;
use serde_json::{Value, json};
use smokenav_platform_config::{RobotConfig, SlamBackendKind};
use smokenav_platform_map::OccupancyGrid;
use smokenav_shared_types::FusionMethod;
use smokenav_sim_link::TruthTrack;
use std::fmt::Write as _;

/// One other back-end over the comparison's recording.
pub struct BackendRun {
    pub backend: SlamBackendKind,
    /// SLAM runs per method (1 for a back-end without random numbers).
    pub seeds: usize,
    pub results: Vec<MethodResult>,
}

/// The back-ends compared beside the profile's own: rbpf and graph, less the one the profile names.
pub fn others(profile: &RobotConfig) -> Vec<SlamBackendKind> {
    [SlamBackendKind::Rbpf, SlamBackendKind::Graph]
        .into_iter()
        .filter(|&b| b != profile.slam.backend)
        .collect()
}

fn seeds_of(backend: SlamBackendKind, seeds: usize) -> usize {
    match backend {
        // Deterministic: more seeds would only repeat the same run.
        SlamBackendKind::Graph => 1,
        _ => seeds,
    }
}

/// Runs every back-end of [`others`] over `log` (fusion again, which is cheap and
/// deterministic, so the scans are the same as the main comparison's).
pub fn run(
    log: &SensorLog,
    profile: &RobotConfig,
    truth: &TruthTrack,
    truth_map: &OccupancyGrid,
    smoke: Option<&OccupancyGrid>,
    threads: usize,
    seeds: usize,
) -> anyhow::Result<Vec<BackendRun>> {
    let mut out = Vec::new();
    for backend in others(profile) {
        let mut p = profile.clone();
        p.slam.backend = backend;
        let seeds = seeds_of(backend, seeds);
        let results = compare::run_all(log, &p, truth, truth_map, smoke, threads, seeds)?;
        out.push(BackendRun {
            backend,
            seeds,
            results,
        });
    }
    Ok(out)
}

fn map_error(results: &[MethodResult], m: FusionMethod) -> Option<f64> {
    results
        .iter()
        .find(|r| r.method == m)
        .and_then(|r| r.map_error_m())
}

/// Map error in smoke over the same method's and back-end's clean-air map error.
fn smoke_over_clean(
    smoke: &[MethodResult],
    clean: &[MethodResult],
    m: FusionMethod,
) -> Option<f64> {
    match (map_error(smoke, m), map_error(clean, m)) {
        (Some(s), Some(c)) if c > 0.0 => Some(s / c),
        _ => None,
    }
}

/// Every back-end's results of `c`: the main one first.
fn all(c: &Comparison) -> Vec<(SlamBackendKind, usize, &[MethodResult])> {
    std::iter::once((c.backend, c.seeds, c.results.as_slice()))
        .chain(
            c.other_backends
                .iter()
                .map(|b| (b.backend, b.seeds, b.results.as_slice())),
        )
        .collect()
}

fn cell(v: Option<f64>, unit: &str) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{x:.3}{unit}"),
        _ => "—".into(),
    }
}

/// The side-by-side table: per fusion method, map error and ATE of each
/// back-end, in smoke and (with a clean reference) in clean air, and each
/// back-end's smoke / clean-air map error ratio.
pub fn table(main: &Comparison, clean: Option<&Comparison>) -> String {
    let mut s = String::new();
    if main.other_backends.is_empty() {
        return s;
    }
    let smoke = all(main);
    let clean = clean.map(all);
    let _ = writeln!(
        s,
        "\nSLAM back-ends over the same fused scans (map error / ATE; mean over seeds, the graph has none):"
    );
    let _ = write!(s, "  {:<11}", "method");
    for (b, n, _) in &smoke {
        let head = format!(
            "{} ({n} seed{})",
            b.as_str(),
            if *n == 1 { "" } else { "s" }
        );
        let _ = write!(s, " {head:>21}");
        if clean.is_some() {
            let _ = write!(
                s,
                " {:>21} {:>12}",
                format!("{} clean air", b.as_str()),
                "smoke/clean"
            );
        }
    }
    let _ = writeln!(s);
    for m in compare::METHODS {
        let _ = write!(s, "  {:<11}", m.as_str());
        for (k, (_, _, results)) in smoke.iter().enumerate() {
            let r = results.iter().find(|r| r.method == m);
            let pair = |r: Option<&MethodResult>| {
                format!(
                    "{} / {}",
                    cell(r.and_then(|r| r.map_error_m()), " m"),
                    cell(r.and_then(|r| r.ate_m()), " m")
                )
            };
            let _ = write!(s, " {:>21}", pair(r));
            if let Some(clean) = &clean {
                let cr = clean.get(k).map(|c| c.2).unwrap_or(&[]);
                let _ = write!(
                    s,
                    " {:>21} {:>12}",
                    pair(cr.iter().find(|r| r.method == m)),
                    cell(smoke_over_clean(results, cr, m), "×")
                );
            }
        }
        let _ = writeln!(s);
    }
    s
}

fn methods_json(results: &[MethodResult]) -> Value {
    let mut o = serde_json::Map::new();
    for r in results {
        o.insert(
            r.method.as_str().into(),
            json!({
                "map_error_m": super::report::num(r.map_error_m()),
                "ate_m": super::report::num(r.ate_m()),
                "map_error_m_runs": r.runs.iter().map(|x| super::report::num(x.0)).collect::<Vec<_>>(),
                "ate_m_runs": r.runs.iter().map(|x| super::report::num(x.1)).collect::<Vec<_>>(),
            }),
        );
    }
    Value::Object(o)
}

/// `{"rbpf": {"seeds": 3, "methods": {…}, "clean_reference": {…}, "smoke_over_clean": {"v2": 1.4, …}}, "graph": …}`:
/// every back-end, the profile's own included.
pub fn json_value(main: &Comparison, clean: Option<&Comparison>) -> Value {
    let mut o = serde_json::Map::new();
    let clean = clean.map(all);
    for (k, (b, seeds, results)) in all(main).into_iter().enumerate() {
        let mut e = serde_json::Map::new();
        e.insert("seeds".into(), json!(seeds));
        e.insert("methods".into(), methods_json(results));
        if let Some(cr) = clean.as_ref().and_then(|c| c.get(k)).map(|c| c.2) {
            e.insert("clean_reference".into(), methods_json(cr));
            let ratios: serde_json::Map<String, Value> = compare::METHODS
                .iter()
                .map(|&m| {
                    (
                        m.as_str().to_string(),
                        super::report::num(smoke_over_clean(results, cr, m)),
                    )
                })
                .collect();
            e.insert("smoke_over_clean".into(), Value::Object(ratios));
        }
        o.insert(b.as_str().into(), Value::Object(e));
    }
    Value::Object(o)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_other_backends_are_rbpf_and_graph_less_the_profiles_own() {
        let mut p = smokenav_sim_world::Scenario::builtin("mrl-clean")
            .unwrap()
            .profile;
        p.slam.backend = SlamBackendKind::Rbpf;
        assert_eq!(others(&p), [SlamBackendKind::Graph]);
        p.slam.backend = SlamBackendKind::Graph;
        assert_eq!(others(&p), [SlamBackendKind::Rbpf]);
        p.slam.backend = SlamBackendKind::Fuzzy;
        assert_eq!(others(&p), [SlamBackendKind::Rbpf, SlamBackendKind::Graph]);
        assert_eq!(seeds_of(SlamBackendKind::Graph, 3), 1);
        assert_eq!(seeds_of(SlamBackendKind::Rbpf, 3), 3);
    }
}
