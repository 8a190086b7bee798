use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// Set when SIGTERM or SIGINT arrives. The signal also interrupts blocking
/// waits (epoll, reads), so loops notice it within one wait.
#[derive(Clone, Debug, Default)]
pub struct Shutdown {
    flag: Arc<AtomicBool>,
}

impl Shutdown {
    /// Registers the handlers. Safe to call more than once.
    pub fn install() -> std::io::Result<Self> {
        let flag = Arc::new(AtomicBool::new(false));
        for sig in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
            signal_hook::flag::register(sig, Arc::clone(&flag))?;
        }
        Ok(Self { flag })
    }

    /// Whether SIGTERM or SIGINT arrived.
    pub fn requested(&self) -> bool {
        self.flag.load(Ordering::Relaxed)
    }

    /// Requests shutdown from inside the process (e.g. a fatal error in a thread).
    pub fn request(&self) {
        self.flag.store(true, Ordering::Relaxed);
    }
}
