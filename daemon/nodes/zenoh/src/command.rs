//! `cmd_vel` from outside: a `geometry_msgs/msg/Twist` sample (what
//! teleop_twist_keyboard and nav2 publish) decoded and checked before it
//! becomes a bus command.
//!
//! The guard is the base driver's own: the bridge forwards each fresh sample
//! once, as it arrives, onto `base/cmd_vel`, so a remote controller that dies
//! or whose link stalls stops sending and the driver's `[base]
//! cmd_timeout_s` stops the robot exactly as for a dead local one. A sample
//! that arrives late (its rmw_zenoh source time older than the timeout: a
//! network that buffered it) is dropped, never replayed; so is one with
//! non-finite velocities.

use crate::keys;
use thiserror::Error;

/// Why a command sample was not forwarded.
#[derive(Debug, Error, PartialEq)]
pub enum CommandError {
    #[error("a Twist is 52 bytes of CDR, got {0}")]
    Length(usize),
    #[error("unknown CDR encapsulation {0:#06x}")]
    Encapsulation(u16),
    #[error("non-finite velocity")]
    NotFinite,
    #[error("sent {age_ms} ms ago, older than the command timeout")]
    Stale { age_ms: i64 },
}

/// The velocities a Twist carries that a planar base uses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Twist2 {
    /// linear.x, m/s.
    pub linear: f64,
    /// angular.z, rad/s.
    pub angular: f64,
}

/// Decodes a CDR `geometry_msgs/msg/Twist` (encapsulation header, then six
/// float64: linear x y z, angular x y z).
pub fn decode_twist(cdr: &[u8]) -> Result<Twist2, CommandError> {
    if cdr.len() != 4 + 48 {
        return Err(CommandError::Length(cdr.len()));
    }
    let enc = u16::from_be_bytes([cdr[0], cdr[1]]);
    let little = match enc {
        0x0001 => true,
        0x0000 => false,
        other => return Err(CommandError::Encapsulation(other)),
    };
    let f = |i: usize| {
        let b: [u8; 8] = cdr[4 + 8 * i..12 + 8 * i].try_into().unwrap_or([0; 8]);
        if little {
            f64::from_le_bytes(b)
        } else {
            f64::from_be_bytes(b)
        }
    };
    let t = Twist2 {
        linear: f(0),
        angular: f(5),
    };
    if (0..6).any(|i| !f(i).is_finite()) {
        return Err(CommandError::NotFinite);
    }
    Ok(t)
}

/// Checks a sample's rmw_zenoh attachment time against `now_unix_ns`: a
/// command sent longer than `timeout_ns` ago (or more than that in the
/// future: a clock that disagrees) is stale. A sample without an
/// attachment is judged on arrival alone.
pub fn check_age(
    attachment: Option<&[u8]>,
    now_unix_ns: i64,
    timeout_ns: i64,
) -> Result<(), CommandError> {
    let Some((_, sent, _)) = attachment.and_then(keys::parse_attachment) else {
        return Ok(());
    };
    let age = now_unix_ns.saturating_sub(sent);
    if age.abs() > timeout_ns {
        return Err(CommandError::Stale {
            age_ms: age / 1_000_000,
        });
    }
    Ok(())
}

/// A CDR Twist (little endian), for tests and tools.
pub fn encode_twist(linear: f64, angular: f64) -> Vec<u8> {
    let mut out = vec![0x00, 0x01, 0x00, 0x00];
    for v in [linear, 0.0, 0.0, 0.0, 0.0, angular] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn twist_round_trips_and_rejects_bad_input() {
        let t = decode_twist(&encode_twist(0.3, -0.5)).unwrap();
        assert_eq!(
            t,
            Twist2 {
                linear: 0.3,
                angular: -0.5
            }
        );
        assert_eq!(decode_twist(&[0; 10]), Err(CommandError::Length(10)));
        let mut bad = encode_twist(f64::NAN, 0.0);
        assert_eq!(decode_twist(&bad), Err(CommandError::NotFinite));
        bad[1] = 7;
        assert_eq!(decode_twist(&bad), Err(CommandError::Encapsulation(7)));
    }

    #[test]
    fn a_command_older_than_the_timeout_is_stale() {
        let g = keys::gid("t");
        let now = 1_000_000_000_000i64;
        let fresh = keys::attachment(1, now - 50_000_000, &g);
        assert_eq!(check_age(Some(&fresh), now, 200_000_000), Ok(()));
        let old = keys::attachment(2, now - 500_000_000, &g);
        assert_eq!(
            check_age(Some(&old), now, 200_000_000),
            Err(CommandError::Stale { age_ms: 500 })
        );
        assert_eq!(check_age(None, now, 200_000_000), Ok(()));
    }
}
