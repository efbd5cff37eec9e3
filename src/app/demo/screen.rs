//! The live table's screen: the plant, the hints and the latest log lines composed into one
//! frame that fits the terminal and is redrawn in place. Pure: the terminal size is passed in.

use std::collections::VecDeque;

use super::view::PlantView;

/// Log lines kept under the table.
pub(super) const LOG_LINES_SHOWN: usize = 6;

/// One frame of the live table: cursor home, the plant (compact when the full table would not
/// fit the terminal), the hints, the latest log lines as room allows, each line cleared to its
/// end, and the rest of the screen cleared.
pub(super) fn compose_screen(
    view: &PlantView,
    header: &str,
    hints: &str,
    log: &VecDeque<String>,
    (width, height): (usize, usize),
) -> String {
    let hint_lines = hints.lines().count();
    let mut table = view.render_table(header, width, false);
    if table.lines().count() + hint_lines + 1 > height {
        table = view.render_table(header, width, true);
    }
    let mut lines: Vec<String> = table.lines().map(str::to_string).collect();
    lines.extend(hints.lines().map(str::to_string));
    let room = height.saturating_sub(lines.len() + 1);
    if room > 1 && !log.is_empty() {
        lines.push("log:".to_string());
        let shown = log.len().min(room - 1);
        for line in log.iter().skip(log.len() - shown) {
            lines.push(format!("  {}", without_timestamp(line)));
        }
    }
    let mut frame = String::from("\x1b[H");
    for line in lines.iter().take(height.saturating_sub(1).max(1)) {
        let clipped: String = line.chars().take(width).collect();
        frame.push_str(&clipped);
        frame.push_str("\x1b[K\n");
    }
    frame.push_str("\x1b[J");
    frame
}

/// A log line without its leading RFC 3339 timestamp (the table is live; the time is now).
pub(super) fn without_timestamp(line: &str) -> &str {
    match line.split_once(' ') {
        Some((first, rest)) if first.len() >= 20 && first.ends_with('Z') && first.contains('T') => {
            rest.trim_start()
        }
        _ => line,
    }
}

/// Keeps the latest [`LOG_LINES_SHOWN`] lines, dropping ordinary lines before warnings and
/// errors (the pty's parity warning should not scroll away behind routine news).
pub(super) fn remember_log_line(recent: &mut VecDeque<String>, line: String) {
    recent.push_back(line);
    if recent.len() > LOG_LINES_SHOWN {
        let is_alarm = |line: &String| line.contains(" WARN ") || line.contains("ERROR ");
        match recent.iter().position(|line| !is_alarm(line)) {
            Some(ordinary) => {
                recent.remove(ordinary);
            }
            None => {
                recent.pop_front();
            }
        }
    }
}

pub(super) fn keep_log_line(line: &str) -> bool {
    !line.trim().is_empty()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn warnings_outlive_ordinary_log_lines() {
        let mut recent = VecDeque::new();
        remember_log_line(&mut recent, "t  WARN parity ignored".to_string());
        for i in 0..20 {
            remember_log_line(&mut recent, format!("t  INFO news {i}"));
        }
        assert_eq!(recent.len(), LOG_LINES_SHOWN);
        assert_eq!(recent[0], "t  WARN parity ignored");
        assert_eq!(recent[LOG_LINES_SHOWN - 1], "t  INFO news 19");
    }

    #[test]
    fn log_lines_lose_their_timestamp_under_the_table() {
        assert_eq!(
            without_timestamp("2026-11-22T02:56:06.029508Z  INFO rtu2mqtt::bridge: up"),
            "INFO rtu2mqtt::bridge: up"
        );
        assert_eq!(without_timestamp("plain words"), "plain words");
    }

    #[test]
    fn the_screen_fits_the_terminal() {
        let fields: Vec<(String, bool)> =
            (0..40).map(|i| (format!("setting_{i}"), i >= 4)).collect();
        let view = PlantView::new("plant", &[("valve".to_string(), fields)]);
        let log: VecDeque<String> = (0..10).map(|i| format!("log line {i}")).collect();
        let hints = "a\nb\nc\n";
        let tall = compose_screen(&view, "header", hints, &log, (80, 60));
        assert!(tall.contains("setting_39"));
        assert!(tall.contains("log line 9"));
        let short = compose_screen(&view, "header", hints, &log, (80, 12));
        assert!(!short.contains("setting_39"), "{short}");
        assert!(short.contains("+ 36 settings and diagnostics not shown"));
        assert!(short.matches('\n').count() <= 11, "{short}");
        assert!(short.starts_with("\x1b[H") && short.ends_with("\x1b[J"));
    }
}
