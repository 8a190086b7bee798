//! The layout's rules, checked on `cargo metadata`: a crate's name is its
//! folder, every internal crate is declared once in the root
//! `[workspace.dependencies]`, and nothing under `daemon/` or `drivers/`
//! depends on the simulator or an emulator outside `[dev-dependencies]` (so
//! the robot's binaries link neither).

use serde_json::Value;
use smokenav_tests::workspace_root;
use std::collections::{BTreeMap, BTreeSet};
use std::process::Command;

struct Package {
    name: String,
    /// Folder relative to the workspace root, e.g. `drivers/hokuyo/codec`.
    folder: String,
    /// (dependency name, kind) with kind `None` for normal dependencies.
    deps: Vec<(String, Option<String>)>,
}

fn packages() -> Vec<Package> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .current_dir(workspace_root())
        .args([
            "metadata",
            "--format-version",
            "1",
            "--no-deps",
            "--offline",
        ])
        .output()
        .expect("cargo metadata runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta: Value = serde_json::from_slice(&out.stdout).unwrap();
    let root = workspace_root();
    meta["packages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let manifest = std::path::Path::new(p["manifest_path"].as_str().unwrap());
            let folder = manifest
                .parent()
                .unwrap()
                .strip_prefix(&root)
                .unwrap()
                .to_string_lossy()
                .into_owned();
            let deps = p["dependencies"]
                .as_array()
                .unwrap()
                .iter()
                .map(|d| {
                    (
                        d["name"].as_str().unwrap().to_owned(),
                        d["kind"].as_str().map(str::to_owned),
                    )
                })
                .collect();
            Package {
                name: p["name"].as_str().unwrap().to_owned(),
                folder,
                deps,
            }
        })
        .collect()
}

/// The name a crate in `folder` must have: `smokenav-` and its folder path,
/// slashes as dashes, leaving out a leading `daemon/` or `drivers/`.
fn expected_name(folder: &str) -> String {
    let rest = folder
        .strip_prefix("daemon/")
        .or_else(|| folder.strip_prefix("drivers/"))
        .unwrap_or(folder);
    format!("smokenav-{}", rest.replace('/', "-"))
}

#[test]
fn every_crate_is_named_after_its_folder() {
    let wrong: Vec<String> = packages()
        .iter()
        .filter(|p| p.name != expected_name(&p.folder))
        .map(|p| {
            format!(
                "{} in {} (expected {})",
                p.name,
                p.folder,
                expected_name(&p.folder)
            )
        })
        .collect();
    assert!(
        wrong.is_empty(),
        "crates not named after their folder: {wrong:#?}"
    );
}

#[test]
fn every_internal_crate_is_declared_once_in_the_workspace() {
    let text = std::fs::read_to_string(workspace_root().join("Cargo.toml")).unwrap();
    let root: toml::Table = text.parse().unwrap();
    let declared: BTreeMap<String, String> = root["workspace"]["dependencies"]
        .as_table()
        .unwrap()
        .iter()
        .filter_map(|(k, v)| Some((k.clone(), v.get("path")?.as_str()?.to_owned())))
        .collect();
    let packages = packages();
    for p in &packages {
        assert_eq!(
            declared.get(&p.name),
            Some(&p.folder),
            "{} is not declared as {{ path = \"{}\" }} in [workspace.dependencies]",
            p.name,
            p.folder
        );
    }
    // And every member refers to its siblings through the workspace, never by path.
    for f in packages
        .iter()
        .map(|p| workspace_root().join(&p.folder).join("Cargo.toml"))
    {
        let text = std::fs::read_to_string(&f).unwrap();
        for line in text.lines().filter(|l| l.starts_with("smokenav-")) {
            assert!(
                line.contains("workspace = true") || line.contains(".workspace = true"),
                "{}: `{line}` does not use the workspace declaration",
                f.display()
            );
        }
    }
}

/// Crates that belong to the simulator side.
fn is_sim_side(name: &str) -> bool {
    name.starts_with("smokenav-sim-") || name.ends_with("-emulator")
}

#[test]
fn nothing_on_the_robot_side_depends_on_the_simulator_or_an_emulator() {
    let packages = packages();
    let mut offenders = BTreeSet::new();
    for p in packages
        .iter()
        .filter(|p| p.folder.starts_with("daemon/") || p.folder.starts_with("drivers/"))
    {
        for (dep, kind) in &p.deps {
            if kind.as_deref() != Some("dev") && is_sim_side(dep) {
                offenders.insert(format!("{} -> {dep}", p.name));
            }
        }
    }
    assert!(
        offenders.is_empty(),
        "robot-side crates linking the simulator: {offenders:#?}"
    );
}

/// Dependencies an algorithm library must not have: algorithms know nothing
/// of the bus or of the processes that wire them.
fn is_wiring(name: &str) -> bool {
    name.starts_with("iceoryx2")
        || name == "smokenav-platform-bus"
        || name == "smokenav-platform-runtime"
        || name.starts_with("smokenav-nodes-")
        || name == "smokenav-tools-cli"
}

#[test]
fn algorithms_know_nothing_of_the_bus_or_the_processes() {
    let packages = packages();
    let algorithms: Vec<&Package> = packages
        .iter()
        .filter(|p| p.folder.starts_with("daemon/algorithms/"))
        .collect();
    // The layer is populated (a rename of the folder would make this test vacuous).
    for name in [
        "smokenav-algorithms-fusion",
        "smokenav-algorithms-slam",
        "smokenav-algorithms-mapping",
    ] {
        assert!(
            algorithms.iter().any(|p| p.name == name),
            "{name} is not under daemon/algorithms/"
        );
    }
    let offenders: BTreeSet<String> = algorithms
        .iter()
        .flat_map(|p| {
            p.deps
                .iter()
                .filter(|(dep, kind)| kind.as_deref() != Some("dev") && is_wiring(dep))
                .map(move |(dep, _)| format!("{} -> {dep}", p.name))
        })
        .collect();
    assert!(
        offenders.is_empty(),
        "algorithm libraries depending on the bus or a process: {offenders:#?}"
    );
}
