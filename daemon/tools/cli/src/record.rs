//! `smokenav record -o run.mcap [TOPICS…]`: tap the bus into an MCAP file.
//!
//! The main thread only receives and encodes (subscribers never block a
//! publisher; a slow recorder shows up as sequence gaps, counted per topic);
//! a writer thread compresses and writes chunks, closing one at least every
//! `--chunk-interval` so a SIGKILL loses at most that much. SIGINT/SIGTERM
//! finish the file (summary, statistics, footer) and print the report.

use crate::topic::{BusArgs, known_topics};
use anyhow::{Context, bail};
use clap::Args;
use smokenav_platform_bus::tap::{self, Tap};
use smokenav_platform_bus::{Attachment, Waiter};
use smokenav_platform_config::RobotConfig;
use smokenav_platform_recording::{
    AnyMessageRef, Batch, Compression, Encoder, McapSink, RobotGeometry, SinkOptions,
};
use smokenav_shared_types::catalog;
use smokenav_shared_types::clock::monotonic_now_ns;
use std::collections::BTreeMap;
use std::io::{BufWriter, Write};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, sync_channel};
use std::time::{Duration, Instant};

#[derive(Debug, Args)]
pub struct RecordArgs {
    /// The MCAP file to write.
    #[arg(short = 'o', long)]
    pub output: PathBuf,
    /// Bus topics to record, as laser/scan or /laser/scan (default: every known topic of the instance).
    #[arg(value_parser = crate::topic::bus_topic)]
    pub topics: Vec<String>,
    /// Close and flush a chunk at least this often, s: the most a crash (SIGKILL) can lose.
    #[arg(long, default_value_t = 1.0)]
    pub chunk_interval: f64,
    /// Close a chunk once it holds this many bytes of messages.
    #[arg(long, default_value_t = 1 << 20)]
    pub chunk_bytes: usize,
    /// Write chunks uncompressed (default: zstd).
    #[arg(long)]
    pub no_compression: bool,
    /// Stop after this many seconds.
    #[arg(long)]
    pub duration: Option<f64>,
    /// Replace the output file if it exists.
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub bus: BusArgs,
}

/// Encoded batches in flight between the receiving and the writing thread.
/// 256 batches ≈ 25 s of every topic at 10 Hz: a disk stall of that length
/// costs no message.
const BATCHES_IN_FLIGHT: usize = 256;

enum ToWriter {
    Batch(Batch),
    Finish(BTreeMap<String, String>),
}

/// Committed-message counter shared with the writer thread, for the final report.
#[derive(Default)]
struct Progress {
    committed: AtomicU64,
    chunks: AtomicU64,
    bytes: AtomicU64,
}

fn writer_thread(
    mut sink: McapSink<BufWriter<std::fs::File>>,
    batches: Receiver<ToWriter>,
    empties: SyncSender<Batch>,
    progress: Arc<Progress>,
) -> anyhow::Result<()> {
    let publish = |sink: &McapSink<_>| {
        let s = sink.stats();
        progress.committed.store(s.committed, Ordering::Relaxed);
        progress.chunks.store(s.chunks, Ordering::Relaxed);
        progress.bytes.store(s.bytes, Ordering::Relaxed);
    };
    let mut chunks = 0;
    loop {
        let msg = batches.recv_timeout(Duration::from_millis(100));
        let now = monotonic_now_ns();
        match msg {
            Ok(ToWriter::Batch(mut b)) => {
                sink.write_batch(&b, now)?;
                b.clear();
                // Never block here: at shutdown nobody takes batches back (dropping one is fine).
                let _ = empties.try_send(b);
            }
            Ok(ToWriter::Finish(stats)) => {
                let (_, s) = sink.finish(Some(stats))?;
                progress.committed.store(s.committed, Ordering::Relaxed);
                progress.chunks.store(s.chunks, Ordering::Relaxed);
                progress.bytes.store(s.bytes, Ordering::Relaxed);
                return Ok(());
            }
            Err(RecvTimeoutError::Timeout) => {
                sink.tick(now)?;
            }
            Err(RecvTimeoutError::Disconnected) => {
                sink.finish(None)?;
                return Ok(());
            }
        }
        let s = sink.stats();
        if s.chunks != chunks {
            chunks = s.chunks;
            publish(&sink);
            tracing::debug!(
                committed = s.committed,
                chunks = s.chunks,
                "chunk committed: {} messages on disk",
                s.committed
            );
        }
    }
}

