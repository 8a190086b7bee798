//! The parts of `smokenav map save` beyond SLAM's occupancy map: the 3D
//! octree of `smokenav-mapping` and the fuzzy back-end's combined map
//! (`slam/map_fuzzy`, saved as fuzzy.pgm + fuzzy.yaml in raw mode and fuzzy.png).
//!
//! The octree is not on the bus (a `.bt` is tens of kilobytes to megabytes
//! and changes shape; every bus sample is fixed-size), so the process saves
//! it itself, as it does on SIGUSR1 from systemd: this command signals the
//! pid that `health/mapping` reports, waits until that process's
//! `octree_saves` count moves (or its `last_error` says why not), and copies
//! the new `octree.bt` from the process's save folder. Only the process that
//! owns the octree writes it, and one file format and one writer serve the
//! operator, systemd and this command.

use anyhow::{Context, bail, ensure};
use smokenav_algorithms_mapping::{ClampLogOdds, Clamping, Octree};
use smokenav_platform_bus::{Bus, Waiter, topics};
use smokenav_shared_types::Health;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The file `smokenav-mapping` writes and `map save` copies.
pub const OCTREE_FILE: &str = "octree.bt";
/// The shipped unit's `--map-dir` (`%S/smokenav/octree`).
pub const UNIT_OCTREE_DIR: &str = "/var/lib/smokenav/octree";

/// What was saved of the 3D map.
pub struct OctreeSaved {
    pub path: PathBuf,
    pub occupied_leaves: usize,
    pub bytes: u64,
}

fn metric(h: &Health, name: &str) -> Option<f64> {
    h.metrics()
        .iter()
        .find(|m| m.name.as_str() == name)
        .map(|m| m.value)
}

/// The file's identity, to tell a new save (a rename: a new inode) from an old file.
fn identity(path: &Path) -> Option<(u64, u64, i64)> {
    std::fs::metadata(path)
        .ok()
        .map(|m| (m.dev(), m.ino(), m.mtime_nsec()))
}

/// Asks the running `smokenav-mapping` for its octree and copies it to
/// `out/octree.bt`. `None` when no mapping process runs on the bus.
pub fn save_octree(
    bus: &Bus,
    process_dir: &Path,
    out: &Path,
    timeout: Duration,
) -> anyhow::Result<Option<OctreeSaved>> {
    let topic = topics::health("mapping");
    if bus.live_publishers(topic.clone())?.is_empty() {
        return Ok(None);
    }
    let sub = bus.subscriber::<Health>(topic.clone())?;
    let waiter = Waiter::new()?;
    let _guard = waiter.attach(&sub)?;
    let deadline = Instant::now() + timeout;
    let next = |what: &str| -> anyhow::Result<Box<Health>> {
        loop {
            if let Some(h) = sub.receive_latest()? {
                return Ok(Box::new(*h));
            }
            let now = Instant::now();
            ensure!(
                now < deadline,
                "no {} within {:.0} s ({what})",
                topic.name(),
                timeout.as_secs_f64()
            );
            waiter.wait(Some(deadline - now))?;
        }
    };
    let before = next("to learn the mapping process's pid")?;
    let saves_before = metric(&before, "octree_saves").unwrap_or(0.0);
    let error_before = before.last_error.as_str().to_owned();
    let pid = before.pid;
    ensure!(
        pid > 1 && pid <= i32::MAX as u32,
        "{} reports pid {pid}",
        topic.name()
    );
    // SIGUSR1 terminates a process that does not handle it: only signal the
    // pid if it really is smokenav-mapping (a stale or wrong health sample
    // must not kill a stranger).
    ensure_is_mapping_process(pid)?;
    let src = process_dir.join(OCTREE_FILE);
    let old = identity(&src);
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(pid as i32),
        nix::sys::signal::Signal::SIGUSR1,
    )
    .map_err(|e| {
        let hint = if e == nix::errno::Errno::EPERM {
            " (it runs as another user: run this as root, or ask systemd with \
             `systemctl kill -s USR1 smokenav-mapping` and copy the octree yourself)"
        } else {
            ""
        };
        anyhow::anyhow!("cannot signal smokenav-mapping (pid {pid}) to save its octree: {e}{hint}")
    })?;
    loop {
        let h = next("after asking it to save its octree")?;
        if h.pid != pid {
            bail!(
                "smokenav-mapping restarted (pid {pid} → {}) before saving its octree",
                h.pid
            );
        }
        if metric(&h, "octree_saves").unwrap_or(0.0) > saves_before {
            break;
        }
        let err = h.last_error.as_str();
        if err != error_before && err.contains("octree") {
            bail!("smokenav-mapping could not save its octree: {err}");
        }
    }
    let new = identity(&src);
    ensure!(
        new.is_some() && new != old,
        "smokenav-mapping saved its octree, but not to {} (its --map-dir differs: pass --octree-dir, or set [mapping] map_dir in the profile)",
        src.display()
    );
    // Read back before copying: what the operator gets is a tree that parses.
    let bytes = std::fs::read(&src).with_context(|| format!("cannot read {}", src.display()))?;
    let tree = Octree::read_bt(
        &mut std::io::Cursor::new(&bytes),
        ClampLogOdds::from(Clamping::default()),
    )
    .with_context(|| format!("{} is not a valid octree", src.display()))?;
    let mut occupied_leaves = 0usize;
    tree.for_each_leaf(|l| occupied_leaves += usize::from(l.logodds > 0.0));
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let dst = out.join(OCTREE_FILE);
    let tmp = out.join(format!(".{OCTREE_FILE}.tmp"));
    std::fs::write(&tmp, &bytes).with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, &dst).with_context(|| format!("cannot write {}", dst.display()))?;
    Ok(Some(OctreeSaved {
        path: dst,
        occupied_leaves,
        bytes: bytes.len() as u64,
    }))
}

