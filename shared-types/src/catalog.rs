//! The message catalog: every message type the bus carries, listed once.
//!
//! [`for_each_message!`](crate::for_each_message) is the list. For each type
//! it names the Rust type and where its [`Header`] sits, the bus topics it
//! travels on, its JSON form (a [`record`] type), its ROS 2 type and, when
//! that standard message cannot carry everything, the `smokenav_msgs`
//! companion that completes it. The list expands, with a small macro at each
//! place that needs it, into:
//!
//! - here: the [`Message`] and [`Cataloged`] impls, [`MessageKind`] with its
//!   metadata and [`MessageKind::visit`], the owned and borrowed "any message"
//!   enums [`AnyMessage`] and [`AnyMessageRef`], and the topic table [`TOPICS`];
//! - in [`record`]: the JSON enum [`record::Message`];
//! - in the bus: the typed topics (`topics::LASER_SCAN: Topic<LaserScan>`);
//! - in the recording: the CDR dispatch and the MCAP channel layout, whose
//!   ros2msg schemas it looks up, at compile time, by the names given here.
//!
//! Code that acts on "whatever a topic carries" (`topic echo`, `record`,
//! `play`) takes the topic's [`MessageKind`] and calls
//! [`MessageKind::visit`], which calls back with the Rust type.
//!
//! The occupancy grid is the one message that is not a fixed-size value: a
//! [`MapInfo`](crate::MapInfo) header followed by `i8` cells. It has its own entry shape and
//! its own visitor method.
//!
//! # Adding a message type
//!
//! 1. The struct: `#[repr(C)]`, `ZeroCopySend`, `#[type_name("smokenav::…")]`,
//!    with a [`Header`]; its [`BitIdentical`] impl.
//! 2. Its JSON record and [`JsonForm`] impl in [`record`].
//! 3. One entry in [`for_each_message!`](crate::for_each_message).
//! 4. Its CDR: `impl Ros2Codec` in the recording crate (the compiler asks
//!    for it), and a ros2msg schema text there if its ROS 2 type is new.
//!
//! The bus trait, the topic constant, the JSON enum variant, `topic
//! echo/hz`, `record`, `play` and the recording's channels follow from the entry.

use crate::identical::BitIdentical;
use crate::record::{self, JsonForm};
use crate::{ConversionError, Header};
use core::borrow::{Borrow, BorrowMut};
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;

