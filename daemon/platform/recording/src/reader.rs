//! Reading recordings back: a streaming MCAP reader that survives files cut
//! short, and [`Playback`], which joins standard messages with their
//! companions into the original smokenav messages.
//!
//! The reader goes front to back (it needs no summary or footer) and checks
//! each chunk's CRC before yielding any of its messages, so a file cut off by
//! SIGKILL yields exactly the messages of its complete chunks and then
//! reports [`EndOfData::Truncated`].

use crate::codec;
use crate::encoder::{DECISIONS_SUFFIX, EXTRAS_SUFFIX};
use crate::schema;
use crate::writer::{MAPPING_VERSION, METADATA_NAME};
use mcap::McapError;
use mcap::records::Record;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use smokenav_shared_types::{
    FusedScan, Health, LaserScan, MapInfo, Odometry, PoseEstimate, SmokeReading, SonarRing,
    VelocityCommand,
};
use std::collections::{BTreeMap, HashMap};
use std::io::Read;
use std::path::Path;
use thiserror::Error;

/// Largest record (chunk) the reader buffers; the recorder writes ~1 MiB chunks.
pub const MAX_RECORD_BYTES: usize = 256 << 20;

#[derive(Debug, Error)]
pub enum ReadError {
    #[error("I/O: {0}")]
    Io(#[from] std::io::Error),
    #[error("MCAP: {0}")]
    Mcap(#[from] McapError),
    #[error("recording uses mapping version {found}; this smokenav reads up to {supported}")]
    UnsupportedVersion { found: String, supported: u32 },
    #[error("message on channel {channel}, which no Channel record declared")]
    UnknownChannel { channel: u16 },
}

/// How the data section ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum EndOfData {
    /// The file ends with its summary and footer.
    Complete,
    /// The file stops inside a record (a recorder killed mid-run); every
    /// complete chunk before that point was read.
    Truncated,
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelInfo {
    pub id: u16,
    pub topic: String,
    pub schema_name: String,
    pub schema_encoding: String,
    pub message_encoding: String,
}

/// A message as stored, borrowed from the reader's buffer.
#[derive(Debug)]
pub struct RawMessage<'a> {
    pub channel: &'a ChannelInfo,
    pub sequence: u32,
    pub log_time: u64,
    pub publish_time: u64,
    pub data: &'a [u8],
}

/// Streams the records of an MCAP file from any `Read`, in file order.
pub struct McapSource<R: Read> {
    input: R,
    reader: LinearReader,
    schemas: HashMap<u16, (String, String)>,
    channels: HashMap<u16, ChannelInfo>,
    metadata: Vec<(String, BTreeMap<String, String>)>,
    end: Option<EndOfData>,
    bytes_read: u64,
}

impl<R: Read> McapSource<R> {
    pub fn new(input: R) -> Self {
        let opts = LinearReaderOptions::default()
            .with_prevalidate_chunk_crcs(true)
            .with_record_length_limit(MAX_RECORD_BYTES);
        Self {
            input,
            reader: LinearReader::new_with_options(opts),
            schemas: HashMap::new(),
            channels: HashMap::new(),
            metadata: Vec::new(),
            end: None,
            bytes_read: 0,
        }
    }

    /// `None` until the end is reached.
    pub fn end(&self) -> Option<&EndOfData> {
        self.end.as_ref()
    }

    pub fn metadata(&self) -> &[(String, BTreeMap<String, String>)] {
        &self.metadata
    }

    pub fn channels(&self) -> impl Iterator<Item = &ChannelInfo> {
        self.channels.values()
    }

    pub fn bytes_read(&self) -> u64 {
        self.bytes_read
    }

