//! `smokenav slam` on logs a user might really have: the real binary on real files.

use std::path::PathBuf;
use std::process::Command;

fn data() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../algorithms/slam/tests/data")
}

/// The log with the robot pose of the `index`-th FLASER record moved `dx` m.
fn corrupt(index: usize, dx: f64) -> String {
    let text = std::fs::read_to_string(data().join("csail-prefix-200.clf")).unwrap();
    let mut seen = 0;
    let mut out = String::new();
    for line in text.lines() {
        let mut f: Vec<String> = line.split_whitespace().map(str::to_owned).collect();
        if f.first().map(String::as_str) == Some("FLASER") {
            if seen == index {
                let n: usize = f[1].parse().unwrap();
                let x: f64 = f[2 + n + 3].parse().unwrap();
                f[2 + n + 3] = format!("{:.6}", x + dx);
                out.push_str(&f.join(" "));
                out.push('\n');
                seen += 1;
                continue;
            }
            seen += 1;
        }
        out.push_str(line);
        out.push('\n');
    }
    out
}

fn max_step(trajectory: &str) -> f64 {
    let poses: Vec<(f64, f64)> = trajectory
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|t| t.parse().unwrap()).collect();
            (v[1], v[2])
        })
        .collect();
    poses
        .windows(2)
        .map(|w| (w[1].0 - w[0].0).hypot(w[1].1 - w[0].1))
        .fold(0.0, f64::max)
}

/// `smokenav slam ARGS`: success, stdout, stderr.
fn slam(args: &[&str]) -> (bool, String, String) {
    slam_in(None, args)
}

/// [`slam`] run in folder `cwd` (relative paths are the user's).
fn slam_in(cwd: Option<&std::path::Path>, args: &[&str]) -> (bool, String, String) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_smokenav"));
    if let Some(dir) = cwd {
        cmd.current_dir(dir);
    }
    let out = cmd.arg("slam").args(args).output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    (out.status.success(), stdout, stderr)
}

