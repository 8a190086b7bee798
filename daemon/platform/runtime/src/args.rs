use clap::Args;
use std::path::PathBuf;

/// Arguments every process takes.
#[derive(Debug, Clone, Args)]
pub struct CommonArgs {
    /// Robot profile (TOML).
    #[arg(
        long,
        short = 'c',
        env = "SMOKENAV_CONFIG",
        default_value = "/etc/smokenav/robot.toml"
    )]
    pub config: PathBuf,
    /// Device to use instead of the configured one: a device path
    /// (`/dev/ttyACM0`, an IIO directory) or `tcp://host:port`. Drivers only.
    #[arg(long)]
    pub port: Option<String>,
    /// Bus instance prefix; overrides `SMOKENAV_INSTANCE` and the profile's `robot.instance`.
    #[arg(long)]
    pub instance: Option<String>,
}
