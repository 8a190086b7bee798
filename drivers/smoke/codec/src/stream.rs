//! A serial byte stream in, samples of one channel out, with counters.

use crate::line::{ChecksumPolicy, Line, LineError, Sample, parse_line};
use crate::splitter::{DEFAULT_MAX_LINE, LineSplitter, Split};

/// Counters for everything the decoder saw, for the driver's health report.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DecoderStats {
    /// Complete lines (any kind).
    pub lines: u64,
    /// Sample lines for the configured channel.
    pub samples: u64,
    /// `#` lines.
    pub comments: u64,
    /// Valid sample lines for another channel, ignored.
    pub other_channel: u64,
    /// Lines rejected for any reason (includes the two below).
    pub parse_errors: u64,
    /// Of `parse_errors`: checksum field or mismatch.
    pub checksum_errors: u64,
    /// Of `parse_errors`: longer than the line buffer.
    pub overlong: u64,
    /// Bytes dropped while resyncing after a (re)connect.
    pub skipped_bytes: u64,
}

/// Something the stream decoder rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum StreamError {
    #[error(transparent)]
    Line(#[from] LineError),
    #[error("expected a line of at most {max} bytes, found one of {bytes}")]
    Overlong { bytes: usize, max: usize },
}

/// Splitter + line parser + channel filter.
#[derive(Debug, Clone)]
pub struct SerialDecoder<const N: usize = DEFAULT_MAX_LINE> {
    splitter: LineSplitter<N>,
    channel: u8,
    policy: ChecksumPolicy,
    stats: DecoderStats,
}

impl<const N: usize> SerialDecoder<N> {
    pub fn new(channel: u8, policy: ChecksumPolicy) -> Self {
        Self {
            splitter: LineSplitter::new(),
            channel,
            policy,
            stats: DecoderStats::default(),
        }
    }

    /// For input known to start on a line boundary.
    pub fn new_synced(channel: u8, policy: ChecksumPolicy) -> Self {
        Self {
            splitter: LineSplitter::new_synced(),
            ..Self::new(channel, policy)
        }
    }

    pub fn stats(&self) -> &DecoderStats {
        &self.stats
    }

    /// Call after reopening the port: drops the partial line.
    pub fn reset(&mut self) {
        self.splitter.reset();
    }

    /// Feeds a chunk of bytes; `on_item` gets every sample of our channel and
    /// every rejected line, in order.
    pub fn feed(&mut self, input: &[u8], mut on_item: impl FnMut(Result<Sample, StreamError>)) {
        let Self {
            splitter,
            channel,
            policy,
            stats,
        } = self;
        splitter.feed(input, |split| match split {
            Split::SkippedPartial { bytes } => stats.skipped_bytes += bytes as u64,
            Split::Overlong { bytes } => {
                stats.lines += 1;
                stats.parse_errors += 1;
                stats.overlong += 1;
                on_item(Err(StreamError::Overlong { bytes, max: N }));
            }
            Split::Line(line) => {
                stats.lines += 1;
                match parse_line(line, *policy) {
                    Ok(Line::Sample(s)) if s.channel == *channel => {
                        stats.samples += 1;
                        on_item(Ok(s));
                    }
                    Ok(Line::Sample(_)) => stats.other_channel += 1,
                    Ok(Line::Comment) => stats.comments += 1,
                    Ok(Line::Blank) => {}
                    Err(e) => {
                        stats.parse_errors += 1;
                        if e.is_checksum() {
                            stats.checksum_errors += 1;
                        }
                        on_item(Err(e.into()));
                    }
                }
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::line::SampleValue;

    #[test]
    fn noisy_stream_yields_good_samples_and_counts_the_rest() {
        let mut dec = SerialDecoder::<32>::new(0, ChecksumPolicy::Optional);
        let mut samples = Vec::new();
        let mut errors = Vec::new();
        let stream: &[u8] = b"12\r\n# smoke-adc v1\r\nA0:512*7D\r\nA1:700\r\nA0:51x\r\n\
            \xFF\xFE\x00garbage\r\nA0:513*99\r\nA0:0123456789012345678901234567890123\r\nA0:514\r\n";
        // Byte by byte, as a slow port delivers it.
        for b in stream.chunks(1) {
            dec.feed(b, |item| match item {
                Ok(s) => samples.push(s.value),
                Err(e) => errors.push(e),
            });
        }
        assert_eq!(
            samples,
            [SampleValue::Counts(512), SampleValue::Counts(514)]
        );
        assert_eq!(errors.len(), 4, "{errors:?}");
        // "A0:" + 34 digits = 37 bytes against a 32-byte buffer.
        assert_eq!(errors[3], StreamError::Overlong { bytes: 37, max: 32 });
        let st = dec.stats();
        assert_eq!(
            *st,
            DecoderStats {
                lines: 8,
                samples: 2,
                comments: 1,
                other_channel: 1,
                parse_errors: 4,
                checksum_errors: 1,
                overlong: 1,
                skipped_bytes: 2,
            }
        );
    }
}
