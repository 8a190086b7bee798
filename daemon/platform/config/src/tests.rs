use super::*;
use std::path::PathBuf;

fn profile(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../config")
        .join(name)
}

fn pioneer_text() -> String {
    std::fs::read_to_string(profile("pioneer-3dx.toml")).unwrap()
}

fn parse(text: &str) -> Result<RobotConfig, ConfigError> {
    RobotConfig::parse(text, Path::new("config/test-robot.toml"))
}

#[test]
fn shipped_profiles_are_valid() {
    for name in ["pioneer-3dx.toml", "nomad-scout.toml"] {
        let path = profile(name);
        let text = std::fs::read_to_string(&path).unwrap();
        let cfg = RobotConfig::parse(&text, &path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(cfg.sonar.transducers.len(), cfg.sonar.count as usize);
    }
}

#[test]
fn builtin_profiles_are_the_shipped_files() {
    for (name, _) in BUILTIN_PROFILES {
        let file = profile(&format!("{name}.toml"));
        let shipped = RobotConfig::parse(&std::fs::read_to_string(&file).unwrap(), &file).unwrap();
        assert_eq!(RobotConfig::builtin(name).unwrap(), shipped);
    }
    let err = RobotConfig::builtin("pioneer-2").unwrap_err().to_string();
    assert!(
        err.contains("pioneer-2") && err.contains("pioneer-3dx, nomad-scout"),
        "{err}"
    );
}

#[test]
fn pioneer_sonar_poses_are_arias() {
    let cfg = parse(&pioneer_text()).unwrap();
    let s3 = cfg.sonar.transducer(3).unwrap();
    assert_eq!((s3.x, s3.y, s3.yaw_deg), (0.166, 0.027, 10.0));
    assert_eq!(cfg.robot.platform, Platform::Pioneer);
}

#[test]
fn unknown_key_names_file_key_and_reason() {
    let text = pioneer_text().replace(
        "stall_timeout_s = 1.0",
        "stall_timeout_s = 1.0\nscan_hz = 10",
    );
    let err = parse(&text).unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("config/test-robot.toml"), "{msg}");
    assert!(
        msg.contains("laser.scan_hz") || msg.contains("`scan_hz`"),
        "{msg}"
    );
    assert!(msg.contains("unknown field"), "{msg}");
    // and the line of the offending key
    let ConfigError::Parse { line, .. } = err else {
        panic!("expected a parse error, got {err:?}")
    };
    let expected = text.lines().position(|l| l.starts_with("scan_hz")).unwrap() + 1;
    assert_eq!(line, expected);
}

#[test]
fn negative_rate_names_file_key_and_reason() {
    let text = pioneer_text().replace(
        "rate_hz = 10.0\n\n[base.pioneer]",
        "rate_hz = -10.0\n\n[base.pioneer]",
    );
    assert!(text.contains("rate_hz = -10.0"));
    let err = parse(&text).unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("config/test-robot.toml"), "{msg}");
    assert_eq!(err.keys(), vec!["base.rate_hz"], "{msg}");
    assert!(msg.contains("-10"), "{msg}");
}

#[test]
fn a_frame_id_longer_than_the_wire_field_is_refused() {
    // 33 bytes: one more than a message header's frame_id holds.
    let long = "hokuyo_urg_04lx_front_mount_laser";
    assert_eq!(long.len(), 33);
    let text = pioneer_text().replace("frame_id = \"laser\"", &format!("frame_id = \"{long}\""));
    let err = parse(&text).unwrap_err();
    let msg = err.to_string();
    assert_eq!(err.keys(), vec!["laser.frame_id"], "{msg}");
    assert!(
        msg.contains("at most 32 bytes") && msg.contains("33"),
        "{msg}"
    );
    // 32 bytes still fit.
    let text = pioneer_text().replace(
        "frame_id = \"laser\"",
        &format!("frame_id = \"{}\"", &long[..32]),
    );
    parse(&text).unwrap();
}