    /// Calls `f` with the next message and returns its result; `Ok(None)` at
    /// the end of the data (complete or truncated, see [`Self::end`]).
    pub fn next_message<T>(
        &mut self,
        f: impl FnOnce(RawMessage<'_>) -> T,
    ) -> Result<Option<T>, ReadError> {
        if self.end.is_some() {
            return Ok(None);
        }
        loop {
            let event = match self.reader.next_event() {
                None => {
                    self.end = Some(EndOfData::Complete);
                    return Ok(None);
                }
                Some(Err(McapError::UnexpectedEof)) => {
                    self.end = Some(EndOfData::Truncated);
                    return Ok(None);
                }
                Some(Err(e)) => return Err(e.into()),
                Some(Ok(event)) => event,
            };
            match event {
                LinearReadEvent::ReadRequest(need) => {
                    let buf = self.reader.insert(need);
                    let got = loop {
                        match self.input.read(buf) {
                            Ok(n) => break n,
                            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                            Err(e) => return Err(e.into()),
                        }
                    };
                    self.bytes_read += got as u64;
                    self.reader.notify_read(got);
                }
                LinearReadEvent::Record { opcode, data } => {
                    match mcap::parse_record(opcode, data)? {
                        Record::Schema { header, .. } => {
                            self.schemas
                                .insert(header.id, (header.name, header.encoding));
                        }
                        Record::Channel(c) => {
                            let (schema_name, schema_encoding) =
                                self.schemas.get(&c.schema_id).cloned().unwrap_or_default();
                            self.channels.insert(
                                c.id,
                                ChannelInfo {
                                    id: c.id,
                                    topic: c.topic,
                                    schema_name,
                                    schema_encoding,
                                    message_encoding: c.message_encoding,
                                },
                            );
                        }
                        Record::Metadata(m) => {
                            if m.name == METADATA_NAME
                                && let Some(v) = m.metadata.get("mapping_version")
                                && v.parse::<u32>().map_or(true, |v| v > MAPPING_VERSION)
                            {
                                return Err(ReadError::UnsupportedVersion {
                                    found: v.clone(),
                                    supported: MAPPING_VERSION,
                                });
                            }
                            self.metadata.push((m.name, m.metadata));
                        }
                        Record::Message { header, data } => {
                            let Some(channel) = self.channels.get(&header.channel_id) else {
                                return Err(ReadError::UnknownChannel {
                                    channel: header.channel_id,
                                });
                            };
                            return Ok(Some(f(RawMessage {
                                channel,
                                sequence: header.sequence,
                                log_time: header.log_time,
                                publish_time: header.publish_time,
                                data: data.as_ref(),
                            })));
                        }
                        _ => {}
                    }
                }
            }
        }
    }
}

/// A smokenav message as it was published.
#[derive(Debug, Clone, PartialEq)]
pub enum Message {
    LaserScan(Box<LaserScan>),
    FusedScan(Box<FusedScan>),
    Odometry(Odometry),
    SonarRing(SonarRing),
    VelocityCommand(VelocityCommand),
    SmokeReading(SmokeReading),
    PoseEstimate(PoseEstimate),
    Map(MapInfo, Vec<i8>),
    Health(Box<Health>),
}

impl Message {
    pub fn header(&self) -> &smokenav_shared_types::Header {
        match self {
            Message::LaserScan(m) => &m.header,
            Message::FusedScan(m) => &m.scan.header,
            Message::Odometry(m) => &m.header,
            Message::SonarRing(m) => &m.header,
            Message::VelocityCommand(m) => &m.header,
            Message::SmokeReading(m) => &m.header,
            Message::PoseEstimate(m) => &m.header,
            Message::Map(m, _) => &m.header,
            Message::Health(m) => &m.header,
        }
    }
}

impl Message {
    pub fn header_mut(&mut self) -> &mut smokenav_shared_types::Header {
        match self {
            Message::LaserScan(m) => &mut m.header,
            Message::FusedScan(m) => &mut m.scan.header,
            Message::Odometry(m) => &mut m.header,
            Message::SonarRing(m) => &mut m.header,
            Message::VelocityCommand(m) => &mut m.header,
            Message::SmokeReading(m) => &mut m.header,
            Message::PoseEstimate(m) => &mut m.header,
            Message::Map(m, _) => &mut m.header,
            Message::Health(m) => &mut m.header,
        }
    }

