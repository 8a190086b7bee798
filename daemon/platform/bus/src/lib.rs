//! The smokenav message bus: a small typed layer over iceoryx2.
//!
//! One place names services (`<instance>/<topic>`), fixes their QoS (bounded
//! history and buffers, publishers that never block on a slow subscriber),
//! pairs every publish–subscribe service with an event service of the same
//! name so subscribers can *wait* for data instead of polling, and numbers
//! messages so a subscriber can count what it lost. No process builds an
//! iceoryx2 service by hand.
//!
//! ```no_run
//! use smokenav_platform_bus::{Bus, BusOptions, topics, Waiter, WaitOutcome};
//! use smokenav_shared_types::LaserScan;
//! # fn main() -> Result<(), smokenav_platform_bus::BusError> {
//! let bus = Bus::open(&BusOptions::new("robot1", "example"))?;
//! let mut scans = bus.subscriber::<LaserScan>(topics::LASER_SCAN)?;
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

mod bus;
mod error;
mod map;
mod message;
mod publisher;
mod subscriber;
pub mod topics;
mod waiter;

pub use bus::{Bus, BusOptions, ServiceInfo, iceoryx2_config};
pub use error::BusError;
pub use map::{MapPublisher, MapSample, MapSubscriber};
pub use message::Message;
pub use publisher::Publisher;
pub use subscriber::{Sample, Subscriber, SubscriberStats};
pub use topics::Qos;
pub use waiter::{Attachment, WaitOutcome, Waiter, Wakeable};
