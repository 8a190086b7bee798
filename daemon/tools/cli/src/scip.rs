//! `smokenav scip decode`: a raw SCIP byte capture (what a Hokuyo sent) in, one
//! JSON object per reply out: command, status, timestamp, ranges in metres with
//! the sensor's error codes kept apart, parameters of VV/PP/II. Damaged replies
//! come out with an `error` field and the exit status is 1.

use anyhow::Context;
use clap::{Args, Subcommand};
use smokenav_hokuyo_codec::{CaptureOptions, decode_capture};
use std::io::{Read, Write};
use std::path::PathBuf;

#[derive(Debug, Subcommand)]
pub enum ScipCommand {
    /// Decode a raw capture (a file, or stdin) to one JSON object per reply.
    Decode(DecodeArgs),
}

#[derive(Debug, Args)]
pub struct DecodeArgs {
    /// The capture file; `-` or nothing reads stdin.
    file: Option<PathBuf>,
    /// DMIN in mm: smaller values are error codes. A PP reply in the capture overrides it.
    #[arg(long, default_value_t = 20)]
    dmin: u32,
    /// Indented JSON instead of one object per line.
    #[arg(long)]
    pretty: bool,
}

/// Largest capture read: an hour of 10 Hz MD scans is ~80 MB.
const MAX_INPUT: u64 = 512 * 1024 * 1024;

pub fn run(cmd: ScipCommand) -> anyhow::Result<()> {
    match cmd {
        ScipCommand::Decode(a) => decode(a),
    }
}

fn decode(a: DecodeArgs) -> anyhow::Result<()> {
    let mut bytes = Vec::new();
    match a.file.as_deref() {
        Some(p) if p.as_os_str() != "-" => {
            std::fs::File::open(p)
                .with_context(|| format!("cannot open {}", p.display()))?
                .take(MAX_INPUT)
                .read_to_end(&mut bytes)
                .with_context(|| format!("cannot read {}", p.display()))?;
        }
        _ => {
            std::io::stdin()
                .take(MAX_INPUT)
                .read_to_end(&mut bytes)
                .context("cannot read stdin")?;
        }
    }
    let replies = decode_capture(
        &bytes,
        &CaptureOptions {
            fallback_dmin_mm: a.dmin,
        },
    );
    let mut out = std::io::stdout().lock();
    let mut damaged = 0;
    for r in &replies {
        damaged += usize::from(r.error.is_some());
        let line = if a.pretty {
            serde_json::to_string_pretty(r)?
        } else {
            r.to_json_line()
        };
        if let Err(e) = writeln!(out, "{line}") {
            // A closed pipe (`| head`) is not an error of ours.
            if e.kind() == std::io::ErrorKind::BrokenPipe {
                return Ok(());
            }
            return Err(e).context("writing to stdout");
        }
    }
    if damaged > 0 {
        anyhow::bail!(
            "{damaged} of {} replies could not be decoded",
            replies.len()
        );
    }
    Ok(())
}
