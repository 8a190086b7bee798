//! The emulated sensor as a state machine: request bytes and the time in, reply
//! bytes out. No I/O and no clock of its own, so it is tested deterministically;
//! [`crate::Emulator`] runs it on a pseudo-terminal or a TCP socket.

use crate::model::{Model, ModelSpec};
use smokenav_hokuyo_codec::{Command, ReplyWriter, Request, StepRange, TimeMode, parse_request};
use std::collections::VecDeque;

/// How the host is attached: decides whether the bit rate matters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Link {
    /// USB CDC-ACM: SS is accepted but has no effect; the host's baud is ignored.
    Usb,
    /// RS-232: the host must talk at the device's current rate (19200 after power-up).
    Rs232,
    /// TCP (Ethernet models).
    Ethernet,
}

/// The state the sensor is in when the host first talks to it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BootState {
    /// Force SCIP 1.1 (`Some(true)`) or 2.0; `None`: what the model does after power-up.
    pub scip11: Option<bool>,
    /// Left streaming MD (full sweep, until QT) by a previous host, which implies SCIP 2.0.
    pub streaming: bool,
    /// Left in time-adjust mode (TM0 without TM2) by a previous host.
    pub time_adjust: bool,
}

#[derive(Debug, Clone, PartialEq)]
pub struct DeviceConfig {
    pub model: Model,
    pub link: Link,
    pub boot: BootState,
    /// Sensor timer value at power-up, ms (set near 2^24 to exercise the wrap).
    pub sensor_time_start_ms: u32,
    /// Sensor clock error against the host, ppm (positive: the sensor clock runs slow).
    pub clock_drift_ppm: f64,
    /// Seed of the fault-injection random numbers.
    pub seed: u64,
}

impl Default for DeviceConfig {
    fn default() -> Self {
        DeviceConfig {
            model: Model::Urg04lx,
            link: Link::Usb,
            boot: BootState::default(),
            sensor_time_start_ms: 0,
            clock_drift_ppm: 0.0,
            seed: 0x5EED,
        }
    }
}

/// Supplies the values of each scan: one per step AMIN..=AMAX, in mm (values below
/// DMIN are sensor error codes), and intensities for ME.
pub trait ScanSource: Send {
    fn fill(&mut self, scan_no: u64, ranges: &mut [u16], intensities: &mut [u16]);
}

/// The same scan every time.
#[derive(Debug, Clone, PartialEq)]
pub struct StaticScan(pub Vec<u16>);

impl ScanSource for StaticScan {
    fn fill(&mut self, _scan_no: u64, ranges: &mut [u16], intensities: &mut [u16]) {
        for (i, r) in ranges.iter_mut().enumerate() {
            *r = self.0.get(i).copied().unwrap_or(0);
        }
        intensities.fill(1000);
    }
}

impl<F: FnMut(u64, &mut [u16]) + Send> ScanSource for F {
    fn fill(&mut self, scan_no: u64, ranges: &mut [u16], intensities: &mut [u16]) {
        self(scan_no, ranges);
        intensities.fill(1000);
    }
}

/// Faults to inject. Applied to replies as they are generated.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Faults {
    /// Probability that a data line of a scan gets a wrong checksum character.
    pub corrupt_line_fraction: f64,
    /// The next N data lines are cut in half (their LF kept).
    pub truncate_lines: u32,
    /// Bytes to send before the next reply.
    pub garbage: Vec<u8>,
    /// The device goes silent: no replies, no scans (input is dropped).
    pub stalled: bool,
    /// Hardware trouble: BM answers 01, scan commands answer this status (50–97).
    pub hardware_fault: Option<u8>,
}

/// Counters of what the device did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DeviceStats {
    pub commands: u64,
    /// Scan replies sent (streamed and GD/GS).
    pub scans_sent: u64,
    /// Scan replies with at least one corrupted or truncated line.
    pub scans_damaged: u64,
    pub lines_corrupted: u64,
    pub lines_truncated: u64,
    pub garbage_bytes: u64,
    /// ME requests received (they hang a URG-04LX).
    pub me_requests: u64,
    /// Scans not sent because the emulator fell behind or was stalled.
    pub scans_skipped: u64,
    /// Input bytes dropped because the host talked at the wrong bit rate.
    pub bytes_at_wrong_baud: u64,
    pub power_cycles: u64,
}