/// The catalog. Calls `$then!` with every message type, in this shape:
///
/// ```text
/// fixed {
///     Kind {
///         doc: "…",                       // what the message is
///         rust: Type,                     // the #[repr(C)] struct
///         header: [path.to.header],       // where its Header sits (same path in its record)
///         owned: Box<Type> | Type,        // how an owned copy is held (big ones boxed)
///         json: Record,                   // its JSON form
///         topics: [CONST = "bus/topic"],  // fixed bus topics
///         family: [CONST = "prefix/"],    // topic families, one topic per member (`health/<role>`)
///         ros2: "pkg/msg/Type",           // standard (or complete smokenav_msgs) ROS 2 type
///         companion: Some(("/suffix", "smokenav_msgs/msg/Type")) | None,
///         latched: bool,                  // ROS 2 transient local: late joiners get the last
///     }
///     …
/// }
/// map { Map { name: …, doc: …, info: MapInfo, cell: i8, json: …, topics: […], ros2: …, companion: …, latched: … } }
/// ```
///
/// `$then` is a `macro_rules!` macro of the caller's that matches this shape.
/// The order is the order `topic list`-like outputs and `record`'s default
/// topics use.
#[macro_export]
macro_rules! for_each_message {
    ($then:ident) => {
        $then! {
            fixed {
                LaserScan {
                    doc: "One planar laser sweep: ranges, and why each beam without one has none.",
                    rust: $crate::laser::LaserScan,
                    header: [header],
                    owned: Box<$crate::laser::LaserScan>,
                    json: $crate::record::LaserScanRecord,
                    topics: [LASER_SCAN = "laser/scan"],
                    family: [],
                    ros2: "sensor_msgs/msg/LaserScan",
                    companion: Some(("/extras", "smokenav_msgs/msg/ScanExtras")),
                    latched: false,
                }
                Odometry {
                    doc: "The base's pose in its odometry frame, with velocities, bumpers and battery.",
                    rust: $crate::odom::Odometry,
                    header: [header],
                    owned: $crate::odom::Odometry,
                    json: $crate::record::OdometryRecord,
                    topics: [BASE_ODOM = "base/odom"],
                    family: [],
                    ros2: "nav_msgs/msg/Odometry",
                    companion: Some(("/extras", "smokenav_msgs/msg/OdometryExtras")),
                    latched: false,
                }
                SonarRing {
                    doc: "One cycle of the sonar ring.",
                    rust: $crate::sonar::SonarRing,
                    header: [header],
                    owned: $crate::sonar::SonarRing,
                    json: $crate::record::SonarRingRecord,
                    topics: [BASE_SONAR = "base/sonar"],
                    family: [],
                    ros2: "smokenav_msgs/msg/SonarRing",
                    companion: None,
                    latched: false,
                }
                VelocityCommand {
                    doc: "A velocity command for the base.",
                    rust: $crate::odom::VelocityCommand,
                    header: [header],
                    owned: $crate::odom::VelocityCommand,
                    json: $crate::record::VelocityCommandRecord,
                    topics: [BASE_CMD_VEL = "base/cmd_vel"],
                    family: [],
                    ros2: "geometry_msgs/msg/TwistStamped",
                    companion: Some(("/extras", "smokenav_msgs/msg/StampSeq")),
                    latched: false,
                }
                SimClock {
                    doc: "Simulated time during a replay (`smokenav play`): the instant of the data.",
                    rust: $crate::sim_clock::SimClock,
                    header: [header],
                    owned: $crate::sim_clock::SimClock,
                    json: $crate::record::SimClockRecord,
                    topics: [CLOCK = "clock"],
                    family: [],
                    ros2: "rosgraph_msgs/msg/Clock",
                    companion: Some(("/extras", "smokenav_msgs/msg/StampSeq")),
                    latched: false,
                }
                SmokeReading {
                    doc: "One smoke sensor reading and the level derived from it.",
                    rust: $crate::smoke::SmokeReading,
                    header: [header],
                    owned: $crate::smoke::SmokeReading,
                    json: $crate::record::SmokeReadingRecord,
                    topics: [SMOKE_LEVEL = "smoke/level"],
                    family: [],
                    ros2: "smokenav_msgs/msg/SmokeReading",
                    companion: None,
                    latched: false,
                }
                FusedScan {
                    doc: "The scan SmokeNav hands to SLAM, with its per-section decisions.",
                    rust: $crate::fused::FusedScan,
                    header: [scan.header],
                    owned: Box<$crate::fused::FusedScan>,
                    json: $crate::record::FusedScanRecord,
                    topics: [FUSION_SCAN = "fusion/scan"],
                    family: [],
                    ros2: "sensor_msgs/msg/LaserScan",
                    companion: Some(("/decisions", "smokenav_msgs/msg/FusedDecisions")),
                    latched: false,
                }
                PoseEstimate {
                    doc: "The robot pose in the map frame: SLAM's, one per processed scan (slam/pose); an operator's, where localisation should search (slam/initial_pose, ROS's /initialpose).",
                    rust: $crate::slam::PoseEstimate,
                    header: [header],
                    owned: $crate::slam::PoseEstimate,
                    json: $crate::record::PoseEstimateRecord,
                    topics: [SLAM_POSE = "slam/pose", SLAM_INITIAL_POSE = "slam/initial_pose"],
                    family: [],
                    ros2: "geometry_msgs/msg/PoseStamped",
                    companion: Some(("/extras", "smokenav_msgs/msg/PoseExtras")),
                    latched: false,
                }
                VoxelCloud {
                    doc: "The 3D map's occupied voxel centres, at most `MAX_VOXELS` (the rest counted in `truncated`).",
                    rust: $crate::voxels::VoxelCloud,
                    header: [header],
                    owned: Box<$crate::voxels::VoxelCloud>,
                    json: $crate::record::VoxelCloudRecord,
                    topics: [MAPPING_VOXELS = "mapping/voxels"],
                    family: [],
                    ros2: "sensor_msgs/msg/PointCloud2",
                    companion: Some(("/extras", "smokenav_msgs/msg/VoxelExtras")),
                    latched: true,
                }
                Health {
                    doc: "A process's periodic health report.",
                    rust: $crate::health::Health,
                    header: [header],
                    owned: Box<$crate::health::Health>,
                    json: $crate::record::HealthRecord,
                    topics: [],
                    family: [HEALTH = "health/"],
                    ros2: "smokenav_msgs/msg/Health",
                    companion: None,
                    latched: false,
                }
            }
            map {
                Map {
                    name: MapInfo,
                    doc: "The occupancy grid: a `MapInfo` header and its cells. `slam/map` carries 0 (free), 100 (occupied) and -1 (unknown) only, as nav2's static layer expects; `slam/map_probability` the occupancy probability 0..100; `slam/map_fuzzy` (fuzzy back-end only) the combined fuzzy map's confidence 0..100 (30 = unknown); with `[slam] backend = \"vote\"`, `slam/vote/<member>` each member's own map (its values as it exports them).",
                    info: $crate::slam::MapInfo,
                    cell: i8,
                    json: $crate::record::MapInfoRecord,
                    topics: [
                        SLAM_MAP = "slam/map",
                        SLAM_MAP_PROBABILITY = "slam/map_probability",
                        SLAM_MAP_FUZZY = "slam/map_fuzzy",
                        SLAM_VOTE_RBPF = "slam/vote/rbpf",
                        SLAM_VOTE_GRAPH = "slam/vote/graph",
                        SLAM_VOTE_FUZZY = "slam/vote/fuzzy",
                        SLAM_VOTE_PROJECTED = "slam/vote/projected",
                        MAPPING_GRID = "mapping/grid",
                        MAPPING_PROJECTED = "mapping/projected"
                    ],
                    ros2: "nav_msgs/msg/OccupancyGrid",
                    companion: Some(("/extras", "smokenav_msgs/msg/MapExtras")),
                    latched: true,
                }
            }
        }
    };
}

