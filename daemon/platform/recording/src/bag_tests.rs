//! rosbag2-shaped files written here (MCAP by the mcap crate, `.db3` by
//! SQLite with rosbag2's tables), read back; damaged ones must give errors
//! that name the file, topic and message, never a panic.

use super::*;
use crate::codec::{Transform2, encode_laser_scan, encode_odometry, encode_tf_message};
use mcap::records::MessageHeader;
use smokenav_shared_types::{BeamReading, Header, Odometry};
use std::collections::BTreeMap;

fn scan(i: u64) -> LaserScan {
    let mut s = LaserScan {
        header: Header::new(
            1_700_000_000_000_000_000 + i * 100_000_000,
            0,
            "laser_frame",
        ),
        angle_min: -1.5,
        angle_increment: 0.01,
        scan_time: 0.1,
        range_min: 0.05,
        range_max: 8.0,
        count: 300,
        ..Default::default()
    };
    for b in 0..300 {
        s.set_beam(
            b,
            if b % 17 == 0 {
                BeamReading::NoReturn
            } else {
                BeamReading::Range(1.0 + b as f32 * 0.01)
            },
        );
    }
    s
}

fn odom(i: u64) -> Odometry {
    Odometry {
        header: Header::new(1_700_000_000_000_000_000 + i * 50_000_000, 0, "odom"),
        x: i as f64 * 0.01,
        y: 0.5,
        theta: 0.25,
        ..Default::default()
    }
}

/// (topic, type, log time, CDR) in receive order: tf_static, then odometry at
/// 20 Hz and scans at 10 Hz, and a topic smokenav does not read.
fn messages(laser_topics: &[&str]) -> Vec<(String, &'static str, u64, Vec<u8>)> {
    let mut out = Vec::new();
    let mut tf = Vec::new();
    encode_tf_message(
        &[Transform2 {
            stamp_ns: 1_700_000_000_000_000_000,
            parent: "base_link",
            child: "laser_frame",
            x: 0.2,
            y: 0.0,
            yaw: 0.1,
        }],
        &mut tf,
    );
    out.push((
        TF_STATIC_TOPIC.to_owned(),
        TF_TYPE,
        1_700_000_000_000_000_000,
        tf,
    ));
    for i in 0..20u64 {
        let mut b = Vec::new();
        encode_odometry(&odom(i), &mut b);
        out.push((
            "/odom".into(),
            ODOMETRY_TYPE,
            odom(i).header.stamp_ns + 1_000,
            b,
        ));
        if i % 2 == 0 {
            for t in laser_topics {
                let mut b = Vec::new();
                encode_laser_scan(&scan(i / 2), &mut b);
                out.push((
                    t.to_string(),
                    LASER_SCAN_TYPE,
                    scan(i / 2).header.stamp_ns + 2_000,
                    b,
                ));
            }
            out.push((
                "/camera/info".into(),
                "sensor_msgs/msg/CameraInfo",
                odom(i).header.stamp_ns,
                vec![0, 1, 0, 0],
            ));
        }
    }
    out
}