/// One streamed scan, for tests to compare against what a driver published.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SentScan {
    pub scan_no: u64,
    /// The 24-bit timestamp in the reply.
    pub timestamp_ms: u32,
    /// Host time the scan started (the rear of the sweep), ns.
    pub start_host_ns: u64,
    /// A fault damaged this reply.
    pub damaged: bool,
}

/// A snapshot of the protocol state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DeviceState {
    pub scip11: bool,
    pub time_adjust: bool,
    pub laser_on: bool,
    pub streaming: bool,
    /// Hung by a command the model does not support (ME on a 04LX) until power-cycled.
    pub hung: bool,
    pub baud: u32,
}

#[derive(Debug, Clone)]
struct Stream {
    command: Command,
    range: StepRange,
    interval: u8,
    /// `None`: until QT.
    remaining: Option<u8>,
    /// The first 13 characters of the request: command + start/end/cluster/interval.
    head: Vec<u8>,
    tag: Option<Vec<u8>>,
    first_scan: u64,
    next_scan: u64,
}

const HISTORY: usize = 4096;
const LOG_LINES: usize = 256;
const MAX_LINE: usize = 128;

pub struct Device {
    cfg: DeviceConfig,
    spec: ModelSpec,
    scip11: bool,
    time_adjust: bool,
    laser_on: bool,
    baud: u32,
    hung: bool,
    stream: Option<Stream>,
    timer_epoch_ns: u64,
    timer_start_ms: u32,
    motor_epoch_ns: u64,
    line: Vec<u8>,
    out: Vec<u8>,
    scratch: Vec<u8>,
    reply_buf: Vec<u8>,
    ranges: Vec<u16>,
    intensities: Vec<u16>,
    values: Vec<u32>,
    rng: u64,
    stats: DeviceStats,
    history: VecDeque<SentScan>,
    log: VecDeque<String>,
}

impl Device {
    pub fn new(cfg: DeviceConfig, now_ns: u64) -> Self {
        let spec = cfg.model.spec();
        let steps = spec.geometry.step_count();
        let mut d = Device {
            spec,
            scip11: false,
            time_adjust: false,
            laser_on: false,
            baud: 0,
            hung: false,
            stream: None,
            timer_epoch_ns: now_ns,
            timer_start_ms: cfg.sensor_time_start_ms,
            motor_epoch_ns: now_ns,
            line: Vec::with_capacity(MAX_LINE),
            out: Vec::with_capacity(16 * 1024),
            scratch: Vec::with_capacity(64),
            reply_buf: Vec::with_capacity(16 * 1024),
            ranges: vec![0; steps],
            intensities: vec![0; steps],
            values: Vec::with_capacity(2 * steps),
            rng: cfg.seed | 1,
            stats: DeviceStats::default(),
            history: VecDeque::with_capacity(HISTORY),
            log: VecDeque::with_capacity(LOG_LINES),
            cfg,
        };
        d.boot(now_ns);
        d
    }

    /// Power-up state: what a USB unplug/replug or a power cycle leads to.
    fn boot(&mut self, now_ns: u64) {
        let boot = self.cfg.boot;
        self.scip11 =
            boot.scip11.unwrap_or(self.spec.boots_scip11) && !boot.streaming && !boot.time_adjust;
        self.time_adjust = boot.time_adjust;
        self.laser_on = boot.streaming;
        self.baud = self.spec.default_baud;
        self.hung = false;
        self.timer_epoch_ns = now_ns;
        self.timer_start_ms = self.cfg.sensor_time_start_ms;
        self.motor_epoch_ns = now_ns;
        self.line.clear();
        self.stream = boot.streaming.then(|| {
            let g = self.spec.geometry;
            let range = StepRange {
                start: g.amin as u16,
                end: g.amax as u16,
                cluster: 1,
            };
            Stream {
                command: Command::Md,
                range,
                interval: 0,
                remaining: None,
                head: format!("MD{:04}{:04}010", range.start, range.end).into_bytes(),
                tag: None,
                first_scan: 0,
                next_scan: 0,
            }
        });
    }

