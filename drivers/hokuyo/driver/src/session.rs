//! One connection to a sensor: robust handshake, identification, clock calibration.
//!
//! Start-up work allocates freely (it runs once per connection); the streaming
//! hot path is [`crate::driver::stream`] around [`crate::core`].

use crate::link::{Port, PortSpec};
use smokenav_hokuyo_codec::{
    ClockSync, Command, DecodeError, FrameSplitter, OffsetEstimate, ParamError, Request,
    SensorSpec, SensorState, Status, StatusKind, TimeMode, TimeSample, VersionInfo, parse_reply,
};
use smokenav_shared_types::Clock;
use std::io;
use std::sync::Arc;
use std::time::Duration;
use thiserror::Error;

#[derive(Debug, Error)]
pub enum SessionError {
    #[error("opening {port}: {source}")]
    Open { port: String, source: io::Error },
    #[error("I/O: {0}")]
    Io(#[from] io::Error),
    #[error("no SCIP answer to QT at {bauds:?} baud")]
    NoResponse { bauds: Vec<u32> },
    #[error("no reply to {request} within {timeout:?}")]
    Timeout { request: String, timeout: Duration },
    #[error("{command} answered {status}: {meaning}")]
    Status {
        command: Command,
        status: Status,
        meaning: &'static str,
    },
    #[error("{0}")]
    Decode(#[from] DecodeError),
    #[error("{0}")]
    Param(#[from] ParamError),
    #[error("no scan for {0:?}: the stream stalled")]
    Stalled(Duration),
    #[error("{0} consecutive damaged frames")]
    TooManyErrors(u32),
    #[error("sensor reports hardware trouble: {command} status {status} ({meaning})")]
    Hardware {
        command: Command,
        status: Status,
        meaning: &'static str,
    },
    #[error("stopped")]
    Stopped,
}

/// What the sensor said about itself at connection.
#[derive(Debug, Clone)]
pub struct SensorInfo {
    pub version: VersionInfo,
    pub spec: SensorSpec,
    pub state: SensorState,
    /// The bit rate the link ended up at (serial only).
    pub baud: u32,
    /// What the handshake had to repair (for logs and tests).
    pub recovered: Recovered,
    pub clock: Option<OffsetEstimate>,
}

/// Abnormal states the handshake found and repaired.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Recovered {
    pub from_scip11: bool,
    pub from_time_adjust: bool,
    /// Frames of a stream left running by a previous host.
    pub stale_frames: u64,
}

/// Counters for health.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SessionCounters {
    /// Frames that were not the reply awaited (stale stream data, late replies).
    pub stale_frames: u64,
    /// Frames that did not parse.
    pub bad_frames: u64,
}

pub struct Session {
    pub(crate) port: Port,
    pub(crate) splitter: FrameSplitter,
    pub(crate) clock: Arc<dyn Clock>,
    pub counters: SessionCounters,
    frame: Vec<u8>,
}

const QT_TIMEOUT: Duration = Duration::from_millis(400);
const REPLY_TIMEOUT: Duration = Duration::from_millis(1000);

impl Session {
    pub fn open(
        spec: &PortSpec,
        baud: u32,
        clock: Arc<dyn Clock>,
    ) -> Result<Session, SessionError> {
        let port = Port::open(spec, baud).map_err(|source| SessionError::Open {
            port: spec.to_string(),
            source,
        })?;
        Ok(Session {
            port,
            splitter: FrameSplitter::default(),
            clock,
            counters: SessionCounters::default(),
            frame: Vec::with_capacity(8192),
        })
    }

    pub fn port_mut(&mut self) -> &mut Port {
        &mut self.port
    }

