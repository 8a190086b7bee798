//! Command codes and reply statuses with their meanings from the SCIP 2.0 spec.

use std::fmt;

/// The command a request or reply echo names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Command {
    /// `SCIP2.0`: switch a SCIP 1.1 sensor to SCIP 2.0.
    Scip20,
    /// `VV`: version information.
    Vv,
    /// `PP`: sensor parameters (geometry).
    Pp,
    /// `II`: sensor state.
    Ii,
    /// `BM`: laser on.
    Bm,
    /// `QT`: laser off, stops streaming.
    Qt,
    /// `RS`: reset.
    Rs,
    /// `TM`: time-adjust mode.
    Tm,
    /// `SS`: bit rate.
    Ss,
    /// `GD`: one scan, 3-character ranges.
    Gd,
    /// `GS`: one scan, 2-character ranges.
    Gs,
    /// `MD`: streaming, 3-character ranges.
    Md,
    /// `MS`: streaming, 2-character ranges.
    Ms,
    /// `ME`: streaming, 3-character range + 3-character intensity.
    Me,
    /// Any other two characters (the sensor answers `0E` to undefined commands).
    Other([u8; 2]),
}

impl Command {
    /// The command named by the first bytes of a request or echo line.
    pub fn from_line(line: &[u8]) -> Option<Command> {
        if line.starts_with(b"SCIP2.0") {
            return Some(Command::Scip20);
        }
        let [a, b] = *line.first_chunk::<2>()?;
        Some(match &[a, b] {
            b"VV" => Command::Vv,
            b"PP" => Command::Pp,
            b"II" => Command::Ii,
            b"BM" => Command::Bm,
            b"QT" => Command::Qt,
            b"RS" => Command::Rs,
            b"TM" => Command::Tm,
            b"SS" => Command::Ss,
            b"GD" => Command::Gd,
            b"GS" => Command::Gs,
            b"MD" => Command::Md,
            b"MS" => Command::Ms,
            b"ME" => Command::Me,
            _ => Command::Other([a, b]),
        })
    }

    /// Width of the text the command itself takes at the start of a line.
    pub fn text_len(self) -> usize {
        match self {
            Command::Scip20 => 7,
            _ => 2,
        }
    }

    /// True for the commands whose replies carry range data.
    pub fn is_scan(self) -> bool {
        matches!(
            self,
            Command::Gd | Command::Gs | Command::Md | Command::Ms | Command::Me
        )
    }

    /// True for the streaming commands (replies come repeatedly with status 99).
    pub fn is_stream(self) -> bool {
        matches!(self, Command::Md | Command::Ms | Command::Me)
    }

    /// Characters per range value in the command's data lines.
    pub fn range_width(self) -> usize {
        match self {
            Command::Gs | Command::Ms => 2,
            _ => 3,
        }
    }

    /// Characters per step (range + intensity for `ME`).
    pub fn step_width(self) -> usize {
        match self {
            Command::Me => 6,
            c => c.range_width(),
        }
    }

    fn write_text(self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = match self {
            Command::Scip20 => "SCIP2.0",
            Command::Vv => "VV",
            Command::Pp => "PP",
            Command::Ii => "II",
            Command::Bm => "BM",
            Command::Qt => "QT",
            Command::Rs => "RS",
            Command::Tm => "TM",
            Command::Ss => "SS",
            Command::Gd => "GD",
            Command::Gs => "GS",
            Command::Md => "MD",
            Command::Ms => "MS",
            Command::Me => "ME",
            Command::Other(b) => {
                for c in b {
                    if c.is_ascii_graphic() {
                        write!(f, "{}", char::from(c))?;
                    } else {
                        write!(f, "\\x{c:02X}")?;
                    }
                }
                return Ok(());
            }
        };
        f.write_str(s)
    }
}

impl fmt::Display for Command {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.write_text(f)
    }
}

/// A reply status: two characters in SCIP 2.0, one bare character from a SCIP 1.1 sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Status {
    Code([u8; 2]),
    Bare(u8),
}