    /// Power cycle (USB unplug and replug).
    pub fn power_cycle(&mut self, now_ns: u64) {
        self.stats.power_cycles += 1;
        self.out.clear();
        self.boot(now_ns);
    }

    pub fn spec(&self) -> &ModelSpec {
        &self.spec
    }

    pub fn stats(&self) -> DeviceStats {
        self.stats
    }

    pub fn state(&self) -> DeviceState {
        DeviceState {
            scip11: self.scip11,
            time_adjust: self.time_adjust,
            laser_on: self.laser_on,
            streaming: self.stream.is_some(),
            hung: self.hung,
            baud: self.baud,
        }
    }

    /// Streamed scans sent, oldest first (the last 4096).
    pub fn history(&self) -> &VecDeque<SentScan> {
        &self.history
    }

    /// The last 256 request lines received.
    pub fn command_log(&self) -> &VecDeque<String> {
        &self.log
    }

    /// Bytes to send to the host; the caller drains what it wrote.
    pub fn output(&mut self) -> &mut Vec<u8> {
        &mut self.out
    }

    /// The device's current bit rate over RS-232 (0 for links without one).
    pub fn baud(&self) -> u32 {
        self.baud
    }

    /// Sensor timer at host time `now_ns`, ms, 24-bit.
    pub fn sensor_ms(&self, now_ns: u64) -> u32 {
        let elapsed = now_ns.saturating_sub(self.timer_epoch_ns) as f64
            * (1.0 - self.cfg.clock_drift_ppm * 1e-6);
        (u64::from(self.timer_start_ms) + (elapsed / 1e6) as u64) as u32 & 0xFF_FFFF
    }

    fn period_ns(&self) -> u64 {
        (self.spec.geometry.scan_period_s() * 1e9) as u64
    }

    /// Host time scan `k` starts (the rear of the sweep).
    pub fn scan_start_ns(&self, k: u64) -> u64 {
        self.motor_epoch_ns + k * self.period_ns()
    }

    /// Host time scan `k` ends at step `end` and is sent.
    fn emit_ns(&self, k: u64, end: u16) -> u64 {
        self.scan_start_ns(k) + (self.spec.geometry.time_from_rear_s(u32::from(end)) * 1e9) as u64
    }

    /// When [`tick`](Self::tick) next has something to send.
    pub fn next_event_ns(&self, faults: &Faults) -> Option<u64> {
        if self.hung || faults.stalled {
            return None;
        }
        self.stream
            .as_ref()
            .map(|s| self.emit_ns(s.next_scan, s.range.end))
    }

    /// Request bytes from the host. `host_baud` is the rate the host's port is set to,
    /// when known (PTY termios); on RS-232 bytes at the wrong rate are lost.
    pub fn receive(
        &mut self,
        bytes: &[u8],
        now_ns: u64,
        host_baud: Option<u32>,
        faults: &mut Faults,
        source: &mut dyn ScanSource,
    ) {
        if self.hung || faults.stalled {
            return;
        }
        if self.cfg.link == Link::Rs232 && host_baud.is_some_and(|b| b != self.baud) {
            self.stats.bytes_at_wrong_baud += bytes.len() as u64;
            return;
        }
        for &b in bytes {
            if b == b'\n' || b == b'\r' {
                if !self.line.is_empty() {
                    let line = std::mem::take(&mut self.line);
                    self.command(&line, now_ns, faults, source);
                    self.line = line;
                    self.line.clear();
                }
            } else if self.line.len() < MAX_LINE {
                self.line.push(b);
            }
        }
    }

