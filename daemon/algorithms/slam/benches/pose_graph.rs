//! The pose-graph optimiser on MITb (808 poses, 827 edges) and the sparse
//! Cholesky solvers it could use, timed in thread CPU time.
//!
//! `cargo bench -p smokenav-algorithms-slam --bench pose_graph`
//!
//! Prints: the whole optimisation from the initial guess (χ² before/after,
//! iterations, CPU-s; GTSAM's Levenberg–Marquardt: χ² 770.24 in 0.05 CPU-s on
//! this class of machine), then one factorisation + solve of the same normal
//! equations with `faer`'s one-call solver (AMD ordering, its own choice of
//! simplicial or supernodal), the optimiser's own `BlockCholesky` (vertex-wise
//! AMD, supernodal, buffers kept: its structure once, then what every further
//! iteration costs) and `nalgebra-sparse` (no fill-reducing ordering), at the
//! initial guess and at the optimum.
//! `POSE_GRAPH_G2O` benchmarks another 2D g2o file instead.

use faer::linalg::solvers::SolveCore;
use faer::reborrow::Reborrow;
use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::{Pair, SparseColMat, SymbolicSparseColMat};
use smokenav_algorithms_slam::graph::block_cholesky::BlockCholesky;
use smokenav_algorithms_slam::graph::{OptimizeParams, PoseGraph, g2o};
use std::path::{Path, PathBuf};

fn thread_cpu_ns() -> u64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID)
        .map(|t| t.tv_sec() as u64 * 1_000_000_000 + t.tv_nsec() as u64)
        .unwrap_or(0)
}

/// Median and minimum CPU time of `runs` calls, ms.
fn time_ms(runs: usize, mut f: impl FnMut()) -> (f64, f64) {
    let mut t: Vec<u64> = (0..runs)
        .map(|_| {
            let t0 = thread_cpu_ns();
            f();
            thread_cpu_ns() - t0
        })
        .collect();
    t.sort_unstable();
    (t[t.len() / 2] as f64 / 1e6, t[0] as f64 / 1e6)
}

fn faer_solve(dim: usize, triplets: &[(usize, usize, f64)], b: &[f64]) -> Vec<f64> {
    let pairs: Vec<Pair<usize, usize>> =
        triplets.iter().map(|&(r, c, _)| Pair::new(r, c)).collect();
    let values: Vec<f64> = triplets.iter().map(|t| t.2).collect();
    let (symbolic, argsort) = SymbolicSparseColMat::try_new_from_indices(dim, dim, &pairs).unwrap();
    let llt_sym = SymbolicLlt::try_new(symbolic.rb(), faer::Side::Lower).unwrap();
    let h = SparseColMat::new_from_argsort(symbolic, &argsort, &values).unwrap();
    let llt = Llt::try_new_with_symbolic(llt_sym, h.rb(), faer::Side::Lower).unwrap();
    let mut x: Vec<f64> = b.iter().map(|v| -v).collect();
    llt.solve_in_place_with_conj(
        faer::Conj::No,
        faer::MatMut::from_column_major_slice_mut(&mut x, dim, 1),
    );
    x
}

fn block_structure(dim: usize, triplets: &[(usize, usize, f64)]) -> BlockCholesky {
    // `linear_system` lists 6 entries per vertex, then 9 per edge, the
    // order BlockCholesky takes its values in.
    let links: Vec<(usize, usize)> = triplets[2 * dim..]
        .chunks(9)
        .map(|b| (b[0].0 / 3, b[0].1 / 3))
        .collect();
    BlockCholesky::new(dim / 3, &links).unwrap()
}

fn block_solve(llt: &mut BlockCholesky, values: &[f64], b: &[f64]) -> Vec<f64> {
    llt.factorize(values).unwrap();
    let mut x: Vec<f64> = b.iter().map(|v| -v).collect();
    llt.solve_in_place(&mut x, 1).unwrap();
    x
}

