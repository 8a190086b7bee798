//! Who may use a bus owned by another user, with real users and real
//! processes: the bus directory belongs to a stand-in for the `smokenav` system
//! user (0750, the driver running as that user with umask 0077, as under the
//! systemd units). Root sees the driver up and its messages (it becomes the
//! bus owner; before, status said `down` and echo timed out); a member of the
//! owner's group without a sudo rule, and a stranger, get a "permission
//! denied on <dir>" naming the group to join instead of iceoryx2's
//! "InternalError". The sudo path itself runs in `systemd_boot_e2e`.
//!
//! Creating users needs root; run as anyone else, the test still checks the
//! stranger's message against a directory owned by root, and says so.

use smokenav_smoke_emulator::{AdcScale, BoardConfig, FakeIio, IioConfig, Profile, SensorParams};
use smokenav_tests::{Child, bin, profile, unique_instance};
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::path::Path;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

const OWNER: &str = "snvacc-bus";
const OPERATOR: &str = "snvacc-op";
const STRANGER: &str = "snvacc-out";

fn sh(cmd: &str, args: &[&str]) -> Output {
    Command::new(cmd).args(args).output().unwrap()
}

/// A system user (idempotent); `group` adds it to that supplementary group.
fn ensure_user(name: &str, group: Option<&str>) {
    if sh("id", &["-u", name]).status.success() {
        return;
    }
    let mut args = vec!["-r", "-M", "-U", "-s", "/usr/sbin/nologin"];
    if let Some(g) = group {
        args.extend(["-G", g]);
    }
    args.push(name);
    let out = sh("useradd", &args);
    assert!(
        out.status.success() || out.status.code() == Some(9),
        "useradd {name}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn id(flag: &str, name: &str) -> u32 {
    let out = sh("id", &[flag, name]);
    String::from_utf8_lossy(&out.stdout).trim().parse().unwrap()
}

/// `smokenav ARGS` as `user` (None: as this process), on `root`.
fn smokenav(user: Option<&str>, root: &Path, instance: &str, args: &[&str]) -> Output {
    let mut cmd = match user {
        Some(u) => {
            let mut c = Command::new("setpriv");
            c.args([
                &format!("--reuid={u}"),
                &format!("--regid={u}"),
                "--init-groups",
                "--",
            ])
            .arg(bin("smokenav"));
            c
        }
        None => Command::new(bin("smokenav")),
    };
    cmd.args(args)
        .env("SMOKENAV_IOX2_ROOT", root)
        .env("SMOKENAV_INSTANCE", instance)
        .env_remove("SUDO_USER")
        .output()
        .unwrap()
}

fn text(out: &Output) -> String {
    format!(
        "exit {:?}\nstdout: {}\nstderr: {}",
        out.status.code(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

fn assert_denied(out: &Output, root: &Path, group: &str) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{}", text(out));
    assert!(
        err.contains(&format!("permission denied on {}", root.display())),
        "{}",
        text(out)
    );
    assert!(
        err.contains(&format!("sudo usermod -aG {group} $USER")),
        "{}",
        text(out)
    );
    assert!(!err.contains("InternalError"), "{}", text(out));
}

#[test]
fn root_observes_a_bus_owned_by_the_service_user_and_others_are_told_which_group_to_join() {
    if !nix::unistd::Uid::effective().is_root() {
        eprintln!(
            "not root: cannot create users; checking only the message for a bus directory \
             owned by someone else (/)"
        );
        let out = smokenav(
            None,
            Path::new("/"),
            "nobody",
            &["status", "--roles", "smoke"],
        );
        assert_denied(&out, Path::new("/"), "root");
        return;
    }
    ensure_user(OWNER, None);
    ensure_user(OPERATOR, Some(OWNER));
    ensure_user(STRANGER, None);
    let (uid, gid) = (id("-u", OWNER), id("-g", OWNER));

    let dir = tempfile::tempdir().unwrap();
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
    // As systemd's RuntimeDirectory= makes it: <run>/smokenav/iox2, both 0750.
    let run = dir.path().join("smokenav");
    let root = run.join("iox2");
    std::fs::create_dir_all(&root).unwrap();
    for d in [&run, &root] {
        std::fs::set_permissions(d, std::fs::Permissions::from_mode(0o750)).unwrap();
        std::os::unix::fs::chown(d, Some(uid), Some(gid)).unwrap();
    }

    let device = dir.path().join("iio:device0");
    let board = BoardConfig {
        adc: AdcScale::new(5000.0, 12).unwrap(),
        sensor: SensorParams {
            warmup_s: 0.0,
            ..SensorParams::default()
        },
        ..BoardConfig::bench(Profile::clean())
    };
    let _adc = FakeIio::start_at(&device, IioConfig::new(board)).unwrap();
    let config = profile(dir.path(), "pioneer-3dx.toml", |c| {
        c.smoke.adc_bits = 12;
        c.smoke.baseline_mv = Some(1000.0);
    });
    std::fs::set_permissions(&config, std::fs::Permissions::from_mode(0o644)).unwrap();
    let instance = unique_instance("access");
    let driver_cmd = format!(
        "umask 077; exec setpriv --reuid={OWNER} --regid={OWNER} --init-groups -- {} \
         --config {} --port {} --warmup 0",
        bin("smokenav-smoke").display(),
        config.display(),
        device.display()
    );
    let root_str = root.to_string_lossy().into_owned();
    let driver = Child::spawn_env(
        Path::new("/bin/sh"),
        &["-c", &driver_cmd],
        &instance,
        &[("SMOKENAV_IOX2_ROOT", &root_str)],
    )
    .unwrap();

    // Root: status shows the driver up, with the driver's pid.
    let end = Instant::now() + Duration::from_secs(20);
    let status = loop {
        let out = smokenav(
            None,
            &root,
            &instance,
            &[
                "status",
                "--json",
                "--roles",
                "smoke",
                "--stale-after",
                "1.5",
            ],
        );
        let v: serde_json::Value =
            serde_json::from_slice(&out.stdout).unwrap_or(serde_json::Value::Null);
        if v["processes"][0]["status"] == "up" || Instant::now() >= end {
            break (out, v);
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    assert_eq!(
        status.1["processes"][0]["status"],
        "up",
        "{}\n{}",
        text(&status.0),
        driver.output()
    );
    assert!(status.0.status.success(), "{}", text(&status.0));
    assert_eq!(
        status.1["processes"][0]["pid"].as_u64(),
        Some(driver.pid() as u64)
    );

    // Root: a message arrives.
    let echo = smokenav(
        None,
        &root,
        &instance,
        &[
            "topic",
            "echo",
            "smoke/level",
            "-n",
            "1",
            "--timeout",
            "5",
            "--json",
        ],
    );
    assert!(echo.status.success(), "{}", text(&echo));
    assert_eq!(
        String::from_utf8_lossy(&echo.stdout).lines().count(),
        1,
        "{}",
        text(&echo)
    );

    // Root left nothing of its own in the bus directory: the driver could not
    // have read it.
    let mut stack = vec![root.clone()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let e = e.unwrap();
            let m = e.metadata().unwrap();
            assert_eq!(
                m.uid(),
                uid,
                "{} belongs to uid {}",
                e.path().display(),
                m.uid()
            );
            if m.is_dir() {
                stack.push(e.path());
            }
        }
    }

    // A member of the owner's group with no sudo rule: a clear refusal that
    // names the way in, not iceoryx2's InternalError.
    let op = smokenav(
        Some(OPERATOR),
        &root,
        &instance,
        &["status", "--roles", "smoke"],
    );
    assert!(!op.status.success(), "{}", text(&op));
    let err = String::from_utf8_lossy(&op.stderr);
    assert!(
        err.contains(&format!("permission denied on {}", root.display())) && err.contains("sudo"),
        "{}",
        text(&op)
    );
    assert!(!err.contains("InternalError"), "{}", text(&op));

    // A stranger cannot even look into the folder: told which group to join.
    let out = smokenav(
        Some(STRANGER),
        &root,
        &instance,
        &["topic", "echo", "smoke/level", "-n", "1"],
    );
    assert_denied(&out, &root, OWNER);
}
