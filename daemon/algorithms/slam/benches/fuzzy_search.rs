//! Cuckoo search against the correlative grid on the fuzzy back-end's
//! overlap cost, over real scan pairs of the MIT CSAIL log: the cost each
//! reaches, the CPU time and the cost evaluations per registration.
//!
//! Pairs are scans k and k + `FUZZY_GAP` (default 1) for every `FUZZY_EVERY`-th
//! k (default 10), both local maps cropped by the odometry's motion (eqs.
//! 8–9), the window centred on it, as the back-end does with
//! `reference = "previous"`.
//!
//! `CSAIL_DIR=... cargo bench -p smokenav-algorithms-slam --bench fuzzy_search`

use smokenav_algorithms_slam::fuzzy::registration::{
    CuckooParams, FuzzyPoint, Reference, SearchResult, Window, correlative, crop, cuckoo,
    reading_points,
};
use smokenav_algorithms_slam::fuzzy::{ConfidenceModel, FuzzyGrid, fuzzy_beams};
use smokenav_algorithms_slam::offline::LogScans;
use smokenav_algorithms_slam::{Pose2, RangeScan};
use smokenav_platform_config::FuzzySection;
use smokenav_shared_types::Rng;
use std::io::BufReader;
use std::path::PathBuf;

fn thread_cpu_ns() -> u64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID)
        .map(|t| t.tv_sec() as u64 * 1_000_000_000 + t.tv_nsec() as u64)
        .unwrap_or(0)
}

struct Pair {
    reference: Reference,
    points: Vec<FuzzyPoint>,
    window: Window,
}

fn local(
    scan: &RangeScan,
    model: &ConfidenceModel,
    p: &FuzzySection,
) -> (FuzzyGrid, Vec<FuzzyPoint>) {
    let mut beams = Vec::new();
    fuzzy_beams(scan, model, 80.0, p.local_radius_m, &mut beams);
    let mut g = FuzzyGrid::square(0.05, p.local_radius_m);
    g.paint(&scan.sensor_pose, &beams, p.local_radius_m);
    let mut pts = Vec::new();
    reading_points(&scan.sensor_pose, &beams, p.max_points as usize, &mut pts);
    (g, pts)
}

