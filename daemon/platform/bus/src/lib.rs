//! The smokenav message bus: a small typed layer over iceoryx2.
//!
//! One place names services (`<instance>/<topic>`), fixes their QoS (bounded
//! history and buffers, publishers that never block on a slow subscriber),
//! pairs every publish–subscribe service with an event service of the same
//! name so subscribers can *wait* for data instead of polling, and numbers
//! messages so a subscriber can count what it lost. No process builds an
//! iceoryx2 service by hand.
//!
//! Topics are typed ([`topics`], expanded from the message catalog of
//! `smokenav_shared_types::catalog`): a topic's name and the type it carries
//! are written once.
//!
//! ```no_run
//! use smokenav_platform_bus::{Bus, BusOptions, topics, Waiter, WaitOutcome};
//! # fn main() -> Result<(), smokenav_platform_bus::BusError> {
//! let bus = Bus::open(&BusOptions::new("robot1", "example"))?;
//! let mut scans = bus.subscriber(topics::LASER_SCAN)?;
//! let waiter = Waiter::new()?;
//! let _attached = waiter.attach(&scans)?;
//! loop {
//!     match waiter.wait(Some(std::time::Duration::from_millis(500)))? {
//!         WaitOutcome::Shutdown => break,
//!         _ => {}
//!     }
//!     while let Some(scan) = scans.receive()? {
//!         let _ = scan.header.seq;
//!     }
//! }
//! # Ok(())
//! # }
//! ```
//!
//! A topic carries one type. This compiles:
//!
//! ```no_run
//! # use smokenav_platform_bus::{Bus, Publisher, topics};
//! # use smokenav_shared_types::LaserScan;
//! # fn f(bus: &Bus) -> Result<(), smokenav_platform_bus::BusError> {
//! let scans: Publisher<LaserScan> = bus.publisher(topics::LASER_SCAN)?;
//! let maps = bus.map_publisher(topics::SLAM_MAP)?;
//! # Ok(()) }
//! ```
//!
//! and each of the following differs from it in one place and does not
//! (stable rustdoc does not check the error codes: each failure was seen to
//! be the one named). Publishing odometry on the laser's topic:
//!
//! ```compile_fail,E0308
//! # use smokenav_platform_bus::{Bus, Publisher, topics};
//! # use smokenav_shared_types::Odometry;
//! # fn f(bus: &Bus) -> Result<(), smokenav_platform_bus::BusError> {
//! let odometry: Publisher<Odometry> = bus.publisher(topics::LASER_SCAN)?;
//! # Ok(()) }
//! ```
//!
//! or opening the map's topic as a fixed-size message (the map is a
//! `MapInfo` header and a slice of cells):
//!
//! ```compile_fail,E0277
//! # use smokenav_platform_bus::{Bus, topics};
//! # fn f(bus: &Bus) -> Result<(), smokenav_platform_bus::BusError> {
//! let maps = bus.publisher(topics::SLAM_MAP)?;
//! # Ok(()) }
//! ```
//!
//! or naming a catalog topic with another type:
//!
//! ```compile_fail,E0080
//! # use smokenav_platform_bus::Topic;
//! # use smokenav_shared_types::Odometry;
//! const ODOMETRY: Topic<Odometry> = Topic::new("laser/scan");
//! # let _ = ODOMETRY;
//! ```

#![warn(missing_docs)]

mod bus;
mod error;
mod map;
mod port;
mod publisher;
mod service;
mod subscriber;
pub mod tap;
pub mod topics;
mod waiter;

pub use bus::{Bus, BusOptions, ServiceInfo, iceoryx2_config};
pub use error::BusError;
pub use map::{MapPublisher, MapSample, MapSubscriber};
pub use port::SubscriberStats;
pub use publisher::Publisher;
pub use service::{PortInfo, TopicPorts};
pub use smokenav_shared_types::Message;
pub use subscriber::{Sample, Subscriber};
pub use tap::{Tap, TapError};
pub use topics::{Qos, Topic, TopicFamily};
pub use waiter::{Attachment, WaitOutcome, Waiter, Wakeable};
