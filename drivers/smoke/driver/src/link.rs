//! The two ADC back-ends. Each `step` blocks for at most `max_wait` (on the
//! port's read timeout or a sleep until the next IIO conversion, never a
//! busy loop), and appends what happened to a reusable event list.

use crate::settings::Settings;
use smokenav_platform_runtime::{Reconnect, ReconnectPolicy};
use smokenav_shared_types::Clock;
use smokenav_smoke_codec::iio::{
    IioCalibration, IioRange, SHARED_OFFSET_ATTR, SHARED_SCALE_ATTR, offset_attr, parse_offset,
    parse_raw, parse_scale, parse_type, raw_attr, scale_attr, type_attr,
};
use smokenav_smoke_codec::{
    AdcScale, ChecksumPolicy, IioError, Measurement, RangeError, SerialDecoder, StreamError,
};
use std::fmt;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// How long to wait before reopening a device that failed to open (it
/// doubles to [`REOPEN_MAX`] while the device stays away).
pub const REOPEN_PERIOD: Duration = Duration::from_millis(250);
pub const REOPEN_MAX: Duration = Duration::from_secs(1);

/// The smoke driver's reconnect policy: without its sensor it is in error at once
/// (fusion would fuse without knowing the smoke).
pub fn reconnect_policy() -> ReconnectPolicy {
    ReconnectPolicy::new(REOPEN_PERIOD, REOPEN_MAX).with_error_after(Duration::ZERO)
}

/// Input that did not decode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Malformed {
    Serial(StreamError),
    Iio(IioError),
}

impl fmt::Display for Malformed {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Malformed::Serial(e) => write!(f, "malformed line: {e}"),
            Malformed::Iio(e) => write!(f, "malformed IIO value: {e}"),
        }
    }
}

impl Malformed {
    pub fn is_checksum(&self) -> bool {
        matches!(self, Malformed::Serial(StreamError::Line(e)) if e.is_checksum())
    }

    pub fn is_overlong(&self) -> bool {
        matches!(self, Malformed::Serial(StreamError::Overlong { .. }))
    }
}

/// What a link step observed, stamped with the host monotonic clock.
#[derive(Debug, Clone, PartialEq)]
pub enum LinkEvent {
    /// The device opened (first time, or again after a loss).
    Connected {
        stamp_ns: u64,
        device: String,
    },
    Sample {
        stamp_ns: u64,
        measurement: Measurement,
    },
    Malformed {
        stamp_ns: u64,
        error: Malformed,
    },
    OutOfRange {
        stamp_ns: u64,
        error: RangeError,
    },
    /// An open device failed (unplugged, removed).
    Lost {
        stamp_ns: u64,
        reason: String,
    },
    /// Opening failed; reported once per outage, retried every
    /// [`REOPEN_PERIOD`].
    OpenFailed {
        stamp_ns: u64,
        reason: String,
    },
}

/// Either back-end.
pub enum Link {
    /// Boxed: each carries its buffers and reconnect state inline.
    Serial(Box<SerialLink>),
    Iio(Box<IioLink>),
}

impl Link {
    pub fn new(settings: &Settings) -> Self {
        match settings.backend {
            smokenav_platform_config::AdcBackend::Serial => {
                Link::Serial(Box::new(SerialLink::new(settings)))
            }
            smokenav_platform_config::AdcBackend::Iio => {
                Link::Iio(Box::new(IioLink::new(settings)))
            }
        }
    }

    pub fn step(&mut self, max_wait: Duration, clock: &dyn Clock, out: &mut Vec<LinkEvent>) {
        match self {
            Link::Serial(l) => l.step(max_wait, clock, out),
            Link::Iio(l) => l.step(max_wait, clock, out),
        }
    }

    pub fn is_open(&self) -> bool {
        match self {
            Link::Serial(l) => l.port.is_some(),
            Link::Iio(l) => l.calibration.is_some(),
        }
    }

