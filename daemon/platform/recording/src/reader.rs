//! Reading recordings back: a streaming MCAP reader that survives files cut
//! short, and [`Playback`], which joins standard messages with their
//! companions into the original smokenav messages.
//!
//! The reader goes front to back (it needs no summary or footer) and checks
//! each chunk's CRC before yielding any of its messages, so a file cut off by
//! SIGKILL yields exactly the messages of its complete chunks and then
//! reports [`EndOfData::Truncated`].

use crate::ros2;
use crate::schema;
use crate::writer::{MAPPING_VERSION, METADATA_NAME};
use mcap::McapError;
use mcap::records::Record;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use smokenav_shared_types::AnyMessage;
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

/// One message of a recording, ready to republish.
#[derive(Debug, Clone, PartialEq)]
pub struct Played {
    /// Bus topic (`laser/scan`, `health/hokuyo`, …).
    pub topic: String,
    /// When the recorder received it (ns of its monotonic clock).
    pub log_time: u64,
    /// The message, as it was published.
    pub message: AnyMessage,
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

/// The standard message of one ROS topic waiting for its companion: its
/// sequence number, schema and payload. Kept per topic once seen, so
/// holding a payload allocates nothing after the first.
#[derive(Default)]
struct Pending {
    held: bool,
    sequence: u32,
    schema: &'static str,
    data: Vec<u8>,
}

/// Reads a recording and yields the smokenav messages in recorded order.
pub struct Playback<R: Read> {
    source: McapSource<R>,
    /// Standard messages waiting for their companion, by ROS topic.
    pending: HashMap<String, Pending>,
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
                    self.stats.orphans += self.pending.values().filter(|p| p.held).count() as u64;
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

/// One stored message: a view is counted, a complete message decoded, a
/// standard message held until its companion joins it (the catalog says
/// which schemas are which).
fn decode_step(
    pending: &mut HashMap<String, Pending>,
    stats: &mut PlaybackStats,
    raw: &RawMessage,
) -> Result<Option<Played>, crate::cdr::CdrError> {
    let ch = raw.channel;
    if ch.message_encoding != "cdr" {
        stats.foreign += 1;
        return Ok(None);
    }
    let name = ch.schema_name.as_str();
    let played = |topic: &str, message: AnyMessage| {
        Some(Played {
            topic: bus_topic(topic),
            log_time: raw.log_time,
            message,
        })
    };
    // The sonar ring's PointCloud2 view is derived; the voxel cloud's is the message.
    let sonar_view =
        name == schema::POINT_CLOUD2.name && ch.topic.ends_with(crate::encoder::POINTS_SUFFIX);
    if name == schema::TF_MESSAGE.name || sonar_view {
        stats.views += 1;
        return Ok(None);
    }
    if let Some(layout) = ros2::kind_with_companion(name) {
        let std_topic = layout
            .companion
            .and_then(|(suffix, _)| ch.topic.strip_suffix(suffix));
        let Some(held) = std_topic
            .and_then(|t| pending.get_mut(t))
            .filter(|p| p.held)
        else {
            stats.orphans += 1;
            return Ok(None);
        };
        held.held = false;
        let layout = ros2::kinds_with_companion(name)
            .find(|l| l.standard.name == held.schema)
            .unwrap_or(layout);
        if held.sequence != raw.sequence || held.schema != layout.standard.name {
            stats.orphans += 2;
            return Ok(None);
        }
        let message = ros2::decode(layout.kind, &held.data, Some(raw.data))?;
        return Ok(played(std_topic.unwrap_or_default(), message));
    }
    let mut kinds = ros2::kinds_with_standard(name);
    let Some(first) = kinds.next() else {
        stats.foreign += 1;
        return Ok(None);
    };
    if first.companion.is_none() {
        // A complete message (its schema is no other kind's).
        return ros2::decode(first.kind, raw.data, None).map(|m| played(&ch.topic, m));
    }
    let held = match pending.get_mut(ch.topic.as_str()) {
        Some(p) => p,
        None => pending.entry(ch.topic.clone()).or_default(),
    };
    if held.held {
        stats.orphans += 1;
    }
    held.held = true;
    held.sequence = raw.sequence;
    held.schema = first.standard.name;
    held.data.clear();
    held.data.extend_from_slice(raw.data);
    Ok(None)
}
