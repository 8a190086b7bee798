//! Runs a scenario and prints one line per second: true pose, smoke at the
//! robot, the laser scan's mean and standard deviation (valid beams), its
//! error-code count, the smoke sensor's output and the sonar echo count.
//!
//!     cargo run -p smokenav-sim-world --example summary -- r32-dense-crossing

use smokenav_sim_world::laser::URG_DMIN_MM;
use smokenav_sim_world::{Scenario, StepOutput, World};
use std::time::Duration;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let spec = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "r32-dense-crossing".into());
    let scenario = Scenario::builtin_or_file(&spec)?;
    println!("# {} — {}", scenario.name, scenario.description);
    println!(
        "#   t      x      y   th°   smoke g/m3  scan mean  scan sd  codes   mV    sonar ok/n  stall"
    );
    let mut world = World::new(scenario)?;
    let mut out = StepOutput::default();
    while !world.is_finished() {
        out.clear();
        world.step_into(Duration::from_secs(1), &mut out);
        let p = world.truth_pose();
        let (mut mean, mut sd, mut codes) = (0.0, 0.0, 0);
        if let Some(scan) = out.laser.last() {
            let v: Vec<f64> = scan
                .ranges_mm
                .iter()
                .filter(|&&r| r >= URG_DMIN_MM)
                .map(|&r| r as f64 / 1000.0)
                .collect();
            codes = scan.ranges_mm.len() - v.len();
            if !v.is_empty() {
                mean = v.iter().sum::<f64>() / v.len() as f64;
                sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
            }
        }
        let mv = out.smoke.last().map_or(0.0, |s| s.output_mv);
        let dens = out.truth.last().map_or(0.0, |t| t.smoke_gpm3);
        let ok = out.sonar.iter().filter(|s| !s.saturated).count();
        let stall = out.odometry.iter().any(|o| o.stalled);
        println!(
            "{:5.0} {:6.2} {:6.2} {:5.0} {:10.3} {:10.2} {:8.2} {:5} {:7.0} {:6}/{:<3} {}",
            world.time_ns() as f64 * 1e-9,
            p.x,
            p.y,
            p.theta.to_degrees(),
            dens,
            mean,
            sd,
            codes,
            mv,
            ok,
            out.sonar.len(),
            if stall { "STALL" } else { "" }
        );
    }
    println!("# route done: {}", world.route_done());
    Ok(())
}
