//! What an MCAP file holds, the way `ros2 bag info` tells it, and whether
//! every chunk of it still reads.
//!
//! [`inspect`] walks the file's top-level records (chunks are not
//! decompressed) and, when the file has a summary, takes message counts
//! from its statistics. With `check` (or when there is no summary, as after
//! a killed recorder) it also decompresses every chunk, verifies its CRC
//! before any record in it is parsed, and reads every record inside: a
//! damaged chunk is listed with its number and file offset, and the walk
//! goes on with the next one. (A flipped byte in compressed data
//! decompresses to garbage lengths; the crate's chunk reader, which checks
//! the CRC only at the end, reserved them, and a 140 TB allocation aborted
//! `smokenav info --check`.)
//! A break in the top-level framing ends the walk, reported the same way.

use crate::reader::MAX_RECORD_BYTES;
use crate::writer::METADATA_NAME;
use mcap::McapResult;
use mcap::records::Record;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use std::collections::BTreeMap;

/// One MCAP channel: its topic, type and message count.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct ChannelSummary {
    pub topic: String,
    /// The schema name (`sensor_msgs/msg/LaserScan`); empty when the channel has none.
    pub schema: String,
    pub message_encoding: String,
    pub messages: u64,
    /// Log times of its first and last message, ns.
    pub first_log_time: Option<u64>,
    pub last_log_time: Option<u64>,
}

impl ChannelSummary {
    /// Messages per second between its own first and last message.
    pub fn rate_hz(&self) -> Option<f64> {
        let (a, b) = (self.first_log_time?, self.last_log_time?);
        (b > a && self.messages > 1).then(|| (self.messages - 1) as f64 / ((b - a) as f64 * 1e-9))
    }
}

/// One chunk as the file frames it.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct ChunkSummary {
    /// Offset of the chunk record in the file, when the summary's chunk index gives it.
    pub offset: Option<u64>,
    /// Length of the chunk record, bytes (from the chunk index).
    pub length: Option<u64>,
    pub compression: String,
    pub compressed_bytes: u64,
    pub uncompressed_bytes: u64,
    pub message_start_time: u64,
    pub message_end_time: u64,
}

/// Damage found in a file.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct Damage {
    /// The chunk (0-based, in file order) that does not read; `None` when the
    /// file's framing broke outside a chunk.
    pub chunk: Option<usize>,
    /// Its file offset, when the chunk index gives it.
    pub offset: Option<u64>,
    /// What the reader said.
    pub error: String,
}

/// What [`inspect`] found.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct FileInfo {
    pub bytes: u64,
    /// The Header record's profile (`ros2`) and writing library.
    pub profile: String,
    pub library: String,
    /// The file ends with a summary (statistics and indexes).
    pub has_summary: bool,
    /// Every chunk was decompressed and read (`check`, or no summary).
    pub chunks_read: bool,
    pub messages: u64,
    /// Log time of the first and last message, ns (Unix time in recordings
    /// made since smokenav stores Unix times; see [`FileInfo::unix_offset_ns`]).
    pub start_time: Option<u64>,
    pub end_time: Option<u64>,
    pub channels: Vec<ChannelSummary>,
    pub chunks: Vec<ChunkSummary>,
    /// Metadata records by name.
    pub metadata: BTreeMap<String, BTreeMap<String, String>>,
    pub damage: Vec<Damage>,
}

impl FileInfo {
    /// The offset smokenav's recorder added to its monotonic clock to make
    /// the file's times Unix times, if it recorded one.
    pub fn unix_offset_ns(&self) -> Option<i64> {
        self.metadata
            .get(METADATA_NAME)?
            .get(crate::UNIX_OFFSET_KEY)?
            .parse()
            .ok()
    }

