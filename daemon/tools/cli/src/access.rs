//! Who may use a bus that the systemd units run (README: "Who may use the bus").
//!
//! iceoryx2 0.10 gives every shared-memory segment, event socket and service
//! file it creates to its creator alone (0600/0400; the `dev_permissions`
//! build makes them 0666 in /dev/shm, open to every local user, which would
//! let anyone drive the robot). Even a subscriber writes into the service's
//! shared memory, so "read-only for a group" cannot be expressed in file
//! modes: a tool must run as the user that owns the bus (`smokenav`).
//!
//! So the CLI, before it touches a bus directory owned by another user:
//! - as root, drops to that user (root's own files would be unreadable to the
//!   processes, which have no capabilities);
//! - otherwise re-runs itself through `sudo -u <owner>` when sudo allows it
//!   (`systemd/install` allows group `smokenav` the observing commands and
//!   group `smokenav-drive` every command);
//! - otherwise stops with a "permission denied" that names the group to join.

use anyhow::{Context, bail};
use nix::unistd::{Gid, Group, Uid, User};
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// The group whose members may run every command, `drive` included.
const DRIVE_GROUP: &str = "smokenav-drive";

/// Makes this process able to use the bus under `root`, or explains why it cannot.
/// `command` is the subcommand's name (for the message).
pub fn ensure_bus_access(root: &Path, command: &str) -> anyhow::Result<()> {
    // `/run/smokenav/iox2/` as iceoryx2 wants it; said without the slash.
    let root: PathBuf = root.components().collect();
    let root = root.as_path();
    let Some((_dir, meta)) = nearest_existing(root) else {
        return Ok(());
    };
    let owner = Uid::from_raw(meta.uid());
    let euid = Uid::effective();
    if owner == euid {
        return Ok(());
    }
    let owner_name = User::from_uid(owner)
        .ok()
        .flatten()
        .map(|u| u.name)
        .unwrap_or_else(|| owner.to_string());
    let group = Gid::from_raw(meta.gid());
    let group_name = Group::from_gid(group)
        .ok()
        .flatten()
        .map(|g| g.name)
        .unwrap_or_else(|| group.to_string());
    if euid.is_root() {
        return become_user(owner, group, &owner_name);
    }
    if std::env::var_os("SUDO_USER").is_some() {
        bail!(
            "permission denied on {}: running through sudo as {} but the bus belongs to {owner_name}",
            root.display(),
            User::from_uid(euid)
                .ok()
                .flatten()
                .map(|u| u.name)
                .unwrap_or_else(|| euid.to_string()),
        );
    }
    let in_group = member_of(group);
    if sudo_allows(&owner_name) {
        return reexec_through_sudo(&owner_name);
    }
    if in_group {
        bail!(
            "permission denied on {}: `smokenav {command}` on this robot needs group \
             {DRIVE_GROUP} (sudo usermod -aG {DRIVE_GROUP} $USER, then log in again); group \
             {group_name} may run `smokenav status` and `smokenav topic list|echo|hz|info|bw` (through sudo as \
             {owner_name}: systemd/install sets that up in /etc/sudoers.d/smokenav)",
            root.display()
        );
    }
    bail!(
        "permission denied on {}: add yourself to group {group_name} \
         (sudo usermod -aG {group_name} $USER, then log in again)",
        root.display()
    )
}

/// `root` itself, or its nearest ancestor this process may look at: a
/// non-member cannot even stat the bus directory inside the 0750 `/run/smokenav`.
/// `None` when nothing on the path exists yet (the bus will be created).
fn nearest_existing(root: &Path) -> Option<(PathBuf, std::fs::Metadata)> {
    let mut dir = Some(root);
    while let Some(d) = dir {
        match std::fs::metadata(d) {
            Ok(m) => {
                if d == root {
                    return Some((d.to_owned(), m));
                }
                // Only a folder we are locked out of says who owns the bus.
                return if std::fs::read_dir(d).is_err() {
                    Some((d.to_owned(), m))
                } else {
                    None
                };
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => dir = d.parent(),
            Err(_) => dir = d.parent(),
        }
    }
    None
}

fn member_of(group: Gid) -> bool {
    Gid::effective() == group || nix::unistd::getgroups().is_ok_and(|gs| gs.contains(&group))
}

/// Root becomes the bus owner: the bus's files stay the owner's, which the
/// capability-less processes need.
fn become_user(uid: Uid, gid: Gid, name: &str) -> anyhow::Result<()> {
    nix::unistd::setgroups(&[gid]).context("cannot drop supplementary groups")?;
    nix::unistd::setgid(gid).with_context(|| format!("cannot switch to the group of {name}"))?;
    nix::unistd::setuid(uid).with_context(|| format!("cannot switch to user {name}"))?;
    tracing::debug!(user = name, "root: using the bus as its owner");
    Ok(())
}

/// Whether `sudo -u owner` runs this very command without a password.
fn sudo_allows(owner: &str) -> bool {
    let Ok(exe) = std::env::current_exe() else {
        return false;
    };
    Command::new("sudo")
        .args(["-n", "-l", "-u", owner, "--"])
        .arg(&exe)
        .args(std::env::args_os().skip(1))
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

fn reexec_through_sudo(owner: &str) -> anyhow::Result<()> {
    use std::os::unix::process::CommandExt;
    let exe = std::env::current_exe().context("cannot find this executable")?;
    let err = Command::new("sudo")
        .args(["-n", "-u", owner, "--"])
        .arg(&exe)
        .args(std::env::args_os().skip(1))
        .exec();
    Err(err).context("cannot run sudo")
}