    /// The device's link: up or down, opens, failures, losses.
    pub fn reconnect(&self) -> &Reconnect {
        match self {
            Link::Serial(l) => &l.reconnect,
            Link::Iio(l) => &l.reconnect,
        }
    }

    pub fn describe(&self) -> String {
        match self {
            Link::Serial(l) => format!("serial {} at {} baud", l.path, l.baud),
            Link::Iio(l) => format!("IIO {} channel {}", l.dir.display(), l.channel),
        }
    }
}

/// An Arduino-class board printing sample lines.
pub struct SerialLink {
    path: String,
    baud: u32,
    adc: AdcScale,
    port: Option<serialport::TTYPort>,
    decoder: SerialDecoder,
    reconnect: Reconnect,
    failing: bool,
    buf: [u8; 512],
}

impl SerialLink {
    pub fn new(s: &Settings) -> Self {
        Self {
            path: s.port.clone(),
            baud: s.baud,
            adc: s.adc,
            port: None,
            decoder: SerialDecoder::new(s.channel, s.checksum),
            reconnect: Reconnect::new(reconnect_policy(), 0),
            failing: false,
            buf: [0; 512],
        }
    }

    /// Counters of the line decoder (lines, comments, skipped bytes, …).
    pub fn decoder_stats(&self) -> smokenav_smoke_codec::DecoderStats {
        *self.decoder.stats()
    }

    fn open(&mut self, clock: &dyn Clock, out: &mut Vec<LinkEvent>) {
        let opened = serialport::new(&self.path, self.baud)
            .timeout(Duration::from_millis(100))
            .open_native();
        match opened {
            Ok(port) => {
                self.decoder.reset();
                self.port = Some(port);
                self.failing = false;
                self.reconnect.opened(clock.now_ns());
                out.push(LinkEvent::Connected {
                    stamp_ns: clock.now_ns(),
                    device: self.path.clone(),
                });
            }
            Err(e) => {
                self.reconnect
                    .open_failed(clock.now_ns(), format!("cannot open {}: {e}", self.path));
                if !self.failing {
                    self.failing = true;
                    out.push(LinkEvent::OpenFailed {
                        stamp_ns: clock.now_ns(),
                        reason: format!("cannot open {}: {e}", self.path),
                    });
                }
            }
        }
    }

    pub fn step(&mut self, max_wait: Duration, clock: &dyn Clock, out: &mut Vec<LinkEvent>) {
        if self.port.is_none() {
            let wait = self.reconnect.wait(clock.now_ns());
            if !wait.is_zero() {
                std::thread::sleep(wait.min(max_wait));
                return;
            }
            self.open(clock, out);
        }
        let Some(port) = self.port.as_mut() else {
            return;
        };
        if let Err(e) =
            serialport::SerialPort::set_timeout(port, max_wait.max(Duration::from_millis(1)))
        {
            tracing::debug!(error = %e, "set_timeout");
        }
        let lost = match port.read(&mut self.buf) {
            Ok(0) => Some("end of file".to_owned()),
            Ok(n) => {
                // One stamp per read: at 115200 baud a line takes ~1 ms on
                // the wire, far below the 100 ms sample period.
                let stamp_ns = clock.now_ns();
                let adc = self.adc;
                let chunk = self.buf.get(..n).unwrap_or(&[]);
                self.decoder.feed(chunk, |item| {
                    out.push(match item {
                        Ok(sample) => match adc.measure(sample.value) {
                            Ok(measurement) => LinkEvent::Sample {
                                stamp_ns,
                                measurement,
                            },
                            Err(error) => LinkEvent::OutOfRange { stamp_ns, error },
                        },
                        Err(e) => LinkEvent::Malformed {
                            stamp_ns,
                            error: Malformed::Serial(e),
                        },
                    })
                });
                None
            }
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => None,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => None,
            Err(e) => Some(e.to_string()),
        };
        if let Some(reason) = lost {
            self.port = None;
            self.reconnect
                .lost(clock.now_ns(), format!("{} lost: {reason}", self.path));
            out.push(LinkEvent::Lost {
                stamp_ns: clock.now_ns(),
                reason: format!("{} lost: {reason}", self.path),
            });
        }
    }
}

