//! Topics: names typed with the message they carry, and their quality of service.
//!
//! Names users and scripts rely on; keep them stable. The constants here
//! expand from the message catalog (`smokenav_shared_types::catalog`), so a
//! topic's name and type are written once: `bus.publisher(topics::LASER_SCAN)`
//! gives a `Publisher<LaserScan>`, and pairing a topic with another type
//! does not compile. Names only known at run time (a topic typed by a user,
//! a health topic by role) become typed topics through the catalog:
//! [`lookup`], [`lookup_map`], [`health`].

use smokenav_shared_types::catalog::{self, MessageKind};
use smokenav_shared_types::{Cataloged, Health, MapInfo};
use std::borrow::Cow;
use std::marker::PhantomData;

/// A bus topic that carries `T`: its name, typed.
pub struct Topic<T: ?Sized> {
    name: Cow<'static, str>,
    // fn() -> T: a name is Send, Sync and Copy-cheap whatever T is.
    _carries: PhantomData<fn() -> T>,
}

impl<T: ?Sized> Topic<T> {
    /// The topic `name` carrying `T`, for topics outside the catalog: those
    /// of tests and tools (`test/...`) and of types the catalog does not
    /// list. A catalog topic must come from this module (its constants,
    /// [`lookup`], [`health`]), where its type is the catalog's: naming one
    /// here panics, which for a `const` is a compile error.
    pub const fn new(name: &'static str) -> Self {
        assert!(
            !catalog::is_catalog_topic(name),
            "a catalog topic: use its constant in `topics` (its type is the catalog's)"
        );
        Self::cataloged(name)
    }

    /// A topic of the catalog, typed by the catalog's expansion below.
    const fn cataloged(name: &'static str) -> Self {
        Self {
            name: Cow::Borrowed(name),
            _carries: PhantomData,
        }
    }

    fn owned(name: String) -> Self {
        Self {
            name: Cow::Owned(name),
            _carries: PhantomData,
        }
    }

    /// The bus topic, without the instance prefix (`laser/scan`).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Its ROS 2 spelling (`/laser/scan`), as the MCAP taps and bridges name it.
    pub fn ros2_name(&self) -> String {
        catalog::ros2_topic_name(&self.name)
    }
}

impl<T: ?Sized> Clone for Topic<T> {
    fn clone(&self) -> Self {
        Self {
            name: self.name.clone(),
            _carries: PhantomData,
        }
    }
}

impl<T: ?Sized> PartialEq for Topic<T> {
    fn eq(&self, other: &Self) -> bool {
        self.name == other.name
    }
}

impl<T: ?Sized> Eq for Topic<T> {}

impl<T: ?Sized> core::fmt::Debug for Topic<T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "Topic<{}>({:?})", core::any::type_name::<T>(), self.name)
    }
}

impl<T: ?Sized> core::fmt::Display for Topic<T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(&self.name)
    }
}

/// A family of topics of one type, one per member (`health/<role>`).
pub struct TopicFamily<T: ?Sized> {
    prefix: &'static str,
    _carries: PhantomData<fn() -> T>,
}

impl<T: ?Sized> TopicFamily<T> {
    const fn new(prefix: &'static str) -> Self {
        Self {
            prefix,
            _carries: PhantomData,
        }
    }

    /// What every member's name starts with (`health/`).
    pub const fn prefix(&self) -> &'static str {
        self.prefix
    }

    /// The topic of `member` (`health/fusion`).
    pub fn member(&self, member: &str) -> Topic<T> {
        Topic::owned(format!("{}{member}", self.prefix))
    }
}

macro_rules! typed_topics {
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
        $($(
            #[doc = concat!("`", $topic, "`: ", $doc)]
            pub const $tconst: Topic<$ty> = Topic::cataloged($topic);
        )*)*
        $(
            #[doc = concat!("`", $mtopic, "`: ", $mdoc, " Open it with `Bus::map_publisher`/`map_subscriber`.")]
            pub const $mtconst: Topic<$mty> = Topic::cataloged($mtopic);
        )*
        $($(
            #[doc = concat!("`", $prefix, "<member>`: ", $doc)]
            pub const $fconst: TopicFamily<$ty> = TopicFamily::new($prefix);
        )*)*
    };
}

smokenav_shared_types::for_each_message!(typed_topics);

/// Prefix of the per-process health topics, `health/<role>`.
pub const HEALTH_PREFIX: &str = HEALTH.prefix();

/// The process roles; each has a `health/<role>` topic.
pub const ROLES: &[&str] = &[
    "hokuyo", "pioneer", "scout", "smoke", "fusion", "slam", "mapping",
];

/// The health topic of `role`.
pub fn health(role: &str) -> Topic<Health> {
    HEALTH.member(role)
}

/// The topic `name` typed as `T`, if the catalog says `name` carries `T`.
/// `name` may be spelt the ROS way (`/laser/scan`); the topic is the bus's (`laser/scan`).
pub fn lookup<T: Cataloged>(name: &str) -> Option<Topic<T>> {
    let name = catalog::bus_topic_name(name);
    (catalog::topic_kind(name) == Some(T::KIND)).then(|| Topic::owned(name.to_owned()))
}

/// The topic `name` typed as the map, if the catalog says `name` carries the map.
pub fn lookup_map(name: &str) -> Option<Topic<MapInfo>> {
    let name = catalog::bus_topic_name(name);
    (catalog::topic_kind(name) == Some(MessageKind::Map)).then(|| Topic::owned(name.to_owned()))
}

