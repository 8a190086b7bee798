//! Taps: a subscriber of one topic, whatever catalog type it carries, for
//! the processes that handle every topic alike (`smokenav record`, the
//! live view). A tap only receives: like every subscriber it never blocks
//! a publisher, and what it falls behind on shows in [`Tap::stats`].

use crate::{
    Attachment, Bus, BusError, MapSubscriber, Subscriber, SubscriberStats, Waiter, topics,
};
use smokenav_shared_types::AnyMessageRef;
use smokenav_shared_types::catalog::{self, Cataloged, MessageVisitor};
use thiserror::Error;

/// What the callback of [`Tap::drain`] may fail with (its own error, boxed).
pub type SinkError = Box<dyn std::error::Error + Send + Sync>;

/// Why a tap could not be opened or drained.
#[derive(Debug, Error)]
pub enum TapError {
    /// The catalog has no such topic.
    #[error("unknown topic `{0}`")]
    UnknownTopic(String),
    /// The topic's name is in the catalog but not for that type.
    #[error("topic `{topic}` does not carry {ty}")]
    WrongType {
        /// The topic.
        topic: String,
        /// The type the catalog says it carries.
        ty: &'static str,
    },
    /// The bus refused.
    #[error("topic `{topic}`: {source}")]
    Bus {
        /// The topic.
        topic: String,
        /// The bus's error.
        source: BusError,
    },
    /// The callback of [`Tap::drain`] failed.
    #[error(transparent)]
    Sink(SinkError),
}

/// A subscriber of one topic, whatever its type.
pub trait Tap {
    /// The bus topic (`laser/scan`).
    fn topic(&self) -> &str;
    /// Attaches the subscriber to `waiter`.
    fn attach<'w>(&'w self, waiter: &'w Waiter) -> Result<Attachment<'w, 'w>, BusError>;
    /// Hands every queued message to `f`; returns how many there were.
    fn drain(
        &self,
        f: &mut dyn FnMut(&str, AnyMessageRef<'_>) -> Result<(), SinkError>,
    ) -> Result<u64, TapError>;
    /// The subscriber's counters.
    fn stats(&self) -> SubscriberStats;
}

struct TypedTap<T: Cataloged> {
    topic: String,
    sub: Subscriber<T>,
}

impl<T: Cataloged> Tap for TypedTap<T> {
    fn topic(&self) -> &str {
        &self.topic
    }

    fn attach<'w>(&'w self, waiter: &'w Waiter) -> Result<Attachment<'w, 'w>, BusError> {
        waiter.attach(&self.sub)
    }

    fn drain(
        &self,
        f: &mut dyn FnMut(&str, AnyMessageRef<'_>) -> Result<(), SinkError>,
    ) -> Result<u64, TapError> {
        let mut n = 0;
        while let Some(sample) = self.sub.receive().map_err(|e| self.bus_error(e))? {
            f(&self.topic, sample.as_any()).map_err(TapError::Sink)?;
            n += 1;
        }
        Ok(n)
    }

    fn stats(&self) -> SubscriberStats {
        self.sub.stats()
    }
}

impl<T: Cataloged> TypedTap<T> {
    fn bus_error(&self, source: BusError) -> TapError {
        TapError::Bus {
            topic: self.topic.clone(),
            source,
        }
    }
}

/// `slam/map`: a map info header and its cells.
struct MapTap {
    topic: String,
    sub: MapSubscriber,
}

impl Tap for MapTap {
    fn topic(&self) -> &str {
        &self.topic
    }

    fn attach<'w>(&'w self, waiter: &'w Waiter) -> Result<Attachment<'w, 'w>, BusError> {
        waiter.attach(&self.sub)
    }

    fn drain(
        &self,
        f: &mut dyn FnMut(&str, AnyMessageRef<'_>) -> Result<(), SinkError>,
    ) -> Result<u64, TapError> {
        let mut n = 0;
        loop {
            let sample = self.sub.receive().map_err(|source| TapError::Bus {
                topic: self.topic.clone(),
                source,
            })?;
            let Some(sample) = sample else { break };
            f(
                &self.topic,
                AnyMessageRef::Map(sample.user_header(), sample.payload()),
            )
            .map_err(TapError::Sink)?;
            n += 1;
        }
        Ok(n)
    }

    fn stats(&self) -> SubscriberStats {
        self.sub.stats()
    }
}

/// Opens the tap of one topic, whatever catalog type it carries.
struct OpenTap<'a> {
    bus: &'a Bus,
    topic: &'a str,
}

impl MessageVisitor for OpenTap<'_> {
    type Output = Result<Box<dyn Tap>, TapError>;

    fn fixed<M: Cataloged>(&mut self) -> Self::Output {
        let topic = topics::lookup::<M>(self.topic).ok_or_else(|| TapError::WrongType {
            topic: self.topic.to_owned(),
            ty: M::NAME,
        })?;
        let sub = self.bus.subscriber(topic).map_err(|source| TapError::Bus {
            topic: self.topic.to_owned(),
            source,
        })?;
        Ok(Box::new(TypedTap::<M> {
            topic: self.topic.to_owned(),
            sub,
        }))
    }

    fn map(&mut self) -> Self::Output {
        let topic = topics::lookup_map(self.topic).ok_or_else(|| TapError::WrongType {
            topic: self.topic.to_owned(),
            ty: "the map",
        })?;
        let sub = self
            .bus
            .map_subscriber(topic)
            .map_err(|source| TapError::Bus {
                topic: self.topic.to_owned(),
                source,
            })?;
        Ok(Box::new(MapTap {
            topic: self.topic.to_owned(),
            sub,
        }))
    }
}

/// The tap of bus topic `topic` (`laser/scan`, `health/slam`).
pub fn open(bus: &Bus, topic: &str) -> Result<Box<dyn Tap>, TapError> {
    let Some(kind) = catalog::topic_kind(topic) else {
        return Err(TapError::UnknownTopic(topic.to_owned()));
    };
    kind.visit(&mut OpenTap { bus, topic })
}

/// Every fixed topic of the catalog and the health topic of every role.
pub fn default_topics() -> Vec<String> {
    catalog::TOPICS
        .iter()
        .flat_map(|t| {
            if t.family {
                topics::ROLES
                    .iter()
                    .map(|r| format!("{}{r}", t.name))
                    .collect()
            } else {
                vec![t.name.to_owned()]
            }
        })
        .collect()
}
