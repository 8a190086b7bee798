//! `systemd/install` staged into a temporary `DESTDIR` with the binaries the
//! test kit built (`--bin-dir`): every shipped unit, the udev rules, the
//! sysusers file, the README the units name as their documentation, the
//! profile and the binaries land where the units expect them (the prefix is
//! `/usr/local`, units in `/etc/systemd/system`), and nothing else does; a
//! second run leaves the same files; an existing robot profile is kept. The
//! host is never touched: `systemctl`, `udevadm`, `systemd-sysusers` and
//! `cargo` are stand-ins on the script's `PATH` that record any call.
//!
//! With `systemd-analyze` on the machine (CI installs it), the installed units
//! are verified the way `systemd/check` does it, but against the installed
//! binaries; `systemd-sysusers --dry-run` reads the installed sysusers file.
//! Without them those two checks are skipped and say so.

use smokenav_tests::{bin, workspace_root};
use std::collections::{BTreeMap, BTreeSet};
use std::fs::File;
use std::io::Read;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Where the script puts things, relative to `DESTDIR`.
const BIN_DIR: &str = "usr/local/bin";
const UNIT_DIR: &str = "etc/systemd/system";
const UDEV_DIR: &str = "etc/udev/rules.d";
const SYSUSERS_FILE: &str = "usr/lib/sysusers.d/smokenav.conf";
const SUDOERS_FILE: &str = "etc/sudoers.d/smokenav";
const PROFILE_FILE: &str = "etc/smokenav/robot.toml";
const DOC_FILE: &str = "usr/local/share/doc/smokenav/README.md";

/// Commands that act on the host; in `DESTDIR` mode the script must run none.
const HOST_COMMANDS: [&str; 4] = ["systemctl", "udevadm", "systemd-sysusers", "cargo"];

fn systemd_dir() -> PathBuf {
    workspace_root().join("systemd")
}

/// Shipped files of `systemd/` whose name ends with one of `suffixes`, sorted.
fn shipped(suffixes: &[&str]) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(systemd_dir())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            let name = p.file_name().unwrap().to_string_lossy();
            suffixes.iter().any(|s| name.ends_with(s))
        })
        .collect();
    v.sort();
    v
}

fn units() -> Vec<PathBuf> {
    shipped(&[".service", ".target"])
}

/// The command of an `Exec*=` line: its first word without systemd's prefixes
/// (`-`, `@`, `:`, `+`, `!`).
fn exec_commands(unit_text: &str) -> Vec<String> {
    unit_text
        .lines()
        .filter_map(|l| l.trim().split_once('='))
        .filter(|(k, _)| k.starts_with("Exec"))
        .filter_map(|(_, v)| v.split_whitespace().next())
        .map(|c| c.trim_start_matches(['-', '@', ':', '+', '!']).to_owned())
        .collect()
}

/// Binaries the shipped units start from `/usr/local/bin`, plus the `smokenav` CLI.
fn expected_binaries() -> BTreeSet<String> {
    let mut names: BTreeSet<String> = units()
        .iter()
        .flat_map(|u| exec_commands(&std::fs::read_to_string(u).unwrap()))
        .filter_map(|c| c.strip_prefix("/usr/local/bin/").map(str::to_owned))
        .collect();
    assert!(
        names.len() >= 6,
        "the units start the drivers, fusion and SLAM: {names:?}"
    );
    names.insert("smokenav".into());
    names
}

/// `objcopy --strip-debug` copies of the expected binaries in `out`, the way
/// the install puts them on the robot; prints the sizes before and after.
fn stripped_binaries(bin_dir: &Path, out: &Path) -> PathBuf {
    std::fs::create_dir_all(out).unwrap();
    let (mut before, mut after) = (0u64, 0u64);
    for b in expected_binaries() {
        let (src, dst) = (bin_dir.join(&b), out.join(&b));
        let st = Command::new("objcopy")
            .arg("--strip-debug")
            .arg(&src)
            .arg(&dst)
            .status()
            .expect("objcopy (binutils) runs");
        assert!(st.success(), "objcopy --strip-debug {}", src.display());
        before += std::fs::metadata(&src).unwrap().len();
        after += std::fs::metadata(&dst).unwrap().len();
        let sections = Command::new("readelf")
            .arg("-S")
            .arg(&dst)
            .output()
            .unwrap();
        assert!(
            !String::from_utf8_lossy(&sections.stdout).contains(".debug_info"),
            "{b} keeps its debug info"
        );
    }
    eprintln!(
        "binaries: {:.1} MB built, {:.1} MB installed without debug info",
        before as f64 / 1e6,
        after as f64 / 1e6
    );
    out.to_owned()
}