/// What a status means, coarsely, for deciding what to do next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StatusKind {
    /// `00` (or a bare SCIP 1.1 `0`).
    Ok,
    /// `99`: a streamed scan follows.
    ScanData,
    /// The command was refused as asked (bad parameter, wrong mode, already done).
    Refused,
    /// `0A`–`0I`: the command was not understood or could not be processed.
    Common,
    /// MD/MS/ME `21`–`49`: streaming stopped for an error check.
    StoppedForErrorCheck,
    /// MD/MS/ME `98`: streaming resumed after an error check.
    Resumed,
    /// `50`–`97` (`50`–`98` for GD/GS), or BM `01`: the sensor reports hardware trouble.
    HardwareFault,
    /// A bare SCIP 1.1 error status (`E` and the like): the sensor speaks SCIP 1.1.
    Scip11Error,
}

impl Status {
    pub const OK: Status = Status::Code(*b"00");
    pub const SCAN_DATA: Status = Status::Code(*b"99");

    /// Decimal value for two-digit statuses.
    pub fn number(self) -> Option<u8> {
        match self {
            Status::Code([a, b]) if a.is_ascii_digit() && b.is_ascii_digit() => {
                Some((a - b'0') * 10 + (b - b'0'))
            }
            _ => None,
        }
    }

    pub fn is_ok(self) -> bool {
        matches!(self, Status::Code(s) if s == *b"00") || self == Status::Bare(b'0')
    }

    pub fn is_scan_data(self) -> bool {
        self == Status::SCAN_DATA
    }

    /// Coarse classification of this status as an answer to `command`.
    pub fn kind(self, command: Command) -> StatusKind {
        match self {
            Status::Bare(b'0') => StatusKind::Ok,
            Status::Bare(_) => StatusKind::Scip11Error,
            Status::Code([b'0', c]) if c.is_ascii_uppercase() => StatusKind::Common,
            s => match (s.number(), command) {
                (Some(0), _) => StatusKind::Ok,
                (Some(99), _) => StatusKind::ScanData,
                (Some(1), Command::Bm) => StatusKind::HardwareFault,
                (Some(21..=49), c) if c.is_stream() => StatusKind::StoppedForErrorCheck,
                (Some(98), c) if c.is_stream() => StatusKind::Resumed,
                (Some(50..=98), c) if c.is_scan() => StatusKind::HardwareFault,
                _ => StatusKind::Refused,
            },
        }
    }

    /// The spec's description of this status as an answer to `command`.
    pub fn meaning(self, command: Command) -> &'static str {
        match self {
            Status::Bare(b'0') => "ok (SCIP 1.1 status)",
            Status::Bare(b'E') => "error: the sensor speaks SCIP 1.1 and rejected the command",
            Status::Bare(_) => "error (SCIP 1.1 status)",
            Status::Code([b'0', c]) if c.is_ascii_uppercase() => common_meaning(c),
            s => match s.number() {
                Some(n) => numeric_meaning(n, command),
                None => "unknown status",
            },
        }
    }

    pub fn as_bytes(&self) -> &[u8] {
        match self {
            Status::Code(c) => c,
            Status::Bare(b) => std::slice::from_ref(b),
        }
    }
}

fn common_meaning(c: u8) -> &'static str {
    match c {
        b'A' => "internal error: the sensor could not create the reply",
        b'B' => "buffer shortage, or a command repeated that is already being processed",
        b'C' => "command with insufficient parameters",
        b'D' => "undefined command",
        b'E' => {
            "undefined command (also SCIP2.0 when already in SCIP 2.0, or a command refused in time-adjust mode)"
        }
        b'F' => "command with insufficient parameters",
        b'G' => "tag longer than 16 characters",
        b'H' => "tag contains invalid characters",
        b'I' => "sensor is in firmware-update mode",
        _ => "unknown common status",
    }
}

