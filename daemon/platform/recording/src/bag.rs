//! ROS 2 bags in: a team's own data, recorded by rosbag2 (or anything that
//! writes the same files), read as smokenav messages.
//!
//! A bag is one of
//! - a rosbag2 folder: `metadata.yaml` naming its storage (`mcap` or
//!   `sqlite3`) and its files, read in the order it lists them;
//! - a single `.mcap` file (rosbag2's or `smokenav record`'s);
//! - a single `.db3` file (rosbag2's sqlite3 storage: tables `topics` and
//!   `messages`, read in insertion order, which is the order rosbag2 received them).
//!
//! The standard topics are mapped to roles ([`RoleRequest`] →
//! [`RoleMap`]): `sensor_msgs/LaserScan` is the laser, `nav_msgs/Odometry`
//! the base's odometry, `/tf_static` gives the laser's mounting pose, and
//! `sensor_msgs/Range` or `PointCloud2` topics are the sonar ring
//! ([`crate::bag_sonar`], through [`Bag::messages_with_sonar`]). A role
//! not named is guessed by type when exactly one topic has it; otherwise the
//! error lists the candidates. Messages come out as [`Played`], on the bus
//! topic of their role (`laser/scan`, `base/odom`, `base/sonar`), with the time the
//! recorder received them — the clock of the bag's header stamps, so the
//! pipelines' pairing works as live.
//!
//! A recording made by `smokenav record` is read through [`Playback`]
//! instead (its companions make every message exact), with its log times
//! shifted back onto the monotonic clock of its stamps.
//!
//! Every length read from a file is bounded (see [`crate::cdr`] and
//! [`crate::reader::MAX_RECORD_BYTES`]); a damaged bag is an error naming the
//! file, the topic and the message's index on it, never a panic.

use crate::bag_decode::{self, PlanarTransform};
use crate::bag_sonar::SonarError;
pub use crate::bag_sonar::{SonarKind, SonarMapper};
use crate::cdr::CdrError;
use crate::codec;
use crate::reader::{EndOfData, MAX_RECORD_BYTES, McapSource, Playback, Played, ReadError};
use mcap::sans_io::summary_reader::{SummaryReadEvent, SummaryReader, SummaryReaderOptions};
use smokenav_platform_config::SonarSection;
use smokenav_shared_types::catalog::topic_names;
use smokenav_shared_types::{AnyMessage, LaserScan};
use std::collections::HashMap;
use std::fmt::Write as _;
use std::fs::File;
use std::io::{BufReader, Read, Seek};
use std::path::{Path, PathBuf};

pub const LASER_SCAN_TYPE: &str = "sensor_msgs/msg/LaserScan";
pub const ODOMETRY_TYPE: &str = "nav_msgs/msg/Odometry";
pub const TF_TYPE: &str = "tf2_msgs/msg/TFMessage";
pub const RANGE_TYPE: &str = "sensor_msgs/msg/Range";
pub const POINT_CLOUD2_TYPE: &str = "sensor_msgs/msg/PointCloud2";
/// The latched transforms (sensor mounts) of a ROS 2 system.
pub const TF_STATIC_TOPIC: &str = "/tf_static";

const SQLITE_MAGIC: &[u8] = b"SQLite format 3\0";
/// Rows fetched from a `.db3` per query (memory stays bounded).
const SQLITE_PAGE: usize = 256;
/// Messages the mounting-pose search reads from the start of a bag
/// (`/tf_static` is latched: rosbag2 records it first).
const PREPASS_MESSAGES: u64 = 10_000;

#[derive(Debug, thiserror::Error)]
pub enum BagError {
    #[error("{}: {reason}", .path.display())]
    Open { path: PathBuf, reason: String },
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: metadata.yaml: {reason}", .path.display())]
    Metadata { path: PathBuf, reason: String },
    #[error("{}: {source}", .path.display())]
    Mcap { path: PathBuf, source: ReadError },
    #[error("{}: sqlite3: {source}", .path.display())]
    Sqlite {
        path: PathBuf,
        source: rusqlite::Error,
    },
    #[error("{}: topic {topic}, message {index}: {source}", .path.display())]
    Decode {
        path: PathBuf,
        topic: String,
        /// 0-based index of the message on its topic.
        index: u64,
        source: CdrError,
    },
    #[error("{}: topic {topic}: {reason}", .path.display())]
    Topic {
        path: PathBuf,
        topic: String,
        reason: String,
    },
    #[error("{}: {reason}", .path.display())]
    Roles { path: PathBuf, reason: String },
}

/// How a bag's messages are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Storage {
    Mcap,
    Sqlite3,
}

/// One topic of a bag.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BagTopic {
    /// As stored (`/scan`).
    pub name: String,
    /// `sensor_msgs/msg/LaserScan`.
    pub type_name: String,
    /// When the bag's index says.
    pub messages: Option<u64>,
}

/// An opened bag: its files and topics (nothing is decoded yet).
#[derive(Debug, Clone)]
pub struct Bag {
    path: PathBuf,
    storage: Storage,
    files: Vec<PathBuf>,
    topics: Vec<BagTopic>,
    /// A `smokenav record` file (companion channels present).
    smokenav: bool,
}

