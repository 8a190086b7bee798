//! The sonar firing order `conf_sn` sends (and the emulator obeys).

/// Number of sonars `conf_sn` can order.
pub const ORDER_SLOTS: usize = 16;
/// Ends the firing order list; as the first entry it disables all sonars.
pub const ORDER_END: u8 = 255;

/// A `conf_sn` firing order as sent: up to 16 sonar indices, then 255s.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SonarOrder([u8; ORDER_SLOTS]);

#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SonarOrderError {
    #[error("a firing order has at most 16 entries, got {0}")]
    TooLong(usize),
    #[error("sonar index {0} is not 0–15")]
    BadIndex(u8),
}

impl SonarOrder {
    /// Every sonar disabled (`order[0] = 255`).
    pub const DISABLED: SonarOrder = SonarOrder([ORDER_END; ORDER_SLOTS]);

    /// An order firing `indices` in turn.
    pub fn from_indices(indices: &[u8]) -> Result<Self, SonarOrderError> {
        if indices.len() > ORDER_SLOTS {
            return Err(SonarOrderError::TooLong(indices.len()));
        }
        let mut raw = [ORDER_END; ORDER_SLOTS];
        for (slot, &i) in raw.iter_mut().zip(indices) {
            if i as usize >= crate::SONARS {
                return Err(SonarOrderError::BadIndex(i));
            }
            *slot = i;
        }
        Ok(Self(raw))
    }

    /// The order as on the wire; entries after the first 255 are ignored.
    /// Fails on an index above 15 before the terminator.
    pub fn from_raw(raw: [u8; ORDER_SLOTS]) -> Result<Self, SonarOrderError> {
        for &i in raw.iter().take_while(|&&i| i != ORDER_END) {
            if i as usize >= crate::SONARS {
                return Err(SonarOrderError::BadIndex(i));
            }
        }
        Ok(Self(raw))
    }

    pub fn raw(&self) -> [u8; ORDER_SLOTS] {
        self.0
    }

    /// The sonar indices fired, in order.
    pub fn indices(&self) -> impl Iterator<Item = u8> + '_ {
        self.0.iter().copied().take_while(|&i| i != ORDER_END)
    }
}