    fn command(
        &mut self,
        line: &[u8],
        now_ns: u64,
        faults: &mut Faults,
        source: &mut dyn ScanSource,
    ) {
        self.stats.commands += 1;
        if self.log.len() == LOG_LINES {
            self.log.pop_front();
        }
        self.log
            .push_back(String::from_utf8_lossy(line).into_owned());
        self.flush_garbage(faults);
        if self.scip11 {
            // SCIP 1.1 knows only its own one-letter commands and the switch to 2.0.
            let mut w = ReplyWriter::new(&mut self.out);
            if line == b"SCIP2.0" {
                w.echo(line).bare_status(b'0').end();
                self.scip11 = false;
            } else {
                w.echo(line).bare_status(b'E').end();
            }
            return;
        }
        let parsed = match parse_request(line) {
            Ok(p) => p,
            Err(rejection) => {
                ReplyWriter::new(&mut self.out)
                    .echo(line)
                    .status(rejection.status)
                    .end();
                return;
            }
        };
        let request = parsed.request;
        if self.time_adjust && !matches!(request, Request::Tm(_)) {
            ReplyWriter::new(&mut self.out)
                .echo(line)
                .status(*b"0E")
                .end();
            return;
        }
        let status: [u8; 2] = match request {
            Request::Scip20 => *b"0E",
            Request::Vv => {
                let vv = self.spec.vv;
                let mut w = ReplyWriter::new(&mut self.out);
                w.echo(line).status(*b"00");
                for (k, v) in vv {
                    w.param(k, v);
                }
                w.end();
                return;
            }
            Request::Pp => {
                let g = self.spec.geometry;
                let mut w = ReplyWriter::new(&mut self.out);
                w.echo(line)
                    .status(*b"00")
                    .param("MODL", self.spec.modl)
                    .param("DMIN", &g.dmin_mm.to_string())
                    .param("DMAX", &g.dmax_mm.to_string())
                    .param("ARES", &g.ares.to_string())
                    .param("AMIN", &g.amin.to_string())
                    .param("AMAX", &g.amax.to_string())
                    .param("AFRT", &g.afrt.to_string())
                    .param("SCAN", &g.scan_rpm.to_string())
                    .end();
                return;
            }
            Request::Ii => {
                self.write_ii(line, now_ns, faults);
                return;
            }
            Request::Bm => {
                if faults.hardware_fault.is_some() {
                    *b"01"
                } else if self.laser_on {
                    *b"02"
                } else {
                    self.laser_on = true;
                    *b"00"
                }
            }
            Request::Qt => {
                self.stream = None;
                self.laser_on = false;
                *b"00"
            }
            Request::Rs => {
                self.stream = None;
                self.laser_on = false;
                self.timer_epoch_ns = now_ns;
                self.timer_start_ms = 0;
                ReplyWriter::new(&mut self.out)
                    .echo(line)
                    .status(*b"00")
                    .end();
                // The reply goes out at the old rate; then the default applies.
                self.baud = self.spec.default_baud;
                return;
            }
            Request::Tm(mode) => match (mode, self.time_adjust) {
                (TimeMode::Enter, true) => *b"02",
                (TimeMode::Enter, false) => {
                    self.time_adjust = true;
                    self.stream = None;
                    self.laser_on = false;
                    *b"00"
                }
                (TimeMode::Read, false) => *b"04",
                (TimeMode::Read, true) => {
                    let t = self.sensor_ms(now_ns);
                    ReplyWriter::new(&mut self.out)
                        .echo(line)
                        .status(*b"00")
                        .time(t)
                        .end();
                    return;
                }
                (TimeMode::Leave, false) => *b"03",
                (TimeMode::Leave, true) => {
                    self.time_adjust = false;
                    *b"00"
                }
            },
            Request::Ss(baud) => match self.set_baud(line, baud) {
                Some(s) => s,
                None => return,
            },
            Request::Get { range, .. } => match self.check_range(range, faults) {
                Some(s) => s,
                None if !self.laser_on => *b"10",
                None => {
                    let k = self.latest_scan(now_ns, range.end);
                    let echo = line.to_vec();
                    self.write_scan(&echo, *b"00", request.command(), range, k, faults, source);
                    return;
                }
            },
            Request::Stream {
                command,
                range,
                interval,
                count,
            } => {
                if command == Command::Me && !self.spec.supports_me {
                    // An unsupported command can hang a 04LX until it is power-cycled.
                    self.stats.me_requests += 1;
                    self.hung = true;
                    return;
                }
                if let Some(s) = self.check_range(range, faults) {
                    s
                } else {
                    let k = self.next_scan_after(now_ns);
                    self.laser_on = true;
                    self.stream = Some(Stream {
                        command,
                        range,
                        interval,
                        remaining: (count > 0).then_some(count),
                        head: line.get(..13).unwrap_or(line).to_vec(),
                        tag: parsed.tag.map(<[u8]>::to_vec),
                        first_scan: k,
                        next_scan: k,
                    });
                    *b"00"
                }
            }
        };
        ReplyWriter::new(&mut self.out)
            .echo(line)
            .status(status)
            .end();
    }