/// A fixed-size message with a [`Header`], as the bus carries it: the
/// publisher fills in `header.seq`; the subscriber uses it to count lost
/// messages. Every fixed catalog type implements it; tests and tools may
/// implement it for their own types.
pub trait Message: ZeroCopySend + Copy + core::fmt::Debug + Default + 'static {
    /// The type's short name (`LaserScan`).
    const NAME: &'static str;
    /// The message's header.
    fn header(&self) -> &Header;
    /// The message's header, to stamp or number it.
    fn header_mut(&mut self) -> &mut Header;
}

/// A fixed-size message type of the catalog: one of the types
/// [`MessageKind::visit`] calls back with.
pub trait Cataloged: Message + JsonForm + BitIdentical {
    /// Its entry in the catalog.
    const KIND: MessageKind;
    /// Its JSON form, tagged with its type.
    fn to_json(&self) -> record::Message;
    /// Writes the JSON form `record` into `out`; a record of another type is an error.
    fn from_json(record: &record::Message, out: &mut Self) -> Result<(), ConversionError>;
    /// Borrowed as "any message" (for the recording encoder).
    fn as_any(&self) -> AnyMessageRef<'_>;
    /// The message inside `m`, when `m` holds this type.
    fn from_any(m: &AnyMessage) -> Option<&Self>;
}

/// The ROS 2 message that completes a standard one: what the standard
/// message cannot carry (exact stamps, sequence numbers, beam reasons, …).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Companion {
    /// Appended to the standard message's ROS 2 topic (`/laser/scan/extras`).
    pub suffix: &'static str,
    /// Its ROS 2 type (`smokenav_msgs/msg/ScanExtras`).
    pub ros2_type: &'static str,
}

const fn companion(c: Option<(&'static str, &'static str)>) -> Option<Companion> {
    match c {
        Some((suffix, ros2_type)) => Some(Companion { suffix, ros2_type }),
        None => None,
    }
}

/// One bus topic (or topic family) of the catalog and the type it carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TopicInfo {
    /// The bus topic (`laser/scan`); for a family, the prefix its members share (`health/`).
    pub name: &'static str,
    /// The ROS 2 spelling of `name` (`/laser/scan`, `/health/`).
    pub ros2_name: &'static str,
    /// The type it carries.
    pub kind: MessageKind,
    /// A family: every `name` + member (`health/fusion`) is a topic of `kind`.
    pub family: bool,
}

