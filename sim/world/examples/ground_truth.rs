//! Runs a scenario to its end and writes its ground truth plus the wheel
//! odometry (a baseline "estimate") for `smokenav eval`:
//!
//!     cargo run -p smokenav-sim-world --release --example ground_truth -- r32-dense-crossing out/
//!     smokenav eval --truth-map out/truth.yaml --map out/truth.yaml \
//!         --truth-trajectory out/truth.txt --trajectory out/odometry.txt

use smokenav_sim_world::{Scenario, StepOutput, World, truth};
use std::path::PathBuf;
use std::time::Duration;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let spec = args.next().unwrap_or_else(|| "mrl-clean".into());
    let dir = PathBuf::from(args.next().unwrap_or_else(|| "sim-out".into()));
    std::fs::create_dir_all(&dir)?;
    let mut world = World::new(Scenario::builtin_or_file(&spec)?)?;
    let mut all = StepOutput::default();
    world.set_laser_enabled(false); // only poses are written
    while !world.is_finished() {
        let mut out = world.step(Duration::from_secs(1));
        all.append(&mut out);
    }
    let map = truth::write_map(&world.truth_map(), &dir, "truth")?;
    truth::write_trajectory(
        &dir.join("truth.txt"),
        all.truth.iter().map(|s| (s.t_ns, &s.pose)),
    )?;
    truth::write_trajectory(
        &dir.join("odometry.txt"),
        all.odometry.iter().map(|s| (s.t_ns, &s.pose)),
    )?;
    println!(
        "{}\n{}\n{}",
        map.display(),
        dir.join("truth.txt").display(),
        dir.join("odometry.txt").display()
    );
    Ok(())
}