    /// The SS status, or `None` when the reply is already written.
    fn set_baud(&mut self, line: &[u8], baud: u32) -> Option<[u8; 2]> {
        if self.cfg.link != Link::Rs232 {
            return Some(*b"00");
        }
        if baud == self.baud {
            Some(*b"03")
        } else if self.spec.bauds.contains(&baud) {
            ReplyWriter::new(&mut self.out)
                .echo(line)
                .status(*b"00")
                .end();
            // Sent at the old rate; the new one applies after the reply.
            self.baud = baud;
            None
        } else if [
            4800, 9600, 38_400, 230_400, 250_000, 500_000, 750_000, 921_600,
        ]
        .contains(&baud)
        {
            Some(*b"04")
        } else {
            Some(*b"02")
        }
    }

    fn check_range(&self, range: StepRange, faults: &Faults) -> Option<[u8; 2]> {
        if u32::from(range.end) > self.spec.geometry.amax {
            return Some(*b"04");
        }
        if range.end < range.start {
            return Some(*b"05");
        }
        faults
            .hardware_fault
            .map(|c| [b'0' + (c / 10) % 10, b'0' + c % 10])
    }

    fn write_ii(&mut self, line: &[u8], now_ns: u64, faults: &Faults) {
        let t = self.sensor_ms(now_ns);
        let laser = if self.laser_on { "ON" } else { "OFF" };
        let mesm = if self.stream.is_some() {
            "Measuring"
        } else {
            "IDLE"
        };
        let sbps = match self.cfg.link {
            Link::Rs232 if self.baud == self.spec.default_baud => {
                format!("{}[bps]<-Default setting by user", self.baud)
            }
            Link::Rs232 => format!("{}[bps]", self.baud),
            Link::Usb => "19200[bps]<-Default setting by user".to_string(),
            Link::Ethernet => "Ethernet 100[Mbps]".to_string(),
        };
        let stat = if faults.hardware_fault.is_some() {
            "Hardware trouble"
        } else {
            "Sensor works well."
        };
        let scsp = format!(
            "Initial({}[rpm])<-Default setting by user",
            self.spec.geometry.scan_rpm
        );
        ReplyWriter::new(&mut self.out)
            .echo(line)
            .status(*b"00")
            .param("MODL", self.spec.modl)
            .param("LASR", laser)
            .param("SCSP", &scsp)
            .param("MESM", mesm)
            .param("SBPS", &sbps)
            // The 04LX prints its timer as 6 hex digits (an assumption from `081615`).
            .param("TIME", &format!("{t:06X}"))
            .param("STAT", stat)
            .end();
    }

    /// Index of the first scan that starts at or after `now_ns`.
    fn next_scan_after(&self, now_ns: u64) -> u64 {
        now_ns
            .saturating_sub(self.motor_epoch_ns)
            .div_ceil(self.period_ns().max(1))
    }

    /// Index of the latest scan already complete up to step `end`.
    fn latest_scan(&self, now_ns: u64, end: u16) -> u64 {
        let tail = self.emit_ns(0, end) - self.motor_epoch_ns;
        now_ns.saturating_sub(self.motor_epoch_ns + tail) / self.period_ns().max(1)
    }

