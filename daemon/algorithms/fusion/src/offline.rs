//! Offline fusion over JSON lines, exactly as `smokenav topic echo --json` prints them.
//!
//! Each input line is one `smokenav_shared_types::record::TopicRecord`. Lines on
//! `laser/scan`, `base/sonar` and `smoke/level` feed the same synchroniser and
//! method the fusion process runs; other topics are skipped. Time is the
//! newest stamp read so far, so timeouts behave as they did on the robot and
//! a replay is deterministic. Each fused scan is written as one
//! `TopicRecord` on `fusion/scan`. A bad line is reported with its number and
//! skipped; the run goes on.

use crate::engine::StepReport;
use crate::pipeline::FusionPipeline;
use smokenav_shared_types::catalog::topic_names;
use smokenav_shared_types::record::{FusedScanRecord, Message, TopicRecord};
use smokenav_shared_types::{ConversionError, FusedScan, LaserScan, SmokeReading, SonarRing};
use std::io::{self, BufRead, Write};

pub const LASER_TOPIC: &str = topic_names::LASER_SCAN;
pub const SONAR_TOPIC: &str = topic_names::BASE_SONAR;
pub const SMOKE_TOPIC: &str = topic_names::SMOKE_LEVEL;
pub const FUSED_TOPIC: &str = topic_names::FUSION_SCAN;

/// Longest line accepted: a full 1081-beam scan is about 30 kB of JSON.
pub const MAX_LINE_BYTES: usize = 4 << 20;

