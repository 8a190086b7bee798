//! The ROS 2 form of every catalog message: which ros2msg schemas its
//! channels use and the CDR of each. The recording writes exactly this; a
//! bridge that publishes the same CDR to ROS 2 or Foxglove takes it from here.
//!
//! The catalog (`smokenav_shared_types::catalog`) names each message's ROS 2
//! type and companion; [`LAYOUTS`] resolves those names to the schemas of
//! [`crate::schema`] at compile time (a name without a schema does not
//! build), and [`Ros2Codec`] is each type's CDR, written with [`crate::codec`].

use crate::cdr::CdrError;
use crate::codec;
use crate::schema::{self, MsgDef};
use smokenav_shared_types::{
    AnyMessage, AnyMessageRef, FusedScan, Health, LaserScan, MessageKind, Odometry, PoseEstimate,
    SimClock, SmokeReading, SonarRing, VelocityCommand, VoxelCloud,
};
use std::borrow::BorrowMut;

/// A catalog type's CDR: its standard (or complete) ROS 2 message and,
/// when the catalog names one, the companion that completes it.
pub trait Ros2Codec: Sized {
    /// The standard ROS 2 message (or the complete `smokenav_msgs` one).
    fn encode_standard(&self, out: &mut Vec<u8>);
    /// The companion; types without one write nothing.
    fn encode_companion(&self, _out: &mut Vec<u8>) {}
    /// Decodes into `out`, a default value: the standard message, then the
    /// companion (when given) completes it.
    fn decode(standard: &[u8], companion: Option<&[u8]>, out: &mut Self) -> Result<(), CdrError>;
}

impl Ros2Codec for LaserScan {
    fn encode_standard(&self, out: &mut Vec<u8>) {
        codec::encode_laser_scan(self, out);
    }
    fn encode_companion(&self, out: &mut Vec<u8>) {
        codec::encode_scan_extras(self, out);
    }
    fn decode(standard: &[u8], companion: Option<&[u8]>, out: &mut Self) -> Result<(), CdrError> {
        codec::decode_laser_scan(standard, out)?;
        companion.map_or(Ok(()), |c| codec::apply_scan_extras(c, out))
    }
}

impl Ros2Codec for FusedScan {
    fn encode_standard(&self, out: &mut Vec<u8>) {
        codec::encode_laser_scan(&self.scan, out);
    }
    fn encode_companion(&self, out: &mut Vec<u8>) {
        codec::encode_fused_decisions(self, out);
    }
    fn decode(standard: &[u8], companion: Option<&[u8]>, out: &mut Self) -> Result<(), CdrError> {
        codec::decode_laser_scan(standard, &mut out.scan)?;
        companion.map_or(Ok(()), |c| codec::apply_fused_decisions(c, out))
    }
}

impl Ros2Codec for Odometry {
    fn encode_standard(&self, out: &mut Vec<u8>) {
        codec::encode_odometry(self, out);
    }
    fn encode_companion(&self, out: &mut Vec<u8>) {
        codec::encode_odometry_extras(self, out);
    }
    fn decode(standard: &[u8], companion: Option<&[u8]>, out: &mut Self) -> Result<(), CdrError> {
        *out = codec::decode_odometry(standard)?;
        companion.map_or(Ok(()), |c| codec::apply_odometry_extras(c, out))
    }
}

impl Ros2Codec for VelocityCommand {
    fn encode_standard(&self, out: &mut Vec<u8>) {
        codec::encode_twist_stamped(self, out);
    }
    fn encode_companion(&self, out: &mut Vec<u8>) {
        codec::encode_stamp_seq(&self.header, out);
    }
    fn decode(standard: &[u8], companion: Option<&[u8]>, out: &mut Self) -> Result<(), CdrError> {
        *out = codec::decode_twist_stamped(standard)?;
        companion.map_or(Ok(()), |c| codec::apply_stamp_seq(c, &mut out.header))
    }
}

impl Ros2Codec for SimClock {
    fn encode_standard(&self, out: &mut Vec<u8>) {
        codec::encode_clock(self, out);
    }
    fn encode_companion(&self, out: &mut Vec<u8>) {
        codec::encode_stamp_seq(&self.header, out);
    }
    fn decode(standard: &[u8], companion: Option<&[u8]>, out: &mut Self) -> Result<(), CdrError> {
        *out = codec::decode_clock(standard)?;
        companion.map_or(Ok(()), |c| codec::apply_stamp_seq(c, &mut out.header))
    }
}

impl Ros2Codec for PoseEstimate {
    fn encode_standard(&self, out: &mut Vec<u8>) {
        codec::encode_pose_stamped(self, out);
    }
    fn encode_companion(&self, out: &mut Vec<u8>) {
        codec::encode_pose_extras(self, out);
    }
    fn decode(standard: &[u8], companion: Option<&[u8]>, out: &mut Self) -> Result<(), CdrError> {
        *out = codec::decode_pose_stamped(standard)?;
        companion.map_or(Ok(()), |c| codec::apply_pose_extras(c, out))
    }
}