/// The newest `slam/map_fuzzy`, when a SLAM process with the fuzzy back-end publishes it.
pub fn fuzzy_map(
    bus: &Bus,
    timeout: Duration,
) -> anyhow::Result<Option<smokenav_platform_map::OccupancyGrid>> {
    let topic = topics::SLAM_MAP_FUZZY;
    if bus.live_map_publishers(topic.clone())?.is_empty() {
        return Ok(None);
    }
    let sub = bus.map_subscriber(topic.clone())?;
    let waiter = Waiter::new()?;
    let _guard = waiter.attach(&sub)?;
    let deadline = Instant::now() + timeout;
    loop {
        let mut newest = None;
        while let Some(s) = sub.receive()? {
            newest = Some(crate::slam::grid_from_wire(s.user_header(), s.payload())?);
        }
        if newest.is_some() {
            return Ok(newest);
        }
        let now = Instant::now();
        ensure!(
            now < deadline,
            "no map on {} within {:.0} s",
            topic.name(),
            timeout.as_secs_f64()
        );
        waiter.wait(Some(deadline - now))?;
    }
}

/// The mapping process's save folder: `--octree-dir`, else the profile's
/// `[mapping] map_dir`, else the shipped unit's.
pub fn octree_dir(arg: Option<PathBuf>, profile: Option<&Path>) -> anyhow::Result<PathBuf> {
    if let Some(d) = arg {
        return Ok(d);
    }
    if let Some(p) = profile {
        let cfg = smokenav_platform_config::RobotConfig::load(p)
            .with_context(|| format!("invalid robot profile {}", p.display()))?;
        if let Some(d) = cfg.mapping.map_dir {
            return Ok(PathBuf::from(d));
        }
    }
    Ok(PathBuf::from(UNIT_OCTREE_DIR))
}

/// The kernel's name of a process (`/proc/PID/comm`, cut at 15 bytes).
fn process_name(pid: u32) -> std::io::Result<String> {
    Ok(std::fs::read_to_string(format!("/proc/{pid}/comm"))?
        .trim_end()
        .to_owned())
}

fn ensure_is_mapping_process(pid: u32) -> anyhow::Result<()> {
    const NAME: &str = "smokenav-mapping";
    let name = process_name(pid).with_context(|| {
        format!("smokenav-mapping's health names pid {pid}, which is not running")
    })?;
    // comm holds at most 15 bytes of the executable's name.
    ensure!(
        !name.is_empty() && NAME.starts_with(&name),
        "smokenav-mapping's health names pid {pid}, but that process is `{name}`: not signalling it"
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_mapping_process_is_signalled() {
        // This test process is not smokenav-mapping: it must be refused, not killed.
        let err = ensure_is_mapping_process(std::process::id()).unwrap_err();
        assert!(err.to_string().contains("not signalling it"), "{err}");
        let err = ensure_is_mapping_process(u32::MAX - 1).unwrap_err();
        assert!(err.to_string().contains("not running"), "{err}");
    }
}