#[derive(Debug, thiserror::Error)]
pub enum LineError {
    #[error("expected a JSON topic record: {0}")]
    Json(#[from] serde_json::Error),
    #[error("line longer than {max} bytes")]
    TooLong { max: usize },
    #[error("line is not UTF-8")]
    NotUtf8,
    #[error("topic {topic} carries {expected} messages, got {got}")]
    WrongType {
        topic: &'static str,
        expected: &'static str,
        got: &'static str,
    },
    #[error("{0}")]
    Conversion(#[from] ConversionError),
}

/// A line that was skipped, and why.
#[derive(Debug)]
pub struct BadLine {
    /// 1-based line number.
    pub line: u64,
    pub error: LineError,
}

/// What a run read and wrote.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct OfflineReport {
    pub lines: u64,
    pub laser: u64,
    pub sonar: u64,
    pub smoke: u64,
    /// Well-formed records on other topics.
    pub ignored: u64,
    pub bad: u64,
    pub written: u64,
}

/// Reads one line of at most `max` bytes into `buf` (without the newline).
/// `Ok(None)` at end of input; `Ok(Some(false))` when the line was too long
/// (it is consumed, `buf` left empty).
fn read_line_capped<R: BufRead>(
    r: &mut R,
    buf: &mut Vec<u8>,
    max: usize,
) -> io::Result<Option<bool>> {
    buf.clear();
    let (mut any, mut fits) = (false, true);
    loop {
        let chunk = match r.fill_buf() {
            Ok(c) => c,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        };
        if chunk.is_empty() {
            return Ok(any.then_some(fits));
        }
        any = true;
        let (take, done) = match chunk.iter().position(|&b| b == b'\n') {
            Some(p) => (p + 1, true),
            None => (chunk.len(), false),
        };
        let body = if done {
            &chunk[..take - 1]
        } else {
            &chunk[..take]
        };
        if fits && buf.len() + body.len() > max {
            fits = false;
            buf.clear();
        }
        if fits {
            buf.extend_from_slice(body);
        }
        r.consume(take);
        if done {
            return Ok(Some(fits));
        }
    }
}

struct Sink<W> {
    out: W,
    written: u64,
    error: Option<io::Error>,
}

impl<W: Write> Sink<W> {
    fn write(&mut self, f: &FusedScan) {
        if self.error.is_some() {
            return;
        }
        let rec = TopicRecord {
            topic: FUSED_TOPIC.to_owned(),
            message: Message::FusedScan(FusedScanRecord::from(f)),
        };
        let res = serde_json::to_writer(&mut self.out, &rec)
            .map_err(io::Error::from)
            .and_then(|()| self.out.write_all(b"\n"));
        match res {
            Ok(()) => self.written += 1,
            Err(e) => self.error = Some(e),
        }
    }
}

/// Runs `pipeline` over `input`, writing fused scans to `output`. Bad lines go
/// to `on_bad` and are skipped; only I/O errors stop the run.
pub fn fuse_jsonl<R: BufRead, W: Write>(
    pipeline: &mut FusionPipeline,
    mut input: R,
    output: W,
    mut on_bad: impl FnMut(&BadLine),
) -> io::Result<OfflineReport> {
    let mut report = OfflineReport::default();
    let mut sink = Sink {
        out: output,
        written: 0,
        error: None,
    };
    let mut emit = |f: &FusedScan, _: &StepReport| sink.write(f);
    let mut scan: Box<LaserScan> = Box::default();
    let mut buf = Vec::with_capacity(64 * 1024);
    let mut now = 0u64;
    while let Some(fits) = read_line_capped(&mut input, &mut buf, MAX_LINE_BYTES)? {
        report.lines += 1;
        let line = report.lines;
        let result = if fits {
            feed(pipeline, &buf, &mut scan, &mut now, &mut report, &mut emit)
        } else {
            Err(LineError::TooLong {
                max: MAX_LINE_BYTES,
            })
        };
        if let Err(error) = result {
            report.bad += 1;
            on_bad(&BadLine { line, error });
        }
    }
    pipeline.flush(&mut emit);
    if let Some(e) = sink.error {
        return Err(e);
    }
    sink.out.flush()?;
    report.written = sink.written;
    Ok(report)
}

fn feed(
    pipeline: &mut FusionPipeline,
    bytes: &[u8],
    scan: &mut LaserScan,
    now: &mut u64,
    report: &mut OfflineReport,
    emit: &mut impl FnMut(&FusedScan, &StepReport),
) -> Result<(), LineError> {
    let text = std::str::from_utf8(bytes).map_err(|_| LineError::NotUtf8)?;
    let text = text.trim();
    if text.is_empty() {
        return Ok(());
    }
    let rec: TopicRecord = serde_json::from_str(text)?;
    let wrong = |topic, expected, m: &Message| LineError::WrongType {
        topic,
        expected,
        got: m.kind().name(),
    };
    match (rec.topic.as_str(), &rec.message) {
        (LASER_TOPIC, Message::LaserScan(m)) => {
            m.write_into(scan)?;
            *now = (*now).max(scan.header.stamp_ns);
            report.laser += 1;
            pipeline.push_laser(scan, *now, emit);
        }
        (SONAR_TOPIC, Message::SonarRing(m)) => {
            let ring = SonarRing::try_from(m)?;
            *now = (*now).max(ring.header.stamp_ns);
            report.sonar += 1;
            pipeline.push_sonar(&ring, *now, emit);
        }
        (SMOKE_TOPIC, Message::SmokeReading(m)) => {
            let reading = SmokeReading::try_from(m)?;
            *now = (*now).max(reading.header.stamp_ns);
            report.smoke += 1;
            pipeline.push_smoke(&reading, *now, emit);
        }
        (LASER_TOPIC, m) => return Err(wrong(LASER_TOPIC, "LaserScan", m)),
        (SONAR_TOPIC, m) => return Err(wrong(SONAR_TOPIC, "SonarRing", m)),
        (SMOKE_TOPIC, m) => return Err(wrong(SMOKE_TOPIC, "SmokeReading", m)),
        _ => report.ignored += 1,
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn capped_reader_splits_lines_and_refuses_long_ones() {
        let data = b"ab\n\nxxxxxxxxxx\ncd";
        let mut r = io::BufReader::with_capacity(3, &data[..]);
        let mut buf = Vec::new();
        let mut got = Vec::new();
        while let Some(fits) = read_line_capped(&mut r, &mut buf, 5).unwrap() {
            got.push((fits, String::from_utf8(buf.clone()).unwrap()));
        }
        assert_eq!(
            got,
            vec![
                (true, "ab".into()),
                (true, "".into()),
                (false, "".into()),
                (true, "cd".into())
            ]
        );
    }
}
