//! One line for an error and its causes, each said once.
//!
//! Library errors name their cause in their own message (`{path}: {source}`)
//! and also return it as their source, so anyhow's `{:#}` repeated it: a
//! damaged recording chunk's CRC failure was said three times on one line.

/// The error and its causes, joined by `: `, leaving out a cause whose text
/// the line already holds.
pub fn error_line(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if line.contains(&text) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&text);
    }
    line
}

#[cfg(test)]
mod tests {
    use super::error_line;
    use anyhow::Context;

    /// A cause that names its own source, as the recording's errors do.
    #[derive(Debug)]
    struct Named(std::io::Error);

    impl std::fmt::Display for Named {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            write!(f, "MCAP: {}", self.0)
        }
    }

    impl std::error::Error for Named {
        fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
            Some(&self.0)
        }
    }

    #[test]
    fn each_cause_is_said_once() {
        let crc = std::io::Error::other("Chunk CRC failed");
        let e = Err::<(), _>(Named(crc))
            .context("/tmp/run.mcap: MCAP: Chunk CRC failed")
            .unwrap_err();
        assert_eq!(format!("{e:#}").matches("Chunk CRC failed").count(), 3);
        assert_eq!(error_line(&e), "/tmp/run.mcap: MCAP: Chunk CRC failed");
        // Context that does not repeat its cause keeps it.
        let e = Err::<(), _>(std::io::Error::other("line 98: unknown key"))
            .context("invalid robot profile robot.toml")
            .unwrap_err();
        assert_eq!(
            error_line(&e),
            "invalid robot profile robot.toml: line 98: unknown key"
        );
    }
}