fn numeric_meaning(n: u8, command: Command) -> &'static str {
    use Command::*;
    match (n, command) {
        (0, _) => "ok",
        (99, _) => "scan data follows",
        (1, Bm) => "laser malfunction",
        (2, Bm) => "laser already on",
        (1, Tm) => "invalid control code",
        (2, Tm) => "already in time-adjust mode",
        (3, Tm) => "already out of time-adjust mode",
        (4, Tm) => "TM1 requested outside time-adjust mode",
        (1, Ss) => "bit rate is not numeric",
        (2, Ss) => "invalid bit rate",
        (3, Ss) => "already at that bit rate",
        (4, Ss) => "bit rate not supported by this model",
        (1, c) if c.is_scan() => "start step is not numeric",
        (2, c) if c.is_scan() => "end step is not numeric",
        (3, c) if c.is_scan() => "cluster count is not numeric",
        (4, c) if c.is_scan() => "end step out of range",
        (5, c) if c.is_scan() => "end step is before start step",
        (6, c) if c.is_stream() => "scan interval is not numeric",
        (7, c) if c.is_stream() => "scan count is not numeric",
        (10, Gd | Gs) => "laser is off (send BM first)",
        (21..=49, c) if c.is_stream() => "streaming stopped for an error check",
        (98, c) if c.is_stream() => "streaming resumed after an error check",
        (50..=97, c) if c.is_scan() => "hardware trouble",
        (98, Gd | Gs) => "hardware trouble",
        _ => "unknown status for this command",
    }
}

impl fmt::Display for Status {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for &b in self.as_bytes() {
            if b.is_ascii_graphic() {
                write!(f, "{}", char::from(b))?;
            } else {
                write!(f, "\\x{b:02X}")?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_kinds_follow_the_command() {
        assert_eq!(Status::OK.kind(Command::Md), StatusKind::Ok);
        assert_eq!(Status::Bare(b'0').kind(Command::Scip20), StatusKind::Ok);
        assert_eq!(
            Status::Bare(b'E').kind(Command::Qt),
            StatusKind::Scip11Error
        );
        assert_eq!(Status::Code(*b"0E").kind(Command::Qt), StatusKind::Common);
        assert_eq!(
            Status::Code(*b"01").kind(Command::Bm),
            StatusKind::HardwareFault
        );
        assert_eq!(Status::Code(*b"02").kind(Command::Bm), StatusKind::Refused);
        assert_eq!(
            Status::Code(*b"30").kind(Command::Md),
            StatusKind::StoppedForErrorCheck
        );
        assert_eq!(Status::Code(*b"98").kind(Command::Md), StatusKind::Resumed);
        assert_eq!(
            Status::Code(*b"98").kind(Command::Gd),
            StatusKind::HardwareFault
        );
        assert_eq!(
            Status::Code(*b"55").kind(Command::Ms),
            StatusKind::HardwareFault
        );
        assert_eq!(Status::Code(*b"10").kind(Command::Gd), StatusKind::Refused);
    }

    #[test]
    fn meanings_name_the_spec_cases() {
        assert_eq!(
            Status::Code(*b"10").meaning(Command::Gd),
            "laser is off (send BM first)"
        );
        assert_eq!(
            Status::Code(*b"04").meaning(Command::Tm),
            "TM1 requested outside time-adjust mode"
        );
        assert_eq!(
            Status::Code(*b"0G").meaning(Command::Vv),
            "tag longer than 16 characters"
        );
        assert_eq!(
            Status::Code(*b"07").meaning(Command::Md),
            "scan count is not numeric"
        );
    }

    #[test]
    fn command_from_line_knows_scip20_and_others() {
        assert_eq!(Command::from_line(b"SCIP2.0"), Some(Command::Scip20));
        assert_eq!(Command::from_line(b"MD0044072501000"), Some(Command::Md));
        assert_eq!(Command::from_line(b"XY"), Some(Command::Other(*b"XY")));
        assert_eq!(Command::from_line(b"X"), None);
        assert_eq!(Command::Other([b'Z', 0]).to_string(), "Z\\x00");
    }
}