/// The roles a caller asks for: topic names as given (`/scan` or `scan`), or
/// `None` to guess by type.
#[derive(Debug, Clone, Default)]
pub struct RoleRequest {
    pub laser: Option<String>,
    pub odom: Option<String>,
    /// Sonar topics in transducer order (`sensor_msgs/Range`, one per
    /// transducer or one with a frame each; or one `sensor_msgs/PointCloud2`).
    pub sonar: Vec<String>,
}

/// The topics chosen for each role (as stored in the bag).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RoleMap {
    pub laser: Option<String>,
    pub odom: Option<String>,
    /// The sonar topics (empty: none), in the order given or by name when guessed.
    pub sonar: Vec<String>,
    /// What they carry.
    pub sonar_kind: Option<SonarKind>,
    /// Named on the command line: their order is the transducers' order.
    pub sonar_ordered: bool,
}

/// What the start of a bag says about the robot's frames.
#[derive(Debug, Clone, Default)]
pub struct Frames {
    /// Every transform on `/tf_static` seen.
    pub static_transforms: Vec<PlanarTransform>,
    /// `header.frame_id` of the first laser scan.
    pub laser_frame: Option<String>,
    /// `child_frame_id` of the first odometry.
    pub base_frame: Option<String>,
}

impl Frames {
    /// The laser's pose in the base frame (x, y, yaw), when `/tf_static` links them.
    pub fn laser_mount(&self) -> Option<(f64, f64, f64)> {
        self.in_base(self.laser_frame.as_deref()?)
    }

    /// The base frames a transform may hang from: the odometry's child
    /// frame, then REP 105's `base_link` and `base_footprint`.
    fn bases(&self) -> impl Iterator<Item = &str> {
        [
            self.base_frame.as_deref(),
            Some("base_link"),
            Some("base_footprint"),
        ]
        .into_iter()
        .flatten()
    }

    /// Whether `frame` is the robot's base frame.
    pub fn is_base(&self, frame: &str) -> bool {
        let frame = frame.trim_start_matches('/');
        self.bases().any(|b| b == frame)
    }

    /// The pose (x, y, yaw) of `frame` in the base frame, when `/tf_static` links them.
    pub fn in_base(&self, frame: &str) -> Option<(f64, f64, f64)> {
        self.bases()
            .find_map(|b| bag_decode::resolve(&self.static_transforms, b, frame))
    }
}

fn same_topic(a: &str, b: &str) -> bool {
    a.trim_start_matches('/') == b.trim_start_matches('/')
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> BagError + '_ {
    move |source| BagError::Io {
        path: path.to_owned(),
        source,
    }
}

fn sql(path: &Path) -> impl FnOnce(rusqlite::Error) -> BagError + '_ {
    move |source| BagError::Sqlite {
        path: path.to_owned(),
        source,
    }
}

// ---- metadata.yaml -----------------------------------------------------------

#[derive(serde::Deserialize)]
struct MetadataFile {
    rosbag2_bagfile_information: BagInformation,
}

#[derive(serde::Deserialize)]
struct BagInformation {
    #[serde(default)]
    version: u32,
    storage_identifier: String,
    #[serde(default)]
    relative_file_paths: Vec<String>,
    #[serde(default)]
    topics_with_message_count: Vec<TopicWithCount>,
    #[serde(default)]
    compression_format: String,
    #[serde(default)]
    compression_mode: String,
}

#[derive(serde::Deserialize)]
struct TopicWithCount {
    topic_metadata: TopicMetadata,
    #[serde(default)]
    message_count: u64,
}

#[derive(serde::Deserialize)]
struct TopicMetadata {
    name: String,
    #[serde(rename = "type")]
    type_name: String,
    #[serde(default)]
    serialization_format: String,
}

/// Largest metadata.yaml read (a real one is a few kB).
const MAX_METADATA_BYTES: u64 = 16 << 20;

