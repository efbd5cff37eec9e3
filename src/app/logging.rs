//! Logging set-up: `tracing` to stderr, plain text or JSON (`RTU2MQTT_LOG_FORMAT=json`),
//! filtered by `RUST_LOG` (default `info`; the demo passes its own default).
//!
//! Colour only when stderr is a terminal and `NO_COLOR` is not set: the journal, a file or a
//! pipe get plain text. Under systemd (`JOURNAL_STREAM` names our stderr) the journal stamps
//! every line itself, so our own timestamp is left out.

use std::io::IsTerminal;

use tracing_subscriber::EnvFilter;

/// How log lines look, decided once from the environment.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LogStyle {
    pub json: bool,
    pub ansi: bool,
    pub timestamps: bool,
}

impl LogStyle {
    /// The style for this process: `stderr_is_terminal` and the variables as given.
    pub fn decide(stderr_is_terminal: bool, var: impl Fn(&str) -> Option<String>) -> LogStyle {
        let json = var("RTU2MQTT_LOG_FORMAT").is_some_and(|v| v.eq_ignore_ascii_case("json"));
        // https://no-color.org: any non-empty value turns colour off.
        let no_color = var("NO_COLOR").is_some_and(|v| !v.is_empty());
        let journal = var("JOURNAL_STREAM").is_some_and(|v| !v.is_empty());
        LogStyle {
            json,
            ansi: stderr_is_terminal && !no_color && !json,
            timestamps: !journal,
        }
    }
}

/// What the daemon logs unless `RUST_LOG` says otherwise.
pub const DEFAULT_FILTER: &str = "info";

/// Logs to stderr in the style [`LogStyle::decide`] picks; `default_filter` applies unless
/// `RUST_LOG` is set.
pub fn init(default_filter: &str) {
    let style = LogStyle::decide(std::io::stderr().is_terminal(), |name| {
        std::env::var(name).ok()
    });
    let filter =
        EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(default_filter));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(style.ansi)
        .with_writer(std::io::stderr);
    // A second init (tests) is harmless: keep the first subscriber.
    let _ = match (style.json, style.timestamps) {
        (true, _) => builder.json().try_init(),
        (false, true) => builder.try_init(),
        (false, false) => builder.without_time().try_init(),
    };
}

#[cfg(test)]
mod tests {
    use super::LogStyle;

    fn style(terminal: bool, vars: &[(&str, &str)]) -> LogStyle {
        LogStyle::decide(terminal, |name| {
            vars.iter()
                .find(|(key, _)| *key == name)
                .map(|(_, value)| value.to_string())
        })
    }

    #[test]
    fn colour_only_on_a_terminal_without_no_color() {
        assert!(style(true, &[]).ansi);
        assert!(!style(false, &[]).ansi);
        assert!(!style(true, &[("NO_COLOR", "1")]).ansi);
        assert!(style(true, &[("NO_COLOR", "")]).ansi);
        assert!(!style(true, &[("RTU2MQTT_LOG_FORMAT", "JSON")]).ansi);
    }

    #[test]
    fn the_journal_stamps_lines_itself() {
        assert!(style(false, &[]).timestamps);
        assert!(!style(false, &[("JOURNAL_STREAM", "8:12345")]).timestamps);
    }
}
