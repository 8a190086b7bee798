//! `smokenav info FILE [--check] [--json]`: a recording described the way
//! `ros2 bag info` does (duration, dates, per-topic counts, types and rates,
//! chunks and compression), and with `--check` every chunk read back.

use anyhow::Context;
use smokenav_platform_recording::info::{FileInfo, format_utc, inspect};
use std::io::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args, Debug)]
pub struct InfoArgs {
    /// The MCAP file (a `smokenav record` recording or any MCAP file).
    pub file: PathBuf,
    /// Decompress and read every chunk, verifying its CRC; list damaged chunks
    /// and exit with status 1 if there is any.
    #[arg(long)]
    pub check: bool,
    /// One JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Times before this are not dates but a monotonic clock (the host's uptime):
/// recordings made before smokenav stored Unix times.
const YEAR_2000_NS: u64 = 946_684_800_000_000_000;

fn size(bytes: u64) -> String {
    match bytes as f64 {
        b if b >= 1e9 => format!("{:.2} GB", b / 1e9),
        b if b >= 1e6 => format!("{:.2} MB", b / 1e6),
        b if b >= 1e3 => format!("{:.1} KB", b / 1e3),
        b => format!("{b} B"),
    }
}

fn time(ns: Option<u64>) -> String {
    match ns {
        Some(t) if t >= YEAR_2000_NS => format!(
            "{} ({}.{:09})",
            format_utc(t),
            t / 1_000_000_000,
            t % 1_000_000_000
        ),
        Some(t) => format!(
            "{}.{:09} s of a monotonic clock (no wall-clock offset recorded)",
            t / 1_000_000_000,
            t % 1_000_000_000
        ),
        None => "-".into(),
    }
}

pub fn run(args: InfoArgs) -> anyhow::Result<ExitCode> {
    let bytes = std::fs::read(&args.file)
        .with_context(|| format!("cannot read {}", args.file.display()))?;
    let info = inspect(&bytes, args.check).with_context(|| args.file.display().to_string())?;
    let damaged = !info.damage.is_empty();
    if args.json {
        let mut v = serde_json::to_value(&info)?;
        v["file"] = serde_json::json!(args.file);
        v["duration_s"] = serde_json::json!(info.duration_s());
        v["start"] = serde_json::json!(info.start_time.map(format_utc));
        v["end"] = serde_json::json!(info.end_time.map(format_utc));
        println!("{v}");
    } else {
        print_text(&args, &info)?;
    }
    Ok(if args.check && damaged {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    })
}

fn print_text(args: &InfoArgs, info: &FileInfo) -> anyhow::Result<()> {
    let mut o = std::io::stdout().lock();
    let d = info.duration_s();
    writeln!(o, "Files:             {}", args.file.display())?;
    writeln!(o, "Bag size:          {}", size(info.bytes))?;
    writeln!(
        o,
        "Storage id:        mcap (profile {}, written by {})",
        if info.profile.is_empty() {
            "none"
        } else {
            &info.profile
        },
        if info.library.is_empty() {
            "?"
        } else {
            &info.library
        }
    )?;
    writeln!(o, "Duration:          {d:.3}s")?;
    writeln!(o, "Start:             {}", time(info.start_time))?;
    writeln!(o, "End:               {}", time(info.end_time))?;
    writeln!(o, "Messages:          {}", info.messages)?;
    let compressed: u64 = info.chunks.iter().map(|c| c.compressed_bytes).sum();
    let uncompressed: u64 = info.chunks.iter().map(|c| c.uncompressed_bytes).sum();
    let mut by_compression = std::collections::BTreeMap::<&str, usize>::new();
    for c in &info.chunks {
        *by_compression.entry(&c.compression).or_default() += 1;
    }
    let kinds: Vec<String> = by_compression
        .iter()
        .map(|(k, n)| format!("{n} {k}"))
        .collect();
    writeln!(
        o,
        "Chunks:            {} ({}), {} compressed from {}{}",
        info.chunks.len(),
        kinds.join(", "),
        size(compressed),
        size(uncompressed),
        if uncompressed > 0 {
            format!(" (ratio {:.2})", compressed as f64 / uncompressed as f64)
        } else {
            String::new()
        }
    )?;
    if !info.has_summary {
        writeln!(
            o,
            "Summary:           none (the recorder was stopped hard?); counts are from the chunks that read"
        )?;
    }
    let width = info
        .channels
        .iter()
        .map(|c| c.topic.len())
        .max()
        .unwrap_or(0);
    let swidth = info
        .channels
        .iter()
        .map(|c| c.schema.len())
        .max()
        .unwrap_or(0);
    for (i, c) in info.channels.iter().enumerate() {
        let rate = c
            .rate_hz()
            .map_or_else(|| "-".to_owned(), |r| format!("{r:.2} Hz"));
        writeln!(
            o,
            "{}Topic: {:width$} | Type: {:swidth$} | Count: {:>7} | Rate: {:>9} | Serialization Format: {}",
            if i == 0 {
                "Topic information: "
            } else {
                "                   "
            },
            c.topic,
            c.schema,
            c.messages,
            rate,
            c.message_encoding
        )?;
    }
    if info.chunks_read {
        if info.damage.is_empty() {
            writeln!(
                o,
                "Check:             OK, every chunk of {} read ({} messages)",
                info.chunks.len(),
                info.messages
            )?;
        } else {
            writeln!(o, "Check:             {} damaged:", info.damage.len())?;
            for dmg in &info.damage {
                match (dmg.chunk, dmg.offset) {
                    (Some(n), Some(off)) => writeln!(
                        o,
                        "  chunk {n} of {} at offset {off}: {}",
                        info.chunks.len(),
                        dmg.error
                    )?,
                    (Some(n), None) => writeln!(o, "  chunk {n}: {}", dmg.error)?,
                    _ => writeln!(o, "  {}", dmg.error)?,
                }
            }
        }
    }
    Ok(())
}