fn read_metadata(dir: &Path) -> Result<Bag, BagError> {
    let path = dir.join("metadata.yaml");
    let len = std::fs::metadata(&path).map_err(io(&path))?.len();
    if len > MAX_METADATA_BYTES {
        return Err(BagError::Metadata {
            path,
            reason: format!("{len} bytes; a rosbag2 metadata file is a few kB"),
        });
    }
    let text = std::fs::read_to_string(&path).map_err(io(&path))?;
    let meta: MetadataFile = serde_yaml_ng::from_str(&text).map_err(|e| BagError::Metadata {
        path: dir.to_owned(),
        reason: match e.location() {
            Some(l) => format!("line {}: {e}", l.line()),
            None => e.to_string(),
        },
    })?;
    let info = meta.rosbag2_bagfile_information;
    let bad = |reason: String| BagError::Metadata {
        path: dir.to_owned(),
        reason,
    };
    if !info.compression_format.is_empty() {
        return Err(bad(format!(
            "version {} bag compressed with {} (mode {}): decompress it first \
             (ros2 bag convert, or write it without --compression-mode)",
            info.version, info.compression_format, info.compression_mode
        )));
    }
    let storage = match info.storage_identifier.as_str() {
        "mcap" => Storage::Mcap,
        "sqlite3" => Storage::Sqlite3,
        other => {
            return Err(bad(format!(
                "key storage_identifier: `{other}` is not a storage smokenav reads (mcap, sqlite3)"
            )));
        }
    };
    if info.relative_file_paths.is_empty() {
        return Err(bad("key relative_file_paths: no files listed".into()));
    }
    let mut files = Vec::new();
    for f in &info.relative_file_paths {
        let rel = Path::new(f);
        // A bag names files beside its metadata, never elsewhere.
        if rel.is_absolute()
            || rel
                .components()
                .any(|c| c == std::path::Component::ParentDir)
        {
            return Err(bad(format!(
                "key relative_file_paths: `{f}` is outside the bag folder"
            )));
        }
        // rosbag2 lists the files of a split bag by name only; older versions with the folder.
        let direct = dir.join(rel);
        let by_name = dir.join(rel.file_name().unwrap_or(rel.as_os_str()));
        files.push(if direct.exists() { direct } else { by_name });
    }
    let topics = info
        .topics_with_message_count
        .into_iter()
        .filter(|t| {
            t.topic_metadata.serialization_format.is_empty()
                || t.topic_metadata.serialization_format == "cdr"
        })
        .map(|t| BagTopic {
            name: t.topic_metadata.name,
            type_name: t.topic_metadata.type_name,
            messages: Some(t.message_count),
        })
        .collect();
    Ok(Bag {
        path: dir.to_owned(),
        storage,
        files,
        topics,
        smokenav: false,
    })
}

// ---- topics of a single file ---------------------------------------------------

fn mcap_topics(path: &Path) -> Result<Vec<BagTopic>, BagError> {
    let mut file = File::open(path).map_err(io(path))?;
    let size = file.metadata().map_err(io(path))?.len();
    let opts = SummaryReaderOptions::default()
        .with_file_size(size)
        .with_record_length_limit(MAX_RECORD_BYTES);
    let mut reader = SummaryReader::new_with_options(opts);
    let mut failed = false;
    while let Some(event) = reader.next_event() {
        match event {
            Ok(SummaryReadEvent::ReadRequest(n)) => {
                let got = file.read(reader.insert(n)).map_err(io(path))?;
                reader.notify_read(got);
            }
            Ok(SummaryReadEvent::SeekRequest(to)) => {
                let at = file.seek(to).map_err(io(path))?;
                reader.notify_seeked(at);
            }
            Err(_) => {
                // No usable summary (a recorder killed mid-run): read the data.
                failed = true;
                break;
            }
        }
    }
    let summary = if failed { None } else { reader.finish() };
    if let Some(s) = summary.filter(|s| !s.channels.is_empty()) {
        let counts = s.stats.as_ref().map(|st| &st.channel_message_counts);
        let mut topics: Vec<BagTopic> = s
            .channels
            .values()
            .map(|c| BagTopic {
                name: c.topic.clone(),
                type_name: c
                    .schema
                    .as_ref()
                    .map(|s| s.name.clone())
                    .unwrap_or_default(),
                messages: counts.and_then(|m| m.get(&c.id).copied()),
            })
            .collect();
        topics.sort_by(|a, b| a.name.cmp(&b.name));
        return Ok(topics);
    }
    let mut src = McapSource::new(BufReader::with_capacity(
        1 << 16,
        File::open(path).map_err(io(path))?,
    ));
    let mut counts: HashMap<u16, u64> = HashMap::new();
    while let Some(id) = src
        .next_message(|m| m.channel.id)
        .map_err(|source| BagError::Mcap {
            path: path.to_owned(),
            source,
        })?
    {
        *counts.entry(id).or_default() += 1;
    }
    let mut topics: Vec<BagTopic> = src
        .channels()
        .map(|c| BagTopic {
            name: c.topic.clone(),
            type_name: c.schema_name.clone(),
            messages: Some(counts.get(&c.id).copied().unwrap_or(0)),
        })
        .collect();
    topics.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(topics)
}