impl Ros2Codec for SonarRing {
    fn encode_standard(&self, out: &mut Vec<u8>) {
        codec::encode_sonar_ring(self, out);
    }
    fn decode(standard: &[u8], _: Option<&[u8]>, out: &mut Self) -> Result<(), CdrError> {
        *out = codec::decode_sonar_ring(standard)?;
        Ok(())
    }
}

impl Ros2Codec for SmokeReading {
    fn encode_standard(&self, out: &mut Vec<u8>) {
        codec::encode_smoke_reading(self, out);
    }
    fn decode(standard: &[u8], _: Option<&[u8]>, out: &mut Self) -> Result<(), CdrError> {
        *out = codec::decode_smoke_reading(standard)?;
        Ok(())
    }
}

impl Ros2Codec for VoxelCloud {
    fn encode_standard(&self, out: &mut Vec<u8>) {
        codec::encode_voxel_cloud(self, out);
    }
    fn encode_companion(&self, out: &mut Vec<u8>) {
        codec::encode_voxel_extras(self, out);
    }
    fn decode(standard: &[u8], companion: Option<&[u8]>, out: &mut Self) -> Result<(), CdrError> {
        codec::decode_voxel_cloud(standard, out)?;
        companion.map_or(Ok(()), |c| codec::apply_voxel_extras(c, out))
    }
}

impl Ros2Codec for Health {
    fn encode_standard(&self, out: &mut Vec<u8>) {
        codec::encode_health(self, out);
    }
    fn decode(standard: &[u8], _: Option<&[u8]>, out: &mut Self) -> Result<(), CdrError> {
        codec::decode_health(standard, out)
    }
}

/// The MCAP channels (and ROS 2 topics) one catalog message becomes.
#[derive(Debug, Clone, Copy)]
pub struct Ros2Layout {
    /// The message kind.
    pub kind: MessageKind,
    /// Schema of the main channel (`/laser/scan`): a standard ROS 2 type,
    /// or a `smokenav_msgs` type that carries the message whole.
    pub standard: &'static MsgDef,
    /// Suffix and schema of the companion channel (`/laser/scan/extras`).
    pub companion: Option<(&'static str, &'static MsgDef)>,
    /// Whether a ROS 2 publisher is transient local (late joiners get the last).
    pub latched: bool,
}

impl Ros2Layout {
    /// The ROS 2 topics of bus topic `bus_topic`: the main one and, when
    /// the kind has one, its companion (`/laser/scan`, `/laser/scan/extras`).
    pub fn ros2_topics(&self, bus_topic: &str) -> (String, Option<String>) {
        let main = smokenav_shared_types::catalog::ros2_topic_name(bus_topic);
        let companion = self.companion.map(|(suffix, _)| format!("{main}{suffix}"));
        (main, companion)
    }
}

const fn str_eq(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    if a.len() != b.len() {
        return false;
    }
    let mut i = 0;
    while i < a.len() {
        if a[i] != b[i] {
            return false;
        }
        i += 1;
    }
    true
}

/// The schema named `name`; evaluated at compile time for [`LAYOUTS`], so
/// a catalog type whose schema is missing does not build.
const fn find_schema(name: &str) -> &'static MsgDef {
    let mut i = 0;
    while i < schema::ALL.len() {
        if str_eq(schema::ALL[i].name, name) {
            return schema::ALL[i];
        }
        i += 1;
    }
    panic!("the catalog names a ROS 2 type the recording has no schema for")
}

const fn layout_of(kind: MessageKind) -> Ros2Layout {
    Ros2Layout {
        kind,
        standard: find_schema(kind.ros2_type()),
        companion: match kind.companion() {
            Some(c) => Some((c.suffix, find_schema(c.ros2_type))),
            None => None,
        },
        latched: kind.latched(),
    }
}

/// The ROS 2 layout of `kind`.
pub fn layout(kind: MessageKind) -> &'static Ros2Layout {
    // LAYOUTS follows MessageKind::ALL, whose order is the enum's.
    &LAYOUTS[kind as usize]
}

/// The kinds whose standard channel has schema `name` (a laser scan and a
/// fused scan share one; their companions tell them apart).
pub fn kinds_with_standard(name: &str) -> impl Iterator<Item = &'static Ros2Layout> + '_ {
    LAYOUTS.iter().filter(move |l| l.standard.name == name)
}

/// The kind whose companion has schema `name`.
pub fn kind_with_companion(name: &str) -> Option<&'static Ros2Layout> {
    kinds_with_companion(name).next()
}

/// The kinds whose companion has schema `name` (`StampSeq` completes both a
/// velocity command and a clock; their standard schemas tell them apart).
pub fn kinds_with_companion(name: &str) -> impl Iterator<Item = &'static Ros2Layout> + '_ {
    LAYOUTS
        .iter()
        .filter(move |l| l.companion.is_some_and(|(_, def)| def.name == name))
}