/// Every file an install must leave: relative path → (source, mode), the
/// binaries taken from `bin_dir` (already stripped as the install strips).
fn expected_tree(profile: &Path, bin_dir: &Path) -> BTreeMap<PathBuf, (PathBuf, u32)> {
    let mut t = BTreeMap::new();
    let mut add = |rel: PathBuf, src: PathBuf, mode: u32| {
        assert!(
            t.insert(rel.clone(), (src, mode)).is_none(),
            "{rel:?} twice"
        );
    };
    for u in units() {
        add(
            Path::new(UNIT_DIR).join(u.file_name().unwrap()),
            u.clone(),
            0o644,
        );
    }
    for r in shipped(&[".rules"]) {
        add(
            Path::new(UDEV_DIR).join(r.file_name().unwrap()),
            r.clone(),
            0o644,
        );
    }
    add(
        SYSUSERS_FILE.into(),
        systemd_dir().join("smokenav.sysusers"),
        0o644,
    );
    // sudo ignores a drop-in that others may write, and visudo wants 0440.
    add(
        SUDOERS_FILE.into(),
        systemd_dir().join("smokenav.sudoers"),
        0o440,
    );
    add(PROFILE_FILE.into(), profile.to_owned(), 0o644);
    add(DOC_FILE.into(), workspace_root().join("README.md"), 0o644);
    for b in expected_binaries() {
        add(Path::new(BIN_DIR).join(&b), bin_dir.join(&b), 0o755);
    }
    t
}

/// Every regular file under `root`, relative to it, with its permission bits.
fn files_under(root: &Path) -> BTreeMap<PathBuf, u32> {
    let mut out = BTreeMap::new();
    let mut stack = vec![root.to_owned()];
    while let Some(dir) = stack.pop() {
        for e in std::fs::read_dir(&dir).unwrap() {
            let e = e.unwrap();
            let meta = std::fs::symlink_metadata(e.path()).unwrap();
            if meta.is_dir() {
                stack.push(e.path());
            } else {
                let rel = e.path().strip_prefix(root).unwrap().to_owned();
                out.insert(rel, meta.permissions().mode() & 0o7777);
            }
        }
    }
    out
}

/// Whether two files hold the same bytes (read in chunks: the debug binaries
/// are ~100 MB each).
fn same_bytes(a: &Path, b: &Path) -> bool {
    let (mut fa, mut fb) = (File::open(a).unwrap(), File::open(b).unwrap());
    if fa.metadata().unwrap().len() != fb.metadata().unwrap().len() {
        return false;
    }
    let (mut ba, mut bb) = (vec![0u8; 1 << 20], vec![0u8; 1 << 20]);
    loop {
        let n = fa.read(&mut ba).unwrap();
        if n == 0 {
            return true;
        }
        fb.read_exact(&mut bb[..n]).unwrap();
        if ba[..n] != bb[..n] {
            return false;
        }
    }
}

/// `dest` holds exactly the files of `expected`, each with its source's bytes and its mode.
fn assert_tree(dest: &Path, expected: &BTreeMap<PathBuf, (PathBuf, u32)>, run: &str) {
    let found = files_under(dest);
    let missing: Vec<_> = expected
        .keys()
        .filter(|p| !found.contains_key(*p))
        .collect();
    let extra: Vec<_> = found
        .keys()
        .filter(|p| !expected.contains_key(*p))
        .collect();
    assert!(
        missing.is_empty() && extra.is_empty(),
        "{run}: missing {missing:?}, unexpected {extra:?}"
    );
    for (rel, (src, mode)) in expected {
        assert_eq!(
            found[rel],
            *mode,
            "{run}: {} has mode {:o}",
            rel.display(),
            found[rel]
        );
        assert!(
            same_bytes(&dest.join(rel), src),
            "{run}: {} differs from {}",
            rel.display(),
            src.display()
        );
    }
}

