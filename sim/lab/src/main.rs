//! `smokenav-lab`: the simulator side of smokenav, kept out of the robot's
//! `smokenav` command so an operator tool installed on a robot links no
//! emulator and no simulated world.
//!
//! - `smokenav-lab sim SCENARIO`: the smoky world feeds the device emulators
//!   on PTYs; run the real drivers against them.
//! - `smokenav-lab demo`: the smoke experiment of SmokeNav (Santos et al. 2015) end to end (what
//!   `./demo` runs).
//! - `smokenav-lab map3d`: laser + 3D sonar-cone occupancy fusion per rule
//!   on a scenario with out-of-plane obstacles; writes an OctoMap `.bt`.
//! - `smokenav-lab drift`: a corrected real log with seeded odometry drift,
//!   and its poses as the reference, for scoring SLAM on large loops.

use clap::{Parser, Subcommand};

mod demo;
mod drift;
mod map3d;
mod sim;

#[derive(Parser)]
#[command(
    name = "smokenav-lab",
    version,
    about = "smokenav's simulator and demo (development machines, not robots)"
)]
struct Cli {
    /// On an error, print its full chain with the backtrace (when
    /// RUST_BACKTRACE=1 captured one), not just the message.
    #[arg(long, global = true)]
    debug: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scenario: the smoky world feeds emulated devices on PTYs for the real drivers.
    Sim(sim::SimArgs),
    /// The SmokeNav paper's smoke experiment end to end: live run, then laser-only vs SmokeNav v1 vs v2.
    Demo(demo::DemoArgs),
    /// 2D/3D occupancy fusion compared per rule (LOP, LIOP, IOP, Bayes) on a scenario with out-of-plane obstacles.
    Map3d(map3d::Map3dArgs),
    /// A corrected CARMEN log with seeded odometry drift, and its own poses as the reference to score SLAM against.
    Drift(drift::DriftArgs),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let done = match cli.command {
        Command::Sim(args) => sim::run(args),
        Command::Demo(args) => demo::run(args),
        Command::Map3d(args) => map3d::run(args),
        Command::Drift(args) => drift::run(args),
    };
    match done {
        Ok(()) => std::process::ExitCode::SUCCESS,
        // A user error is one message; main returning it would print anyhow's
        // Debug form, backtrace included whenever RUST_BACKTRACE is set.
        Err(e) if cli.debug => {
            eprintln!("smokenav-lab: error: {e:?}");
            std::process::ExitCode::FAILURE
        }
        Err(e) => {
            eprintln!(
                "smokenav-lab: error: {}",
                smokenav_platform_runtime::error_line(&e)
            );
            std::process::ExitCode::FAILURE
        }
    }
}