    /// Sends a request (no tag: the 04LX handshake must work in SCIP 1.1 too).
    pub fn send(&mut self, req: &Request) -> Result<Vec<u8>, SessionError> {
        let enc = req
            .encode(None)
            .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e.to_string()))?;
        self.port.write_all(enc.as_bytes())?;
        Ok(enc.echo().to_vec())
    }

    /// Reads until a frame echoing `echo` arrives; other frames are counted and skipped.
    /// The frame is left in `self.frame`.
    fn await_echo(&mut self, echo: &[u8], timeout: Duration) -> Result<bool, SessionError> {
        let deadline = self.clock.now_ns() + timeout.as_nanos() as u64;
        loop {
            while let Some(f) = self.splitter.next_frame() {
                match parse_reply(f) {
                    Ok(r) if r.echo.line == echo => {
                        self.frame.clear();
                        self.frame.extend_from_slice(f);
                        return Ok(true);
                    }
                    Ok(_) => self.counters.stale_frames += 1,
                    Err(_) => self.counters.bad_frames += 1,
                }
            }
            let now = self.clock.now_ns();
            if now >= deadline {
                return Ok(false);
            }
            let spare = self.splitter.spare();
            let n = self
                .port
                .read_timeout(spare, Duration::from_nanos(deadline - now))?;
            self.splitter.commit(n);
        }
    }

    /// Sends `req` and returns its reply frame (owned by the session until the next call).
    pub fn transact(&mut self, req: &Request, timeout: Duration) -> Result<&[u8], SessionError> {
        let echo = self.send(req)?;
        if self.await_echo(&echo, timeout)? {
            Ok(&self.frame)
        } else {
            Err(SessionError::Timeout {
                request: String::from_utf8_lossy(&echo).into_owned(),
                timeout,
            })
        }
    }

    /// `transact` and require status 00 (or SCIP 1.1 `0`).
    fn expect_ok(&mut self, req: &Request) -> Result<(), SessionError> {
        let frame = self.transact(req, REPLY_TIMEOUT)?;
        let r = parse_reply(frame)?;
        if r.status.is_ok() {
            Ok(())
        } else {
            Err(SessionError::Status {
                command: r.echo.command,
                status: r.status,
                meaning: r.status.meaning(r.echo.command),
            })
        }
    }

    /// Discards input for up to `max` (a stream in progress never goes quiet).
    fn drain(&mut self, quiet: Duration, max: Duration) -> Result<(), SessionError> {
        let end = self.clock.now_ns() + max.as_nanos() as u64;
        let mut buf = [0u8; 1024];
        while self.clock.now_ns() < end {
            if self.port.read_timeout(&mut buf, quiet)? == 0 {
                break;
            }
        }
        self.splitter.reset();
        Ok(())
    }

    /// Brings the sensor to "SCIP 2.0, idle, laser off" whatever state it is in:
    /// tries each bit rate, switches SCIP 1.1 to 2.0, leaves time-adjust mode,
    /// stops a stream left running. Returns the rate that answered.
    pub fn handshake(
        &mut self,
        bauds: &[u32],
        recovered: &mut Recovered,
    ) -> Result<u32, SessionError> {
        let serial = self.port.is_serial();
        let candidates: &[u32] = if serial {
            bauds
        } else {
            &bauds[..1.min(bauds.len())]
        };
        for &baud in candidates {
            if serial {
                self.port.set_baud(baud)?;
            }
            // An LF ends whatever half-line the sensor holds; then drop what is queued.
            self.port.write_all(b"\n")?;
            self.drain(Duration::from_millis(30), Duration::from_millis(100))?;
            let stale_before = self.counters.stale_frames;
            for _attempt in 0..4 {
                let qt = match self.transact(&Request::Qt, QT_TIMEOUT) {
                    Ok(f) => parse_reply(f)?.status,
                    Err(SessionError::Timeout { .. }) => break,
                    Err(e) => return Err(e),
                };
                recovered.stale_frames += self.counters.stale_frames - stale_before;
                match qt.kind(Command::Qt) {
                    StatusKind::Ok => return Ok(baud),
                    StatusKind::Scip11Error => {
                        tracing::info!("sensor speaks SCIP 1.1: switching to SCIP 2.0");
                        recovered.from_scip11 = true;
                        let f = self.transact(&Request::Scip20, REPLY_TIMEOUT)?;
                        let st = parse_reply(f)?.status;
                        // `0` from 1.1, `0E` if it already was in 2.0: both mean 2.0 now.
                        if !(st.is_ok() || st == Status::Code(*b"0E")) {
                            tracing::warn!("SCIP2.0 answered {st}");
                        }
                    }
                    StatusKind::Common if qt == Status::Code(*b"0E") => {
                        tracing::info!("QT refused: sensor stuck in time-adjust mode, sending TM2");
                        recovered.from_time_adjust = true;
                        let _ = self.transact(&Request::Tm(TimeMode::Leave), REPLY_TIMEOUT)?;
                    }
                    _ => tracing::warn!("QT answered {qt}: {}", qt.meaning(Command::Qt)),
                }
            }
            tracing::debug!(baud, "no SCIP answer");
        }
        Err(SessionError::NoResponse {
            bauds: candidates.to_vec(),
        })
    }

    /// Switches an RS-232 link to `want` with SS (USB and TCP accept or ignore it).
    pub fn set_bit_rate(&mut self, current: u32, want: u32) -> Result<u32, SessionError> {
        if !self.port.is_serial() || current == want {
            return Ok(current);
        }
        let f = self.transact(&Request::Ss(want), REPLY_TIMEOUT)?;
        let st = parse_reply(f)?.status;
        match st.number() {
            Some(0) => {
                self.port.set_baud(want)?;
                Ok(want)
            }
            Some(3) => Ok(current),
            _ => {
                tracing::warn!(
                    "SS{want:06} answered {st} ({}); staying at {current}",
                    st.meaning(Command::Ss)
                );
                Ok(current)
            }
        }
    }

    /// VV, PP, II.
    pub fn identify(&mut self) -> Result<(VersionInfo, SensorSpec, SensorState), SessionError> {
        let version =
            VersionInfo::from_reply(&parse_reply(self.transact(&Request::Vv, REPLY_TIMEOUT)?)?)?;
        let spec =
            SensorSpec::from_reply(&parse_reply(self.transact(&Request::Pp, REPLY_TIMEOUT)?)?)?;
        let state =
            SensorState::from_reply(&parse_reply(self.transact(&Request::Ii, REPLY_TIMEOUT)?)?)?;
        Ok((version, spec, state))
    }

    /// TM0, `samples` × TM1 (host time before and after each), TM2.
    pub fn calibrate(
        &mut self,
        sync: &mut ClockSync,
        samples: usize,
    ) -> Result<OffsetEstimate, SessionError> {
        self.expect_ok(&Request::Tm(TimeMode::Enter))?;
        let mut got = Vec::with_capacity(samples);
        let mut result = Ok(());
        for _ in 0..samples {
            let before = self.clock.now_ns();
            match self
                .transact(&Request::Tm(TimeMode::Read), REPLY_TIMEOUT)
                .and_then(|f| Ok(parse_reply(f)?.time()?))
            {
                Ok(t) => got.push(TimeSample {
                    host_before_ns: before,
                    host_after_ns: self.clock.now_ns(),
                    sensor_ms: t,
                }),
                Err(e) => {
                    result = Err(e);
                    break;
                }
            }
        }
        // Leave time-adjust mode whatever happened, or the sensor refuses everything.
        self.expect_ok(&Request::Tm(TimeMode::Leave))?;
        result?;
        sync.calibrate(&got).map_err(|e| {
            SessionError::Io(io::Error::new(io::ErrorKind::InvalidData, e.to_string()))
        })
    }

    /// Full connection: handshake, bit rate, identification, clock calibration.
    pub fn connect(
        &mut self,
        bauds: &[u32],
        want_baud: u32,
        sync: &mut ClockSync,
        tm_samples: usize,
    ) -> Result<SensorInfo, SessionError> {
        let mut recovered = Recovered::default();
        let found = self.handshake(bauds, &mut recovered)?;
        let baud = self.set_bit_rate(found, want_baud)?;
        let (version, spec, state) = self.identify()?;
        let clock = match self.calibrate(sync, tm_samples) {
            Ok(est) => Some(est),
            Err(e) => {
                tracing::warn!("clock calibration failed, stamps fall back to arrival time: {e}");
                sync.forget();
                None
            }
        };
        Ok(SensorInfo {
            version,
            spec,
            state,
            baud,
            recovered,
            clock,
        })
    }

    /// QT, waiting briefly for its reply (on shutdown and before reconfiguring).
    pub fn quit(&mut self) -> Result<(), SessionError> {
        let _ = self.transact(&Request::Qt, Duration::from_millis(300))?;
        Ok(())
    }
}

/// Whether the model may be asked for ME. Decided from PP's MODL only; unknown
/// models never are: an unsupported command can hang a URG-04LX until power-cycled.
pub fn use_intensity(requested: bool, spec: &SensorSpec) -> bool {
    requested && spec.family().supports_intensity()
}