    /// Moves every stamp the message carries by `offset_ns` (saturating), so
    /// a replay looks recorded "now" to processes that compare stamps with
    /// their clock. Zero stamps (absent inputs of a fused scan) stay zero.
    pub fn shift_stamps(&mut self, offset_ns: i64) {
        fn shift(t: &mut u64, offset: i64) {
            if *t != 0 {
                *t = t.saturating_add_signed(offset);
            }
        }
        shift(&mut self.header_mut().stamp_ns, offset_ns);
        if let Message::FusedScan(f) = self {
            shift(&mut f.sonar_stamp_ns, offset_ns);
            shift(&mut f.smoke_stamp_ns, offset_ns);
        }
    }
}

/// One message of a recording, ready to republish.
#[derive(Debug, Clone, PartialEq)]
pub struct Played {
    /// Bus topic (`laser/scan`, `health/hokuyo`, …).
    pub topic: String,
    /// When the recorder received it (ns of its monotonic clock).
    pub log_time: u64,
    pub message: Message,
}

/// What playback skipped, and why.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PlaybackStats {
    /// smokenav messages reconstructed.
    pub messages: u64,
    /// Derived views (`/tf`, sonar points), not replayed.
    pub views: u64,
    /// Channels smokenav does not know (another tool's data).
    pub foreign: u64,
    /// A standard message without its companion, or the reverse.
    pub orphans: u64,
    /// Messages whose payload did not decode.
    pub decode_errors: u64,
    pub last_error: Option<String>,
}

enum Pending {
    Scan(Box<LaserScan>),
    Odometry(Odometry),
    Twist(VelocityCommand),
    Pose(PoseEstimate),
    Map(MapInfo, Vec<i8>),
}

/// Reads a recording and yields the smokenav messages in recorded order.
pub struct Playback<R: Read> {
    source: McapSource<R>,
    /// Standard messages waiting for their companion, by ROS topic.
    pending: HashMap<String, (u32, Pending)>,
    stats: PlaybackStats,
}

impl Playback<std::io::BufReader<std::fs::File>> {
    pub fn open(path: &Path) -> Result<Self, ReadError> {
        let f = std::fs::File::open(path)?;
        Ok(Self::new(std::io::BufReader::with_capacity(1 << 16, f)))
    }
}

impl<R: Read> Playback<R> {
    pub fn new(input: R) -> Self {
        Self {
            source: McapSource::new(input),
            pending: HashMap::new(),
            stats: PlaybackStats::default(),
        }
    }

    pub fn stats(&self) -> &PlaybackStats {
        &self.stats
    }

    pub fn source(&self) -> &McapSource<R> {
        &self.source
    }

    /// The next reconstructed message, or `None` at the end of the data.
    pub fn read_next(&mut self) -> Result<Option<Played>, ReadError> {
        loop {
            let pending = &mut self.pending;
            let stats = &mut self.stats;
            let step = self
                .source
                .next_message(|raw| match decode_step(pending, stats, &raw) {
                    Ok(played) => played,
                    Err(e) => {
                        stats.decode_errors += 1;
                        stats.last_error = Some(format!(
                            "{} (sequence {}): {e}",
                            raw.channel.topic, raw.sequence
                        ));
                        None
                    }
                })?;
            match step {
                None => {
                    // Standard messages still waiting never got their companion.
                    self.stats.orphans += self.pending.len() as u64;
                    self.pending.clear();
                    return Ok(None);
                }
                Some(Some(p)) => {
                    self.stats.messages += 1;
                    return Ok(Some(p));
                }
                Some(None) => {}
            }
        }
    }
}

impl<R: Read> Iterator for Playback<R> {
    type Item = Result<Played, ReadError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.read_next().transpose()
    }
}

fn bus_topic(ros_topic: &str) -> String {
    ros_topic.trim_start_matches('/').to_owned()
}