    /// Sends the streamed scans that are due.
    pub fn tick(&mut self, now_ns: u64, faults: &mut Faults, source: &mut dyn ScanSource) {
        if self.hung || faults.stalled {
            return;
        }
        let Some(stream) = self.stream.as_ref() else {
            return;
        };
        let (end, next) = (stream.range.end, stream.next_scan);
        if self.emit_ns(next, end) > now_ns {
            return;
        }
        let due = self.latest_scan(now_ns, end);
        // Fell behind (or was stalled): send the newest two, count the rest.
        let from = next.max(due.saturating_sub(1));
        self.stats.scans_skipped += from - next;
        for k in from..=due {
            let Some(s) = self.stream.as_mut() else { break };
            s.next_scan = k + 1;
            if (k - s.first_scan) % (u64::from(s.interval) + 1) != 0 {
                continue;
            }
            let remaining = match s.remaining {
                Some(n) => n.saturating_sub(1),
                None => 0,
            };
            let mut echo = std::mem::take(&mut self.scratch);
            echo.clear();
            echo.extend_from_slice(&s.head);
            echo.extend_from_slice(format!("{remaining:02}").as_bytes());
            if let Some(tag) = &s.tag {
                echo.push(b';');
                echo.extend_from_slice(tag);
            }
            let (command, range) = (s.command, s.range);
            if s.remaining.is_some() {
                s.remaining = Some(remaining);
            }
            let finished = s.remaining == Some(0);
            self.flush_garbage(faults);
            let damaged = self.write_scan(&echo, *b"99", command, range, k, faults, source);
            self.scratch = echo;
            if self.history.len() == HISTORY {
                self.history.pop_front();
            }
            self.history.push_back(SentScan {
                scan_no: k,
                timestamp_ms: self.sensor_ms(self.scan_start_ns(k)),
                start_host_ns: self.scan_start_ns(k),
                damaged,
            });
            if finished {
                self.stream = None;
                break;
            }
        }
    }

    fn flush_garbage(&mut self, faults: &mut Faults) {
        if !faults.garbage.is_empty() {
            self.stats.garbage_bytes += faults.garbage.len() as u64;
            self.out.append(&mut faults.garbage);
        }
    }

    fn next_random(&mut self) -> u64 {
        // xorshift64: deterministic per seed, good enough for fault placement.
        self.rng ^= self.rng << 13;
        self.rng ^= self.rng >> 7;
        self.rng ^= self.rng << 17;
        self.rng
    }

    /// Writes one scan reply (echo, status, timestamp, data) with faults applied.
    /// Returns whether a fault damaged it.
    #[allow(clippy::too_many_arguments)]
    fn write_scan(
        &mut self,
        echo: &[u8],
        status: [u8; 2],
        command: Command,
        range: StepRange,
        k: u64,
        faults: &mut Faults,
        source: &mut dyn ScanSource,
    ) -> bool {
        source.fill(k, &mut self.ranges, &mut self.intensities);
        let g = self.spec.geometry;
        let value_at = |v: &[u16], step: u32| -> u32 {
            if step < g.amin || step > g.amax {
                19 // step not measurable
            } else {
                u32::from(v.get((step - g.amin) as usize).copied().unwrap_or(0))
            }
        };
        self.values.clear();
        let cluster = u32::from(range.cluster.max(1));
        let mut step = u32::from(range.start);
        while step <= u32::from(range.end) {
            let last = (step + cluster - 1).min(u32::from(range.end));
            // A cluster reports its smallest valid range, else the first step's code.
            let valid = (step..=last)
                .map(|s| value_at(&self.ranges, s))
                .filter(|&v| v >= g.dmin_mm)
                .min();
            self.values
                .push(valid.unwrap_or_else(|| value_at(&self.ranges, step)));
            if command == Command::Me {
                self.values.push(value_at(&self.intensities, step));
            }
            step = last + 1;
        }
        let t = self.sensor_ms(self.scan_start_ns(k));
        let mut reply = std::mem::take(&mut self.reply_buf);
        reply.clear();
        ReplyWriter::new(&mut reply)
            .echo(echo)
            .status(status)
            .time(t)
            .data(command.range_width(), self.values.iter().copied())
            .end();
        let damaged = self.emit_with_faults(&reply, faults);
        self.reply_buf = reply;
        self.stats.scans_sent += 1;
        if damaged {
            self.stats.scans_damaged += 1;
        }
        damaged
    }