/// Quality of service of one topic. Every process derives it from this table,
/// so whichever process creates a service, the others can open it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Qos {
    /// Samples a late-joining subscriber receives on connect.
    pub history: usize,
    /// Samples queued per subscriber; when full, the oldest is overwritten
    /// (publishers never block on a slow or dead subscriber) and the
    /// subscriber sees a gap in sequence numbers.
    pub buffer: usize,
    /// Publishers allowed at once (drivers, `smokenav play`, `smokenav drive`, taps).
    pub max_publishers: usize,
    /// Subscribers allowed at once (consumers, `topic echo/hz`, `record`, `status`).
    pub max_subscribers: usize,
}

/// Default for sensor streams: a second of 10 Hz data absorbs a descheduled consumer.
const SENSOR: Qos = Qos {
    history: 1,
    buffer: 32,
    max_publishers: 4,
    max_subscribers: 16,
};

/// Maps are large and only the newest matters.
const MAP: Qos = Qos {
    history: 1,
    buffer: 2,
    max_publishers: 2,
    max_subscribers: 6,
};

/// The QoS of bus topic `topic`.
pub fn qos(topic: &str) -> Qos {
    match topic {
        // Several sources may command the base (controller, `smokenav drive`, replay).
        t if t == BASE_CMD_VEL.name() => Qos {
            history: 0,
            buffer: 16,
            max_publishers: 8,
            max_subscribers: 8,
        },
        // An operator's pose is for the SLAM running now: none is kept for
        // a process that starts later (it would put the robot where it was).
        t if t == SLAM_INITIAL_POSE.name() => Qos {
            history: 0,
            buffer: 4,
            max_publishers: 4,
            max_subscribers: 8,
        },
        // Maps are large and only the newest matters.
        t if t == SLAM_MAP.name()
            || t == SLAM_MAP_PROBABILITY.name()
            || t == SLAM_MAP_FUZZY.name()
            || t == SLAM_VOTE_RBPF.name()
            || t == SLAM_VOTE_GRAPH.name()
            || t == SLAM_VOTE_FUZZY.name()
            || t == SLAM_VOTE_PROJECTED.name()
            || t == MAPPING_GRID.name()
            || t == MAPPING_PROJECTED.name() =>
        {
            MAP
        }
        // The voxel cloud is 192 KiB and only the newest matters, like a map.
        t if t == MAPPING_VOXELS.name() => MAP,
        t if t.starts_with(HEALTH_PREFIX) => Qos {
            history: 1,
            buffer: 4,
            max_publishers: 2,
            max_subscribers: 8,
        },
        // Bus self-tests and benchmarks use `test/...` topics.
        t if t.starts_with("test/") => Qos {
            history: 0,
            buffer: 64,
            max_publishers: 4,
            max_subscribers: 4,
        },
        _ => SENSOR,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_shared_types::LaserScan;

    #[test]
    fn constants_are_the_catalogs_topics() {
        assert_eq!(LASER_SCAN.name(), "laser/scan");
        assert_eq!(LASER_SCAN.ros2_name(), "/laser/scan");
        assert_eq!(SLAM_MAP.name(), "slam/map");
        assert_eq!(health("fusion").name(), "health/fusion");
    }

    #[test]
    fn a_name_becomes_a_typed_topic_only_for_its_own_type() {
        assert_eq!(lookup::<LaserScan>("laser/scan"), Some(LASER_SCAN));
        assert_eq!(lookup::<LaserScan>("fusion/scan"), None);
        assert_eq!(lookup::<Health>("health/scout"), Some(health("scout")));
        assert_eq!(lookup::<LaserScan>("lazer/scan"), None);
        assert_eq!(lookup_map("slam/map"), Some(SLAM_MAP));
        assert_eq!(lookup_map("slam/pose"), None);
        // The ROS spelling names the same bus topic.
        assert_eq!(lookup::<LaserScan>("/laser/scan"), Some(LASER_SCAN));
        assert_eq!(lookup::<Health>("/health/scout"), Some(health("scout")));
        assert_eq!(lookup_map("/slam/map"), Some(SLAM_MAP));
        assert_eq!(lookup::<LaserScan>("//laser/scan"), None);
    }

    #[test]
    #[should_panic(expected = "a catalog topic")]
    fn a_catalog_name_cannot_be_given_another_type() {
        let _ = Topic::<Health>::new("laser/scan");
    }

    #[test]
    #[should_panic(expected = "a catalog topic")]
    fn a_family_member_cannot_be_given_another_type() {
        let _ = Topic::<LaserScan>::new("health/fusion");
    }

    #[test]
    fn names_outside_the_catalog_take_any_type() {
        assert_eq!(Topic::<LaserScan>::new("test/scan").name(), "test/scan");
        assert_eq!(Topic::<Health>::new("health").name(), "health");
    }

    #[test]
    fn qos_keys_on_the_topic_name() {
        assert_eq!(qos(BASE_CMD_VEL.name()).history, 0);
        assert_eq!(qos(SLAM_MAP.name()).buffer, 2);
        assert_eq!(qos(MAPPING_PROJECTED.name()), qos(SLAM_MAP.name()));
        assert_eq!(qos(MAPPING_VOXELS.name()), MAP);
        assert_eq!(qos(health("slam").name()).buffer, 4);
        assert_eq!(qos(LASER_SCAN.name()), SENSOR);
    }
}
