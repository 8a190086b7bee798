//! Sonar from a team's own bags, as smokenav's [`SonarRing`] keyed by the
//! robot profile's transducer index.
//!
//! Two shapes are read:
//! - `sensor_msgs/Range`, one reading per message: one topic per transducer
//!   (`/sonar/0` … `/sonar/7`), or one topic whose messages carry a frame per
//!   transducer. Each (topic, frame) is mapped to a transducer once: by the
//!   frame's pose in `/tf_static` (a Range measures along its frame's x axis)
//!   matched to the profile's `[sonar]` poses — bearing within
//!   [`MATCH_YAW_DEG`], offset within [`MATCH_OFFSET_M`] — else by the order
//!   the topics were named on the command line (`--sonar` *i*-th → the *i*-th
//!   transducer of the profile). Readings are collected into one ring per
//!   cycle as the Pioneer driver does: a ring is complete when every
//!   transducer of the profile has reported, or ends when one reports again;
//!   it carries the stamp of its newest reading.
//! - `sensor_msgs/PointCloud2`, the whole ring in one message (RosAria's
//!   `sonar_pointcloud2`: x, y, z of each echo in the robot frame, one point
//!   per transducer). Each point goes to the transducer whose axis points at
//!   it (bearing from the transducer's position within half the profile's
//!   `cone_deg`); its range is the distance from that transducer. A point no
//!   axis points at, or a second point for one transducer, is dropped and
//!   counted.
//!
//! Ranges follow REP 117 and the driver: `+inf`, or a range at the profile's
//! (or the message's) maximum, is *saturated* (no echo; range = the
//! profile's maximum); NaN, `-inf`, zero or below the message's minimum is
//! *invalid*. Nothing here panics on a message's content.

use crate::bag::Frames;
use crate::bag_decode::{self, CloudInfo};
use crate::cdr::CdrError;
use crate::codec::BASE_FRAME;
use smokenav_platform_config::SonarSection;
use smokenav_shared_types::{Header, MAX_SONARS, SonarReading, SonarRing, SonarStatus};

/// A `/tf_static` sonar frame's bearing must lie this close to a transducer's axis.
pub const MATCH_YAW_DEG: f64 = 10.0;
/// … and its origin this close to the transducer's position.
pub const MATCH_OFFSET_M: f64 = 0.1;
/// A range within this of the maximum is saturated (a cloud's float32
/// coordinates do not give back the maximum exactly).
const SATURATION_SLACK_M: f64 = 1e-3;

/// How the bag carries the sonar.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SonarKind {
    /// `sensor_msgs/Range`, one reading per message.
    Range,
    /// `sensor_msgs/PointCloud2`, the ring in one message.
    Cloud,
}

/// What went wrong with one sonar message.
#[derive(Debug)]
pub enum SonarError {
    /// The message does not decode.
    Decode(CdrError),
    /// It decodes but cannot be mapped onto the profile's transducers.
    Map(String),
}

impl From<CdrError> for SonarError {
    fn from(e: CdrError) -> Self {
        SonarError::Decode(e)
    }
}

/// One transducer of the profile, in radians.
#[derive(Debug, Clone, Copy)]
struct Transducer {
    index: u8,
    x: f64,
    y: f64,
    yaw: f64,
}

