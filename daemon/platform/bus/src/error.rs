use thiserror::Error;

/// Errors from the bus. Each says which service and which operation.
#[derive(Debug, Error)]
pub enum BusError {
    #[error("invalid bus name `{name}`: {reason}")]
    InvalidName { name: String, reason: String },
    #[error("cannot create the bus node `{node}`: {reason}")]
    Node { node: String, reason: String },
    #[error("service `{service}`: cannot {op}: {reason}")]
    Service {
        service: String,
        op: &'static str,
        reason: String,
    },
    #[error("waitset: {op}: {reason}")]
    WaitSet { op: &'static str, reason: String },
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