/// A Linux IIO ADC channel, read at the publishing rate.
pub struct IioLink {
    dir: PathBuf,
    channel: u8,
    /// The profile's guesses, used only where the device says nothing.
    profile_bits: u8,
    vref_mv: f64,
    period: Duration,
    next_read: Option<Instant>,
    calibration: Option<(IioCalibration, IioRange)>,
    raw_path: PathBuf,
    reconnect: Reconnect,
    failing: bool,
}

/// Bytes read from an attribute: more than the parser accepts, so an
/// oversized file is reported as such.
const ATTR_BUF: usize = smokenav_smoke_codec::iio::MAX_ATTR_LEN + 16;

/// Reads a whole attribute into `buf` (open, read, close: a sysfs file
/// converts on each read, and a removed device fails the open).
fn read_attr<'b>(path: &Path, buf: &'b mut [u8; ATTR_BUF]) -> std::io::Result<&'b [u8]> {
    let mut f = std::fs::File::open(path)?;
    let mut n = 0;
    while n < buf.len() {
        let Some(rest) = buf.get_mut(n..) else { break };
        match f.read(rest) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(buf.get(..n).unwrap_or(&[]))
}

/// The first of `names` in `dir` that exists.
fn first_existing(dir: &Path, names: &[&str]) -> Option<PathBuf> {
    names.iter().map(|n| dir.join(n)).find(|p| p.exists())
}

impl IioLink {
    pub fn new(s: &Settings) -> Self {
        let dir = PathBuf::from(&s.port);
        Self {
            raw_path: dir.join(raw_attr(s.channel)),
            dir,
            channel: s.channel,
            profile_bits: s.adc.bits(),
            vref_mv: s.adc.vref_mv(),
            period: Duration::from_secs_f64(1.0 / s.rate_hz),
            next_read: None,
            calibration: None,
            reconnect: Reconnect::new(reconnect_policy(), 0),
            failing: false,
        }
    }

    /// Scale (per channel, else shared), offset (likewise, else 0) and the
    /// range the device can produce: its stated resolution where it has a
    /// `scan_elements` type, else below the profile's reference voltage.
    fn read_calibration(&self) -> Result<(IioCalibration, IioRange), String> {
        let mut buf = [0u8; ATTR_BUF];
        let scale_name = scale_attr(self.channel);
        let scale_path =
            first_existing(&self.dir, &[&scale_name, SHARED_SCALE_ATTR]).ok_or_else(|| {
                format!(
                    "{}: neither {scale_name} nor {SHARED_SCALE_ATTR} exists",
                    self.dir.display()
                )
            })?;
        let text = read_attr(&scale_path, &mut buf)
            .map_err(|e| format!("{}: {e}", scale_path.display()))?;
        let scale_mv = parse_scale(text).map_err(|e| format!("{}: {e}", scale_path.display()))?;
        let offset_name = offset_attr(self.channel);
        let offset = match first_existing(&self.dir, &[&offset_name, SHARED_OFFSET_ATTR]) {
            None => 0.0,
            Some(p) => {
                let text = read_attr(&p, &mut buf).map_err(|e| format!("{}: {e}", p.display()))?;
                parse_offset(text).map_err(|e| format!("{}: {e}", p.display()))?
            }
        };
        if !self.raw_path.exists() {
            return Err(format!("{} does not exist", self.raw_path.display()));
        }
        let type_path = self.dir.join(type_attr(self.channel));
        let range = if type_path.exists() {
            let text = read_attr(&type_path, &mut buf)
                .map_err(|e| format!("{}: {e}", type_path.display()))?;
            let bits = parse_type(text).map_err(|e| format!("{}: {e}", type_path.display()))?;
            if bits != self.profile_bits {
                tracing::warn!(
                    device_bits = bits,
                    profile_bits = self.profile_bits,
                    "the IIO device states a {bits}-bit converter, the profile's \
                     [smoke] adc_bits says {}: using the device's",
                    self.profile_bits
                );
            }
            IioRange::Counts { bits }
        } else {
            IioRange::BelowReference {
                vref_mv: self.vref_mv,
            }
        };
        Ok((IioCalibration { scale_mv, offset }, range))
    }