impl TopicInfo {
    /// Whether bus topic `topic` is this topic, or a member of this family.
    pub fn matches(&self, topic: &str) -> bool {
        if self.family {
            topic
                .strip_prefix(self.name)
                .is_some_and(|member| !member.is_empty() && !member.contains('/'))
        } else {
            topic == self.name
        }
    }
}

const fn bytes_eq(a: &[u8], b: &[u8]) -> bool {
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

/// Whether bus topic `topic` is one of the catalog's (or a member of one of
/// its families). A `const fn`, so typed topics can be checked at compile time.
pub const fn is_catalog_topic(topic: &str) -> bool {
    let t = topic.as_bytes();
    let mut i = 0;
    while i < TOPICS.len() {
        let name = TOPICS[i].name.as_bytes();
        if TOPICS[i].family {
            if t.len() > name.len() {
                let (head, _) = t.split_at(name.len());
                if bytes_eq(head, name) {
                    return true;
                }
            }
        } else if bytes_eq(t, name) {
            return true;
        }
        i += 1;
    }
    false
}

/// The bus name of a topic given either way: `laser/scan` as the bus spells
/// it or `/laser/scan` as ROS 2 (and `ros2 topic`, rosbag2, Foxglove) does.
pub fn bus_topic_name(topic: &str) -> &str {
    // One leading slash only, so a name passed through twice stays the same
    // and `//laser/scan` is not a topic.
    topic
        .strip_prefix('/')
        .filter(|rest| !rest.starts_with('/'))
        .unwrap_or(topic)
}

/// The catalog entry of bus topic `topic` (bus or ROS spelling, see
/// [`bus_topic_name`]), `None` for topics the catalog does not know.
pub fn topic_info(topic: &str) -> Option<&'static TopicInfo> {
    let topic = bus_topic_name(topic);
    TOPICS.iter().find(|t| t.matches(topic))
}

/// The type bus topic `topic` carries, `None` for topics the catalog does not know.
pub fn topic_kind(topic: &str) -> Option<MessageKind> {
    topic_info(topic).map(|t| t.kind)
}

/// The ROS 2 topic name of a bus topic: `laser/scan` → `/laser/scan`.
pub fn ros2_topic_name(topic: &str) -> String {
    format!("/{}", topic.trim_start_matches('/'))
}

/// Called back by [`MessageKind::visit`] with the Rust type of a kind.
pub trait MessageVisitor {
    /// What a visit returns.
    type Output;
    /// The kind is the fixed-size type `M`.
    fn fixed<M: Cataloged>(&mut self) -> Self::Output;
    /// The kind is the occupancy grid: a [`MapInfo`](crate::MapInfo) header and `i8` cells.
    fn map(&mut self) -> Self::Output;
}