fn nalgebra_solve(dim: usize, triplets: &[(usize, usize, f64)], b: &[f64]) -> Vec<f64> {
    use nalgebra_sparse::{CooMatrix, CscMatrix, factorization::CscCholesky};
    let mut coo = CooMatrix::new(dim, dim);
    for &(r, c, v) in triplets {
        coo.push(r, c, v);
        if r != c {
            coo.push(c, r, v);
        }
    }
    let csc = CscMatrix::from(&coo);
    let chol = CscCholesky::factor(&csc).unwrap();
    let rhs = nalgebra_sparse::na::DMatrix::from_iterator(dim, 1, b.iter().map(|v| -v));
    chol.solve(&rhs).iter().copied().collect()
}

/// Largest system given to nalgebra-sparse.
const NALGEBRA_MAX_DIM: usize = 5000;

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    let path = std::env::var("POSE_GRAPH_G2O")
        .map(PathBuf::from)
        .unwrap_or_else(|_| {
            Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/input_MITb_g2o.g2o")
        });
    let read = || -> PoseGraph {
        g2o::read(std::io::BufReader::new(std::fs::File::open(&path).unwrap())).unwrap()
    };
    let initial = read();
    let name = path.file_name().unwrap().to_string_lossy().to_string();
    let mut report = None;
    let mut optimum = initial.clone();
    let (med, min) = time_ms(20, || {
        let mut g = initial.clone();
        report = Some(g.optimize(&OptimizeParams::default()).unwrap());
        optimum = g;
    });
    let r = report.unwrap();
    println!(
        "pose_graph {name}: {} poses, {} edges; χ² {:.2} → {:.2} in {} iterations; optimise CPU {:.1} ms median, {:.1} ms min (GTSAM LM: χ² 770.24, 50 ms)",
        initial.len(),
        initial.edges().len(),
        r.chi2_before,
        r.chi2_after,
        r.iterations,
        med,
        min
    );
    for (label, g) in [("initial guess", &initial), ("optimum", &optimum)] {
        let (dim, triplets, b) = g.linear_system().unwrap();
        let mut xf = Vec::new();
        let (fmed, fmin) = time_ms(30, || xf = faer_solve(dim, &triplets, &b));
        let (smed, smin) = time_ms(30, || drop(block_structure(dim, &triplets)));
        let mut llt = block_structure(dim, &triplets);
        let mut xb = Vec::new();
        let values: Vec<f64> = triplets.iter().map(|t| t.2).collect();
        let (bmed, bmin) = time_ms(30, || xb = block_solve(&mut llt, &values, &b));
        // Without a fill-reducing order nalgebra-sparse's factor of a large
        // graph is near dense (a 3737-vertex graph: over a gigabyte).
        let mut xn = Vec::new();
        let nalgebra = if dim <= NALGEBRA_MAX_DIM {
            let (nmed, nmin) = time_ms(30, || xn = nalgebra_solve(dim, &triplets, &b));
            format!("{nmed:.2} ms (min {nmin:.2})")
        } else {
            format!("not run (over {NALGEBRA_MAX_DIM} unknowns)")
        };
        let scale = xf.iter().map(|v| v.abs()).fold(0.0, f64::max).max(1e-300);
        let apart = |x: &[f64]| {
            if x.is_empty() {
                return "-".to_string();
            }
            let d = xf
                .iter()
                .zip(x)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            format!("{:.1e}", d / scale)
        };
        println!(
            "pose_graph {name} at the {label}: {dim}×{dim} system, {} entries: faer symbolic+numeric+solve {fmed:.2} ms (min {fmin:.2}); BlockCholesky structure {smed:.2} ms (min {smin:.2}), then numeric+solve {bmed:.2} ms (min {bmin:.2}); nalgebra-sparse {nalgebra}; solutions agree with faer's to {} (block), {} (nalgebra) (relative)",
            triplets.len(),
            apart(&xb),
            apart(&xn)
        );
    }
}
