//! `smokenav arcos decode`: an ARCOS capture (hex text or raw bytes) in, one
//! JSON object per packet out — SYNC replies, SIPs with every field, CONFIG,
//! commands with their arguments, and framing errors.

use anyhow::Context;
use clap::{Args, Subcommand};
use smokenav_pioneer_codec::capture::{CaptureFormat, Direction, decode_capture};
use std::io::{Read, Write};
use std::path::PathBuf;

#[derive(Debug, Subcommand)]
pub enum ArcosCommand {
    /// Decode a capture: hex lines (`fa fb 03 00 00 00`, optionally prefixed
    /// `TX`/`RX` as in AMRISim logs) or raw bytes. One JSON object per packet.
    Decode(DecodeArgs),
}

#[derive(Debug, Args)]
pub struct DecodeArgs {
    /// The capture file; `-` or nothing reads stdin.
    file: Option<PathBuf>,
    /// Input format (auto: raw if the file holds FA FB bytes, else hex text).
    #[arg(long, value_enum, default_value_t = CaptureFormat::Auto)]
    format: CaptureFormat,
    /// Who sent bytes that carry no TX/RX marker.
    #[arg(long, value_enum, default_value_t = Direction::Unknown)]
    from: Direction,
    /// Convert SIP units with this subclass's factors until a SYNC2 reply names one.
    #[arg(long)]
    subclass: Option<String>,
    /// Indented JSON instead of one object per line.
    #[arg(long)]
    pretty: bool,
}

/// Largest capture read (a day of SIPs at 10 Hz is ~80 MB; refuse anything absurd).
const MAX_INPUT: u64 = 512 * 1024 * 1024;

pub fn run(cmd: ArcosCommand) -> anyhow::Result<()> {
    match cmd {
        ArcosCommand::Decode(a) => decode(a),
    }
}

fn decode(a: DecodeArgs) -> anyhow::Result<()> {
    let mut input = Vec::new();
    match a.file.as_deref() {
        None => std::io::stdin()
            .take(MAX_INPUT)
            .read_to_end(&mut input)
            .context("reading stdin")?,
        Some(p) if p.as_os_str() == "-" => std::io::stdin()
            .take(MAX_INPUT)
            .read_to_end(&mut input)
            .context("reading stdin")?,
        Some(p) => std::fs::File::open(p)
            .and_then(|f| f.take(MAX_INPUT).read_to_end(&mut input))
            .with_context(|| format!("reading {}", p.display()))?,
    };
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    let mut write_err = None;
    let summary = decode_capture(&input, a.format, a.from, a.subclass.as_deref(), |v| {
        if write_err.is_some() {
            return;
        }
        let r = if a.pretty {
            serde_json::to_writer_pretty(&mut out, &v)
        } else {
            serde_json::to_writer(&mut out, &v)
        };
        if let Err(e) = r.map_err(std::io::Error::from).and_then(|_| writeln!(out)) {
            write_err = Some(e);
        }
    })?;
    if let Some(e) = write_err
        && e.kind() != std::io::ErrorKind::BrokenPipe
    {
        return Err(e).context("writing stdout");
    }
    out.flush().ok();
    eprintln!(
        "{} packets, {} checksum errors, {} bad counts, {} bytes skipped",
        summary.framing.packets,
        summary.framing.checksum_errors,
        summary.framing.bad_counts,
        summary.framing.discarded_bytes
    );
    Ok(())
}