fn open_sqlite(path: &Path) -> Result<rusqlite::Connection, BagError> {
    use rusqlite::OpenFlags;
    rusqlite::Connection::open_with_flags(
        path,
        OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(sql(path))
}

/// (id, name, type) of every cdr topic of a `.db3`.
fn sqlite_topic_rows(
    path: &Path,
    conn: &rusqlite::Connection,
) -> Result<Vec<(i64, String, String)>, BagError> {
    let mut stmt = conn
        .prepare("SELECT id, name, type, serialization_format FROM topics ORDER BY id")
        .map_err(sql(path))?;
    let rows = stmt
        .query_map([], |r| {
            Ok((
                r.get::<_, i64>(0)?,
                r.get::<_, String>(1)?,
                r.get::<_, String>(2)?,
                r.get::<_, String>(3)?,
            ))
        })
        .map_err(sql(path))?;
    let mut out = Vec::new();
    for r in rows {
        let (id, name, ty, format) = r.map_err(sql(path))?;
        if format == "cdr" {
            out.push((id, name, ty));
        }
    }
    Ok(out)
}

fn sqlite_topics(path: &Path) -> Result<Vec<BagTopic>, BagError> {
    let conn = open_sqlite(path)?;
    let rows = sqlite_topic_rows(path, &conn)?;
    let mut stmt = conn
        .prepare("SELECT count(*) FROM messages WHERE topic_id = ?1")
        .map_err(sql(path))?;
    let mut topics = Vec::new();
    for (id, name, type_name) in rows {
        let n: i64 = stmt.query_row([id], |r| r.get(0)).map_err(sql(path))?;
        topics.push(BagTopic {
            name,
            type_name,
            messages: Some(n.max(0) as u64),
        });
    }
    Ok(topics)
}

impl Bag {
    /// Opens a rosbag2 folder, an `.mcap` or a `.db3` file.
    pub fn open(path: &Path) -> Result<Self, BagError> {
        let meta = std::fs::metadata(path).map_err(io(path))?;
        if meta.is_dir() {
            if !path.join("metadata.yaml").exists() {
                return Err(BagError::Open {
                    path: path.to_owned(),
                    reason: "a folder without metadata.yaml is not a rosbag2 bag".into(),
                });
            }
            let mut bag = read_metadata(path)?;
            for f in &bag.files {
                if !f.is_file() {
                    return Err(BagError::Open {
                        path: f.clone(),
                        reason: "listed in metadata.yaml but missing".into(),
                    });
                }
            }
            if bag.topics.is_empty() {
                // Older writers leave the counts out: ask the files.
                let mut topics: Vec<BagTopic> = Vec::new();
                for f in &bag.files {
                    let more = match bag.storage {
                        Storage::Mcap => mcap_topics(f)?,
                        Storage::Sqlite3 => sqlite_topics(f)?,
                    };
                    for t in more {
                        match topics.iter_mut().find(|x| x.name == t.name) {
                            Some(x) => x.messages = x.messages.zip(t.messages).map(|(a, b)| a + b),
                            None => topics.push(t),
                        }
                    }
                }
                bag.topics = topics;
            }
            return Ok(bag);
        }
        let mut head = [0u8; 16];
        let n = File::open(path)
            .and_then(|mut f| {
                let mut got = 0;
                while got < head.len() {
                    match f.read(&mut head[got..])? {
                        0 => break,
                        k => got += k,
                    }
                }
                Ok(got)
            })
            .map_err(io(path))?;
        let head = &head[..n];
        let (storage, topics) = if head.starts_with(mcap::MAGIC) {
            (Storage::Mcap, mcap_topics(path)?)
        } else if head == SQLITE_MAGIC {
            (Storage::Sqlite3, sqlite_topics(path)?)
        } else {
            return Err(BagError::Open {
                path: path.to_owned(),
                reason: "neither an MCAP file, a rosbag2 .db3 nor a rosbag2 folder".into(),
            });
        };
        let smokenav = storage == Storage::Mcap
            && topics
                .iter()
                .any(|t| t.type_name.starts_with("smokenav_msgs/"));
        Ok(Self {
            path: path.to_owned(),
            storage,
            files: vec![path.to_owned()],
            topics,
            smokenav,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn storage(&self) -> Storage {
        self.storage
    }

    pub fn files(&self) -> &[PathBuf] {
        &self.files
    }

    pub fn topics(&self) -> &[BagTopic] {
        &self.topics
    }

    /// Written by `smokenav record` (read exactly, through its companions).
    pub fn is_smokenav(&self) -> bool {
        self.smokenav
    }

    fn roles_error(&self, reason: String) -> BagError {
        BagError::Roles {
            path: self.path.clone(),
            reason,
        }
    }

    fn topic_list(&self) -> String {
        let mut s = String::new();
        for t in &self.topics {
            let _ = write!(s, "\n  {} ({})", t.name, t.type_name);
        }
        if s.is_empty() {
            s.push_str(" none");
        }
        s
    }

    /// One role's topic: the one asked for (checked), else the only topic of
    /// its type (a smokenav recording: its own topic).
    fn role(
        &self,
        asked: Option<&str>,
        type_name: &str,
        flag: &str,
        native: &str,
    ) -> Result<Option<String>, BagError> {
        let of_type: Vec<&BagTopic> = self
            .topics
            .iter()
            .filter(|t| t.type_name == type_name)
            .collect();
        if let Some(asked) = asked {
            let Some(t) = self.topics.iter().find(|t| same_topic(&t.name, asked)) else {
                return Err(self.roles_error(format!(
                    "{flag} {asked}: no such topic; the bag has:{}",
                    self.topic_list()
                )));
            };
            if t.type_name != type_name {
                return Err(self.roles_error(format!(
                    "{flag} {asked}: the topic carries {}, not {type_name}",
                    t.type_name
                )));
            }
            return Ok(Some(t.name.clone()));
        }
        if self.smokenav {
            return Ok(of_type
                .iter()
                .find(|t| same_topic(&t.name, native))
                .map(|t| t.name.clone()));
        }
        match of_type.as_slice() {
            [] => Ok(None),
            [one] => Ok(Some(one.name.clone())),
            many => Err(self.roles_error(format!(
                "{} topics carry {type_name}: {}; choose one with {flag} TOPIC",
                many.len(),
                many.iter()
                    .map(|t| t.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ))),
        }
    }

    /// The sonar topics: those asked for (each a Range, or one PointCloud2),
    /// else every Range topic, else the one PointCloud2 topic whose name
    /// says sonar (a bag's other clouds are a lidar's or a camera's).
    fn sonar_roles(
        &self,
        asked: &[String],
    ) -> Result<(Vec<String>, Option<SonarKind>, bool), BagError> {
        let kind_of = |t: &BagTopic| match t.type_name.as_str() {
            RANGE_TYPE => Some(SonarKind::Range),
            POINT_CLOUD2_TYPE => Some(SonarKind::Cloud),
            _ => None,
        };
        if !asked.is_empty() {
            let mut topics = Vec::new();
            let mut kind = None;
            for a in asked {
                let Some(t) = self.topics.iter().find(|t| same_topic(&t.name, a)) else {
                    return Err(self.roles_error(format!(
                        "--sonar {a}: no such topic; the bag has:{}",
                        self.topic_list()
                    )));
                };
                let Some(k) = kind_of(t) else {
                    return Err(self.roles_error(format!(
                        "--sonar {a}: the topic carries {}, not {RANGE_TYPE} or {POINT_CLOUD2_TYPE}",
                        t.type_name
                    )));
                };
                if kind.is_some_and(|kind| kind != k)
                    || (k == SonarKind::Cloud && !topics.is_empty())
                {
                    return Err(self.roles_error(format!(
                        "--sonar {a}: give either Range topics (one per transducer) or one PointCloud2 topic"
                    )));
                }
                if topics.contains(&t.name) {
                    return Err(self.roles_error(format!("--sonar {a}: given twice")));
                }
                kind = Some(k);
                topics.push(t.name.clone());
            }
            return Ok((topics, kind, true));
        }
        if self.smokenav {
            // Its base/sonar is played as recorded.
            return Ok((Vec::new(), None, false));
        }
        let mut ranges: Vec<&BagTopic> = self
            .topics
            .iter()
            .filter(|t| t.type_name == RANGE_TYPE)
            .collect();
        ranges.sort_by(|a, b| a.name.cmp(&b.name));
        let clouds: Vec<&BagTopic> = self
            .topics
            .iter()
            .filter(|t| {
                t.type_name == POINT_CLOUD2_TYPE && t.name.to_ascii_lowercase().contains("sonar")
            })
            .collect();
        let names = |v: &[&BagTopic]| {
            v.iter()
                .map(|t| t.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        };
        match (ranges.as_slice(), clouds.as_slice()) {
            ([], []) => Ok((Vec::new(), None, false)),
            ([], [one]) => Ok((vec![one.name.clone()], Some(SonarKind::Cloud), false)),
            (r, []) => Ok((r.iter().map(|t| t.name.clone()).collect(), Some(SonarKind::Range), false)),
            (r, c) => Err(self.roles_error(format!(
                "the sonar could be the Range topics {} or the PointCloud2 topic{} {}; choose with --sonar TOPIC",
                names(r),
                if c.len() > 1 { "s" } else { "" },
                names(c)
            ))),
        }
    }

    /// The topics of each role: those asked for, else guessed by type.
    pub fn roles(&self, request: &RoleRequest) -> Result<RoleMap, BagError> {
        let (sonar, sonar_kind, sonar_ordered) = self.sonar_roles(&request.sonar)?;
        Ok(RoleMap {
            sonar,
            sonar_kind,
            sonar_ordered,
            laser: self.role(
                request.laser.as_deref(),
                LASER_SCAN_TYPE,
                "--laser",
                topic_names::LASER_SCAN,
            )?,
            odom: self.role(
                request.odom.as_deref(),
                ODOMETRY_TYPE,
                "--odom",
                topic_names::BASE_ODOM,
            )?,
        })
    }

    /// Like [`Self::roles`], with both the laser and the odometry required.
    pub fn laser_and_odometry(&self, request: &RoleRequest) -> Result<RoleMap, BagError> {
        let roles = self.roles(request)?;
        for (got, ty, flag) in [
            (&roles.laser, LASER_SCAN_TYPE, "--laser"),
            (&roles.odom, ODOMETRY_TYPE, "--odom"),
        ] {
            if got.is_none() {
                return Err(self.roles_error(format!(
                    "no {ty} topic (name one with {flag} TOPIC); the bag has:{}",
                    self.topic_list()
                )));
            }
        }
        Ok(roles)
    }

    /// The robot's frames from the start of the bag: `/tf_static`, the
    /// laser's frame and the base frame.
    pub fn frames(&self, roles: &RoleMap) -> Result<Frames, BagError> {
        let mut frames = Frames::default();
        let mut raw = RawReader::new(self, roles, true, false)?;
        let mut seen = 0u64;
        while seen < PREPASS_MESSAGES
            && (frames.laser_frame.is_none() && roles.laser.is_some()
                || frames.base_frame.is_none() && roles.odom.is_some()
                || seen < 100)
        {
            let step = raw.next(|m| {
                let decoded = match m.role {
                    RawRole::Tf => {
                        bag_decode::decode_tf_message(m.data, &mut frames.static_transforms)
                    }
                    RawRole::Laser if frames.laser_frame.is_none() => {
                        bag_decode::header_frame(m.data)
                            .map(|f| frames.laser_frame = Some(f.into()))
                    }
                    RawRole::Odom if frames.base_frame.is_none() => {
                        bag_decode::odometry_child_frame(m.data)
                            .map(|f| frames.base_frame = Some(f.trim_start_matches('/').into()))
                    }
                    _ => Ok(()),
                };
                decoded.map_err(|source| (m.topic.to_owned(), m.index, source))
            })?;
            match step {
                None => break,
                Some(Err((topic, index, source))) => {
                    return Err(BagError::Decode {
                        path: raw.current_path(),
                        topic,
                        index,
                        source,
                    });
                }
                Some(Ok(())) => seen += 1,
            }
        }
        Ok(frames)
    }

    /// The messages of the chosen roles, in the order they were received;
    /// the sonar topics (if any) as rings of `geometry`'s transducers, on
    /// `base/sonar` (see [`crate::bag_sonar`]).
    pub fn messages_with_sonar(
        &self,
        roles: &RoleMap,
        geometry: &SonarSection,
    ) -> Result<BagMessages, BagError> {
        let mut messages = self.messages(roles)?;
        if let (Some(kind), false) = (roles.sonar_kind, self.smokenav) {
            let frames = self.frames(roles)?;
            messages.sonar = Some(Box::new(SonarMapper::new(
                kind,
                roles.sonar.clone(),
                roles.sonar_ordered,
                frames,
                geometry,
            )));
            if let Inner::Foreign(raw) = &mut messages.inner {
                **raw = RawReader::new(self, roles, false, true)?;
            }
        }
        Ok(messages)
    }

    /// The messages of the chosen roles, in the order they were received
    /// (the laser and the odometry; for the sonar see [`Self::messages_with_sonar`]).
    pub fn messages(&self, roles: &RoleMap) -> Result<BagMessages, BagError> {
        let inner = if self.smokenav {
            let playback = Playback::open(&self.path).map_err(|source| BagError::Mcap {
                path: self.path.clone(),
                source,
            })?;
            Inner::Native(Box::new(playback))
        } else {
            Inner::Foreign(Box::new(RawReader::new(self, roles, false, false)?))
        };
        let bus = |t: &Option<String>, standard: &str| match t {
            Some(t) if self.smokenav => t.trim_start_matches('/').to_owned(),
            _ => standard.to_owned(),
        };
        Ok(BagMessages {
            inner,
            path: self.path.clone(),
            laser_topic: bus(&roles.laser, topic_names::LASER_SCAN),
            odom_topic: bus(&roles.odom, topic_names::BASE_ODOM),
            roles: roles.clone(),
            sonar: None,
            last_log_time: 0,
            end: None,
        })
    }
}

// ---- raw messages ----------------------------------------------------------------

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum RawRole {
    Laser,
    Odom,
    Tf,
    /// The n-th sonar topic of the role map.
    Sonar(usize),
}

/// One stored message of a role topic.
struct RawMsg<'a> {
    role: RawRole,
    topic: &'a str,
    /// Its index on its topic.
    index: u64,
    log_time: u64,
    data: &'a [u8],
}

struct SqliteRow {
    topic_id: i64,
    timestamp: i64,
    data: Vec<u8>,
}

struct SqliteCursor {
    path: PathBuf,
    conn: rusqlite::Connection,
    query: String,
    /// topic id → (role, name, slot in the reader's table).
    topics: HashMap<i64, (RawRole, String, usize)>,
    last_id: i64,
    page: Vec<SqliteRow>,
    filled: usize,
    pos: usize,
    done: bool,
}

impl SqliteCursor {
    fn open(path: &Path, wanted: &[(RawRole, String)]) -> Result<Self, BagError> {
        let conn = open_sqlite(path)?;
        let mut topics = HashMap::new();
        for (id, name, _) in sqlite_topic_rows(path, &conn)? {
            if let Some(slot) = wanted.iter().position(|(_, w)| *w == name) {
                topics.insert(id, (wanted[slot].0, name, slot));
            }
        }
        // Only the role topics' rows are fetched (a bag's images stay on disk).
        let ids: Vec<String> = topics.keys().map(|id| id.to_string()).collect();
        let query = format!(
            "SELECT id, topic_id, timestamp, data FROM messages \
             WHERE id > ?1 AND topic_id IN ({}) ORDER BY id LIMIT {SQLITE_PAGE}",
            ids.join(",")
        );
        Ok(Self {
            path: path.to_owned(),
            conn,
            query,
            done: topics.is_empty(),
            topics,
            last_id: i64::MIN,
            page: Vec::new(),
            filled: 0,
            pos: 0,
        })
    }

    fn fill(&mut self) -> Result<(), BagError> {
        let path = self.path.clone();
        let mut stmt = self.conn.prepare_cached(&self.query).map_err(sql(&path))?;
        let mut rows = stmt.query([self.last_id]).map_err(sql(&path))?;
        self.filled = 0;
        self.pos = 0;
        while let Some(r) = rows.next().map_err(sql(&path))? {
            let id: i64 = r.get(0).map_err(sql(&path))?;
            let topic_id: i64 = r.get(1).map_err(sql(&path))?;
            let timestamp: i64 = r.get(2).map_err(sql(&path))?;
            let data = r.get_ref(3).map_err(sql(&path))?;
            let bytes = data.as_blob().map_err(|e| BagError::Sqlite {
                path: path.clone(),
                source: e.into(),
            })?;
            if self.filled == self.page.len() {
                self.page.push(SqliteRow {
                    topic_id: 0,
                    timestamp: 0,
                    data: Vec::new(),
                });
            }
            // Buffers are reused page after page.
            let row = &mut self.page[self.filled];
            row.topic_id = topic_id;
            row.timestamp = timestamp;
            row.data.clear();
            row.data.extend_from_slice(bytes);
            self.filled += 1;
            self.last_id = id;
        }
        if self.filled == 0 {
            self.done = true;
        }
        Ok(())
    }
}

enum Source {
    Mcap(McapSource<BufReader<File>>),
    Sqlite(SqliteCursor),
}

/// Streams the role topics' stored messages file after file.
struct RawReader {
    storage: Storage,
    files: Vec<PathBuf>,
    next_file: usize,
    current: Option<(PathBuf, Source)>,
    /// The topics read and their roles.
    wanted: Vec<(RawRole, String)>,
    /// Messages read per wanted topic.
    counts: Vec<u64>,
}

impl RawReader {
    fn new(bag: &Bag, roles: &RoleMap, tf: bool, sonar: bool) -> Result<Self, BagError> {
        let mut wanted = Vec::new();
        if let Some(l) = &roles.laser {
            wanted.push((RawRole::Laser, l.clone()));
        }
        if let Some(o) = &roles.odom {
            wanted.push((RawRole::Odom, o.clone()));
        }
        if tf {
            wanted.push((RawRole::Tf, TF_STATIC_TOPIC.to_owned()));
        }
        if sonar {
            for (i, t) in roles.sonar.iter().enumerate() {
                wanted.push((RawRole::Sonar(i), t.clone()));
            }
        }
        Ok(Self {
            storage: bag.storage,
            files: bag.files.clone(),
            next_file: 0,
            current: None,
            counts: vec![0; wanted.len()],
            wanted,
        })
    }

    fn current_path(&self) -> PathBuf {
        self.current
            .as_ref()
            .map(|(p, _)| p.clone())
            .or_else(|| self.files.last().cloned())
            .unwrap_or_default()
    }

    fn open_next(&mut self) -> Result<bool, BagError> {
        let Some(path) = self.files.get(self.next_file).cloned() else {
            return Ok(false);
        };
        self.next_file += 1;
        let source = match self.storage {
            Storage::Mcap => {
                let f = File::open(&path).map_err(io(&path))?;
                Source::Mcap(McapSource::new(BufReader::with_capacity(1 << 16, f)))
            }
            Storage::Sqlite3 => Source::Sqlite(SqliteCursor::open(&path, &self.wanted)?),
        };
        self.current = Some((path, source));
        Ok(true)
    }

    /// Calls `f` with the next message of a role topic; `Ok(None)` at the end of the bag.
    fn next<T>(&mut self, mut f: impl FnMut(RawMsg<'_>) -> T) -> Result<Option<T>, BagError> {
        loop {
            if self.current.is_none() && !self.open_next()? {
                return Ok(None);
            }
            let wanted = &self.wanted;
            let role_of = |topic: &str| -> Option<(RawRole, usize)> {
                let slot = wanted.iter().position(|(_, w)| w == topic)?;
                Some((wanted[slot].0, slot))
            };
            let counts = &mut self.counts;
            let Some((path, source)) = &mut self.current else {
                continue;
            };
            let got = match source {
                Source::Mcap(src) => {
                    let step = src
                        .next_message(|m| {
                            let (role, slot) = role_of(&m.channel.topic)?;
                            let index = counts[slot];
                            counts[slot] += 1;
                            if m.channel.message_encoding != "cdr" {
                                return Some(Err(BagError::Topic {
                                    path: path.clone(),
                                    topic: m.channel.topic.clone(),
                                    reason: format!(
                                        "message encoding `{}`; smokenav reads cdr",
                                        m.channel.message_encoding
                                    ),
                                }));
                            }
                            Some(Ok(f(RawMsg {
                                role,
                                topic: &m.channel.topic,
                                index,
                                log_time: m.log_time,
                                data: m.data,
                            })))
                        })
                        .map_err(|source| BagError::Mcap {
                            path: path.clone(),
                            source,
                        })?;
                    match step {
                        None => {
                            if src.end() == Some(&EndOfData::Truncated) {
                                tracing::warn!(
                                    "{}: the file is cut short; read every complete chunk",
                                    path.display()
                                );
                            }
                            None
                        }
                        Some(None) => continue,
                        Some(Some(r)) => Some(r?),
                    }
                }
                Source::Sqlite(cur) => {
                    if cur.pos == cur.filled && !cur.done {
                        cur.fill()?;
                    }
                    if cur.done && cur.pos == cur.filled {
                        None
                    } else {
                        let row = &cur.page[cur.pos];
                        cur.pos += 1;
                        let Some((role, name, slot)) = cur.topics.get(&row.topic_id) else {
                            continue;
                        };
                        let index = counts[*slot];
                        counts[*slot] += 1;
                        Some(f(RawMsg {
                            role: *role,
                            topic: name,
                            index,
                            log_time: row.timestamp.max(0) as u64,
                            data: &row.data,
                        }))
                    }
                }
            };
            match got {
                Some(v) => return Ok(Some(v)),
                None => self.current = None,
            }
        }
    }
}

enum Inner {
    Native(Box<Playback<BufReader<File>>>),
    Foreign(Box<RawReader>),
}

/// The messages of a bag's role topics as smokenav messages, in receive order.
pub struct BagMessages {
    inner: Inner,
    path: PathBuf,
    laser_topic: String,
    odom_topic: String,
    roles: RoleMap,
    sonar: Option<Box<SonarMapper>>,
    /// Receive time of the last message returned (the end-of-bag ring's).
    last_log_time: u64,
    end: Option<EndOfData>,
}

impl BagMessages {
    /// The next message on its bus topic (`laser/scan`, `base/odom`; a
    /// smokenav recording: every recorded topic), `None` at the end.
    pub fn read_next(&mut self) -> Result<Option<Played>, BagError> {
        match &mut self.inner {
            Inner::Native(playback) => {
                let p = playback.read_next().map_err(|source| BagError::Mcap {
                    path: self.path.clone(),
                    source,
                })?;
                let Some(mut p) = p else {
                    self.end = playback.source().end().cloned();
                    return Ok(None);
                };
                // Log times are Unix times; the stamps are on the recorder's monotonic clock.
                let offset = crate::unix_offset(playback.source().metadata());
                p.log_time = crate::shift_ns(p.log_time, offset.saturating_neg());
                Ok(Some(p))
            }
            Inner::Foreign(raw) => loop {
                let sonar = &mut self.sonar;
                let step = raw.next(|m| {
                    let decoded = match m.role {
                        RawRole::Laser => {
                            let mut scan = Box::<LaserScan>::default();
                            codec::decode_laser_scan(m.data, &mut scan)
                                .map(|()| {
                                    Some((topic_names::LASER_SCAN, AnyMessage::LaserScan(scan)))
                                })
                                .map_err(SonarError::Decode)
                        }
                        RawRole::Odom => codec::decode_odometry(m.data)
                            .map(|o| Some((topic_names::BASE_ODOM, AnyMessage::Odometry(o))))
                            .map_err(SonarError::Decode),
                        RawRole::Sonar(slot) => match sonar.as_deref_mut() {
                            Some(s) => match s.kind() {
                                SonarKind::Range => s.range(slot, m.data),
                                SonarKind::Cloud => s.cloud(m.data),
                            }
                            .map(|ring| {
                                ring.map(|r| (topic_names::BASE_SONAR, AnyMessage::SonarRing(r)))
                            }),
                            None => Ok(None),
                        },
                        RawRole::Tf => unreachable_tf().map(Some).map_err(SonarError::Decode),
                    };
                    match decoded {
                        Ok(Some((topic, message))) => Ok(Some(Played {
                            topic: topic.to_owned(),
                            log_time: m.log_time,
                            message,
                        })),
                        Ok(None) => Ok(None),
                        Err(source) => Err((m.topic.to_owned(), m.index, source)),
                    }
                });
                let path = raw.current_path();
                match step? {
                    None => {
                        // The cycle still being collected when the bag ends.
                        if let Some(ring) = self.sonar.as_deref_mut().and_then(SonarMapper::finish)
                        {
                            return Ok(Some(Played {
                                topic: topic_names::BASE_SONAR.to_owned(),
                                log_time: self.last_log_time,
                                message: AnyMessage::SonarRing(ring),
                            }));
                        }
                        self.end = Some(EndOfData::Complete);
                        return Ok(None);
                    }
                    Some(Ok(Some(p))) => {
                        self.last_log_time = p.log_time;
                        return Ok(Some(p));
                    }
                    // A reading that does not end a ring yet.
                    Some(Ok(None)) => continue,
                    Some(Err((topic, index, SonarError::Decode(source)))) => {
                        return Err(BagError::Decode {
                            path,
                            topic,
                            index,
                            source,
                        });
                    }
                    Some(Err((topic, index, SonarError::Map(reason)))) => {
                        return Err(BagError::Topic {
                            path,
                            topic,
                            reason: format!("message {index}: {reason}"),
                        });
                    }
                }
            },
        }
    }

    /// How the sonar topics were read (`None` without sonar).
    pub fn sonar(&self) -> Option<&SonarMapper> {
        self.sonar.as_deref()
    }

    pub fn roles(&self) -> &RoleMap {
        &self.roles
    }

    /// The bus topic the laser role's messages come out on.
    pub fn laser_topic(&self) -> &str {
        &self.laser_topic
    }

    /// The bus topic the odometry role's messages come out on.
    pub fn odom_topic(&self) -> &str {
        &self.odom_topic
    }

    /// `None` until the end is reached.
    pub fn end(&self) -> Option<&EndOfData> {
        self.end.as_ref()
    }
}

/// The foreign reader of [`BagMessages`] is opened without `/tf_static`.
fn unreachable_tf() -> Result<(&'static str, AnyMessage), CdrError> {
    Err(CdrError::InvalidValue {
        field: "tf_static (not a message role)",
        value: 0,
    })
}

#[cfg(test)]
#[path = "bag_tests.rs"]
mod tests;