/// 1-based line of the first line of `text` starting with `prefix` (after indentation).
fn line_starting(text: &str, prefix: &str) -> usize {
    text.lines()
        .position(|l| l.trim_start().starts_with(prefix))
        .unwrap_or_else(|| panic!("no line starts with {prefix:?}"))
        + 1
}

#[test]
fn invalid_value_names_its_line() {
    let text = pioneer_text().replace("cone_deg = 15.0", "cone_deg = 0.0");
    let err = parse(&text).unwrap_err();
    let ConfigError::Invalid { issues, .. } = &err else {
        panic!("expected invalid values, got {err:?}")
    };
    let line = line_starting(&text, "cone_deg = 0.0");
    assert_eq!(issues[0].line, Some(line));
    assert!(
        err.to_string().starts_with(&format!(
            "config/test-robot.toml:{line}: key `sonar.cone_deg`: "
        )),
        "{err}"
    );
}

#[test]
fn invalid_array_element_names_the_elements_line() {
    let text = pioneer_text().replace(
        "{ index = 5, x = 0.148, y = -0.078, yaw_deg = -30.0 }",
        "{ index = 5, x = 0.148, y = -0.078, yaw_deg = -390.0 }",
    );
    let err = parse(&text).unwrap_err();
    assert_eq!(err.keys(), vec!["sonar.transducers[5].yaw_deg"], "{err}");
    let line = line_starting(&text, "{ index = 5,");
    assert!(
        err.to_string()
            .starts_with(&format!("config/test-robot.toml:{line}: ")),
        "{err}"
    );
}

#[test]
fn a_default_that_no_longer_fits_names_its_tables_line() {
    // The inter-message bounds keep their default 0.05 s, now above the timeout.
    let text = pioneer_text().replace(
        "[fusion]\nmethod = \"v2\"\nsonar_cap_m = 2.5\n",
        "[fusion]\nmethod = \"v2\"\nsonar_cap_m = 2.5\n\n[fusion.sync]\ntimeout_s = 0.04\n",
    );
    let err = parse(&text).unwrap_err();
    let ConfigError::Invalid { issues, .. } = &err else {
        panic!("expected invalid values, got {err:?}")
    };
    let laser = issues
        .iter()
        .find(|i| i.key == "fusion.sync.laser_min_period_s")
        .unwrap_or_else(|| panic!("{err}"));
    assert_eq!(laser.line, Some(line_starting(&text, "[fusion.sync]")));
}

#[test]
fn key_line_follows_tables_arrays_and_inline_tables() {
    let text = "a = 1\n[b]\nc = [\n  { d = 2 },\n  { d = 3, e = 4 },\n]\n[b.f]\ng = 5\n";
    assert_eq!(key_line(text, "a"), Some(1));
    assert_eq!(key_line(text, "b"), Some(2));
    assert_eq!(key_line(text, "b.c"), Some(3));
    assert_eq!(key_line(text, "b.c[1].e"), Some(5));
    assert_eq!(
        key_line(text, "b.c[9].e"),
        Some(3),
        "missing element: its array"
    );
    assert_eq!(key_line(text, "b.f.g"), Some(8));
    assert_eq!(key_line(text, "b.f.h"), Some(7), "missing key: its table");
    assert_eq!(key_line(text, "z"), None);
    assert_eq!(key_line("not toml [", "a"), None);
}

#[test]
fn missing_sonar_pose_names_the_index() {
    let text = pioneer_text().replace(
        "  { index = 5, x = 0.148, y = -0.078, yaw_deg = -30.0 },\n",
        "",
    );
    let err = parse(&text).unwrap_err();
    let msg = err.to_string();
    assert_eq!(err.keys(), vec!["sonar.transducers"], "{msg}");
    assert!(msg.contains("[5]"), "{msg}");
}

#[test]
fn wrong_type_names_key() {
    let text = pioneer_text().replace("cone_deg = 15.0", "cone_deg = \"wide\"");
    let err = parse(&text).unwrap_err();
    assert_eq!(err.keys(), vec!["sonar.cone_deg"], "{err}");
}

