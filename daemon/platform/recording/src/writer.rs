//! Batches → an MCAP file in the `ros2` profile, chunk by chunk.
//!
//! Chunks are built in memory and written whole (`disable_seeking`), and a
//! chunk is closed only between batches, when it holds `chunk_bytes` or has
//! been open for `chunk_interval`. Each close flushes the file, so a process
//! killed at any instant leaves every message of every closed chunk readable
//! (see [`crate::reader`]); at most one interval of data is lost.

use crate::encoder::{Batch, ChannelSpec};
use mcap::records::{MessageHeader, Metadata};
use mcap::write::{WriteOptions, Writer};
use std::collections::{BTreeMap, HashMap};
use std::io::{Seek, Write};
use thiserror::Error;

/// Name of the metadata record that identifies a smokenav recording.
pub const METADATA_NAME: &str = "smokenav";
/// Name of the metadata record written when a recording finishes cleanly.
pub const STATS_METADATA_NAME: &str = "smokenav.stats";
/// Version of the channel/schema mapping (see the crate docs). Readers refuse newer ones.
pub const MAPPING_VERSION: u32 = 1;

#[derive(Debug, Error)]
pub enum WriteError {
    #[error("MCAP: {0}")]
    Mcap(#[from] mcap::McapError),
    #[error("I/O: {0}")]
    Io(#[from] std::io::Error),
    #[error("batch refers to channel {channel}, which was never announced")]
    UnknownChannel { channel: usize },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compression {
    None,
    Zstd,
}

#[derive(Debug, Clone)]
pub struct SinkOptions {
    pub compression: Compression,
    /// Close a chunk once it holds this many payload bytes.
    pub chunk_bytes: usize,
    /// Close a chunk once it has been open this long (ns of the caller's clock).
    pub chunk_interval_ns: u64,
}

impl Default for SinkOptions {
    fn default() -> Self {
        Self {
            compression: Compression::Zstd,
            chunk_bytes: 1 << 20,
            chunk_interval_ns: 1_000_000_000,
        }
    }
}

/// Counters of a sink.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SinkStats {
    /// MCAP messages handed to the writer.
    pub messages: u64,
    /// Of those, messages in closed chunks (on disk, readable after a crash).
    pub committed: u64,
    pub chunks: u64,
    /// Payload bytes written.
    pub bytes: u64,
}

pub struct McapSink<W: Write + Seek> {
    writer: Writer<W>,
    /// Encoder channel index → MCAP channel id.
    ids: Vec<Option<u16>>,
    schema_ids: HashMap<&'static str, u16>,
    opts: SinkOptions,
    chunk_payload: usize,
    chunk_opened_ns: Option<u64>,
    in_chunk: u64,
    stats: SinkStats,
}

impl<W: Write + Seek> McapSink<W> {
    /// Starts the file: header (`ros2` profile) and the `smokenav` metadata
    /// record (mapping version plus `metadata`, e.g. instance and start time).
    pub fn create(
        w: W,
        opts: SinkOptions,
        metadata: &BTreeMap<String, String>,
    ) -> Result<Self, WriteError> {
        let compression = match opts.compression {
            Compression::None => None,
            Compression::Zstd => Some(mcap::Compression::Zstd),
        };
        let mut writer = WriteOptions::new()
            .profile("ros2")
            .library(concat!("smokenav-recording ", env!("CARGO_PKG_VERSION")))
            .compression(compression)
            // Chunks are closed by `commit`, only between batches.
            .chunk_size(None)
            .disable_seeking(true)
            // zstd's worker threads would compete with the robot's processes.
            .compression_threads(0)
            .create(w)?;
        let mut meta = metadata.clone();
        meta.insert("mapping_version".into(), MAPPING_VERSION.to_string());
        writer.write_metadata(&Metadata {
            name: METADATA_NAME.into(),
            metadata: meta,
        })?;
        writer.flush()?;
        Ok(Self {
            writer,
            ids: Vec::new(),
            schema_ids: HashMap::new(),
            opts,
            chunk_payload: 0,
            chunk_opened_ns: None,
            in_chunk: 0,
            stats: SinkStats::default(),
        })
    }

    pub fn stats(&self) -> SinkStats {
        self.stats
    }

    fn register(&mut self, index: usize, spec: &ChannelSpec) -> Result<(), WriteError> {
        let schema_id = match self.schema_ids.get(spec.schema.name) {
            Some(&id) => id,
            None => {
                let text = spec.schema.schema_text();
                let id = self
                    .writer
                    .add_schema(spec.schema.name, "ros2msg", text.as_bytes())?;
                self.schema_ids.insert(spec.schema.name, id);
                id
            }
        };
        let mut meta = BTreeMap::new();
        meta.insert("offered_qos_profiles".to_owned(), spec.qos.yaml());
        let id = self
            .writer
            .add_channel(schema_id, &spec.topic, "cdr", &meta)?;
        if self.ids.len() <= index {
            self.ids.resize(index + 1, None);
        }
        self.ids[index] = Some(id);
        Ok(())
    }

    /// Writes one batch (never split across chunks), then closes the chunk
    /// if it is full or old. `now_ns` is the caller's clock.
    pub fn write_batch(&mut self, batch: &Batch, now_ns: u64) -> Result<(), WriteError> {
        for (index, spec) in &batch.new_channels {
            self.register(*index, spec)?;
        }
        for m in batch.messages() {
            let Some(&Some(channel_id)) = self.ids.get(m.channel) else {
                return Err(WriteError::UnknownChannel { channel: m.channel });
            };
            self.writer.write_to_known_channel(
                &MessageHeader {
                    channel_id,
                    sequence: m.sequence,
                    log_time: m.log_time,
                    publish_time: m.publish_time,
                },
                &m.data,
            )?;
            self.chunk_payload += m.data.len();
            self.stats.bytes += m.data.len() as u64;
            self.stats.messages += 1;
            self.in_chunk += 1;
        }
        if self.in_chunk > 0 && self.chunk_opened_ns.is_none() {
            self.chunk_opened_ns = Some(now_ns);
        }
        if self.chunk_payload >= self.opts.chunk_bytes {
            self.commit()?;
        } else {
            self.tick(now_ns)?;
        }
        Ok(())
    }

    /// Closes the open chunk if it has been open for the chunk interval.
    /// Call it periodically (e.g. after every bus wait) so quiet topics are
    /// committed too. Returns whether a chunk was closed.
    pub fn tick(&mut self, now_ns: u64) -> Result<bool, WriteError> {
        match self.chunk_opened_ns {
            Some(t) if now_ns.saturating_sub(t) >= self.opts.chunk_interval_ns => {
                self.commit()?;
                Ok(true)
            }
            _ => Ok(false),
        }
    }

    /// Closes the open chunk and flushes it to the file.
    pub fn commit(&mut self) -> Result<(), WriteError> {
        if self.in_chunk == 0 {
            return Ok(());
        }
        self.writer.flush()?;
        self.stats.committed += self.in_chunk;
        self.stats.chunks += 1;
        self.in_chunk = 0;
        self.chunk_payload = 0;
        self.chunk_opened_ns = None;
        Ok(())
    }

    /// Closes the last chunk, writes `stats_metadata` (if any), the summary
    /// (with Statistics, which `ros2 bag` requires) and the footer, and
    /// returns the flushed output.
    pub fn finish(
        mut self,
        stats_metadata: Option<BTreeMap<String, String>>,
    ) -> Result<(W, SinkStats), WriteError> {
        self.commit()?;
        if let Some(m) = stats_metadata {
            self.writer.write_metadata(&Metadata {
                name: STATS_METADATA_NAME.into(),
                metadata: m,
            })?;
        }
        self.writer.finish()?;
        let mut w = self.writer.into_inner();
        w.flush()?;
        Ok((w, self.stats))
    }
}
