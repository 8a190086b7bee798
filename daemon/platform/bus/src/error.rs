//! The bus's one error type.

use thiserror::Error;

/// Errors from the bus. Each says which service and which operation.
#[derive(Debug, Error)]
pub enum BusError {
    /// An instance, node or service name iceoryx2 cannot use.
    #[error("invalid bus name `{name}`: {reason}")]
    InvalidName {
        /// The name.
        name: String,
        /// Why it is refused.
        reason: String,
    },
    /// This process's node could not be created.
    #[error("cannot create the bus node `{node}`: {reason}")]
    Node {
        /// The node's name.
        node: String,
        /// iceoryx2's reason.
        reason: String,
    },
    /// An operation on one service failed.
    #[error("service `{service}`: cannot {op}: {reason}")]
    Service {
        /// The full service name, `<instance>/<topic>`.
        service: String,
        /// What was attempted.
        op: &'static str,
        /// iceoryx2's reason.
        reason: String,
    },
    /// The topic's service exists with another layout of its message type:
    /// the processes on it were built from another smokenav release (an
    /// upgrade installed while they ran).
    #[error(
        "service `{service}`: the processes on it exchange another version of its message type \
         (built from another smokenav release): restart every smokenav process after an upgrade \
         (`systemctl restart smokenav.target`), or use the tools of the release they run"
    )]
    IncompatibleType {
        /// The full service name, `<instance>/<topic>`.
        service: String,
    },
    /// Waiting failed.
    #[error("waitset: {op}: {reason}")]
    WaitSet {
        /// What was attempted.
        op: &'static str,
        /// iceoryx2's reason.
        reason: String,
    },
}

impl BusError {
    pub(crate) fn service(service: &str, op: &'static str, e: impl std::fmt::Debug) -> Self {
        BusError::Service {
            service: service.to_owned(),
            op,
            reason: format!("{e:?}"),
        }
    }
}