#[test]
fn missing_required_section_is_reported() {
    let text = pioneer_text();
    let cut = text.find("[smoke]").unwrap();
    let end = text.find("[fusion]").unwrap();
    let text = format!("{}{}", &text[..cut], &text[end..]);
    let err = parse(&text).unwrap_err().to_string();
    assert!(err.contains("smoke"), "{err}");
}

#[test]
fn all_issues_are_listed_at_once() {
    let text = pioneer_text()
        .replace("cone_deg = 15.0", "cone_deg = 0.0")
        .replace("port = \"/dev/hokuyo\"", "port = \"tcp://nohost\"");
    let err = parse(&text).unwrap_err();
    let keys = err.keys();
    assert!(
        keys.contains(&"sonar.cone_deg") && keys.contains(&"laser.port"),
        "{keys:?}"
    );
}

#[test]
fn scout_profile_needs_scout_options() {
    let text = std::fs::read_to_string(profile("nomad-scout.toml")).unwrap();
    let start = text.find("[base.scout]").unwrap();
    let end = text.find("[sonar]").unwrap();
    let text = format!("{}{}", &text[..start], &text[end..]);
    let err = parse(&text).unwrap_err();
    assert_eq!(err.keys(), vec!["base.scout"], "{err}");
}

#[test]
fn effective_config_round_trips() {
    let cfg = parse(&pioneer_text()).unwrap();
    let again = parse(&cfg.to_toml()).unwrap();
    assert_eq!(cfg, again);
}

#[test]
fn unreadable_file_names_the_path() {
    let err = RobotConfig::load(Path::new("/nonexistent/robot.toml")).unwrap_err();
    assert!(err.to_string().contains("/nonexistent/robot.toml"));
}

mod props {
    //! Profiles from the outside world: whatever the text, `parse` returns a
    //! profile or a typed error that names a key, and never panics.
    use super::*;
    use proptest::prelude::*;

    /// Values a hand-edited or damaged file may hold where a number, string,
    /// flag, table or array was expected.
    fn value() -> impl Strategy<Value = String> {
        prop_oneof![
            any::<f64>().prop_map(|v| format!("{v:?}")),
            any::<i64>().prop_map(|v| v.to_string()),
            Just("nan".to_owned()),
            Just("-inf".to_owned()),
            Just("1e309".to_owned()),
            Just("18446744073709551616".to_owned()),
            "\"[^\"\\\\]{0,12}\"".prop_map(|s| s),
            any::<bool>().prop_map(|b| b.to_string()),
            Just("[]".to_owned()),
            Just("{}".to_owned()),
            Just("[1, \"a\", true]".to_owned()),
            Just("{ a = 1 }".to_owned()),
        ]
    }