macro_rules! catalog_items {
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
        /// A message type of the catalog.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
        pub enum MessageKind {
            $(#[doc = $doc] $kind,)*
            #[doc = $mdoc]
            $mkind,
        }

        impl MessageKind {
            /// Every kind, in catalog order.
            pub const ALL: &'static [MessageKind] = &[$(MessageKind::$kind,)* MessageKind::$mkind];

            /// The type's short name (`LaserScan`; the map's is `MapInfo`), as
            /// JSON records tag it and `topic echo` prints it.
            pub const fn name(self) -> &'static str {
                match self {
                    $(MessageKind::$kind => stringify!($kind),)*
                    MessageKind::$mkind => stringify!($mname),
                }
            }

            /// The kind of short name `name`.
            pub fn from_name(name: &str) -> Option<Self> {
                Self::ALL.iter().copied().find(|k| k.name() == name)
            }

            /// The ROS 2 type it is published as (`sensor_msgs/msg/LaserScan`):
            /// a standard type, or a `smokenav_msgs` type that carries it whole.
            pub const fn ros2_type(self) -> &'static str {
                match self {
                    $(MessageKind::$kind => $ros2,)*
                    MessageKind::$mkind => $mros2,
                }
            }

            /// The companion that completes the standard ROS 2 message, if it needs one.
            pub const fn companion(self) -> Option<Companion> {
                match self {
                    $(MessageKind::$kind => companion($companion),)*
                    MessageKind::$mkind => companion($mcompanion),
                }
            }

            /// Whether ROS 2 publishers of it are transient local (late joiners get the last one).
            pub const fn latched(self) -> bool {
                match self {
                    $(MessageKind::$kind => $latched,)*
                    MessageKind::$mkind => $mlatched,
                }
            }

            /// The bus topics (and families) that carry it.
            pub fn topics(self) -> impl Iterator<Item = &'static TopicInfo> {
                TOPICS.iter().filter(move |t| t.kind == self)
            }

            /// Calls `visitor` back with the Rust type of this kind.
            pub fn visit<V: MessageVisitor + ?Sized>(self, visitor: &mut V) -> V::Output {
                match self {
                    $(MessageKind::$kind => visitor.fixed::<$ty>(),)*
                    MessageKind::$mkind => visitor.map(),
                }
            }
        }

        impl core::fmt::Display for MessageKind {
            fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                f.write_str(self.name())
            }
        }

        /// The catalog's bus topic names as plain strings, for code that names
        /// topics without the bus (offline tools). Bus code uses the typed
        /// topics of `smokenav_platform_bus::topics`.
        pub mod topic_names {
            $($(
                #[doc = concat!("`", $topic, "`: ", $doc)]
                pub const $tconst: &str = $topic;
            )*)*
            $(
                #[doc = concat!("`", $mtopic, "`: ", $mdoc)]
                pub const $mtconst: &str = $mtopic;
            )*
            $($(
                #[doc = concat!("Prefix of `", $prefix, "<member>`: ", $doc)]
                pub const $fconst: &str = $prefix;
            )*)*
        }

        /// Every bus topic of the catalog: the fixed topics, then the topic families.
        pub static TOPICS: &[TopicInfo] = &[
            $($(
                TopicInfo {
                    name: $topic,
                    ros2_name: concat!("/", $topic),
                    kind: MessageKind::$kind,
                    family: false,
                },
            )*)*
            $(
                TopicInfo {
                    name: $mtopic,
                    ros2_name: concat!("/", $mtopic),
                    kind: MessageKind::$mkind,
                    family: false,
                },
            )*
            $($(
                TopicInfo {
                    name: $prefix,
                    ros2_name: concat!("/", $prefix),
                    kind: MessageKind::$kind,
                    family: true,
                },
            )*)*
        ];

        $(
            impl Message for $ty {
                const NAME: &'static str = stringify!($kind);
                fn header(&self) -> &Header {
                    &self.$($h).+
                }
                fn header_mut(&mut self) -> &mut Header {
                    &mut self.$($h).+
                }
            }

            impl Cataloged for $ty {
                const KIND: MessageKind = MessageKind::$kind;

                fn to_json(&self) -> record::Message {
                    record::Message::$kind(JsonForm::to_record(self))
                }

                fn from_json(
                    record: &record::Message,
                    out: &mut Self,
                ) -> Result<(), ConversionError> {
                    match record {
                        record::Message::$kind(r) => <$ty as JsonForm>::write_record(r, out),
                        other => Err(ConversionError::WrongType {
                            expected: stringify!($kind),
                            got: other.kind().name(),
                        }),
                    }
                }

                fn as_any(&self) -> AnyMessageRef<'_> {
                    AnyMessageRef::$kind(self)
                }

                fn from_any(m: &AnyMessage) -> Option<&Self> {
                    match m {
                        AnyMessage::$kind(v) => Some(<$owned as Borrow<$ty>>::borrow(v)),
                        _ => None,
                    }
                }
            }
        )*

        /// Any catalog message, owned (the big ones boxed): what playback yields.
        #[derive(Debug, Clone, PartialEq)]
        pub enum AnyMessage {
            $(#[doc = $doc] $kind($owned),)*
            #[doc = $mdoc]
            $mkind($mty, Vec<$cell>),
        }

        /// Any catalog message, borrowed: what the recording encodes.
        #[derive(Debug, Clone, Copy)]
        pub enum AnyMessageRef<'a> {
            $(#[doc = $doc] $kind(&'a $ty),)*
            #[doc = $mdoc]
            $mkind(&'a $mty, &'a [$cell]),
        }

        impl AnyMessage {
            /// Its type.
            pub fn kind(&self) -> MessageKind {
                match self {
                    $(AnyMessage::$kind(_) => MessageKind::$kind,)*
                    AnyMessage::$mkind(..) => MessageKind::$mkind,
                }
            }

            /// Its header.
            pub fn header(&self) -> &Header {
                self.as_ref().header()
            }

            /// Its header, to restamp it.
            pub fn header_mut(&mut self) -> &mut Header {
                match self {
                    $(AnyMessage::$kind(m) => {
                        Message::header_mut(<$owned as BorrowMut<$ty>>::borrow_mut(m))
                    })*
                    AnyMessage::$mkind(info, _) => &mut info.header,
                }
            }

            /// Borrowed.
            pub fn as_ref(&self) -> AnyMessageRef<'_> {
                match self {
                    $(AnyMessage::$kind(m) => AnyMessageRef::$kind(<$owned as Borrow<$ty>>::borrow(m)),)*
                    AnyMessage::$mkind(info, cells) => AnyMessageRef::$mkind(info, cells),
                }
            }

            /// Its JSON form (the map with its cells).
            pub fn to_json(&self) -> record::Message {
                match self {
                    $(AnyMessage::$kind(m) => Cataloged::to_json(<$owned as Borrow<$ty>>::borrow(m)),)*
                    AnyMessage::$mkind(info, cells) => {
                        record::Message::$mname(<$mjson>::from_map(info, Some(cells)))
                    }
                }
            }

            /// The message a JSON record holds.
            pub fn from_json(record: &record::Message) -> Result<Self, ConversionError> {
                Ok(match record {
                    $(record::Message::$kind(r) => {
                        let mut m = <$owned>::default();
                        <$ty as JsonForm>::write_record(r, <$owned as BorrowMut<$ty>>::borrow_mut(&mut m))?;
                        AnyMessage::$kind(m)
                    })*
                    record::Message::$mname(r) => {
                        let (info, cells) = r.to_map()?;
                        AnyMessage::$mkind(info, cells)
                    }
                })
            }
        }

        impl<'a> AnyMessageRef<'a> {
            /// Its type.
            pub fn kind(&self) -> MessageKind {
                match self {
                    $(AnyMessageRef::$kind(_) => MessageKind::$kind,)*
                    AnyMessageRef::$mkind(..) => MessageKind::$mkind,
                }
            }

            /// Its header.
            pub fn header(&self) -> &'a Header {
                match *self {
                    $(AnyMessageRef::$kind(m) => Message::header(m),)*
                    AnyMessageRef::$mkind(info, _) => &info.header,
                }
            }

            /// Its bus sequence number.
            pub fn seq(&self) -> u64 {
                self.header().seq
            }
        }

        impl From<AnyMessageRef<'_>> for AnyMessage {
            fn from(m: AnyMessageRef<'_>) -> Self {
                match m {
                    $(AnyMessageRef::$kind(v) => AnyMessage::$kind(<$owned>::from(*v)),)*
                    AnyMessageRef::$mkind(info, cells) => AnyMessage::$mkind(*info, cells.to_vec()),
                }
            }
        }

        impl BitIdentical for AnyMessage {
            fn bit_identical(&self, other: &Self) -> bool {
                match (self, other) {
                    $((AnyMessage::$kind(a), AnyMessage::$kind(b)) => {
                        <$owned as Borrow<$ty>>::borrow(a).bit_identical(<$owned as Borrow<$ty>>::borrow(b))
                    })*
                    (AnyMessage::$mkind(a, ca), AnyMessage::$mkind(b, cb)) => {
                        a.bit_identical(b) && ca == cb
                    }
                    _ => false,
                }
            }
        }
    };
}

crate::for_each_message!(catalog_items);

impl AnyMessage {
    /// Moves every stamp the message carries by `offset_ns` (saturating), so
    /// a replay looks recorded "now" to processes that compare stamps with
    /// their clock. Zero stamps (absent inputs of a fused scan) stay zero.
    pub fn shift_stamps(&mut self, offset_ns: i64) {
        fn shift(t: &mut u64, offset: i64) {
            if *t != 0 {
                *t = t.saturating_add_signed(offset);
            }
        }
        shift(&mut self.header_mut().stamp_ns, offset_ns);
        if let AnyMessage::FusedScan(f) = self {
            shift(&mut f.sonar_stamp_ns, offset_ns);
            shift(&mut f.smoke_stamp_ns, offset_ns);
        }
    }
}

#[cfg(test)]
mod tests;