    /// Copies a scan reply to the output, corrupting or truncating data lines.
    fn emit_with_faults(&mut self, reply: &[u8], faults: &mut Faults) -> bool {
        let mut damaged = false;
        let mut line_no = 0;
        for line in reply.split_inclusive(|&b| b == b'\n') {
            line_no += 1;
            // Lines 1–3 are echo, status, timestamp; the final empty line has only LF.
            if line_no <= 3 || line.len() < 3 {
                self.out.extend_from_slice(line);
                continue;
            }
            let body = &line[..line.len() - 1];
            if faults.truncate_lines > 0 {
                faults.truncate_lines -= 1;
                self.stats.lines_truncated += 1;
                damaged = true;
                self.out.extend_from_slice(&body[..body.len() / 2]);
                self.out.push(b'\n');
                continue;
            }
            let p = faults.corrupt_line_fraction;
            if p > 0.0 && (self.next_random() % 1_000_000) as f64 / 1e6 < p {
                let (data, sum) = body.split_at(body.len() - 1);
                let shift = 1 + (self.next_random() % 63) as u8;
                let wrong = (sum[0] - 0x30 + shift) % 64 + 0x30;
                self.stats.lines_corrupted += 1;
                damaged = true;
                self.out.extend_from_slice(data);
                self.out.push(wrong);
                self.out.push(b'\n');
                continue;
            }
            self.out.extend_from_slice(line);
        }
        damaged
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_hokuyo_codec::{FrameSplitter, parse_reply};

    const MS: u64 = 1_000_000;

    fn scip20() -> DeviceConfig {
        DeviceConfig {
            boot: BootState {
                scip11: Some(false),
                ..Default::default()
            },
            ..Default::default()
        }
    }

    /// Remaining-scans fields of the data replies in the device's output.
    fn remaining_fields(d: &mut Device) -> Vec<u8> {
        let mut s = FrameSplitter::default();
        let mut out = Vec::new();
        s.feed(d.output(), |f| {
            let r = parse_reply(f).unwrap();
            if r.status.is_scan_data() {
                out.push(r.echo.scan().unwrap().remaining);
            }
        });
        d.output().clear();
        out
    }

    fn run(d: &mut Device, from_ms: u64, to_ms: u64, faults: &mut Faults, src: &mut StaticScan) {
        for t in (from_ms..to_ms).step_by(5) {
            d.tick(t * MS, faults, src);
        }
    }

    #[test]
    fn count_00_streams_until_qt_with_remaining_00() {
        let mut d = Device::new(scip20(), 0);
        let (mut f, mut src) = (Faults::default(), StaticScan(vec![500; 682]));
        d.receive(b"MD0044072501000\n", 0, None, &mut f, &mut src);
        d.output().clear();
        run(&mut d, 0, 1000, &mut f, &mut src);
        // Scans 0..9 end 83 ms after their start: 10 of them within the first second.
        assert_eq!(remaining_fields(&mut d), vec![0; 10]);
        d.receive(b"QT\n", 1000 * MS, None, &mut f, &mut src);
        run(&mut d, 1000, 2000, &mut f, &mut src);
        assert_eq!(remaining_fields(&mut d), Vec::<u8>::new());
    }

    #[test]
    fn interval_2_sends_every_third_scan() {
        let mut d = Device::new(scip20(), 0);
        let (mut f, mut src) = (Faults::default(), StaticScan(vec![500; 682]));
        d.receive(b"MD0044072501205\n", 0, None, &mut f, &mut src);
        run(&mut d, 0, 3000, &mut f, &mut src);
        assert_eq!(remaining_fields(&mut d), vec![4, 3, 2, 1, 0]);
        let nos: Vec<u64> = d.history().iter().map(|s| s.scan_no).collect();
        assert_eq!(nos, vec![0, 3, 6, 9, 12]);
    }

    #[test]
    fn sensor_clock_drift_and_start_value_apply() {
        let d = Device::new(
            DeviceConfig {
                sensor_time_start_ms: 500,
                clock_drift_ppm: 1000.0,
                ..scip20()
            },
            0,
        );
        // 1000 ppm slow: 10 s of host time is 9.99 s of sensor time.
        assert_eq!(d.sensor_ms(10_000 * MS), 500 + 9990);
    }

    #[test]
    fn stalled_device_drops_input_and_sends_nothing() {
        let mut d = Device::new(scip20(), 0);
        let (mut f, mut src) = (
            Faults {
                stalled: true,
                ..Faults::default()
            },
            StaticScan(vec![500; 682]),
        );
        d.receive(b"QT\n", 0, None, &mut f, &mut src);
        assert!(d.output().is_empty());
        assert_eq!(d.next_event_ns(&f), None);
    }
}