    /// The shipped profile with the value of its `line`-th `key = value` line replaced.
    fn mutated(text: &str, line: usize, new: &str) -> String {
        let assignments: Vec<usize> = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim_start().starts_with('#') && l.contains(" = "))
            .map(|(i, _)| i)
            .collect();
        let target = assignments[line % assignments.len()];
        text.lines()
            .enumerate()
            .map(|(i, l)| match l.split_once(" = ") {
                Some((k, _)) if i == target && !l.trim_start().starts_with('{') => {
                    format!("{k} = {new}")
                }
                _ => l.to_owned(),
            })
            .collect::<Vec<_>>()
            .join("\n")
    }

    fn outcome_names_a_key(r: &Result<RobotConfig, ConfigError>) -> Result<(), TestCaseError> {
        if let Err(e) = r {
            prop_assert!(!e.keys().is_empty(), "no key in {e:?}");
            prop_assert!(e.keys().iter().all(|k| !k.is_empty()), "{e:?}");
        }
        Ok(())
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(1500))]

        #[test]
        fn a_mutated_value_gives_a_profile_or_an_error_naming_a_key(
            shipped in 0usize..2,
            line in 0usize..1000,
            new in value(),
        ) {
            let text = BUILTIN_PROFILES[shipped].1;
            let r = parse(&mutated(text, line, &new));
            outcome_names_a_key(&r)?;
        }

        #[test]
        fn arbitrary_text_gives_a_profile_or_an_error_naming_a_key(text in "\\PC{0,300}") {
            outcome_names_a_key(&parse(&text))?;
        }

        #[test]
        fn damaged_bytes_give_a_profile_or_an_error_naming_a_key(
            shipped in 0usize..2,
            at in 0usize..4000,
            cut in 0usize..40,
            insert in "[\\[\\]{}=\"#.,\n a-z0-9]{0,8}",
        ) {
            let text = BUILTIN_PROFILES[shipped].1;
            let mut s: Vec<char> = text.chars().collect();
            let at = at % s.len();
            let cut = cut.min(s.len() - at);
            s.splice(at..at + cut, insert.chars());
            outcome_names_a_key(&parse(&s.into_iter().collect::<String>()))?;
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(300))]

        /// Whatever valid profile a mutation produced, `to_toml` writes it so
        /// that it loads back the same.
        #[test]
        fn a_valid_profile_round_trips_through_to_toml(
            shipped in 0usize..2,
            line in 0usize..1000,
            new in value(),
        ) {
            let text = BUILTIN_PROFILES[shipped].1;
            if let Ok(cfg) = parse(&mutated(text, line, &new)) {
                let back = parse(&cfg.to_toml()).map_err(|e| TestCaseError::fail(e.to_string()))?;
                prop_assert_eq!(back, cfg);
            }
        }
    }

    #[test]
    fn shipped_profiles_round_trip_through_to_toml() {
        for (name, _) in BUILTIN_PROFILES {
            let cfg = RobotConfig::builtin(name).unwrap();
            assert_eq!(parse(&cfg.to_toml()).unwrap(), cfg, "{name}");
        }
    }
}

#[test]
fn fuzzy_sonar_cone_comes_from_the_robot_unless_given() {
    let cfg = parse(&pioneer_text()).unwrap();
    assert_eq!(cfg.slam.fuzzy.sonar_cone_deg, Some(cfg.sonar.cone_deg));
    let text = format!("{}\n[slam.fuzzy]\nsonar_cone_deg = 30.0\n", pioneer_text());
    let cfg = parse(&text).unwrap();
    assert_eq!(cfg.slam.fuzzy.sonar_cone_deg, Some(30.0));
}

#[test]
fn mapping_defaults_to_bayes_at_five_centimetres() {
    let cfg = parse(&pioneer_text()).unwrap();
    assert_eq!(cfg.mapping.rule, crate::MappingRule::Bayes);
    assert_eq!(cfg.mapping.resolution_m, 0.05);
    let cfg = parse(&format!(
        "{}\n[mapping]\nrule = \"iop\"\nresolution_m = 0.1\n",
        pioneer_text()
    ))
    .unwrap();
    assert_eq!(cfg.mapping.rule, crate::MappingRule::Iop);
    assert_eq!(cfg.mapping.resolution_m, 0.1);
}

#[test]
fn mapping_keys_are_strict() {
    let text = format!("{}\n[mapping]\nresolution = 0.1\n", pioneer_text());
    let msg = parse(&text).unwrap_err().to_string();
    assert!(msg.contains("unknown field"), "{msg}");
    assert!(msg.contains("resolution"), "{msg}");
    let text = format!("{}\n[mapping]\nrule = \"average\"\n", pioneer_text());
    let msg = parse(&text).unwrap_err().to_string();
    assert!(msg.contains("mapping.rule"), "{msg}");
    let text = format!("{}\n[mapping]\nresolution_m = 0.001\n", pioneer_text());
    let msg = parse(&text).unwrap_err().to_string();
    assert!(msg.contains("mapping.resolution_m"), "{msg}");
    let text = format!(
        "{}\n[mapping]\nresolution_m = 0.01\nsize_m = 100.0\n",
        pioneer_text()
    );
    let msg = parse(&text).unwrap_err().to_string();
    assert!(msg.contains("mapping.size_m"), "{msg}");
}