fn env(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    let Ok(dir) = std::env::var("CSAIL_DIR").map(PathBuf::from) else {
        eprintln!("fuzzy_search: set CSAIL_DIR to the folder holding mit-csail.clf");
        std::process::exit(2);
    };
    let (every, gap) = (env("FUZZY_EVERY", 10).max(1), env("FUZZY_GAP", 1).max(1));
    let p = FuzzySection::default();
    let model = ConfidenceModel::from_config(&p);
    let mut scans = LogScans::new(BufReader::new(
        std::fs::File::open(dir.join("mit-csail.clf")).unwrap(),
    ));
    let mut all: Vec<(RangeScan, Pose2)> = Vec::new();
    while let Some((scan, odom)) = scans.next_scan() {
        all.push((scan.clone(), odom));
    }
    let mut pairs = Vec::new();
    for k in (0..all.len().saturating_sub(gap)).step_by(every) {
        let (a, oa) = &all[k];
        let (b, ob) = &all[k + gap];
        let predicted = oa.between(ob);
        let (ga, pa) = local(a, &model, &p);
        let (gb, pb) = local(b, &model, &p);
        let (mut cropped_b, mut cropped_a) = (Vec::new(), Vec::new());
        crop(&pb, &ga, &predicted, &mut cropped_b);
        crop(&pa, &gb, &predicted.inverse(), &mut cropped_a);
        if cropped_a.len() < 20 || cropped_b.len() < 20 {
            continue;
        }
        let mut reference = Reference::default();
        reference.build(&ga, &cropped_a, p.match_radius_m);
        pairs.push(Pair {
            reference,
            points: cropped_b,
            window: Window {
                centre: predicted,
                window_m: p.window_m,
                window_rad: p.window_rad,
            },
        });
    }
    let cuckoo_with = |generations: usize| CuckooParams {
        nests: p.cuckoo_nests as usize,
        generations,
        abandon: p.cuckoo_abandon,
        beta: p.cuckoo_levy_beta,
        alpha: p.cuckoo_alpha,
    };
    type Search<'a> = Box<dyn Fn(&Pair, &mut Rng) -> SearchResult + 'a>;
    let searches: Vec<(String, Search)> = vec![
        (
            format!(
                "correlative {}/{}",
                p.correlative_step_m, p.correlative_step_rad
            ),
            Box::new(|pair: &Pair, _: &mut Rng| {
                correlative(
                    &pair.window,
                    p.correlative_step_m,
                    p.correlative_step_rad,
                    |t| pair.reference.overlap(&pair.points, t),
                )
            }),
        ),
        (
            format!("cuckoo {} nests x 10 gen", p.cuckoo_nests),
            Box::new(move |pair: &Pair, rng: &mut Rng| {
                cuckoo(&pair.window, &cuckoo_with(10), rng, |t| {
                    pair.reference.overlap(&pair.points, t)
                })
            }),
        ),
        (
            format!("cuckoo {} nests x 20 gen", p.cuckoo_nests),
            Box::new(move |pair: &Pair, rng: &mut Rng| {
                cuckoo(&pair.window, &cuckoo_with(20), rng, |t| {
                    pair.reference.overlap(&pair.points, t)
                })
            }),
        ),
        (
            format!(
                "cuckoo {} nests x {} gen (default)",
                p.cuckoo_nests, p.cuckoo_generations
            ),
            Box::new(move |pair: &Pair, rng: &mut Rng| {
                cuckoo(
                    &pair.window,
                    &cuckoo_with(p.cuckoo_generations as usize),
                    rng,
                    |t| pair.reference.overlap(&pair.points, t),
                )
            }),
        ),
        (
            format!("cuckoo {} nests x 80 gen", p.cuckoo_nests),
            Box::new(move |pair: &Pair, rng: &mut Rng| {
                cuckoo(&pair.window, &cuckoo_with(80), rng, |t| {
                    pair.reference.overlap(&pair.points, t)
                })
            }),
        ),
    ];
    let results: Vec<Vec<(SearchResult, u64)>> = searches
        .iter()
        .map(|(_, search)| {
            let mut rng = Rng::new(42, 0);
            pairs
                .iter()
                .map(|pair| {
                    let t0 = thread_cpu_ns();
                    let r = search(pair, &mut rng);
                    (r, thread_cpu_ns() - t0)
                })
                .collect()
        })
        .collect();
    let best: Vec<f64> = (0..pairs.len())
        .map(|i| results.iter().map(|r| r[i].0.cost).fold(f64::MIN, f64::max))
        .collect();
    let prediction: f64 = pairs
        .iter()
        .map(|pair| pair.reference.overlap(&pair.points, &pair.window.centre))
        .sum::<f64>()
        / pairs.len() as f64;
    println!(
        "fuzzy_search: {} CSAIL scan pairs (gap {gap}, every {every}); overlap at the odometry's prediction {prediction:.4}",
        pairs.len()
    );
    for ((name, _), res) in searches.iter().zip(&results) {
        let n = res.len() as f64;
        let mean_cost = res.iter().map(|(r, _)| r.cost).sum::<f64>() / n;
        let gap_to_best = res
            .iter()
            .zip(&best)
            .map(|((r, _), b)| b - r.cost)
            .sum::<f64>()
            / n;
        let near_best = res
            .iter()
            .zip(&best)
            .filter(|((r, _), b)| *b - r.cost < 0.005)
            .count();
        let mut times: Vec<u64> = res.iter().map(|(_, t)| *t).collect();
        times.sort_unstable();
        let pct = |q: f64| times[((q * n).ceil() as usize).clamp(1, times.len()) - 1] as f64 / 1e6;
        let evals = res
            .iter()
            .map(|(r, _)| f64::from(r.evaluations))
            .sum::<f64>()
            / n;
        println!(
            "fuzzy_search {name:>36}: mean overlap {mean_cost:.4}, {:.4} below the best found, within 0.005 of it in {:.0} %; {evals:.0} evaluations, CPU p50 {:.2} ms p99 {:.2} ms",
            gap_to_best,
            100.0 * near_best as f64 / n,
            pct(0.5),
            pct(0.99),
        );
    }
}
