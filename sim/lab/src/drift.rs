//! `smokenav-lab drift`: a real log with large loops and strong drift, made
//! from a corrected one. A corrected CARMEN log (Radish's `*-corrected.log.gz`,
//! a SLAM system's output) carries real scans at poses some SLAM already
//! aligned; its motion is corrupted with seeded noise and systematic drift
//! (`smokenav_algorithms_slam::drift`) and written back as the odometry, and
//! the log's own poses become the reference the run is scored against:
//!
//! ```text
//! smokenav-lab drift intel-corrected.log.gz --seed 1 --out D/intel-1.log --reference D/intel-ref.txt
//! smokenav slam --carmen D/intel-1.log --backend graph --reference D/intel-ref.txt --out D/run
//! ```
//!
//! The reference is that SLAM system's estimate, not ground truth: figures
//! against it say how far two estimates agree, which on a good log is
//! centimetres.

use anyhow::Context;
use smokenav_algorithms_eval::{
    StampedPose, TrajectoryOptions, evaluate_trajectories, load_trajectory,
};
use smokenav_algorithms_slam::drift::{DriftParams, drift_log};
use smokenav_algorithms_slam::offline::LogScans;
use std::io::{BufReader, BufWriter};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct DriftArgs {
    /// The corrected CARMEN log (FLASER or ROBOTLASER1 records; gzip-compressed or not).
    #[arg(value_name = "LOG")]
    pub log: PathBuf,
    /// Write the drifted log here.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Write the input's poses here (`timestamp x y theta`), for `smokenav slam --reference`.
    #[arg(long, value_name = "FILE")]
    pub reference: PathBuf,
    /// Seed of the noise: the same seed gives the same log.
    #[arg(long, default_value_t = DriftParams::default().seed)]
    pub seed: u64,
    /// Translation scale error (0.02: every step reads 2 % long).
    #[arg(long, default_value_t = DriftParams::default().scale, allow_hyphen_values = true)]
    pub scale: f64,
    /// Rotation scale error.
    #[arg(long, default_value_t = DriftParams::default().turn_scale, allow_hyphen_values = true)]
    pub turn_scale: f64,
    /// Heading error per metre travelled, rad/m: what bends a long loop by metres.
    #[arg(long, default_value_t = DriftParams::default().heading_bias, allow_hyphen_values = true)]
    pub heading_bias: f64,
    /// σ of the translation noise per metre of step.
    #[arg(long, default_value_t = DriftParams::default().sigma_t, allow_hyphen_values = true)]
    pub sigma_t: f64,
    /// σ of the rotation noise per radian of turn.
    #[arg(long, default_value_t = DriftParams::default().sigma_r, allow_hyphen_values = true)]
    pub sigma_r: f64,
    /// σ of the rotation noise per metre of step, rad/m.
    #[arg(long, default_value_t = DriftParams::default().sigma_r_per_m, allow_hyphen_values = true)]
    pub sigma_r_per_m: f64,
}

pub fn run(args: DriftArgs) -> anyhow::Result<()> {
    let p = DriftParams {
        seed: args.seed,
        scale: args.scale,
        turn_scale: args.turn_scale,
        heading_bias: args.heading_bias,
        sigma_t: args.sigma_t,
        sigma_r: args.sigma_r,
        sigma_r_per_m: args.sigma_r_per_m,
    };
    // Before any file is touched; the library's message names the field,
    // the operator typed the flag.
    p.validate().map_err(|e| {
        let flag = format!("--{}", e.field().replace('_', "-"));
        anyhow::anyhow!(e.to_string().replacen(e.field(), &flag, 1))
    })?;
    let input = std::fs::File::open(&args.log)
        .with_context(|| format!("cannot open {}", args.log.display()))?;
    let input = smokenav_algorithms_slam::carmen::text(BufReader::new(input))
        .with_context(|| format!("cannot read {}", args.log.display()))?;
    let create = |path: &PathBuf| {
        std::fs::File::create(path)
            .map(BufWriter::new)
            .with_context(|| format!("cannot create {}", path.display()))
    };
    let out = create(&args.out)?;
    let mut reference = create(&args.reference)?;
    let report = drift_log(input, out, &p, None, Some(&mut reference))
        .with_context(|| args.log.display().to_string())?;
    drop(reference);
    anyhow::ensure!(
        report.laser_records > 0,
        "{} holds no laser record (FLASER or ROBOTLASER1)",
        args.log.display()
    );
    // The drifted odometry against the reference: how much a SLAM run has to undo.
    let truth = load_trajectory(&args.reference)
        .with_context(|| format!("reading back {}", args.reference.display()))?;
    let drifted = {
        let file = std::fs::File::open(&args.out)
            .with_context(|| format!("reading back {}", args.out.display()))?;
        let mut scans = LogScans::new(BufReader::new(file));
        let mut v = Vec::with_capacity(report.laser_records);
        while let Some((scan, odom)) = scans.next_scan() {
            v.push(StampedPose::from_ns(scan.stamp_ns, &odom));
        }
        v
    };
    let ate = evaluate_trajectories(&truth, &drifted, &TrajectoryOptions::same_stamp())
        .map(|a| format!("{:.3} m", a.ate_m.rmse))
        .unwrap_or_else(|e| format!("not measured ({e})"));
    println!(
        "{} laser records over {:.1} m; the drifted odometry ends {:.2} m from the log's last pose; odometry ATE RMS {ate} (best rigid alignment)",
        report.laser_records, report.path_m, report.end_offset_m
    );
    if let Some(first) = &report.first_skipped {
        let (n, s) = (report.skipped_lines, plural(report.skipped_lines));
        println!("{n} unreadable line{s} left out (the first: {first})");
    }
    if let Some(first) = report.first_restamped {
        let (n, s) = (report.restamped, plural(report.restamped));
        println!(
            "{n} record{s} stamped at or before the record before moved a second after it (the first: record {first}, counted from 0)"
        );
    }
    println!("drifted log  {}", args.out.display());
    println!("reference    {}", args.reference.display());
    Ok(())
}

fn plural(n: usize) -> &'static str {
    if n == 1 { "" } else { "s" }
}