#[test]
fn mapping_heights_and_save_folder_are_keys() {
    let cfg = parse(&pioneer_text()).unwrap();
    let m = &cfg.mapping;
    assert_eq!(
        (m.laser_height_m, m.sonar_height_m, m.robot_height_m),
        (0.40, 0.30, 0.60)
    );
    assert_eq!(m.map_dir, None);
    let cfg = parse(&format!(
        "{}\n[mapping]\nrobot_height_m = 1.2\nlaser_height_m = 0.25\nmap_dir = \"/tmp/oct\"\n",
        pioneer_text()
    ))
    .unwrap();
    assert_eq!(cfg.mapping.robot_height_m, 1.2);
    assert_eq!(cfg.mapping.laser_height_m, 0.25);
    assert_eq!(cfg.mapping.map_dir.as_deref(), Some("/tmp/oct"));
    // Written back and read again: the same section.
    assert_eq!(parse(&cfg.to_toml()).unwrap().mapping, cfg.mapping);
    let text = format!("{}\n[mapping]\nrobot_height_m = 0.0\n", pioneer_text());
    let msg = parse(&text).unwrap_err().to_string();
    assert!(msg.contains("mapping.robot_height_m"), "{msg}");
    let text = format!("{}\n[mapping]\nmap_dir = \"\"\n", pioneer_text());
    let msg = parse(&text).unwrap_err().to_string();
    assert!(msg.contains("mapping.map_dir"), "{msg}");
    assert_eq!(
        cfg.mapping.climb_height_m, 0.0,
        "nothing to climb unless said"
    );
    let text = format!("{}\n[mapping]\nclimb_height_m = -0.1\n", pioneer_text());
    let msg = parse(&text).unwrap_err().to_string();
    assert!(msg.contains("mapping.climb_height_m"), "{msg}");
}

#[test]
fn zenoh_defaults_are_loopback_without_multicast() {
    let cfg = parse(&pioneer_text()).unwrap();
    let z = &cfg.zenoh;
    assert_eq!(z.mode, crate::ZenohMode::Peer);
    assert!(!z.multicast_scouting);
    assert!(!z.cmd_vel);
    assert_eq!(z.listen, ["tcp/127.0.0.1:0"]);
    assert_eq!(z.connect, ["tcp/127.0.0.1:7447"]);
    let cfg = parse(&format!(
        "{}\n[zenoh]\nmode = \"client\"\nconnect = [\"tcp/10.0.0.2:7447\"]\nnamespace = \"/robot1\"\ntopics = [\"laser/scan\", \"health/slam\"]\n",
        pioneer_text()
    ))
    .unwrap();
    assert_eq!(cfg.zenoh.mode, crate::ZenohMode::Client);
    assert_eq!(cfg.zenoh.namespace, "/robot1");
}

#[test]
fn zenoh_keys_are_strict_and_name_the_problem() {
    let bad = |section: &str, key: &str| {
        let text = format!("{}\n[zenoh]\n{section}\n", pioneer_text());
        let msg = parse(&text).unwrap_err().to_string();
        assert!(msg.contains(key), "{section}: {msg}");
        msg
    };
    assert!(bad("multicast = true", "multicast").contains("unknown field"));
    assert!(
        bad("listen = [\"udp/127.0.0.1:7447\"]", "zenoh.listen").contains("only tcp/HOST:PORT")
    );
    bad("connect = [\"tcp/127.0.0.1\"]", "zenoh.connect");
    bad("namespace = \"robot1\"", "zenoh.namespace");
    bad("namespace = \"/1robot\"", "zenoh.namespace");
    bad("domain_id = 300", "zenoh.domain_id");
    assert!(bad("topics = [\"laser/scans\"]", "zenoh.topics").contains("laser/scans"));
    bad("mode = \"client\"\nconnect = []", "zenoh.connect");
    bad("mode = \"router\"", "zenoh.mode");
}

#[test]
fn keep_uncontradicted_laser_is_on_by_default_and_can_be_turned_off() {
    assert!(
        parse(&pioneer_text())
            .unwrap()
            .fusion
            .v2
            .keep_uncontradicted_laser
    );
    let cfg = parse(&format!(
        "{}\n[fusion.v2]\nkeep_uncontradicted_laser = false\n",
        pioneer_text()
    ))
    .unwrap();
    assert!(!cfg.fusion.v2.keep_uncontradicted_laser);
    let err = parse(&format!(
        "{}\n[fusion.v2]\nkeep_uncontradicted_laser = 1\n",
        pioneer_text()
    ))
    .unwrap_err();
    assert!(
        err.to_string().contains("keep_uncontradicted_laser"),
        "{err}"
    );
}

