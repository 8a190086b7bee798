//! The units under a booted systemd, no VM: `tests/systemd/boot-test` boots a
//! minimal Debian root with `systemd-nspawn -b`, installs smokenav into it
//! with `systemd/install`, runs the emulators on PTYs and, inside, checks
//! (`tests/systemd/inside-checks`): every unit `active` through `READY=1`;
//! `smokenav status` as an operator (group smokenav, through the installed
//! sudo rule) and as root shows every process up, the operator can echo a
//! topic but not drive nor publish (`topic pub`, `initial-pose`), a stranger
//! is told which group to join; `kill -9`
//! of fusion is restarted and fused scans flow again within 2 s; a SIGSTOPped
//! SLAM is killed by the watchdog and restarted; the laser driver stops when
//! its device goes and comes back with it; the journal holds each process's
//! structured (tracing-journald) log; all of it under the units' sandbox.
//!
//! udev does not run in a container, so there are no `dev-*.device` units:
//! the script replaces each by a stand-in service running the emulator (the
//! drivers' `BindsTo=`/`After=` lines name it; nothing else in the units changes).
//!
//! The Debian root is cached in `target/systemd-boot/root` (built when
//! missing, about 1.5 min; `./test` installs debootstrap and systemd-nspawn).
//! Booting a container needs root: run as anyone else, this test says so and
//! checks only that the scripts parse.

use smokenav_tests::{bin, workspace_root};
use std::collections::BTreeMap;
use std::process::Command;

#[test]
fn units_under_a_booted_systemd_start_restart_watchdog_follow_devices_and_admit_operators() {
    let script = workspace_root().join("tests/systemd/boot-test");
    let inside = workspace_root().join("tests/systemd/inside-checks");
    for s in [&script, &inside] {
        let out = Command::new("bash").arg("-n").arg(s).output().unwrap();
        assert!(
            out.status.success(),
            "{}: {}",
            s.display(),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    if !nix::unistd::Uid::effective().is_root() {
        eprintln!("not root: cannot boot a container; checked only that the scripts parse");
        return;
    }
    let bin_dir = bin("smokenav").parent().unwrap().to_owned();
    let work = workspace_root().join("target/systemd-boot");
    let out = Command::new(&script)
        .arg(&bin_dir)
        .arg(&work)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let report = format!(
        "{stdout}\nstderr: {}\n(console: {}, inside: {})",
        String::from_utf8_lossy(&out.stderr),
        work.join("console.log").display(),
        work.join("results").display()
    );
    let results: BTreeMap<&str, &str> = stdout.lines().filter_map(|l| l.split_once('=')).collect();
    for check in [
        "units_active_notify",
        "operator_status_all_up",
        "root_status_all_up",
        "operator_topic_echo",
        "operator_cannot_drive",
        "operator_cannot_publish",
        "stranger_told_the_group",
        "fusion_restarted_data_within_2s",
        "watchdog_restarts_stopped_process",
        "driver_follows_device",
        "journal_structured",
        "sandbox_in_force",
    ] {
        assert_eq!(
            results.get(format!("check_{check}").as_str()),
            Some(&"pass"),
            "{check}\n{report}"
        );
    }
    let figure = |k: &str| -> f64 {
        results
            .get(k)
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("no figure {k}\n{report}"))
    };
    assert!(figure("fusion_kill9_to_data_s") <= 2.0, "{report}");
    // WatchdogSec=5s plus RestartSec=1s at most, with slack for the restart itself.
    assert!(figure("slam_sigstop_to_restart_s") <= 8.0, "{report}");
    assert_eq!(results.get("all_passed"), Some(&"1"), "{report}");
    assert!(out.status.success(), "{report}");
    eprintln!("{stdout}");
}
