//! `smokenav`: the operator's command-line tool.

use anyhow::Context;
use clap::{CommandFactory, Parser, Subcommand};
use std::path::PathBuf;

mod access;
mod arcos;
mod bag;
mod drive;
mod eval;
mod fleet;
mod fuse;
mod graph;
mod info;
mod initial_pose;
mod mapsave;
mod mapvote;
mod play;
mod record;
mod scip;
mod slam;
mod status;
mod topic;
mod topic_info;
mod topic_pub;

#[derive(Parser)]
#[command(
    name = "smokenav",
    version,
    about = "Mapping and localisation in smoke: operator tools"
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
    /// Robot profile tools.
    #[command(subcommand)]
    Config(ConfigCommand),
    /// See what flows on the bus: list, echo, hz, info, bw, pub (ROS spellings like /laser/scan work).
    #[command(subcommand)]
    Topic(topic::TopicCommand),
    /// One line per process: up/down, heartbeat age, rates, counters. Exit 1 if anything is unhealthy.
    Status(status::StatusArgs),
    /// Run SLAM offline over a CARMEN log or a ROS 2 bag; write trajectory (`--format tum` for evo), map and timing.
    Slam(slam::SlamArgs),
    /// Maps published by the SLAM process: `map save [DIR] [--mode trinary|scale|raw]` writes them as nav2's map_saver does (and the 3D octree of smokenav-mapping).
    #[command(subcommand)]
    Map(slam::MapCommand),
    /// Run SmokeNav fusion offline: `topic echo --json` lines in, `fusion/scan` lines out.
    Fuse(fuse::FuseArgs),
    /// Pioneer ARCOS tools: decode a capture to JSON.
    #[command(subcommand)]
    Arcos(arcos::ArcosCommand),
    /// Publish `base/cmd_vel` at 10 Hz for a while, then stop (Pioneer or Scout).
    Drive(drive::DriveArgs),
    /// Tell SLAM where the robot is on its map (RViz's 2D Pose Estimate): a lost localisation searches there.
    InitialPose(initial_pose::InitialPoseArgs),
    /// Hokuyo SCIP tools: decode a capture to JSON.
    #[command(subcommand)]
    Scip(scip::ScipCommand),
    /// Record bus topics to an MCAP file (ros2 profile: Foxglove, ros2 bag).
    Record(record::RecordArgs),
    /// Describe a recording like `ros2 bag info`: duration, dates, per-topic counts, types and
    /// rates, chunks and compression; `--check` reads every chunk and reports damage.
    Info(info::InfoArgs),
    /// Republish a recording onto the bus, with its original timing or as fast as possible.
    Play(play::PlayArgs),
    /// Pose-graph tools: `graph optimize IN.g2o [--out OUT.g2o]`.
    #[command(subcommand)]
    Graph(graph::GraphCommand),
    /// Score an estimated map (and trajectory) against ground truth: k-NN error, pixel error, ATE, RPE; or a trajectory against a benchmark relations file.
    Eval(eval::EvalArgs),
    /// Print a shell completion script (`smokenav completions bash >
    /// /usr/local/share/bash-completion/completions/smokenav`; systemd/install does it).
    Completions {
        /// bash, zsh, fish, elvish or powershell.
        shell: clap_complete::Shell,
    },
    /// Write the man pages (smokenav.1, smokenav-topic-echo.1, …) into DIR.
    Man {
        /// Output folder, e.g. /usr/local/share/man/man1.
        dir: PathBuf,
    },
}

#[derive(Subcommand)]
enum ConfigCommand {
    /// Validate a robot profile and print the effective configuration.
    Check {
        /// The profile, e.g. config/pioneer-3dx.toml.
        file: PathBuf,
    },
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let debug = cli.debug;
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            // A user error is a message, not a stack trace: returning the error
            // from main would print anyhow's Debug form, backtrace included
            // whenever RUST_BACKTRACE is set.
            if debug {
                eprintln!("smokenav: error: {e:?}");
            } else {
                eprintln!(
                    "smokenav: error: {}",
                    smokenav_platform_runtime::error_line(&e)
                );
            }
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<std::process::ExitCode> {
    let done = match cli.command {
        Command::Status(args) => return status::run(args),
        Command::Info(args) => return info::run(args),
        Command::Config(ConfigCommand::Check { file }) => {
            let cfg = smokenav_platform_config::RobotConfig::load(&file)
                .with_context(|| format!("invalid robot profile {}", file.display()))?;
            print!("{}", cfg.to_toml());
            Ok(())
        }
        Command::Slam(args) => slam::run(args),
        Command::Map(cmd) => slam::run_map(cmd),
        Command::Fuse(args) => fuse::run(args),
        Command::Topic(cmd) => topic::run(cmd),
        Command::Arcos(cmd) => arcos::run(cmd),
        Command::Drive(args) => drive::run(args),
        Command::InitialPose(args) => initial_pose::run(args),
        Command::Scip(cmd) => scip::run(cmd),
        Command::Record(args) => record::run(args),
        Command::Play(args) => play::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Graph(cmd) => graph::run(cmd),
        Command::Completions { shell } => {
            // Into memory first: clap_complete panics on a write error (`| head`).
            let mut script = Vec::new();
            clap_complete::generate(shell, &mut Cli::command(), "smokenav", &mut script);
            use std::io::Write as _;
            match std::io::stdout().lock().write_all(&script) {
                Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
                r => r.context("cannot write the completion script"),
            }
        }
        Command::Man { dir } => {
            std::fs::create_dir_all(&dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
            clap_mangen::generate_to(Cli::command(), &dir)
                .with_context(|| format!("cannot write man pages to {}", dir.display()))?;
            Ok(())
        }
    };
    done.map(|()| std::process::ExitCode::SUCCESS)
}
