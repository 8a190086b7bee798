//! What the lab's benches share: where the workspace and this profile's
//! binaries are, and building the programs a bench runs before it runs them.

use std::path::{Path, PathBuf};
use std::process::Command;

pub fn workspace_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// target/<profile>/ (a bench runs from target/<profile>/deps/).
pub fn profile_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("current_exe");
    exe.parent()
        .and_then(Path::parent)
        .expect("bench in target/<profile>/deps")
        .to_owned()
}

/// Builds `packages` in this bench's profile, so it never runs stale programs.
pub fn build(packages: &[&str]) {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut cmd = Command::new(cargo);
    cmd.current_dir(workspace_root()).args(["build", "--quiet"]);
    for p in packages {
        cmd.args(["-p", p]);
    }
    if profile_dir().ends_with("release") {
        cmd.arg("--release");
    }
    let status = cmd.status().expect("cannot run cargo");
    assert!(status.success(), "cargo build of {packages:?} failed");
}