/// `smokenav slam --carmen LOG --out OUT EXTRA…`.
fn slam_on(log: &std::path::Path, out: &std::path::Path, extra: &[&str]) -> (bool, String, String) {
    let mut args = vec![
        "--carmen",
        log.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    slam(&args)
}

/// The report's `ATE trajectory` line and its RMS, m.
fn ate_rms(report: &str) -> (f64, &str) {
    let line = report
        .lines()
        .find(|l| l.starts_with("ATE trajectory"))
        .unwrap_or_else(|| panic!("no ATE line:\n{report}"));
    let rms = line
        .split("RMS ")
        .nth(1)
        .and_then(|t| t.split(' ').next())
        .and_then(|t| t.parse().ok())
        .unwrap_or_else(|| panic!("no RMS in {line}"));
    (rms, line)
}

/// The scans a localising run matched to the saved map, and the report's line.
fn matched_scans(report: &str) -> (f64, &str) {
    let line = report
        .lines()
        .find(|l| l.starts_with("localization"))
        .unwrap_or_else(|| panic!("no localization line in\n{report}"));
    let matched = line
        .split(": ")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{line}"));
    (matched, line)
}

#[test]
fn one_corrupt_odometry_record_is_reported_by_line_and_never_taken_as_motion() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("corrupt.clf");
    std::fs::write(&log, corrupt(100, 812.0)).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_smokenav"))
        .args(["slam", "--carmen", log.to_str().unwrap(), "--out"])
        .arg(dir.path().join("run"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains(" 1 bad lines,"), "{stdout}");
    assert!(stdout.contains("odometry jumps 8"), "{stdout}");
    let trajectory = std::fs::read_to_string(dir.path().join("run/trajectory.txt")).unwrap();
    // CSAIL's own odometry moves under 1 m per record; 812 m would show.
    let step = max_step(&trajectory);
    assert!(step < 2.0, "the trajectory jumps {step:.1} m");
}

/// Logs are often shipped gzip-compressed (Radish's, the corrected CSAIL
/// log): read as text, every line was "not UTF-8" and the run ended with no
/// scan and exit status 0. Compressed, the log gives the same trajectory.
#[test]
fn a_gzip_compressed_log_maps_as_its_text_does() {
    use std::io::Write as _;
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read(data().join("csail-prefix-200.clf")).unwrap();
    let gz = dir.path().join("csail-prefix-200.clf.gz");
    let mut enc = flate2::write::GzEncoder::new(
        std::fs::File::create(&gz).unwrap(),
        flate2::Compression::default(),
    );
    enc.write_all(&text).unwrap();
    enc.finish().unwrap();
    let mut trajectories = Vec::new();
    for (log, out) in [
        (data().join("csail-prefix-200.clf"), "plain"),
        (gz.clone(), "gz"),
    ] {
        let out = dir.path().join(out);
        let (ok, stdout, stderr) = slam_on(&log, &out, &["--backend", "graph"]);
        assert!(ok, "{stderr}");
        assert!(stdout.contains(" 0 bad lines,"), "{stdout}");
        trajectories.push(std::fs::read_to_string(out.join("trajectory.txt")).unwrap());
    }
    assert!(trajectories[0].lines().count() > 100, "{}", trajectories[0]);
    assert_eq!(trajectories[0], trajectories[1]);
}

/// GMapping writes its corrected logs with `%g` stamps (six significant
/// digits: a whole run under one or two values) and one scan per metre or so.
/// Checked for speed against 0 s, most of those steps were refused as
/// odometry jumps and their scans skipped.
#[test]
fn a_log_stamped_to_six_digits_with_sparse_scans_is_mapped_whole() {
    let text = std::fs::read_to_string(data().join("csail-prefix-200.clf")).unwrap();
    let mut flaser = 0;
    let mut log = String::new();
    for line in text.lines() {
        let f: Vec<&str> = line.split_whitespace().collect();
        if f.first() == Some(&"FLASER") {
            flaser += 1;
            // Every fifth scan: 0.2–0.9 m apart, as GMapping keeps them.
            if (flaser - 1) % 5 != 0 {
                continue;
            }
        }
        let coarse: Vec<String> = f
            .iter()
            .map(|t| match t.parse::<f64>() {
                Ok(v) if v > 1e9 => format!("{v:.5e}"),
                _ => (*t).to_owned(),
            })
            .collect();
        log.push_str(&coarse.join(" "));
        log.push('\n');
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("coarse.clf");
    std::fs::write(&path, log).unwrap();
    let (ok, stdout, stderr) = slam_on(&path, &dir.path().join("run"), &["--backend", "graph"]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("scans              40 read,"), "{stdout}");
    assert!(stdout.contains(" 0 bad lines,"), "{stdout}");
    assert!(stdout.contains("written to 10000 s only"), "{stdout}");
}

/// `--slam-params` takes the keys bare or under the `[slam]` header they
/// have in a profile (a user copies them from one); under the header a wrong
/// key is still named with its file and line.
#[test]
fn slam_params_are_read_bare_or_under_their_profile_header() {
    let dir = tempfile::tempdir().unwrap();
    let log = data().join("csail-prefix-200.clf");
    let mut trajectories = Vec::new();
    for (name, text) in [
        ("bare.toml", "particles = 4\nseed = 9\n"),
        (
            "header.toml",
            "# copied from a profile\n[slam]\nparticles = 4\nseed = 9\n",
        ),
    ] {
        let params = dir.path().join(name);
        std::fs::write(&params, text).unwrap();
        let out = dir.path().join(name).with_extension("run");
        let (ok, _, stderr) = slam_on(
            &log,
            &out,
            &[
                "--slam-params",
                params.to_str().unwrap(),
                "--max-scans",
                "40",
            ],
        );
        assert!(ok, "{name}: {stderr}");
        let stats = std::fs::read_to_string(out.join("stats.txt")).unwrap();
        assert!(stats.contains("rbpf (4 particles)"), "{name}: {stats}");
        trajectories.push(std::fs::read_to_string(out.join("trajectory.txt")).unwrap());
    }
    assert_eq!(trajectories[0], trajectories[1]);
    let bad = dir.path().join("typo.toml");
    std::fs::write(&bad, "[slam]\nparticles = 4\nparticle = 5\n").unwrap();
    let (ok, _, stderr) = slam_on(
        &log,
        &dir.path().join("typo"),
        &["--slam-params", bad.to_str().unwrap()],
    );
    assert!(!ok);
    assert!(stderr.contains("typo.toml:3"), "{stderr}");
    assert!(stderr.contains("particle"), "{stderr}");
}

/// `--relations`: a benchmark relations file (`t1 t2 x y z roll pitch
/// yaw`) at the log's own scan stamps. Written from one run's trajectory,
/// a second run scores zero against it; moved 5 cm, 5 cm; from another
/// log, an error naming both spans.
#[test]
fn relations_at_the_logs_stamps_score_the_trajectory() {
    let dir = tempfile::tempdir().unwrap();
    let log = data().join("csail-prefix-200.clf");
    let run = |name: &str, extra: &[&str]| {
        let mut a = vec!["--backend", "graph"];
        a.extend_from_slice(extra);
        slam_on(&log, &dir.path().join(name), &a)
    };
    let (ok, _, stderr) = run("first", &[]);
    assert!(ok, "{stderr}");
    let poses: Vec<Vec<f64>> = std::fs::read_to_string(dir.path().join("first/trajectory.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split_whitespace().map(|t| t.parse().unwrap()).collect())
        .collect();
    let relations = |shift: f64| {
        let mut s = String::from("# t1 t2 x y z roll pitch yaw\n");
        for w in poses.windows(5).step_by(5) {
            let (a, b) = (&w[0], &w[4]);
            let (sn, cs) = a[3].sin_cos();
            let (dx, dy) = (b[1] - a[1], b[2] - a[2]);
            s.push_str(&format!(
                "{:.6} {:.6} {} {} 0 0 0 {}\n",
                a[0],
                b[0],
                cs * dx + sn * dy + shift,
                -sn * dx + cs * dy,
                b[3] - a[3]
            ));
        }
        s
    };
    for (name, shift, says) in [
        ("same.relations", 0.0, "translation 0.0000 ± 0.0000 m"),
        ("shifted.relations", 0.05, "translation 0.0500 ± 0.0000 m"),
    ] {
        let path = dir.path().join(name);
        std::fs::write(&path, relations(shift)).unwrap();
        let (ok, stdout, stderr) = run(
            &format!("{name}.run"),
            &["--relations", path.to_str().unwrap()],
        );
        assert!(ok, "{stderr}");
        let line = stdout
            .lines()
            .find(|l| l.starts_with("relations   "))
            .unwrap_or_else(|| panic!("{stdout}"));
        assert!(line.contains(says), "{line}");
        assert!(!line.contains("outside"), "{line}");
    }
    let other = dir.path().join("other.relations");
    std::fs::write(&other, "5.0 6.0 1 0 0 0 0 0\n").unwrap();
    let (ok, stdout, _) = run("other", &["--relations", other.to_str().unwrap()]);
    assert!(ok);
    assert!(stdout.contains("is it the same log?"), "{stdout}");
    let bad = dir.path().join("bad.relations");
    std::fs::write(&bad, "5.0 6.0 1 0 0 0 0\n").unwrap();
    let (ok, _, stderr) = run("bad", &["--relations", bad.to_str().unwrap()]);
    assert!(!ok);
    assert!(stderr.contains("bad.relations:1"), "{stderr}");
}

/// A file with no scan in it is an error naming what was wrong with it, not
/// a success with an empty trajectory.
#[test]
fn a_file_without_scans_is_an_error_that_says_what_was_read() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("not-a-log.clf");
    // A zstd frame's magic and some binary: a compressed format we do not read.
    std::fs::write(
        &log,
        [0x28, 0xb5, 0x2f, 0xfd, 0xff, 0xfe, 0x00, b'\n', 0x80, 0x81],
    )
    .unwrap();
    let (ok, stdout, stderr) = slam_on(&log, &dir.path().join("run"), &[]);
    assert!(!ok, "{stdout}");
    assert!(stderr.contains("no laser scan could be read"), "{stderr}");
    assert!(stderr.contains("not UTF-8"), "{stderr}");
    assert!(!dir.path().join("run/trajectory.txt").exists());
    // A log of laser records without a pose of their own: the error says so.
    let raw = dir.path().join("raw.clf");
    std::fs::write(
        &raw,
        "ODOM 0 0 0 0 0 0 1.0 h 1.0\n\
         RAWLASER1 0 -1.57 3.14 0.0175 80 0.01 0 3 1 1 1 0 1.1 h 1.1\n\
         RAWLASER1 0 -1.57 3.14 0.0175 80 0.01 0 3 1 1 1 0 1.2 h 1.2\n",
    )
    .unwrap();
    let (ok, _, stderr) = slam_on(&raw, &dir.path().join("raw-run"), &[]);
    assert!(!ok);
    assert!(stderr.contains("2 RAWLASER/RLASER"), "{stderr}");
}

/// `--save-graph` on the first half of a real log, then `--load-graph
/// --localization` on the second: the robot is tracked on the saved map,
/// which comes out unchanged (the same map file, the same graph files).
#[test]
fn localization_on_a_saved_graph_tracks_the_second_half_and_leaves_the_map_unchanged() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(data().join("csail-prefix-200.clf")).unwrap();
    let mut halves = (String::new(), String::new());
    let mut scans = 0;
    for line in text.lines() {
        scans += usize::from(line.starts_with("FLASER"));
        let half = if scans <= 100 {
            &mut halves.0
        } else {
            &mut halves.1
        };
        half.push_str(line);
        half.push('\n');
    }
    let (first, second) = (dir.path().join("first.clf"), dir.path().join("second.clf"));
    std::fs::write(&first, &halves.0).unwrap();
    std::fs::write(&second, &halves.1).unwrap();
    let d = |p: &str| dir.path().join(p).to_string_lossy().into_owned();
    let (ok, _, err) = slam(&[
        "--carmen",
        &d("first.clf"),
        "--backend",
        "graph",
        "--save-graph",
        &d("first.g2o"),
        "--out",
        &d("a"),
    ]);
    assert!(ok, "{err}");
    assert!(dir.path().join("first.g2o.scans").exists());
    let (ok, report, err) = slam(&[
        "--carmen",
        &d("second.clf"),
        "--load-graph",
        &d("first.g2o"),
        "--localization",
        "--save-graph",
        &d("again.g2o"),
        "--out",
        &d("b"),
    ]);
    assert!(ok, "{err}");
    let (matched, line) = matched_scans(&report);
    // The second half drives on beyond the part the first half mapped (48 of
    // 100 scans matched here): where it overlaps, the saved map is found.
    assert!(matched >= 25.0, "{line}");
    for (a, b) in [
        ("a/map.pgm", "b/map.pgm"),
        ("first.g2o", "again.g2o"),
        ("first.g2o.scans", "again.g2o.scans"),
    ] {
        assert_eq!(
            std::fs::read(dir.path().join(a)).unwrap(),
            std::fs::read(dir.path().join(b)).unwrap(),
            "{a} vs {b}"
        );
    }
    // The second half's poses continue where the first half ended (no jump back to the origin).
    let traj = std::fs::read_to_string(dir.path().join("b/trajectory.txt")).unwrap();
    assert!(max_step(&traj) < 0.5, "{traj}");
    // Localisation without a saved graph is refused with the reason.
    let (ok, _, err) = slam(&[
        "--carmen",
        &d("second.clf"),
        "--localization",
        "--out",
        &d("c"),
    ]);
    assert!(!ok && err.contains("--load-graph"), "{err}");
    // A graph without its scans is refused naming the missing file.
    std::fs::remove_file(dir.path().join("first.g2o.scans")).unwrap();
    let (ok, _, err) = slam(&[
        "--carmen",
        &d("second.clf"),
        "--load-graph",
        &d("first.g2o"),
        "--out",
        &d("c"),
    ]);
    assert!(!ok && err.contains("first.g2o.scans"), "{err}");
}

/// `--reference` sampled on its own clock (a simulator's truth, ticks that
/// are not the log's stamps) is interpolated at the estimate's stamps: a
/// run's own trajectory, resampled halfway between its poses, scores a few
/// millimetres. Same-stamp pairing alone found no pose and printed no ATE.
#[test]
fn a_reference_on_its_own_clock_is_interpolated_not_refused() {
    let dir = tempfile::tempdir().unwrap();
    let log = data().join("csail-prefix-200.clf");
    let run = |out: &str, extra: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_smokenav"))
            .args([
                "slam",
                "--backend",
                "graph",
                "--carmen",
                log.to_str().unwrap(),
            ])
            .args(extra)
            .arg("--out")
            .arg(dir.path().join(out))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    run("first", &[]);
    let poses: Vec<Vec<f64>> = std::fs::read_to_string(dir.path().join("first/trajectory.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| l.split_whitespace().map(|t| t.parse().unwrap()).collect())
        .collect();
    assert!(poses.len() > 100, "{} poses", poses.len());
    let mut reference = String::from("# timestamp x y theta\n");
    for w in poses.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        if b[0] - a[0] < 0.01 || b[0] - a[0] > 0.4 {
            continue;
        }
        let dth = (b[3] - a[3] + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        reference.push_str(&format!(
            "{:.6} {:.6} {:.6} {:.6}\n",
            (a[0] + b[0]) / 2.0,
            (a[1] + b[1]) / 2.0,
            (a[2] + b[2]) / 2.0,
            a[3] + dth / 2.0
        ));
    }
    let path = dir.path().join("reference.txt");
    std::fs::write(&path, reference).unwrap();
    let report = run("second", &["--reference", path.to_str().unwrap()]);
    let (rms, line) = ate_rms(&report);
    assert!(
        line.contains("paired with the reference interpolated"),
        "{line}"
    );
    assert!(rms < 0.02, "{line}");
    // Without a ground-truth map the scans drawn at the reference are the truth.
    let map = report
        .lines()
        .find(|l| l.starts_with("map error"))
        .unwrap_or_else(|| panic!("no map error line:\n{report}"));
    assert!(map.contains("k-NN"), "{map}");
    // … and where the error lies is drawn beside the map: the run's own walls
    // lie on the walls its reference implies (black), hardly any far off
    // (phantom, magenta). A run without a truth draws no picture.
    let image = dir.path().join("second/errors.png");
    assert!(report.contains("errors.png"), "{report}");
    let png = image::open(&image).unwrap().to_rgb8();
    let count =
        |c: smokenav_algorithms_eval::ErrorClass| png.pixels().filter(|p| p.0 == c.rgb()).count();
    use smokenav_algorithms_eval::ErrorClass::{EstimateOnWall, Phantom};
    assert!(
        count(EstimateOnWall) > 20 * count(Phantom).max(1),
        "on a wall {}, phantom {}",
        count(EstimateOnWall),
        count(Phantom)
    );
    assert!(!dir.path().join("first/errors.png").exists());
    // A picture that cannot be written costs the run nothing else: the
    // report says so, the map and stats are there.
    std::fs::create_dir_all(dir.path().join("third/errors.png")).unwrap();
    let report = run("third", &["--reference", path.to_str().unwrap()]);
    assert!(report.contains("error image        not drawn"), "{report}");
    assert!(dir.path().join("third/stats.txt").exists());
    assert!(dir.path().join("third/map.yaml").exists());
}

/// A robot that starts every run from its dock: the same log localised on
/// the graph it mapped, from the saved run's first node (`--resume-at
/// first`), is matched scan after scan and follows the mapping run's poses
/// within centimetres; placed where that run ended (the default) its first
/// scan finds nothing to match (the route ends metres from its start) and
/// the pose only follows the odometry.
#[test]
fn localization_from_the_dock_starts_at_the_saved_runs_first_node() {
    let dir = tempfile::tempdir().unwrap();
    let log = data().join("csail-prefix-200.clf");
    let d = |p: &str| dir.path().join(p).to_string_lossy().into_owned();
    // `smokenav slam` on the log, run in the test's folder.
    let slam = |args: &[&str]| {
        let mut all = vec!["--carmen", log.to_str().unwrap()];
        all.extend_from_slice(args);
        let (ok, report, err) = slam_in(Some(dir.path()), &all);
        assert!(ok, "{err}");
        report
    };
    slam(&[
        "--backend",
        "graph",
        "--save-graph",
        &d("run.g2o"),
        "--out",
        &d("map"),
    ]);
    let mapped = d("map/trajectory.txt");
    let localise = |out: &str, at: &[&str]| {
        let (graph, out) = (d("run.g2o"), d(out));
        let mut args = vec![
            "--load-graph",
            graph.as_str(),
            "--localization",
            "--reference",
            mapped.as_str(),
            "--out",
            out.as_str(),
        ];
        args.extend_from_slice(at);
        let report = slam(&args);
        let (matched, loc) = matched_scans(&report);
        let (ate, _) = ate_rms(&report);
        (matched, ate, loc.to_owned())
    };
    let (matched, ate, loc) = localise("dock", &["--resume-at", "first"]);
    assert!(matched >= 190.0, "{loc}");
    assert!(ate < 0.03, "{ate} m from the mapping run: {loc}");
    // From the end nothing is found, and nothing false either: the pose
    // keeps the odometry's shape (a wide search on every lost scan matched
    // places metres off and ended 0.47 m ATE from the mapping run).
    let (matched_last, ate_last, loc_last) = localise("end", &[]);
    assert!(matched_last < 20.0, "{loc_last}");
    assert!(
        ate_last < 0.1,
        "{ate_last} m from the mapping run: {loc_last}"
    );

    // Mapping on from the dock: the first new node is tied to a saved node
    // near the start, not to the last one metres away where the run ended.
    slam(&[
        "--load-graph",
        &d("run.g2o"),
        "--resume-at",
        "first",
        "--save-graph",
        &d("again.g2o"),
        "--out",
        &d("again"),
    ]);
    let saved = std::fs::read_to_string(d("run.g2o")).unwrap();
    let n = saved
        .lines()
        .filter(|l| l.starts_with("VERTEX_SE2"))
        .count();
    let again = std::fs::read_to_string(d("again.g2o")).unwrap();
    let tie: Vec<usize> = again
        .lines()
        .filter(|l| l.starts_with("EDGE_SE2"))
        .map(|l| {
            l.split_whitespace()
                .skip(1)
                .take(2)
                .map(|t| t.parse().unwrap())
                .collect::<Vec<usize>>()
        })
        .find(|e| e[1] == n)
        .unwrap_or_else(|| panic!("no edge to vertex {n}"));
    assert!(
        tie[0] <= 2,
        "the new node is tied to vertex {} of {n}",
        tie[0]
    );

    // A path on the command line is the user's, relative to where they are
    // (only the profile's `[slam] load_graph` must be absolute).
    slam(&[
        "--load-graph",
        "run.g2o",
        "--localization",
        "--max-scans",
        "5",
        "--out",
        "relative",
    ]);
}

/// The vote keeps a pose graph in its graph member: `--save-graph` writes
/// it, and a graph back-end localises on it; a back-end without a graph
/// (the particle filter) is refused with the reason.
#[test]
fn the_votes_graph_member_is_saved_and_localised_on() {
    let dir = tempfile::tempdir().unwrap();
    let d = |p: &str| dir.path().join(p).to_string_lossy().into_owned();
    let log = data().join("csail-prefix-200.clf");
    let log = log.to_str().unwrap();
    let (ok, report, err) = slam(&[
        "--carmen",
        log,
        "--backend",
        "vote",
        "--particles",
        "5",
        "--save-graph",
        &d("vote.g2o"),
        "--out",
        &d("vote"),
    ]);
    assert!(ok, "{err}");
    assert!(report.contains("pose graph"), "{report}");
    let (ok, report, err) = slam(&[
        "--carmen",
        log,
        "--load-graph",
        &d("vote.g2o"),
        "--localization",
        "--resume-at",
        "first",
        "--out",
        &d("loc"),
    ]);
    assert!(ok, "{err}");
    let (matched, line) = matched_scans(&report);
    assert!(matched >= 150.0, "{line}");
    let (ok, _, err) = slam(&[
        "--carmen",
        log,
        "--backend",
        "rbpf",
        "--save-graph",
        &d("rbpf.g2o"),
        "--out",
        &d("rbpf"),
    ]);
    assert!(!ok && err.contains("keep a pose graph"), "{err}");
}