fn decode_step(
    pending: &mut HashMap<String, (u32, Pending)>,
    stats: &mut PlaybackStats,
    raw: &RawMessage,
) -> Result<Option<Played>, crate::cdr::CdrError> {
    let ch = raw.channel;
    if ch.message_encoding != "cdr" {
        stats.foreign += 1;
        return Ok(None);
    }
    let emit = |topic: &str, message: Message| {
        Some(Played {
            topic: bus_topic(topic),
            log_time: raw.log_time,
            message,
        })
    };
    let mut hold = |value: Pending| {
        if pending
            .insert(ch.topic.clone(), (raw.sequence, value))
            .is_some()
        {
            stats.orphans += 1;
        }
        Ok(None)
    };
    let name = ch.schema_name.as_str();
    match name {
        n if n == schema::LASER_SCAN.name => {
            let mut scan = Box::<LaserScan>::default();
            codec::decode_laser_scan(raw.data, &mut scan)?;
            hold(Pending::Scan(scan))
        }
        n if n == schema::ODOMETRY.name => {
            hold(Pending::Odometry(codec::decode_odometry(raw.data)?))
        }
        n if n == schema::TWIST_STAMPED.name => {
            hold(Pending::Twist(codec::decode_twist_stamped(raw.data)?))
        }
        n if n == schema::POSE_STAMPED.name => {
            hold(Pending::Pose(codec::decode_pose_stamped(raw.data)?))
        }
        n if n == schema::OCCUPANCY_GRID.name => {
            let (info, cells) = codec::decode_occupancy_grid(raw.data)?;
            hold(Pending::Map(info, cells))
        }
        n if n == schema::SONAR_RING.name => Ok(emit(
            &ch.topic,
            Message::SonarRing(codec::decode_sonar_ring(raw.data)?),
        )),
        n if n == schema::SMOKE_READING.name => Ok(emit(
            &ch.topic,
            Message::SmokeReading(codec::decode_smoke_reading(raw.data)?),
        )),
        n if n == schema::HEALTH.name => {
            let mut h = Box::<Health>::default();
            codec::decode_health(raw.data, &mut h)?;
            Ok(emit(&ch.topic, Message::Health(h)))
        }
        n if n == schema::TF_MESSAGE.name || n == schema::POINT_CLOUD2.name => {
            stats.views += 1;
            Ok(None)
        }
        _ => {
            let suffix = if name == schema::FUSED_DECISIONS.name {
                DECISIONS_SUFFIX
            } else {
                EXTRAS_SUFFIX
            };
            let is_companion = [
                schema::SCAN_EXTRAS.name,
                schema::FUSED_DECISIONS.name,
                schema::ODOMETRY_EXTRAS.name,
                schema::STAMP_SEQ.name,
                schema::POSE_EXTRAS.name,
                schema::MAP_EXTRAS.name,
            ]
            .contains(&name);
            if !is_companion {
                stats.foreign += 1;
                return Ok(None);
            }
            let Some(std_topic) = ch.topic.strip_suffix(suffix) else {
                stats.orphans += 1;
                return Ok(None);
            };
            let Some((sequence, value)) = pending.remove(std_topic) else {
                stats.orphans += 1;
                return Ok(None);
            };
            if sequence != raw.sequence {
                stats.orphans += 2;
                return Ok(None);
            }
            let message = match (name, value) {
                (n, Pending::Scan(mut scan)) if n == schema::SCAN_EXTRAS.name => {
                    codec::apply_scan_extras(raw.data, &mut scan)?;
                    Message::LaserScan(scan)
                }
                (n, Pending::Scan(scan)) if n == schema::FUSED_DECISIONS.name => {
                    let mut f = Box::<FusedScan>::default();
                    f.scan = *scan;
                    codec::apply_fused_decisions(raw.data, &mut f)?;
                    Message::FusedScan(f)
                }
                (n, Pending::Odometry(mut o)) if n == schema::ODOMETRY_EXTRAS.name => {
                    codec::apply_odometry_extras(raw.data, &mut o)?;
                    Message::Odometry(o)
                }
                (n, Pending::Twist(mut c)) if n == schema::STAMP_SEQ.name => {
                    codec::apply_stamp_seq(raw.data, &mut c.header)?;
                    Message::VelocityCommand(c)
                }
                (n, Pending::Pose(mut p)) if n == schema::POSE_EXTRAS.name => {
                    codec::apply_pose_extras(raw.data, &mut p)?;
                    Message::PoseEstimate(p)
                }
                (n, Pending::Map(mut info, cells)) if n == schema::MAP_EXTRAS.name => {
                    codec::apply_map_extras(raw.data, &mut info)?;
                    Message::Map(info, cells)
                }
                _ => {
                    stats.orphans += 2;
                    return Ok(None);
                }
            };
            Ok(emit(std_topic, message))
        }
    }
}