/// Directory of stand-ins for the host commands, each appending its name and
/// arguments to `calls.log` and failing.
fn host_command_stand_ins(dir: &Path) -> PathBuf {
    let stubs = dir.join("stubs");
    std::fs::create_dir(&stubs).unwrap();
    let log = dir.join("calls.log");
    for name in HOST_COMMANDS {
        let path = stubs.join(name);
        std::fs::write(
            &path,
            format!(
                "#!/bin/sh\necho \"{name} $*\" >> '{}'\nexit 1\n",
                log.display()
            ),
        )
        .unwrap();
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    stubs
}

/// Runs `systemd/install --profile PROFILE --bin-dir BIN_DIR` with `DESTDIR=dest`.
fn install(dest: &Path, profile: &Path, bin_dir: &Path, stubs: &Path) -> Output {
    let path = format!(
        "{}:{}",
        stubs.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    Command::new(systemd_dir().join("install"))
        .arg("--profile")
        .arg(profile)
        .arg("--bin-dir")
        .arg(bin_dir)
        .env("DESTDIR", dest)
        .env("PATH", path)
        .output()
        .expect("cannot run systemd/install")
}

fn text(out: &Output) -> String {
    format!(
        "status {}\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

fn have(command: &str, arg: &str) -> bool {
    Command::new(command)
        .arg(arg)
        .output()
        .is_ok_and(|o| o.status.success())
}

/// The installed units' commands are the installed binaries; their config
/// and documentation paths are installed files.
fn assert_units_point_into_the_install(dest: &Path, binaries: &BTreeSet<String>) {
    let mut started = BTreeSet::new();
    for u in units() {
        let installed = dest.join(UNIT_DIR).join(u.file_name().unwrap());
        let unit = std::fs::read_to_string(&installed).unwrap();
        let name = u.file_name().unwrap().to_string_lossy().into_owned();
        for cmd in exec_commands(&unit) {
            assert!(
                cmd.starts_with('/'),
                "{name}: {cmd} is not an absolute path"
            );
            if let Some(b) = cmd.strip_prefix("/usr/local/bin/") {
                let file = dest.join(BIN_DIR).join(b);
                let meta = std::fs::metadata(&file)
                    .unwrap_or_else(|e| panic!("{name}: {cmd} not installed ({e})"));
                assert!(
                    meta.is_file() && meta.permissions().mode() & 0o111 == 0o111,
                    "{name}: {} is not executable",
                    file.display()
                );
                assert!(binaries.contains(b), "{name}: {b}");
                started.insert(b.to_owned());
            } else {
                // A system command (the rundir unit's /bin/true), not ours.
                assert!(
                    !cmd.contains("smokenav"),
                    "{name}: {cmd} is outside the install prefix /usr/local/bin"
                );
                assert!(Path::new(&cmd).exists(), "{name}: {cmd}");
            }
        }
        // `--config /etc/smokenav/robot.toml` and `Documentation=file:/usr/local/…`.
        for word in unit.split([' ', '=', '\n']) {
            let path = word.strip_prefix("file:").unwrap_or(word);
            if path.starts_with("/etc/smokenav/") || path.starts_with("/usr/local/share/") {
                assert!(
                    dest.join(&path[1..]).is_file(),
                    "{name} names {path}, which the install did not create"
                );
            }
        }
    }
    let daemons: BTreeSet<String> = binaries
        .iter()
        .filter(|b| *b != "smokenav")
        .cloned()
        .collect();
    assert_eq!(started, daemons, "each installed daemon has its unit");
}

/// `systemd-analyze verify` on the installed units, as `systemd/check` runs it
/// (copies in a folder of their own, `--man=no`, any output fails), with
/// `/usr/local/bin/` pointed at the installed binaries instead of stand-ins.
fn verify_installed_units(dest: &Path, work: &Path) {
    let dir = work.join("units");
    std::fs::create_dir(&dir).unwrap();
    let installed_bin = format!("{}/", dest.join(BIN_DIR).display());
    let mut names = Vec::new();
    for u in units() {
        let name = u.file_name().unwrap().to_string_lossy().into_owned();
        let unit = std::fs::read_to_string(dest.join(UNIT_DIR).join(&name)).unwrap();
        std::fs::write(
            dir.join(&name),
            unit.replace("/usr/local/bin/", &installed_bin),
        )
        .unwrap();
        names.push(format!("./{name}"));
    }
    let out = Command::new("systemd-analyze")
        .args(["verify", "--man=no"])
        .args(&names)
        .current_dir(&dir)
        .output()
        .unwrap();
    assert!(
        out.status.success() && out.stdout.is_empty() && out.stderr.is_empty(),
        "systemd-analyze verify on the installed units:\n{}",
        text(&out)
    );
    eprintln!(
        "systemd-analyze verify: {} installed units, no output",
        names.len()
    );
}

/// `systemd-sysusers --dry-run` with the staged tree as root: the installed
/// file parses and creates the `smokenav` user (nothing is written).
fn dry_run_sysusers(dest: &Path) {
    let out = Command::new("systemd-sysusers")
        .arg("--dry-run")
        .arg(format!("--root={}", dest.display()))
        .output()
        .unwrap();
    let all = text(&out);
    assert!(out.status.success(), "{all}");
    assert!(
        !all.contains("smokenav.conf:"),
        "the installed sysusers file has errors:\n{all}"
    );
    assert!(all.contains("Creating user 'smokenav'"), "{all}");
    eprintln!("systemd-sysusers --dry-run: the installed file creates the smokenav user");
}

#[test]
fn destdir_install_stages_units_rules_user_profile_and_binaries_and_reruns_unchanged() {
    let bin_dir = bin("smokenav").parent().unwrap().to_owned();
    let work = tempfile::tempdir().unwrap();
    let dest = work.path().join("dest");
    let stubs = host_command_stand_ins(work.path());
    let pioneer = workspace_root().join("config/pioneer-3dx.toml");
    let stripped = stripped_binaries(&bin_dir, &work.path().join("stripped"));
    let expected = expected_tree(&pioneer, &stripped);
    let binaries = expected_binaries();

    // First run: everything staged, nothing else.
    let out = install(&dest, &pioneer, &bin_dir, &stubs);
    assert!(out.status.success(), "{}", text(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains(&format!("staged in {}", dest.display())),
        "{}",
        text(&out)
    );
    assert!(stdout.contains("platform pioneer"), "{}", text(&out));
    assert!(
        out.stderr.is_empty(),
        "no warning (e.g. a binary not built):\n{}",
        text(&out)
    );
    assert_tree(&dest, &expected, "first run");
    assert_units_point_into_the_install(&dest, &binaries);

    // The installed CLI runs and accepts the installed profile.
    let check = Command::new(dest.join(BIN_DIR).join("smokenav"))
        .args(["config", "check"])
        .arg(dest.join(PROFILE_FILE))
        .output()
        .unwrap();
    assert!(check.status.success(), "{}", text(&check));

    if have("systemd-analyze", "--version") {
        verify_installed_units(&dest, work.path());
    } else {
        eprintln!("systemd-analyze not found: verify of the installed units skipped");
    }
    if have("systemd-sysusers", "--version") {
        dry_run_sysusers(&dest);
    } else {
        eprintln!("systemd-sysusers not found: sysusers dry run skipped");
    }

    // Second run over the first: no error, the very same files.
    let out = install(&dest, &pioneer, &bin_dir, &stubs);
    assert!(out.status.success(), "{}", text(&out));
    assert!(out.stderr.is_empty(), "{}", text(&out));
    assert_tree(&dest, &expected, "second run");

    // The same platform's profile, edited: the robot's own profile is kept,
    // the new one put beside it for the operator to merge.
    let edited = work.path().join("pioneer-edited.toml");
    let mut text_of = std::fs::read_to_string(&pioneer).unwrap();
    text_of.push_str("\n# edited\n");
    std::fs::write(&edited, text_of).unwrap();
    let out = install(&dest, &edited, &bin_dir, &stubs);
    assert!(out.status.success(), "{}", text(&out));
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("keeping existing /etc/smokenav/robot.toml"),
        "{}",
        text(&out)
    );
    let mut with_new = expected.clone();
    with_new.insert(
        PathBuf::from(PROFILE_FILE).with_extension("toml.new"),
        (edited, 0o644),
    );
    assert_tree(&dest, &with_new, "install of an edited profile");

    // Another platform's profile would leave the robot inconsistent (its
    // driver enabled, the old profile kept): refused, naming the way out.
    let scout = workspace_root().join("config/nomad-scout.toml");
    let out = install(&dest, &scout, &bin_dir, &stubs);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("pioneer profile") && err.contains("--replace-profile"),
        "{}",
        text(&out)
    );
    assert_tree(&dest, &with_new, "refused switch");
    // Asked for: the robot switches, the old profile kept as .old.
    let out = Command::new(systemd_dir().join("install"))
        .args(["--replace-profile", "--profile"])
        .arg(&scout)
        .arg("--bin-dir")
        .arg(&bin_dir)
        .env("DESTDIR", &dest)
        .env(
            "PATH",
            format!(
                "{}:{}",
                stubs.display(),
                std::env::var("PATH").unwrap_or_default()
            ),
        )
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", text(&out));
    let mut switched = expected.clone();
    switched.insert(PROFILE_FILE.into(), (scout.clone(), 0o644));
    switched.insert(
        PathBuf::from(PROFILE_FILE).with_extension("toml.old"),
        (pioneer.clone(), 0o644),
    );
    assert_tree(&dest, &switched, "switch to the Scout");

    // Uninstall: everything but the profiles; --purge: nothing at all.
    let uninstall = |purge: bool| {
        let mut c = Command::new(systemd_dir().join("uninstall"));
        if purge {
            c.arg("--purge");
        }
        c.env("DESTDIR", &dest)
            .env(
                "PATH",
                format!(
                    "{}:{}",
                    stubs.display(),
                    std::env::var("PATH").unwrap_or_default()
                ),
            )
            .output()
            .unwrap()
    };
    let out = uninstall(false);
    assert!(out.status.success(), "{}", text(&out));
    let kept: BTreeMap<_, _> = switched
        .iter()
        .filter(|(rel, _)| rel.starts_with("etc/smokenav"))
        .map(|(k, v)| (k.clone(), v.clone()))
        .collect();
    assert_tree(&dest, &kept, "uninstall");
    let out = uninstall(true);
    assert!(out.status.success(), "{}", text(&out));
    assert_tree(&dest, &BTreeMap::new(), "uninstall --purge");

    let calls = std::fs::read_to_string(work.path().join("calls.log")).unwrap_or_default();
    assert!(calls.is_empty(), "DESTDIR mode ran host commands:\n{calls}");
}

/// Every smokenav unit a unit or the target refers to is shipped, and the one
/// that creates the shared runtime directory is named for it (not for the
/// runtime crate).
#[test]
fn unit_references_resolve_and_the_rundir_unit_creates_the_runtime_directory() {
    let shipped: BTreeSet<String> = units()
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    let mut creators = Vec::new();
    for unit in units() {
        let text = std::fs::read_to_string(&unit).unwrap();
        for (key, value) in text.lines().filter_map(|l| l.trim().split_once('=')) {
            if key == "RuntimeDirectory" {
                creators.push(unit.file_name().unwrap().to_string_lossy().into_owned());
            }
            if matches!(key, "Requires" | "After" | "Wants" | "BindsTo" | "PartOf") {
                for name in value
                    .split_whitespace()
                    .filter(|n| n.starts_with("smokenav"))
                {
                    assert!(
                        shipped.contains(name),
                        "{}: {key}={name} is not shipped in systemd/",
                        unit.display()
                    );
                }
            }
        }
    }
    assert_eq!(creators, ["smokenav-rundir.service"]);
}

/// `systemd/package` builds a Debian package with exactly the install's file
/// set; dpkg installs it into an empty root (as `--root`, scripts outside a
/// chroot with `DPKG_ROOT` set, so they leave the host alone), removes it
/// keeping the operator's files, and purges it.
#[test]
fn debian_package_installs_the_install_file_set_into_a_fresh_root() {
    if !have("dpkg-deb", "--version") {
        panic!("dpkg-deb is missing: this test runs on Debian, where dpkg is essential");
    }
    let bin_dir = bin("smokenav").parent().unwrap().to_owned();
    let work = tempfile::tempdir().unwrap();
    let stubs = host_command_stand_ins(work.path());
    let pioneer = workspace_root().join("config/pioneer-3dx.toml");
    let stripped = stripped_binaries(&bin_dir, &work.path().join("stripped"));
    let expected = expected_tree(&pioneer, &stripped);
    let path = format!(
        "{}:{}",
        stubs.display(),
        std::env::var("PATH").unwrap_or_default()
    );

    let out = Command::new(systemd_dir().join("package"))
        .arg("--bin-dir")
        .arg(&bin_dir)
        .arg("--out")
        .arg(work.path())
        .env("PATH", &path)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", text(&out));
    let deb = PathBuf::from(String::from_utf8_lossy(&out.stdout).trim());
    assert!(deb.exists(), "{}", text(&out));
    eprintln!(
        "{}: {:.1} MB",
        deb.display(),
        std::fs::metadata(&deb).unwrap().len() as f64 / 1e6
    );

    let root = work.path().join("root");
    let db = root.join("var/lib/dpkg");
    for d in ["info", "updates", "triggers"] {
        std::fs::create_dir_all(db.join(d)).unwrap();
    }
    std::fs::write(db.join("status"), "").unwrap();
    std::fs::write(db.join("available"), "").unwrap();
    let dpkg = |args: &[&str]| {
        let out = Command::new("dpkg")
            .arg(format!("--root={}", root.display()))
            .args([
                "--force-not-root",
                "--force-script-chrootless",
                "--force-bad-path",
                "--force-depends",
                "--no-triggers",
            ])
            .arg(format!("--log={}", work.path().join("dpkg.log").display()))
            .args(args)
            .env("PATH", &path)
            .output()
            .unwrap();
        assert!(out.status.success(), "dpkg {args:?}: {}", text(&out));
    };
    let installed = |root: &Path| {
        let mut t = files_under(root);
        t.retain(|p, _| !p.starts_with("var/lib/dpkg"));
        t
    };
    dpkg(&["-i", deb.to_str().unwrap()]);
    let mut found = installed(&root);
    let mut want = expected.clone();
    for (rel, (src, mode)) in &expected {
        assert_eq!(
            found.remove(rel),
            Some(*mode),
            "{} from the .deb",
            rel.display()
        );
        assert!(
            same_bytes(&root.join(rel), src),
            "{} differs",
            rel.display()
        );
    }
    assert!(
        found.is_empty(),
        "the .deb installs more than install does: {found:?}"
    );
    dpkg(&["-r", "smokenav"]);
    want.retain(|rel, _| {
        [PROFILE_FILE, SUDOERS_FILE]
            .iter()
            .any(|k| rel == Path::new(k))
            || rel.starts_with(UDEV_DIR)
    });
    let left: BTreeSet<_> = installed(&root).into_keys().collect();
    let want: BTreeSet<_> = want.into_keys().collect();
    assert_eq!(left, want, "remove keeps exactly the operator's files");
    dpkg(&["-P", "smokenav"]);
    assert!(installed(&root).is_empty(), "{:?}", installed(&root));
    let calls = std::fs::read_to_string(work.path().join("calls.log")).unwrap_or_default();
    assert!(
        calls.is_empty(),
        "the package scripts ran host commands:\n{calls}"
    );
}