fn wrap(a: f64) -> f64 {
    (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
}

/// A (topic, frame) of a Range topic and the transducer it is.
struct Key {
    slot: usize,
    frame: String,
    index: u8,
}

/// Collects one cycle of readings (the Pioneer driver's rule).
struct Assembler {
    wanted: u32,
    seen: u32,
    pending: SonarRing,
}

impl Assembler {
    fn push(&mut self, r: SonarReading, stamp_ns: u64) -> Option<SonarRing> {
        // Indices come from the validated profile: below 32.
        let bit = 1u32 << r.index;
        let done = if self.seen & bit != 0 {
            self.take()
        } else {
            None
        };
        self.pending.push(r);
        self.pending.header.stamp_ns = stamp_ns;
        self.seen |= bit;
        if done.is_some() {
            return done;
        }
        if self.seen == self.wanted {
            return self.take();
        }
        None
    }

    fn take(&mut self) -> Option<SonarRing> {
        if self.pending.is_empty() {
            return None;
        }
        self.seen = 0;
        let max_range = self.pending.max_range;
        let ring = std::mem::take(&mut self.pending);
        self.pending.max_range = max_range;
        Some(ring)
    }
}

/// Turns a bag's sonar messages into rings.
pub struct SonarMapper {
    kind: SonarKind,
    /// Topics named on the command line, so their order is the transducers' order.
    ordered: bool,
    topics: Vec<String>,
    transducers: Vec<Transducer>,
    max_range: f64,
    half_cone: f64,
    frames: Frames,
    keys: Vec<Key>,
    assembler: Assembler,
    frame: String,
    points: Vec<[f64; 3]>,
    /// Cloud points no transducer's axis pointed at, or a second one for a transducer.
    pub dropped_points: u64,
    /// Rings made.
    pub rings: u64,
}

impl SonarMapper {
    /// `topics` in the order given (`ordered`) or guessed; `frames` from the
    /// start of the bag; the profile's ring.
    pub fn new(
        kind: SonarKind,
        topics: Vec<String>,
        ordered: bool,
        frames: Frames,
        geometry: &SonarSection,
    ) -> Self {
        let mut transducers: Vec<Transducer> = geometry
            .transducers
            .iter()
            .filter(|t| usize::from(t.index) < MAX_SONARS)
            .map(|t| Transducer {
                index: t.index,
                x: t.x,
                y: t.y,
                yaw: t.yaw_deg.to_radians(),
            })
            .collect();
        transducers.sort_by_key(|t| t.index);
        let wanted = transducers.iter().fold(0u32, |m, t| m | (1 << t.index));
        Self {
            kind,
            ordered,
            topics,
            transducers,
            max_range: geometry.max_range_m,
            half_cone: (geometry.cone_deg * 0.5).to_radians(),
            frames,
            keys: Vec::new(),
            assembler: Assembler {
                wanted,
                seen: 0,
                pending: SonarRing {
                    header: Header::new(0, 0, BASE_FRAME),
                    max_range: geometry.max_range_m as f32,
                    ..Default::default()
                },
            },
            frame: String::new(),
            points: Vec::new(),
            dropped_points: 0,
            rings: 0,
        }
    }

    pub fn kind(&self) -> SonarKind {
        self.kind
    }

    pub fn topics(&self) -> &[String] {
        &self.topics
    }

    /// The transducers each (topic, frame) seen so far was mapped to.
    pub fn mapping(&self) -> Vec<(&str, &str, u8)> {
        self.keys
            .iter()
            .map(|k| (self.topics[k.slot].as_str(), k.frame.as_str(), k.index))
            .collect()
    }

    /// One reading as the driver classifies it.
    fn reading(&self, index: u8, range: f64, min: f64, max: f64) -> SonarReading {
        let limit = if max > 0.0 && max.is_finite() {
            max.min(self.max_range)
        } else {
            self.max_range
        };
        if range.is_nan() || range <= 0.0 || (min > 0.0 && range < min) {
            SonarReading::new(index, 0.0, SonarStatus::Invalid)
        } else if range >= limit - SATURATION_SLACK_M {
            SonarReading::new(index, self.max_range as f32, SonarStatus::Saturated)
        } else {
            SonarReading::new(index, range as f32, SonarStatus::Valid)
        }
    }

    /// The transducer a sonar frame at `pose` (in the base frame) is.
    fn match_pose(&self, frame: &str, (x, y, yaw): (f64, f64, f64)) -> Result<u8, String> {
        let cost = |t: &Transducer| {
            let dyaw = wrap(yaw - t.yaw).abs();
            let d = (x - t.x).hypot(y - t.y);
            (dyaw, d)
        };
        let best = self.transducers.iter().min_by(|a, b| {
            let (ya, da) = cost(a);
            let (yb, db) = cost(b);
            let ca = ya / MATCH_YAW_DEG.to_radians() + da / MATCH_OFFSET_M;
            let cb = yb / MATCH_YAW_DEG.to_radians() + db / MATCH_OFFSET_M;
            ca.total_cmp(&cb)
        });
        let Some(t) = best else {
            return Err("the profile's [sonar] has no transducers".into());
        };
        let (dyaw, d) = cost(t);
        if dyaw <= MATCH_YAW_DEG.to_radians() && d <= MATCH_OFFSET_M {
            return Ok(t.index);
        }
        Err(format!(
            "/tf_static puts frame {frame} at ({x:.3}, {y:.3}) m, {:.1}°, which matches no \
             transducer of the profile's [sonar] (nearest: index {} at ({:.3}, {:.3}) m, {:.1}°; \
             within {MATCH_YAW_DEG}° and {MATCH_OFFSET_M} m needed): give the profile of this robot",
            yaw.to_degrees(),
            t.index,
            t.x,
            t.y,
            t.yaw.to_degrees()
        ))
    }

    /// The transducer of a Range message on topic `slot` with the frame in `self.frame`.
    fn resolve(&mut self, slot: usize) -> Result<u8, String> {
        let frame = self.frame.trim_start_matches('/');
        if let Some(k) = self
            .keys
            .iter()
            .find(|k| k.slot == slot && k.frame == frame)
        {
            return Ok(k.index);
        }
        let index = if let Some(pose) = self.frames.in_base(frame) {
            self.match_pose(frame, pose)?
        } else if self.ordered {
            if let Some(other) = self.keys.iter().find(|k| k.slot == slot) {
                return Err(format!(
                    "carries frames {} and {frame}, and /tf_static places neither: give one \
                     topic per transducer, in order, with --sonar, or a bag with /tf_static",
                    other.frame
                ));
            }
            match self.transducers.get(slot) {
                Some(t) => t.index,
                None => {
                    return Err(format!(
                        "--sonar names {} topics; the profile's [sonar] has {} transducers",
                        self.topics.len(),
                        self.transducers.len()
                    ));
                }
            }
        } else {
            return Err(format!(
                "/tf_static does not place frame `{frame}`: name the Range topics in \
                 transducer order with --sonar TOPIC (repeated)"
            ));
        };
        if let Some(k) = self.keys.iter().find(|k| k.index == index) {
            return Err(format!(
                "frame `{frame}` and frame `{}` on {} are both transducer {index}",
                k.frame, self.topics[k.slot]
            ));
        }
        self.keys.push(Key {
            slot,
            frame: frame.to_owned(),
            index,
        });
        Ok(index)
    }

    /// A `sensor_msgs/Range` of the `slot`-th sonar topic; a ring when this reading ends one.
    pub fn range(&mut self, slot: usize, data: &[u8]) -> Result<Option<SonarRing>, SonarError> {
        let r = bag_decode::decode_range(data, &mut self.frame)?;
        let index = self.resolve(slot).map_err(SonarError::Map)?;
        let reading = self.reading(
            index,
            f64::from(r.range),
            f64::from(r.min_range),
            f64::from(r.max_range),
        );
        let ring = self.assembler.push(reading, r.stamp_ns);
        self.rings += u64::from(ring.is_some());
        Ok(ring)
    }

    /// A `sensor_msgs/PointCloud2` holding the ring: the ring.
    pub fn cloud(&mut self, data: &[u8]) -> Result<Option<SonarRing>, SonarError> {
        let CloudInfo { stamp_ns, .. } =
            bag_decode::decode_point_cloud2(data, &mut self.frame, &mut self.points)?;
        let frame = self.frame.trim_start_matches('/');
        let (fx, fy, fyaw) = if frame.is_empty() || self.frames.is_base(frame) {
            (0.0, 0.0, 0.0)
        } else {
            self.frames.in_base(frame).ok_or_else(|| {
                SonarError::Map(format!(
                    "the cloud is in frame `{frame}`, which /tf_static does not place in the base frame"
                ))
            })?
        };
        let (s, c) = fyaw.sin_cos();
        let mut ring = SonarRing {
            header: Header::new(stamp_ns, 0, BASE_FRAME),
            max_range: self.max_range as f32,
            ..Default::default()
        };
        let mut seen = 0u32;
        for i in 0..self.points.len() {
            let [px, py, _] = self.points[i];
            if !(px.is_finite() && py.is_finite()) {
                self.dropped_points += 1;
                continue;
            }
            // Into the base frame.
            let (bx, by) = (fx + c * px - s * py, fy + s * px + c * py);
            let best = self
                .transducers
                .iter()
                .filter_map(|t| {
                    let (dx, dy) = (bx - t.x, by - t.y);
                    let range = dx.hypot(dy);
                    (range > 1e-6).then(|| (t.index, range, wrap(dy.atan2(dx) - t.yaw).abs()))
                })
                .min_by(|a, b| a.2.total_cmp(&b.2));
            match best {
                Some((index, range, off)) if off <= self.half_cone && seen & (1 << index) == 0 => {
                    seen |= 1 << index;
                    ring.push(self.reading(index, range, 0.0, 0.0));
                }
                _ => self.dropped_points += 1,
            }
        }
        // The driver's order: by transducer index.
        let n = ring.len();
        ring.readings[..n].sort_by_key(|r| r.index);
        self.rings += 1;
        Ok(Some(ring))
    }

    /// The ring still being collected at the end of the bag.
    pub fn finish(&mut self) -> Option<SonarRing> {
        let ring = self.assembler.take();
        self.rings += u64::from(ring.is_some());
        ring
    }
}

#[cfg(test)]
#[path = "bag_sonar_tests.rs"]
mod tests;