    /// Seconds from the first message to the last.
    pub fn duration_s(&self) -> f64 {
        match (self.start_time, self.end_time) {
            (Some(a), Some(b)) => b.saturating_sub(a) as f64 * 1e-9,
            _ => 0.0,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum InfoError {
    #[error("not an MCAP file: {0}")]
    NotMcap(String),
}

/// The chunk record again, opcode to the end of its data, from its parsed
/// header and data (the top-level reader copies the data out of the file).
fn chunk_record(header: &mcap::records::ChunkHeader, data: &[u8]) -> Vec<u8> {
    let c = header.compression.as_bytes();
    let body = 8 + 8 + 8 + 4 + (4 + c.len()) + 8 + data.len();
    let mut r = Vec::with_capacity(1 + 8 + body);
    r.push(mcap::records::op::CHUNK);
    r.extend_from_slice(&(body as u64).to_le_bytes());
    r.extend_from_slice(&header.message_start_time.to_le_bytes());
    r.extend_from_slice(&header.message_end_time.to_le_bytes());
    r.extend_from_slice(&header.uncompressed_size.to_le_bytes());
    r.extend_from_slice(&header.uncompressed_crc.to_le_bytes());
    r.extend_from_slice(&(c.len() as u32).to_le_bytes());
    r.extend_from_slice(c);
    r.extend_from_slice(&(data.len() as u64).to_le_bytes());
    r.extend_from_slice(data);
    r
}

/// Reads one chunk record's inner records, its CRC checked before the first
/// is parsed and every record's length held to [`MAX_RECORD_BYTES`].
fn read_chunk(chunk: &[u8], mut each: impl FnMut(Record<'_>)) -> McapResult<()> {
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_start_magic(true)
            .with_skip_end_magic(true)
            .with_prevalidate_chunk_crcs(true)
            .with_record_length_limit(MAX_RECORD_BYTES),
    );
    let mut rest = chunk;
    while let Some(event) = reader.next_event() {
        match event? {
            LinearReadEvent::ReadRequest(need) => {
                let n = need.min(rest.len());
                reader.insert(n).copy_from_slice(&rest[..n]);
                reader.notify_read(n);
                rest = &rest[n..];
            }
            LinearReadEvent::Record { opcode, data } => each(mcap::parse_record(opcode, data)?),
        }
    }
    Ok(())
}

#[derive(Default)]
struct ChannelAcc {
    topic: String,
    schema_id: u16,
    message_encoding: String,
    messages: u64,
    times: Option<(u64, u64)>,
}

fn widen(times: &mut Option<(u64, u64)>, t: u64) {
    *times = Some(times.map_or((t, t), |(a, b)| (a.min(t), b.max(t))));
}

/// Reads what `bytes` (a whole MCAP file) holds; with `check`, decompresses
/// and reads every chunk. Damage is reported in [`FileInfo::damage`], not
/// as an error: only a file that does not start as MCAP is an error.
pub fn inspect(bytes: &[u8], check: bool) -> Result<FileInfo, InfoError> {
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(InfoError::NotMcap(
            "it does not start with the MCAP magic".into(),
        ));
    }
    let mut info = FileInfo {
        bytes: bytes.len() as u64,
        ..FileInfo::default()
    };
    // A summary that does not parse counts as none: the chunks are then read.
    let summary = mcap::read::Summary::read(bytes).ok().flatten();
    info.has_summary = summary.as_ref().is_some_and(|s| s.stats.is_some());
    let read_chunks = check || !info.has_summary;
    info.chunks_read = read_chunks;
    let chunk_index: Vec<(u64, u64)> = summary
        .as_ref()
        .map(|s| {
            let mut v: Vec<(u64, u64)> = s
                .chunk_indexes
                .iter()
                .map(|c| (c.chunk_start_offset, c.chunk_length))
                .collect();
            v.sort();
            v
        })
        .unwrap_or_default();

    let mut schemas: BTreeMap<u16, String> = BTreeMap::new();
    let mut channels: BTreeMap<u16, ChannelAcc> = BTreeMap::new();
    let mut times: Option<(u64, u64)> = None;
    let on_record = |r: Record<'_>,
                     schemas: &mut BTreeMap<u16, String>,
                     channels: &mut BTreeMap<u16, ChannelAcc>,
                     times: &mut Option<(u64, u64)>| match r {
        Record::Schema { header, .. } => {
            schemas.insert(header.id, header.name);
        }
        Record::Channel(c) => {
            let e = channels.entry(c.id).or_default();
            e.topic = c.topic;
            e.schema_id = c.schema_id;
            e.message_encoding = c.message_encoding;
        }
        Record::Message { header, .. } => {
            let c = channels.entry(header.channel_id).or_default();
            c.messages += 1;
            widen(&mut c.times, header.log_time);
            widen(times, header.log_time);
        }
        _ => {}
    };

    let reader = mcap::read::LinearReader::new_with_options(
        bytes,
        enumset::enum_set!(mcap::read::Options::IgnoreEndMagic),
    )
    .map_err(|e| InfoError::NotMcap(e.to_string()))?;
    for record in reader {
        let record = match record {
            Ok(r) => r,
            Err(e) => {
                info.damage.push(Damage {
                    chunk: None,
                    offset: None,
                    error: format!(
                        "the file's records end after chunk {}: {e}",
                        info.chunks.len()
                    ),
                });
                break;
            }
        };
        match record {
            Record::Header(h) => {
                info.profile = h.profile;
                info.library = h.library;
            }
            Record::Metadata(m) => {
                info.metadata.insert(m.name, m.metadata);
            }
            // Without reading the chunks, their message indexes give each
            // channel's times (the summary's statistics give the counts).
            Record::MessageIndex(mi) if !read_chunks => {
                let c = channels.entry(mi.channel_id).or_default();
                for e in &mi.records {
                    widen(&mut c.times, e.log_time);
                }
            }
            Record::Chunk { header, data } => {
                let n = info.chunks.len();
                let (offset, length) = chunk_index
                    .get(n)
                    .map_or((None, None), |&(o, l)| (Some(o), Some(l)));
                info.chunks.push(ChunkSummary {
                    offset,
                    length,
                    compression: if header.compression.is_empty() {
                        "none".into()
                    } else {
                        header.compression.clone()
                    },
                    compressed_bytes: data.len() as u64,
                    uncompressed_bytes: header.uncompressed_size,
                    message_start_time: header.message_start_time,
                    message_end_time: header.message_end_time,
                });
                if read_chunks {
                    // Counted into copies first: a chunk that fails half way
                    // must not leave half of its messages counted.
                    let (mut s, mut c, mut t) =
                        (schemas.clone(), channels_snapshot(&channels), times);
                    let chunk = chunk_record(&header, &data);
                    let outcome = read_chunk(&chunk, |r| on_record(r, &mut s, &mut c, &mut t));
                    match outcome {
                        Ok(()) => {
                            schemas = s;
                            channels = c;
                            times = t;
                        }
                        Err(e) => info.damage.push(Damage {
                            chunk: Some(n),
                            offset,
                            error: e.to_string(),
                        }),
                    }
                }
            }
            r @ (Record::Schema { .. } | Record::Channel(_) | Record::Message { .. }) => {
                on_record(r, &mut schemas, &mut channels, &mut times);
            }
            _ => {}
        }
    }

    if let Some(s) = &summary {
        for (id, sc) in &s.schemas {
            schemas.entry(*id).or_insert_with(|| sc.name.clone());
        }
        for (id, ch) in &s.channels {
            let e = channels.entry(*id).or_default();
            if e.topic.is_empty() {
                e.topic = ch.topic.clone();
                e.schema_id = ch.schema.as_ref().map_or(0, |s| s.id);
                e.message_encoding = ch.message_encoding.clone();
            }
        }
        if !read_chunks && let Some(stats) = &s.stats {
            for (id, n) in &stats.channel_message_counts {
                channels.entry(*id).or_default().messages = *n;
            }
            if stats.message_count > 0 {
                times = Some((stats.message_start_time, stats.message_end_time));
            }
        }
    }
    info.start_time = times.map(|t| t.0);
    info.end_time = times.map(|t| t.1);
    info.channels = channels
        .into_values()
        .map(|c| ChannelSummary {
            schema: schemas.get(&c.schema_id).cloned().unwrap_or_default(),
            topic: c.topic,
            message_encoding: c.message_encoding,
            messages: c.messages,
            first_log_time: c.times.map(|t| t.0),
            last_log_time: c.times.map(|t| t.1),
        })
        .collect();
    info.channels.sort_by(|a, b| a.topic.cmp(&b.topic));
    info.messages = info.channels.iter().map(|c| c.messages).sum();
    if check
        && let Some(stats) = summary.as_ref().and_then(|s| s.stats.as_ref())
        && stats.message_count != info.messages
        && info.damage.is_empty()
    {
        info.damage.push(Damage {
            chunk: None,
            offset: None,
            error: format!(
                "the summary counts {} messages, the chunks hold {}",
                stats.message_count, info.messages
            ),
        });
    }
    Ok(info)
}

fn channels_snapshot(c: &BTreeMap<u16, ChannelAcc>) -> BTreeMap<u16, ChannelAcc> {
    c.iter()
        .map(|(k, v)| {
            (
                *k,
                ChannelAcc {
                    topic: v.topic.clone(),
                    schema_id: v.schema_id,
                    message_encoding: v.message_encoding.clone(),
                    messages: v.messages,
                    times: v.times,
                },
            )
        })
        .collect()
}

/// A Unix time in ns as `YYYY-MM-DD HH:MM:SS.mmm UTC` (proleptic Gregorian).
pub fn format_utc(unix_ns: u64) -> String {
    let secs = unix_ns / 1_000_000_000;
    let ms = (unix_ns % 1_000_000_000) / 1_000_000;
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    // Days since 1970-01-01 to a civil date (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02} {:02}:{:02}:{:02}.{ms:03} UTC",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Recorder, SinkOptions};
    use smokenav_shared_types::{AnyMessageRef, Header, LaserScan};

    /// 40 scans at 10 Hz in chunks of about 20 kB, the summary written.
    fn recording() -> Vec<u8> {
        let opts = SinkOptions {
            chunk_bytes: 20_000,
            ..Default::default()
        };
        let mut rec = Recorder::create(
            std::io::Cursor::new(Vec::new()),
            opts,
            None,
            &BTreeMap::new(),
            0,
        )
        .unwrap();
        let mut scan = Box::<LaserScan>::default();
        for k in 0..40u64 {
            scan.header = Header::new(k * 100_000_000, k, "laser");
            scan.count = 500;
            rec.record(
                "laser/scan",
                AnyMessageRef::LaserScan(&scan),
                k * 100_000_000,
            )
            .unwrap();
        }
        rec.finish(None).unwrap().0.into_inner()
    }

    #[test]
    fn the_summary_gives_counts_types_duration_and_chunks() {
        let bytes = recording();
        let info = inspect(&bytes, false).unwrap();
        assert!(info.has_summary && !info.chunks_read);
        assert_eq!(info.profile, "ros2");
        let scans = info
            .channels
            .iter()
            .find(|c| c.topic == "/laser/scan")
            .unwrap();
        assert_eq!(scans.schema, "sensor_msgs/msg/LaserScan");
        assert_eq!(scans.messages, 40);
        // From the message indexes: 40 scans 0.1 s apart.
        assert_eq!(scans.first_log_time, Some(0));
        assert_eq!(scans.last_log_time, Some(3_900_000_000));
        assert!((scans.rate_hz().unwrap() - 10.0).abs() < 1e-9);
        assert!(
            (info.duration_s() - 3.9).abs() < 1e-9,
            "{}",
            info.duration_s()
        );
        assert!(info.chunks.len() > 1, "{:?}", info.chunks);
        assert!(
            info.chunks
                .iter()
                .all(|c| c.compression == "zstd" && c.offset.is_some())
        );
        // Reading every chunk finds the same and no damage.
        let checked = inspect(&bytes, true).unwrap();
        assert!(
            checked.chunks_read && checked.damage.is_empty(),
            "{:?}",
            checked.damage
        );
        assert_eq!(checked.channels, info.channels);
        assert_eq!(
            (checked.start_time, checked.end_time),
            (info.start_time, info.end_time)
        );
    }

    #[test]
    fn a_flipped_byte_in_a_chunk_is_found_and_named() {
        let mut bytes = recording();
        let info = inspect(&bytes, false).unwrap();
        let c = &info.chunks[1];
        let at = (c.offset.unwrap() + c.length.unwrap() / 2) as usize;
        bytes[at] ^= 0x10;
        // The summary alone does not see it.
        assert!(inspect(&bytes, false).unwrap().damage.is_empty());
        let checked = inspect(&bytes, true).unwrap();
        assert_eq!(checked.damage.len(), 1, "{:?}", checked.damage);
        assert_eq!(checked.damage[0].chunk, Some(1));
        assert_eq!(checked.damage[0].offset, c.offset);
        // The other chunks still read; the damaged one's messages are not counted.
        assert!(
            checked.messages < info.messages && checked.messages > 0,
            "{}",
            checked.messages
        );
    }

    /// Flipped bits anywhere in a chunk's compressed data: the chunk is
    /// reported damaged, never parsed, unless the flip changed nothing the
    /// data decodes to (a bit of the zstd frame header's window size). Before
    /// the CRC was checked first, some flips decompressed to record lengths
    /// of terabytes and the process aborted on the allocation (`smokenav info
    /// --check`, 10 of 151 flips in one simulator recording).
    #[test]
    fn flipped_bits_in_compressed_data_are_damage_not_an_abort() {
        let bytes = recording();
        let info = inspect(&bytes, false).unwrap();
        let intact = inspect(&bytes, true).unwrap();
        let c = &info.chunks[1];
        let end = (c.offset.unwrap() + c.length.unwrap()) as usize;
        let data = end - c.compressed_bytes as usize;
        for at in (data..end).step_by(3) {
            for bit in [0x01u8, 0x80] {
                let mut b = bytes.clone();
                b[at] ^= bit;
                let checked = inspect(&b, true).unwrap();
                let damaged = checked.damage.iter().any(|d| d.chunk == Some(1));
                let unchanged = checked.damage.is_empty()
                    && (checked.messages, &checked.channels) == (intact.messages, &intact.channels);
                assert!(
                    damaged || unchanged,
                    "byte {at} ^ {bit:#x}: {:?}",
                    checked.damage
                );
            }
        }
    }

    #[test]
    fn a_file_without_summary_is_read_chunk_by_chunk() {
        let bytes = recording();
        let info = inspect(&bytes, false).unwrap();
        // Cut inside the last chunk, as a killed recorder leaves a file.
        let last = info.chunks.last().unwrap();
        let cut = &bytes[..(last.offset.unwrap() + last.length.unwrap() / 2) as usize];
        let partial = inspect(cut, false).unwrap();
        assert!(!partial.has_summary && partial.chunks_read);
        assert!(
            partial.messages > 0 && partial.messages < info.messages,
            "{}",
            partial.messages
        );
        assert_eq!(partial.damage.len(), 1, "{:?}", partial.damage);
        assert!(inspect(b"not mcap", false).is_err());
        // Any bytes at all: an answer, never a panic.
        for n in (0..bytes.len()).step_by(997) {
            let _ = inspect(&bytes[..n], true);
        }
    }

    #[test]
    fn utc_dates_match_known_instants() {
        assert_eq!(format_utc(0), "1970-01-01 00:00:00.000 UTC");
        // 2000-02-29 12:34:56.789 UTC: a leap day of a century leap year.
        assert_eq!(
            format_utc(951_827_696_789_000_000),
            "2000-02-29 12:34:56.789 UTC"
        );
        assert_eq!(
            format_utc(1_796_158_233_726_927_692),
            "2026-12-01 20:50:33.726 UTC"
        );
    }
}