macro_rules! ros2_dispatch {
    (
        fixed {
            $(
                $kind:ident {
                    doc: $doc:literal,
                    rust: $ty:ty,
                    header: [$($h:ident).+],
                    owned: $owned:ty,
                    json: $json:ty,
                    topics: [$($tconst:ident = $topic:literal),*],
                    family: [$($fconst:ident = $prefix:literal),*],
                    ros2: $ros2:literal,
                    companion: $companion:expr,
                    latched: $latched:literal $(,)?
                }
            )*
        }
        map {
            $mkind:ident {
                name: $mname:ident,
                doc: $mdoc:literal,
                info: $mty:ty,
                cell: $cell:ty,
                json: $mjson:ty,
                topics: [$($mtconst:ident = $mtopic:literal),*],
                ros2: $mros2:literal,
                companion: $mcompanion:expr,
                latched: $mlatched:literal $(,)?
            }
        }
    ) => {
        /// The layout of every catalog kind, in catalog order.
        pub static LAYOUTS: &[Ros2Layout] = &[
            $(layout_of(MessageKind::$kind),)*
            layout_of(MessageKind::$mkind),
        ];

        /// Writes the CDR of `msg`'s standard (or complete) message to `out`.
        pub fn encode_standard(msg: AnyMessageRef<'_>, out: &mut Vec<u8>) {
            match msg {
                $(AnyMessageRef::$kind(m) => Ros2Codec::encode_standard(m, out),)*
                AnyMessageRef::$mkind(info, cells) => codec::encode_occupancy_grid(info, cells, out),
            }
        }

        /// Writes the CDR of `msg`'s companion to `out`; false (nothing
        /// written) when its kind has none.
        pub fn encode_companion(msg: AnyMessageRef<'_>, out: &mut Vec<u8>) -> bool {
            if msg.kind().companion().is_none() {
                return false;
            }
            match msg {
                $(AnyMessageRef::$kind(m) => Ros2Codec::encode_companion(m, out),)*
                AnyMessageRef::$mkind(info, _) => codec::encode_map_extras(info, out),
            }
            true
        }

        /// The message of `kind` a standard payload and its companion hold.
        pub fn decode(
            kind: MessageKind,
            standard: &[u8],
            companion: Option<&[u8]>,
        ) -> Result<AnyMessage, CdrError> {
            Ok(match kind {
                $(MessageKind::$kind => {
                    let mut m = <$owned>::default();
                    <$ty as Ros2Codec>::decode(standard, companion, BorrowMut::borrow_mut(&mut m))?;
                    AnyMessage::$kind(m)
                })*
                MessageKind::$mkind => {
                    let (mut info, cells) = codec::decode_occupancy_grid(standard)?;
                    if let Some(c) = companion {
                        codec::apply_map_extras(c, &mut info)?;
                    }
                    AnyMessage::$mkind(info, cells)
                }
            })
        }
    };
}

smokenav_shared_types::for_each_message!(ros2_dispatch);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layouts_follow_the_catalog() {
        assert_eq!(LAYOUTS.len(), MessageKind::ALL.len());
        for (l, &k) in LAYOUTS.iter().zip(MessageKind::ALL) {
            assert_eq!(l.kind, k);
            assert_eq!(layout(k).kind, k);
            assert_eq!(l.standard.name, k.ros2_type());
            assert_eq!(
                l.companion.map(|(s, d)| (s, d.name)),
                k.companion().map(|c| (c.suffix, c.ros2_type))
            );
        }
        assert_eq!(
            kind_with_companion("smokenav_msgs/msg/FusedDecisions").map(|l| l.kind),
            Some(MessageKind::FusedScan)
        );
        assert_eq!(kinds_with_standard("sensor_msgs/msg/LaserScan").count(), 2);
    }

    #[test]
    fn ros2_topics_are_the_recordings_channels() {
        assert_eq!(
            layout(MessageKind::FusedScan).ros2_topics("fusion/scan"),
            ("/fusion/scan".into(), Some("/fusion/scan/decisions".into()))
        );
        assert_eq!(
            layout(MessageKind::Health).ros2_topics("health/slam"),
            ("/health/slam".into(), None)
        );
    }

    #[test]
    fn the_cdr_here_is_what_the_recording_writes() {
        let scan = LaserScan {
            header: smokenav_shared_types::Header::new(7, 3, "laser"),
            count: 2,
            ..Default::default()
        };
        let (mut standard, mut companion) = (Vec::new(), Vec::new());
        encode_standard(AnyMessageRef::LaserScan(&scan), &mut standard);
        assert!(encode_companion(
            AnyMessageRef::LaserScan(&scan),
            &mut companion
        ));
        let mut batch = crate::Batch::new();
        crate::Encoder::new(None).encode(
            "laser/scan",
            AnyMessageRef::LaserScan(&scan),
            1,
            &mut batch,
        );
        let written: Vec<&[u8]> = batch.messages().iter().map(|m| m.data.as_slice()).collect();
        assert_eq!(written, [standard.as_slice(), companion.as_slice()]);
        let back = decode(MessageKind::LaserScan, &standard, Some(&companion)).unwrap();
        assert!(smokenav_shared_types::BitIdentical::bit_identical(
            &back,
            &AnyMessage::LaserScan(Box::new(scan))
        ));
        let ring = SonarRing::default();
        assert!(!encode_companion(
            AnyMessageRef::SonarRing(&ring),
            &mut companion
        ));
    }
}
