//! `smokenav`: the operator's command-line tool.

use anyhow::Context;
use clap::{Parser, Subcommand};
use std::path::PathBuf;

#[derive(Parser)]
#[command(name = "smokenav", version, about = "Mapping and localisation in smoke: operator tools")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Robot profile tools.
    #[command(subcommand)]
    Config(ConfigCommand),
}

#[derive(Subcommand)]
enum ConfigCommand {
    /// Validate a robot profile and print the effective configuration.
    Check {
        /// The profile, e.g. config/pioneer-3dx.toml.
        file: PathBuf,
    },
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Config(ConfigCommand::Check { file }) => {
            let cfg = smokenav_config::RobotConfig::load(&file)
                .with_context(|| format!("invalid robot profile {}", file.display()))?;
            print!("{}", cfg.to_toml());
            Ok(())
        }
    }
}