fn write_mcap(path: &Path, msgs: &[(String, &'static str, u64, Vec<u8>)]) {
    write_mcap_compressed(path, msgs, Some(mcap::Compression::Zstd));
}

fn write_mcap_compressed(
    path: &Path,
    msgs: &[(String, &'static str, u64, Vec<u8>)],
    compression: Option<mcap::Compression>,
) {
    let f = std::fs::File::create(path).unwrap();
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .compression(compression)
        .chunk_size(Some(4096))
        .create(std::io::BufWriter::new(f))
        .unwrap();
    let mut channels: BTreeMap<String, u16> = BTreeMap::new();
    for (seq, (topic, ty, t, data)) in msgs.iter().enumerate() {
        let id = match channels.get(topic) {
            Some(&id) => id,
            None => {
                let schema = w.add_schema(ty, "ros2msg", b"").unwrap();
                let id = w
                    .add_channel(schema, topic, "cdr", &BTreeMap::new())
                    .unwrap();
                channels.insert(topic.clone(), id);
                id
            }
        };
        w.write_to_known_channel(
            &MessageHeader {
                channel_id: id,
                sequence: seq as u32,
                log_time: *t,
                publish_time: *t,
            },
            data,
        )
        .unwrap();
    }
    w.finish().unwrap();
}

fn write_db3(path: &Path, msgs: &[(String, &'static str, u64, Vec<u8>)]) {
    let c = rusqlite::Connection::open(path).unwrap();
    c.execute_batch(
        "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL, \
         serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);
         CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, \
         timestamp INTEGER NOT NULL, data BLOB NOT NULL);",
    )
    .unwrap();
    let mut ids: BTreeMap<String, i64> = BTreeMap::new();
    for (topic, ty, t, data) in msgs {
        let n = ids.len() as i64 + 1;
        let id = *ids.entry(topic.clone()).or_insert_with(|| {
            c.execute(
                "INSERT INTO topics VALUES (?1, ?2, ?3, 'cdr', '')",
                rusqlite::params![n, topic, ty],
            )
            .unwrap();
            n
        });
        c.execute(
            "INSERT INTO messages(topic_id, timestamp, data) VALUES (?1, ?2, ?3)",
            rusqlite::params![id, *t as i64, data],
        )
        .unwrap();
    }
}

fn write_folder(dir: &Path, storage: &str, file: &str) {
    let yaml = format!(
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: {storage}\n  \
         relative_file_paths:\n    - {file}\n  compression_format: ''\n  compression_mode: ''\n"
    );
    std::fs::write(dir.join("metadata.yaml"), yaml).unwrap();
}

fn read_all(bag: &Bag, roles: &RoleMap) -> Result<Vec<Played>, BagError> {
    let mut m = bag.messages(roles)?;
    let mut out = Vec::new();
    while let Some(p) = m.read_next()? {
        out.push(p);
    }
    Ok(out)
}

fn check_standard_bag(bag: &Bag) {
    let roles = bag.laser_and_odometry(&RoleRequest::default()).unwrap();
    assert_eq!(roles.laser.as_deref(), Some("/scan"));
    assert_eq!(roles.odom.as_deref(), Some("/odom"));
    let frames = bag.frames(&roles).unwrap();
    assert_eq!(frames.laser_frame.as_deref(), Some("laser_frame"));
    assert_eq!(frames.base_frame.as_deref(), Some("base_link"));
    let (x, y, yaw) = frames.laser_mount().unwrap();
    assert!((x - 0.2).abs() < 1e-12 && y.abs() < 1e-12 && (yaw - 0.1).abs() < 1e-12);
    let played = read_all(bag, &roles).unwrap();
    assert_eq!(played.len(), 30);
    // Receive order, and each message as it was sent.
    assert!(played.windows(2).all(|w| w[0].log_time <= w[1].log_time));
    let scans: Vec<&LaserScan> = played
        .iter()
        .filter_map(|p| match &p.message {
            AnyMessage::LaserScan(s) if p.topic == "laser/scan" => Some(&**s),
            _ => None,
        })
        .collect();
    assert_eq!(scans.len(), 10);
    let want = scan(3);
    assert_eq!(scans[3].header.stamp_ns, want.header.stamp_ns);
    assert_eq!(scans[3].len(), 300);
    assert!((0..300).all(|b| scans[3].beam(b) == want.beam(b)));
    let odoms = played
        .iter()
        .filter(|p| p.topic == "base/odom" && matches!(p.message, AnyMessage::Odometry(_)))
        .count();
    assert_eq!(odoms, 20);
}

#[test]
fn rosbag2_mcap_file_and_folder_read_with_roles_guessed_by_type() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run_0.mcap");
    write_mcap(&path, &messages(&["/scan"]));
    let bag = Bag::open(&path).unwrap();
    assert_eq!(bag.storage(), Storage::Mcap);
    assert!(!bag.is_smokenav());
    assert_eq!(
        bag.topics()
            .iter()
            .find(|t| t.name == "/scan")
            .unwrap()
            .messages,
        Some(10)
    );
    check_standard_bag(&bag);
    write_folder(dir.path(), "mcap", "run_0.mcap");
    check_standard_bag(&Bag::open(dir.path()).unwrap());
}

/// MCAP writers other than rosbag2's presets (zstd or none) compress chunks
/// with lz4: such a bag was refused with "Unsupported compression format".
#[test]
fn mcap_chunks_compressed_with_lz4_or_not_at_all_are_read() {
    let dir = tempfile::tempdir().unwrap();
    for (name, compression) in [
        ("lz4.mcap", Some(mcap::Compression::Lz4)),
        ("plain.mcap", None),
    ] {
        let path = dir.path().join(name);
        write_mcap_compressed(&path, &messages(&["/scan"]), compression);
        check_standard_bag(&Bag::open(&path).unwrap());
    }
}

#[test]
fn rosbag2_sqlite3_file_and_folder_read_with_roles_guessed_by_type() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run_0.db3");
    write_db3(&path, &messages(&["/scan"]));
    let bag = Bag::open(&path).unwrap();
    assert_eq!(bag.storage(), Storage::Sqlite3);
    check_standard_bag(&bag);
    write_folder(dir.path(), "sqlite3", "run_0.db3");
    check_standard_bag(&Bag::open(dir.path()).unwrap());
}

#[test]
fn two_laser_topics_need_a_choice_and_the_error_lists_them() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("two.mcap");
    write_mcap(&path, &messages(&["/front/scan", "/rear/scan"]));
    let bag = Bag::open(&path).unwrap();
    let e = bag.roles(&RoleRequest::default()).unwrap_err().to_string();
    assert!(
        e.contains("/front/scan, /rear/scan") && e.contains("--laser"),
        "{e}"
    );
    let roles = bag
        .laser_and_odometry(&RoleRequest {
            laser: Some("rear/scan".into()),
            ..Default::default()
        })
        .unwrap();
    assert_eq!(roles.laser.as_deref(), Some("/rear/scan"));
    assert_eq!(read_all(&bag, &roles).unwrap().len(), 30);
    let e = bag
        .roles(&RoleRequest {
            laser: Some("/odom".into()),
            ..Default::default()
        })
        .unwrap_err()
        .to_string();
    assert!(e.contains("carries nav_msgs/msg/Odometry"), "{e}");
    let e = bag
        .roles(&RoleRequest {
            laser: Some("/nope".into()),
            ..Default::default()
        })
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("no such topic") && e.contains("/front/scan (sensor_msgs/msg/LaserScan)"),
        "{e}"
    );
}

#[test]
fn a_damaged_message_names_file_topic_and_index() {
    let dir = tempfile::tempdir().unwrap();
    let mut msgs = messages(&["/scan"]);
    // The 5th scan (index 4) claims more beams than it holds.
    let (_, _, _, data) = msgs.iter_mut().filter(|m| m.0 == "/scan").nth(4).unwrap();
    let at = data.len() - 300 * 4 - 4 - 4;
    data[at..at + 4].copy_from_slice(&5000u32.to_le_bytes());
    for (name, write) in [
        (
            "bad.mcap",
            write_mcap as fn(&Path, &[(String, &'static str, u64, Vec<u8>)]),
        ),
        ("bad.db3", write_db3),
    ] {
        let path = dir.path().join(name);
        write(&path, &msgs);
        let bag = Bag::open(&path).unwrap();
        let roles = bag.laser_and_odometry(&RoleRequest::default()).unwrap();
        let e = read_all(&bag, &roles).unwrap_err();
        assert!(
            matches!(&e, BagError::Decode { topic, index: 4, .. } if topic == "/scan"),
            "{e}"
        );
        let text = e.to_string();
        assert!(
            text.contains(name) && text.contains("topic /scan, message 4"),
            "{text}"
        );
    }
}

#[test]
fn compressed_or_unknown_storage_folders_are_refused_by_key() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n  \
         relative_file_paths: [a.mcap.zstd]\n  compression_format: zstd\n  compression_mode: FILE\n",
    )
    .unwrap();
    let e = Bag::open(dir.path()).unwrap_err().to_string();
    assert!(e.contains("metadata.yaml") && e.contains("zstd"), "{e}");
    std::fs::write(
        dir.path().join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: rosbag_v1\n  relative_file_paths: [a]\n",
    )
    .unwrap();
    let e = Bag::open(dir.path()).unwrap_err().to_string();
    assert!(e.contains("key storage_identifier"), "{e}");
    std::fs::write(
        dir.path().join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  storage_identifier: mcap\n  relative_file_paths: [../../etc/passwd]\n",
    )
    .unwrap();
    let e = Bag::open(dir.path()).unwrap_err().to_string();
    assert!(e.contains("outside the bag folder"), "{e}");
    std::fs::write(
        dir.path().join("metadata.yaml"),
        "rosbag2_bagfile_information: [\n",
    )
    .unwrap();
    let e = Bag::open(dir.path()).unwrap_err().to_string();
    assert!(e.contains("metadata.yaml: line"), "{e}");
    let e = Bag::open(&dir.path().join("metadata.yaml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("neither an MCAP file"), "{e}");
}

/// Every prefix-cut and many byte flips of both storages: errors, never panics.
#[test]
fn damaged_bags_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let msgs = messages(&["/scan"]);
    let good_mcap = dir.path().join("good.mcap");
    let good_db3 = dir.path().join("good.db3");
    write_mcap(&good_mcap, &msgs);
    write_db3(&good_db3, &msgs);
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut rand = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    for good in [&good_mcap, &good_db3] {
        let bytes = std::fs::read(good).unwrap();
        let bad = dir.path().join(format!(
            "bad.{}",
            good.extension().unwrap().to_string_lossy()
        ));
        for k in 0..120 {
            let mut b = bytes.clone();
            if k % 4 == 0 {
                b.truncate((rand() as usize) % bytes.len());
            } else {
                for _ in 0..(1 + k % 8) {
                    let i = (rand() as usize) % b.len();
                    b[i] ^= 1 << (rand() % 8);
                }
            }
            std::fs::write(&bad, &b).unwrap();
            let Ok(bag) = Bag::open(&bad) else { continue };
            let Ok(roles) = bag.roles(&RoleRequest::default()) else {
                continue;
            };
            let _ = bag.frames(&roles);
            let _ = read_all(&bag, &roles);
        }
    }
}

/// A Range of transducer `i` (frame `sonar_<i>`) at `range`.
fn range_cdr(stamp_ns: u64, i: u8, range: f32) -> Vec<u8> {
    let mut buf = Vec::new();
    let mut w = crate::cdr::CdrWriter::new(&mut buf);
    w.i32((stamp_ns / 1_000_000_000) as i32);
    w.u32((stamp_ns % 1_000_000_000) as u32);
    w.string(&format!("sonar_{i}"));
    w.u8(0);
    w.f32(0.26);
    w.f32(0.1);
    w.f32(5.0);
    w.f32(range);
    buf
}

/// Sonar roles: every Range topic when guessed, a PointCloud2 only when its
/// name says sonar, both kinds an error listing them; a Range bag with
/// `--sonar` order gives the rings on base/sonar, in both storages.
#[test]
fn sonar_topics_are_guessed_named_and_read_as_rings() {
    let dir = tempfile::tempdir().unwrap();
    let mut msgs = messages(&["/scan"]);
    let sonar = smokenav_platform_config::RobotConfig::builtin("pioneer-3dx")
        .unwrap()
        .sonar;
    for cycle in 0..3u64 {
        let t = 1_700_000_000_000_000_000 + cycle * 100_000_000 + 5;
        for i in 0..8u8 {
            msgs.push((
                format!("/sonar/{i}"),
                RANGE_TYPE,
                t + u64::from(i),
                range_cdr(t, i, 1.0 + f32::from(i) * 0.5),
            ));
        }
    }
    msgs.push((
        "/points".into(),
        POINT_CLOUD2_TYPE,
        1_700_000_000_900_000_000,
        vec![0, 1, 0, 0],
    ));
    let mcap = dir.path().join("b.mcap");
    write_mcap(&mcap, &msgs);
    let db3 = dir.path().join("b.db3");
    write_db3(&db3, &msgs);
    for path in [&mcap, &db3] {
        let bag = Bag::open(path).unwrap();
        let roles = bag.roles(&RoleRequest::default()).unwrap();
        // A lidar's /points is not taken for the sonar.
        assert_eq!(roles.sonar.len(), 8);
        assert_eq!(roles.sonar_kind, Some(SonarKind::Range));
        assert!(!roles.sonar_ordered);
        let e = bag
            .roles(&RoleRequest {
                sonar: vec!["/scan".into()],
                ..Default::default()
            })
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--sonar /scan") && e.contains("LaserScan"),
            "{e}"
        );
        let e = bag
            .roles(&RoleRequest {
                sonar: vec!["/sonar/0".into(), "/points".into()],
                ..Default::default()
            })
            .unwrap_err()
            .to_string();
        assert!(e.contains("either Range topics"), "{e}");
        let order: Vec<String> = (0..8).map(|i| format!("sonar/{i}")).collect();
        let roles = bag
            .roles(&RoleRequest {
                sonar: order,
                ..Default::default()
            })
            .unwrap();
        assert!(roles.sonar_ordered);
        let mut m = bag.messages_with_sonar(&roles, &sonar).unwrap();
        let mut rings = Vec::new();
        while let Some(p) = m.read_next().unwrap() {
            if let AnyMessage::SonarRing(r) = p.message {
                assert_eq!(p.topic, "base/sonar");
                // Out when its last reading was received.
                assert_eq!(p.log_time, r.header.stamp_ns + 7);
                rings.push(r);
            }
        }
        assert_eq!(rings.len(), 3, "{}", path.display());
        assert_eq!(
            rings[2].by_index(3),
            Some(&smokenav_shared_types::SonarReading::new(
                3,
                2.5,
                smokenav_shared_types::SonarStatus::Valid
            ))
        );
    }
    // A cloud named for the sonar is guessed; beside Range topics it is a choice to make.
    msgs.push((
        "/sonar_pointcloud2".into(),
        POINT_CLOUD2_TYPE,
        1_700_000_000_950_000_000,
        vec![0, 1, 0, 0],
    ));
    let both = dir.path().join("both.mcap");
    write_mcap(&both, &msgs);
    let e = Bag::open(&both)
        .unwrap()
        .roles(&RoleRequest::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("/sonar/0") && e.contains("/sonar_pointcloud2") && e.contains("--sonar"),
        "{e}"
    );
}