pub fn run(args: RecordArgs) -> anyhow::Result<()> {
    smokenav_platform_runtime::init_logging("record");
    let topics = if args.topics.is_empty() {
        tap::default_topics()
    } else {
        args.topics.clone()
    };
    for t in &topics {
        if catalog::topic_kind(t).is_none() {
            bail!("unknown topic `{t}` (known: {})", known_topics());
        }
    }
    if args.chunk_interval <= 0.0 || !args.chunk_interval.is_finite() {
        bail!("--chunk-interval must be a positive number of seconds");
    }
    let profile = match &args.bus.config {
        Some(path) => Some(
            RobotConfig::load(path)
                .with_context(|| format!("invalid robot profile {}", path.display()))?,
        ),
        None => None,
    };
    if profile.is_none() {
        tracing::info!("no robot profile (--config): /tf_static and sonar points are not written");
    }
    let bus = args.bus.open("record")?;

    let file = if args.force {
        std::fs::File::create(&args.output)
    } else {
        std::fs::File::create_new(&args.output)
    }
    .with_context(|| format!("cannot create {}", args.output.display()))?;
    let started_ns = monotonic_now_ns();
    // The bus keeps the monotonic clock; the file's log and publish times are
    // Unix times, so tools show real dates. Fixed once: an NTP step during the
    // recording does not tear its timeline.
    let unix_offset = smokenav_platform_recording::unix_offset_now();
    let mut meta = BTreeMap::new();
    meta.insert("instance".to_owned(), bus.instance().to_owned());
    meta.insert(
        "recorder".to_owned(),
        format!("smokenav {}", env!("CARGO_PKG_VERSION")),
    );
    meta.insert(
        "clock".to_owned(),
        "log and publish times: Unix ns (bus CLOCK_MONOTONIC + unix_offset_ns); \
         message header stamps: CLOCK_MONOTONIC ns"
            .to_owned(),
    );
    meta.insert(
        smokenav_platform_recording::UNIX_OFFSET_KEY.to_owned(),
        unix_offset.to_string(),
    );
    meta.insert("start_monotonic_ns".to_owned(), started_ns.to_string());
    meta.insert(
        "start_unix_ns".to_owned(),
        smokenav_platform_recording::shift_ns(started_ns, unix_offset).to_string(),
    );
    meta.insert("topics".to_owned(), topics.join(","));
    if let Some(cfg) = &profile {
        meta.insert("robot".to_owned(), cfg.robot.name.clone());
    }
    let opts = SinkOptions {
        compression: if args.no_compression {
            Compression::None
        } else {
            Compression::Zstd
        },
        chunk_bytes: args.chunk_bytes.max(1),
        chunk_interval_ns: (args.chunk_interval * 1e9) as u64,
    };
    let sink = McapSink::create(BufWriter::with_capacity(1 << 16, file), opts, &meta)?;

    let taps: Vec<Box<dyn Tap>> = topics
        .iter()
        .map(|t| tap::open(&bus, t))
        .collect::<Result<_, _>>()?;

    let (to_writer, batches) = sync_channel::<ToWriter>(BATCHES_IN_FLIGHT);
    let (empties_tx, empties) = sync_channel::<Batch>(BATCHES_IN_FLIGHT);
    for _ in 0..BATCHES_IN_FLIGHT {
        empties_tx.send(Batch::new())?;
    }
    let progress = Arc::new(Progress::default());
    let writer = {
        let progress = progress.clone();
        std::thread::Builder::new()
            .name("mcap-writer".into())
            .spawn(move || writer_thread(sink, batches, empties_tx, progress))?
    };

    let mut encoder = Encoder::new(profile.as_ref().map(RobotGeometry::from_config));
    encoder.set_unix_offset(unix_offset);
    let mut first = Batch::new();
    encoder.static_transforms(started_ns, &mut first);
    to_writer.send(ToWriter::Batch(first))?;

    let stop = smokenav_platform_runtime::Shutdown::install()?;
    let end = args
        .duration
        .map(|d| Instant::now() + Duration::from_secs_f64(d));
    println!(
        "recording {} topics of instance `{}` to {}",
        topics.len(),
        bus.instance(),
        args.output.display()
    );
    std::io::stdout().flush()?;

    let mut stalls = 0u64;
    let waiter = Waiter::new()?;
    let attached: Vec<Attachment> = taps
        .iter()
        .map(|t| t.attach(&waiter))
        .collect::<Result<_, _>>()?;
    let mut send = |topic: &str, msg: AnyMessageRef<'_>| -> anyhow::Result<()> {
        let mut batch = match empties.try_recv() {
            Ok(b) => b,
            Err(_) => {
                // The writer is behind: wait for it (the bus queues absorb the pause).
                stalls += 1;
                empties.recv().context("the MCAP writer stopped")?
            }
        };
        encoder.encode(topic, msg, monotonic_now_ns(), &mut batch);
        to_writer
            .send(ToWriter::Batch(batch))
            .context("the MCAP writer stopped")
    };
    loop {
        // Data, a signal or the timeout all lead to a drain of every topic.
        waiter.wait(Some(Duration::from_millis(100)))?;
        for tap in &taps {
            tap.drain(&mut |t, m| send(t, m).map_err(Into::into))?;
        }
        if stop.requested() || end.is_some_and(|e| Instant::now() >= e) || writer.is_finished() {
            break;
        }
    }
    drop(attached);

    let mut report = BTreeMap::new();
    let mut total_lost = 0;
    let mut lines = Vec::new();
    for tap in &taps {
        let s = tap.stats();
        total_lost += s.lost;
        report.insert(format!("{}.received", tap.topic()), s.received.to_string());
        report.insert(format!("{}.lost", tap.topic()), s.lost.to_string());
        report.insert(
            format!("{}.publisher_restarts", tap.topic()),
            s.publisher_restarts.to_string(),
        );
        if s.received > 0 || s.lost > 0 {
            lines.push(format!(
                "  {:<16} received {:>8}  lost {:>6}  publisher restarts {}",
                tap.topic(),
                s.received,
                s.lost,
                s.publisher_restarts
            ));
        }
    }
    report.insert("writer_stalls".into(), stalls.to_string());
    let finished = to_writer.send(ToWriter::Finish(report)).is_ok();
    drop(to_writer);
    let written = writer
        .join()
        .map_err(|_| anyhow::anyhow!("the MCAP writer panicked"))?;
    written.with_context(|| format!("writing {} failed", args.output.display()))?;
    if !finished {
        bail!("the MCAP writer stopped early");
    }
    let received: u64 = taps.iter().map(|t| t.stats().received).sum();
    let size = std::fs::metadata(&args.output)
        .map(|m| m.len())
        .unwrap_or(0);
    println!(
        "recorded {received} messages ({} MCAP messages, {} chunks, {:.1} MB) to {}",
        progress.committed.load(Ordering::Relaxed),
        progress.chunks.load(Ordering::Relaxed),
        size as f64 / 1e6,
        args.output.display()
    );
    for l in lines {
        println!("{l}");
    }
    println!(
        "gaps: {total_lost} messages lost{}",
        if stalls > 0 {
            format!(" (the writer fell behind {stalls} times)")
        } else {
            String::new()
        }
    );
    Ok(())
}