#[test]
fn speck_max_beams_is_read_and_bounded() {
    let cfg = parse(&format!(
        "{}\n[fusion.v2]\nspeck_max_beams = 0\n",
        pioneer_text()
    ))
    .unwrap();
    assert_eq!(cfg.fusion.v2.speck_max_beams, 0);
    let err = parse(&format!(
        "{}\n[fusion.v2]\nspeck_max_beams = 40\n",
        pioneer_text()
    ))
    .unwrap_err();
    let msg = err.to_string();
    assert_eq!(err.keys(), vec!["fusion.v2.speck_max_beams"], "{msg}");
    assert!(msg.contains("40"), "{msg}");
}

#[test]
fn deskewing_is_on_by_default_and_can_be_turned_off() {
    assert!(parse(&pioneer_text()).unwrap().slam.deskew);
    let off = pioneer_text().replace("[slam]\n", "[slam]\ndeskew = false\n");
    assert!(!parse(&off).unwrap().slam.deskew);
    let err = parse(&pioneer_text().replace("[slam]\n", "[slam]\ndeskew = 1\n")).unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("deskew") && msg.contains("config/test-robot.toml"),
        "{msg}"
    );
}

#[test]
fn the_footprint_is_cleared_by_default_and_can_be_turned_off() {
    let on = parse(&pioneer_text()).unwrap();
    assert!(on.slam.clear_footprint);
    assert!(on.robot.radius_m > 0.1, "{}", on.robot.radius_m);
    let off = pioneer_text().replace("[slam]\n", "[slam]\nclear_footprint = false\n");
    assert!(!parse(&off).unwrap().slam.clear_footprint);
    let err = parse(&pioneer_text().replace("[slam]\n", "[slam]\nclear_footprint = \"yes\"\n"))
        .unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("clear_footprint") && msg.contains("config/test-robot.toml"),
        "{msg}"
    );
    // The Pioneer is longer than wide: its profile gives the inscribed radius.
    assert_eq!(on.slam.footprint_radius_m, 0.185);
    assert_eq!(
        SlamSection::default().footprint_radius_m,
        0.0,
        "0: the robot's radius"
    );
    let err =
        parse(&pioneer_text().replace("footprint_radius_m = 0.185", "footprint_radius_m = 5.0"))
            .unwrap_err();
    assert_eq!(err.keys(), vec!["slam.footprint_radius_m"], "{err}");
}

#[test]
fn particle_filter_threads_default_to_one_per_core_and_are_bounded() {
    assert_eq!(parse(&pioneer_text()).unwrap().slam.threads, 0);
    let two = pioneer_text().replace("[slam]\n", "[slam]\nthreads = 2\n");
    assert_eq!(parse(&two).unwrap().slam.threads, 2);
    let err = parse(&pioneer_text().replace("[slam]\n", "[slam]\nthreads = 1000\n")).unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("slam.threads") && msg.contains("config/test-robot.toml"),
        "{msg}"
    );
}

#[test]
fn the_largest_map_published_is_a_key_and_bounded() {
    assert_eq!(parse(&pioneer_text()).unwrap().slam.max_map_cells, 1 << 25);
    let small = pioneer_text().replace("[slam]\n", "[slam]\nmax_map_cells = 4000000\n");
    assert_eq!(parse(&small).unwrap().slam.max_map_cells, 4_000_000);
    for bad in ["10", "2000000000"] {
        let err =
            parse(&pioneer_text().replace("[slam]\n", &format!("[slam]\nmax_map_cells = {bad}\n")))
                .unwrap_err();
        assert_eq!(err.keys(), vec!["slam.max_map_cells"], "{err}");
        assert!(err.to_string().contains(&format!("got {bad}")), "{err}");
    }
}