    pub fn step(&mut self, max_wait: Duration, clock: &dyn Clock, out: &mut Vec<LinkEvent>) {
        let now = Instant::now();
        let due = self.next_read.unwrap_or(now);
        if due > now {
            std::thread::sleep((due - now).min(max_wait));
            if Instant::now() < due {
                return;
            }
        }
        // Keep the schedule; after a stall, restart it instead of bursting.
        let next = due + self.period;
        self.next_read = Some(if next < Instant::now() {
            Instant::now() + self.period
        } else {
            next
        });

        let calibration = match self.calibration {
            Some(c) => c,
            None => match self.read_calibration() {
                Ok(c) => {
                    self.calibration = Some(c);
                    self.failing = false;
                    self.reconnect.opened(clock.now_ns());
                    tracing::info!(
                        scale_mv = c.0.scale_mv,
                        offset = c.0.offset,
                        range = ?c.1,
                        "IIO calibration"
                    );
                    out.push(LinkEvent::Connected {
                        stamp_ns: clock.now_ns(),
                        device: self.dir.display().to_string(),
                    });
                    c
                }
                Err(reason) => {
                    self.reconnect.open_failed(clock.now_ns(), &reason);
                    if !self.failing {
                        self.failing = true;
                        out.push(LinkEvent::OpenFailed {
                            stamp_ns: clock.now_ns(),
                            reason,
                        });
                    }
                    return;
                }
            },
        };

        let mut buf = [0u8; ATTR_BUF];
        let read = read_attr(&self.raw_path, &mut buf);
        // The conversion happens during the read.
        let stamp_ns = clock.now_ns();
        match read {
            Err(e) => {
                self.calibration = None;
                let reason = format!("{} vanished: {e}", self.raw_path.display());
                self.reconnect.lost(stamp_ns, &reason);
                out.push(LinkEvent::Lost { stamp_ns, reason });
            }
            Ok(text) => out.push(match parse_raw(text) {
                Err(e) => LinkEvent::Malformed {
                    stamp_ns,
                    error: Malformed::Iio(e),
                },
                Ok(raw) => match calibration.0.measure(raw, calibration.1) {
                    Ok(measurement) => LinkEvent::Sample {
                        stamp_ns,
                        measurement,
                    },
                    Err(error) => LinkEvent::OutOfRange { stamp_ns, error },
                },
            }),
        }
    }
}

/// The checksum policy's name for logs.
pub fn policy_name(p: ChecksumPolicy) -> &'static str {
    match p {
        ChecksumPolicy::Optional => "optional",
        ChecksumPolicy::Required => "required",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_shared_types::MonotonicClock;

    #[test]
    fn a_board_that_is_not_there_is_retried_with_a_growing_back_off() {
        let dir = tempfile::tempdir().unwrap();
        let port = dir.path().join("smoke-adc").to_string_lossy().into_owned();
        let section = crate::settings::test_section(&port);
        let settings = Settings::new(&section, None, Some(0.0)).unwrap();
        let mut link = Link::new(&settings);
        let clock = MonotonicClock;
        let start = Instant::now();
        let mut events = Vec::new();
        while start.elapsed() < Duration::from_millis(2000) {
            link.step(Duration::from_millis(50), &clock, &mut events);
        }
        // Attempts at 0, 0.25, 0.75 and 1.75 s (waits 250, 500, 1000 ms);
        // a fixed 250 ms retry would have made 8. One event per outage.
        assert_eq!(link.reconnect().counters().failures, 4);
        assert_eq!(events.len(), 1, "{events:?}");
        assert!(matches!(events[0], LinkEvent::OpenFailed { .. }));
        assert!(!link.is_open());
    }
}
