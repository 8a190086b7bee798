//! `smokenav graph optimize IN.g2o [--out OUT.g2o]`: optimises a 2D pose
//! graph (`VERTEX_SE2`, `EDGE_SE2`, `FIX`) and prints χ² before and after,
//! the iterations and the CPU time. A graph that cannot be optimised (an
//! under-constrained vertex, a bad line) is an error naming the vertex or
//! the line; nothing is written then.

use anyhow::Context;
use smokenav_algorithms_slam::graph::{OptimizeParams, RobustKernel, g2o};
use std::path::PathBuf;

#[derive(clap::Subcommand, Debug)]
pub enum GraphCommand {
    /// Optimise a 2D g2o pose graph from its initial guess.
    Optimize(OptimizeArgs),
}

#[derive(clap::Args, Debug)]
pub struct OptimizeArgs {
    /// The graph (2D g2o: VERTEX_SE2, EDGE_SE2, FIX).
    input: PathBuf,
    /// Write the optimised graph here.
    #[arg(long, value_name = "OUT.g2o")]
    out: Option<PathBuf>,
    /// Most Levenberg–Marquardt iterations.
    #[arg(long, default_value_t = 500)]
    max_iterations: u32,
    /// Apply a Cauchy kernel of this width (Mahalanobis units) to every edge.
    #[arg(long, value_name = "C")]
    cauchy: Option<f64>,
}

fn process_cpu_s() -> f64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_PROCESS_CPUTIME_ID)
        .map(|t| t.tv_sec() as f64 + t.tv_nsec() as f64 * 1e-9)
        .unwrap_or(0.0)
}

pub fn run(cmd: GraphCommand) -> anyhow::Result<()> {
    let GraphCommand::Optimize(args) = cmd;
    let file = std::fs::File::open(&args.input)
        .with_context(|| format!("cannot open {}", args.input.display()))?;
    let mut graph = g2o::read(std::io::BufReader::new(file))
        .with_context(|| format!("bad graph file {}", args.input.display()))?;
    let mut params = OptimizeParams {
        max_iterations: args.max_iterations,
        ..OptimizeParams::default()
    };
    if let Some(c) = args.cauchy {
        anyhow::ensure!(c.is_finite() && c > 0.0, "--cauchy must be positive");
        params.kernel = RobustKernel::Cauchy(c);
        let edges: Vec<_> = graph.edges().to_vec();
        let mut robust = smokenav_algorithms_slam::graph::PoseGraph::new();
        for (i, p) in graph.poses().iter().enumerate() {
            robust.add_vertex(graph.ids()[i], *p);
            robust.set_fixed(i, graph.is_fixed(i));
        }
        for e in edges {
            robust.add_edge(smokenav_algorithms_slam::graph::Edge { robust: true, ..e });
        }
        graph = robust;
    }
    let cpu0 = process_cpu_s();
    let report = graph
        .optimize(&params)
        .with_context(|| format!("cannot optimise {}", args.input.display()))?;
    let cpu = process_cpu_s() - cpu0;
    println!(
        "graph     {}: {} vertices, {} edges",
        args.input.display(),
        graph.len(),
        graph.edges().len()
    );
    println!("chi2      before {:.4}", report.chi2_before);
    println!("chi2      after  {:.4}", report.chi2_after);
    if args.cauchy.is_some() {
        println!(
            "cost      {:.4} → {:.4} (Cauchy)",
            report.cost_before, report.cost_after
        );
    }
    println!(
        "iterations {}{}",
        report.iterations,
        if report.converged {
            " (converged)"
        } else {
            " (iteration limit)"
        }
    );
    println!("time      {cpu:.3} CPU-s");
    if let Some(out) = &args.out {
        let mut text = Vec::new();
        g2o::write(&graph, &mut text)?;
        std::fs::write(out, text).with_context(|| format!("cannot write {}", out.display()))?;
        println!("wrote     {}", out.display());
    }
    Ok(())
}
