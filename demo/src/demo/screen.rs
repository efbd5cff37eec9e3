//! The live table's screen: the plant, the hints and the latest log lines composed into one
//! frame that fits the terminal and is redrawn in place, with the footer ("Ctrl-C stops") on
//! the last row whatever the size. Lines too long for the terminal are wrapped between words,
//! never cut, so no value is hidden; when rows run short the log goes first, then settings and
//! diagnostics, then hint lines, then table rows (every device keeps its heading). Pure: the
//! terminal size and the time are passed in.

use std::collections::VecDeque;
use std::time::Duration;

use super::view::{PlantView, Section};

/// Log lines kept under the table.
pub(super) const LOG_LINES_SHOWN: usize = 6;

/// The last row of every frame.
pub(super) const FOOTER: &str = "Ctrl-C stops";

/// One frame of the live table: cursor home, the rows (each cleared to its end), the footer on
/// the terminal's last row.
pub(super) fn compose_screen(
    view: &PlantView,
    header: &str,
    hints: &str,
    log: &VecDeque<String>,
    (width, height): (usize, usize),
    now: Duration,
) -> String {
    // At most `height - 1` rows above the footer, none wider than `width`.
    let room = height.saturating_sub(1);
    let hint_rows: Vec<String> = hints
        .lines()
        .flat_map(|line| wrap(line, width, 5))
        .collect();
    let mut table = view.render_sections(header, width, false, now);
    if table_rows(&table, width) + hint_rows.len() > room {
        table = view.render_sections(header, width, true, now);
    }
    let table_room = room
        .saturating_sub(hint_rows.len())
        .max(table.len().min(room));
    let mut rows = fit_sections(&table, width, table_room);
    let hints_shown = room.saturating_sub(rows.len()).min(hint_rows.len());
    rows.extend(hint_rows.into_iter().take(hints_shown));
    let left = room.saturating_sub(rows.len());
    if left > 1 && !log.is_empty() {
        let mut log_rows: Vec<String> = log
            .iter()
            .flat_map(|line| wrap(&format!("  {}", without_timestamp(line)), width, 6))
            .collect();
        let shown = log_rows.len().min(left - 1);
        rows.push("log:".to_string());
        rows.extend(log_rows.drain(log_rows.len() - shown..));
    }
    // The footer keeps the last row, however short the table is.
    rows.resize(room.max(rows.len()), String::new());
    let mut frame = String::from("\x1b[H");
    for row in &rows {
        frame.push_str(row);
        frame.push_str("\x1b[K\r\n");
    }
    frame.push_str(FOOTER);
    // No newline after the last row: it would scroll the screen by one.
    frame.push_str("\x1b[K\x1b[J");
    frame
}

/// The rows the table takes when nothing is left out.
fn table_rows(sections: &[Section], width: usize) -> usize {
    sections
        .iter()
        .map(|s| wrap(&s.heading, width, 4).len() + s.rows.len())
        .sum()
}

/// The sections in at most `room` rows: every heading first (wrapped), then the sections' rows
/// taken in turns so that each device shows its first rows; a section with rows left out says
/// how many.
fn fit_sections(sections: &[Section], width: usize, room: usize) -> Vec<String> {
    if table_rows(sections, width) <= room {
        return sections
            .iter()
            .flat_map(|s| {
                let mut rows = wrap(&s.heading, width, 4);
                rows.extend(s.rows.iter().map(|row| clip(row, width)));
                rows
            })
            .collect();
    }
    let mut budget = room.saturating_sub(sections.len());
    let mut taken = vec![0usize; sections.len()];
    while budget > 0 {
        let mut progressed = false;
        for (index, section) in sections.iter().enumerate() {
            if budget > 0 && taken[index] < section.rows.len() {
                taken[index] += 1;
                budget -= 1;
                progressed = true;
            }
        }
        if !progressed {
            break;
        }
    }
    let mut rows = Vec::new();
    for (section, taken) in sections.iter().zip(taken) {
        let hidden = section.rows.len() - taken;
        let heading = if hidden > 0 {
            format!("{}  ({hidden} more rows below)", section.heading)
        } else {
            section.heading.clone()
        };
        rows.push(clip(&heading, width));
        rows.extend(section.rows.iter().take(taken).map(|row| clip(row, width)));
    }
    rows.truncate(room);
    rows
}

/// `text` in lines of at most `width` visible characters, broken between words; continuation
/// lines are indented by `indent`. A word longer than a line is split.
pub(super) fn wrap(text: &str, width: usize, indent: usize) -> Vec<String> {
    let width = width.max(indent + 10);
    if visible_width(text) <= width {
        return vec![text.to_string()];
    }
    let lead = text.len() - text.trim_start_matches(' ').len();
    let mut lines = Vec::new();
    let mut line = " ".repeat(lead);
    let mut used = lead;
    let mut empty = true;
    for word in text.split_whitespace() {
        let mut rest = word;
        while !rest.is_empty() {
            let need = visible_width(rest) + usize::from(!empty);
            if used + need <= width {
                if !empty {
                    line.push(' ');
                }
                line.push_str(rest);
                used += need;
                empty = false;
                break;
            }
            if empty {
                // A word longer than a whole line: split it where the line ends.
                let fits = width.saturating_sub(used).max(1);
                let split = rest
                    .char_indices()
                    .nth(fits)
                    .map_or(rest.len(), |(index, _)| index);
                line.push_str(&rest[..split]);
                rest = &rest[split..];
            }
            lines.push(std::mem::replace(&mut line, " ".repeat(indent)));
            used = indent;
            empty = true;
        }
    }
    if !empty {
        lines.push(line);
    }
    lines
}

/// Characters a line takes on screen: ANSI escape sequences take none.
pub(super) fn visible_width(text: &str) -> usize {
    let mut width = 0;
    let mut chars = text.chars();
    while let Some(c) = chars.next() {
        if c == '\x1b' {
            for c in chars.by_ref() {
                if c.is_ascii_alphabetic() {
                    break;
                }
            }
        } else {
            width += 1;
        }
    }
    width
}

/// `line` cut to `width` visible characters (escape sequences kept, a mark switched off).
fn clip(line: &str, width: usize) -> String {
    if visible_width(line) <= width {
        return line.to_string();
    }
    let mut out = String::new();
    let mut shown = 0;
    let mut chars = line.chars();
    while let Some(c) = chars.next() {
        if c == '\x1b' {
            out.push(c);
            for c in chars.by_ref() {
                out.push(c);
                if c.is_ascii_alphabetic() {
                    break;
                }
            }
        } else if shown < width {
            out.push(c);
            shown += 1;
        }
    }
    out.push_str("\x1b[0m");
    out
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
    use crate::demo::view::DeviceOutline;
    use rtu2mqtt::topics::Topics;

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

    fn outline(name: &str, fields: usize, primary: usize) -> DeviceOutline {
        DeviceOutline {
            name: name.to_string(),
            fields: (0..fields)
                .map(|i| (format!("setting_{i}"), i >= primary))
                .collect(),
            starting_allowance: Duration::from_secs(10),
        }
    }

    /// The visible rows of a frame (escape sequences removed).
    fn rows(frame: &str) -> Vec<String> {
        let plain = crate::demo::capture::strip_ansi(frame);
        plain.split("\r\n").map(str::to_string).collect()
    }

    #[test]
    fn the_screen_fits_the_terminal_with_the_footer_last() {
        let view = PlantView::new(
            Topics::new("rtu2mqtt-demo", "plant"),
            &[outline("valve", 40, 4)],
        );
        let log: VecDeque<String> = (0..10).map(|i| format!("log line {i}")).collect();
        let hints = "a\nb\nc\n";
        let tall = compose_screen(&view, "header", hints, &log, (80, 60), Duration::ZERO);
        assert!(tall.contains("setting_39"));
        assert!(tall.contains("log line 9"));
        assert_eq!(rows(&tall).last().map(String::as_str), Some(FOOTER));
        let short = compose_screen(&view, "header", hints, &log, (80, 12), Duration::ZERO);
        assert!(!short.contains("setting_39"), "{short}");
        assert!(short.contains("+ 36 settings and diagnostics not shown"));
        let short_rows = rows(&short);
        assert_eq!(short_rows.len(), 12, "{short_rows:#?}");
        assert_eq!(short_rows[11], FOOTER);
        assert!(short.starts_with("\x1b[H") && short.ends_with("\x1b[J"));
    }

    #[test]
    fn every_device_keeps_its_heading_when_rows_run_short() {
        let devices: Vec<DeviceOutline> =
            (0..4).map(|i| outline(&format!("d{i}"), 30, 30)).collect();
        let view = PlantView::new(Topics::new("rtu2mqtt-demo", "plant"), &devices);
        let frame = compose_screen(
            &view,
            "header",
            "hint\n",
            &VecDeque::new(),
            (40, 12),
            Duration::ZERO,
        );
        let rows = rows(&frame);
        assert_eq!(rows.len(), 12, "{rows:#?}");
        for i in 0..4 {
            assert!(
                rows.iter().any(|r| r.starts_with(&format!("d{i} ["))),
                "{rows:#?}"
            );
        }
        assert!(rows.iter().all(|r| r.chars().count() <= 40), "{rows:#?}");
        assert_eq!(rows[11], FOOTER);
    }

    #[test]
    fn long_lines_wrap_between_words() {
        let text =
            "WARN pseudo-terminal does not take this setting; running without it path=/dev/pts/4";
        let lines = wrap(text, 40, 4);
        assert!(lines.len() > 1);
        assert!(lines.iter().all(|l| visible_width(l) <= 40), "{lines:#?}");
        assert!(lines
            .iter()
            .any(|l| l.trim() == "path=/dev/pts/4" || l.ends_with("path=/dev/pts/4")));
        let words: Vec<&str> = lines.iter().flat_map(|l| l.split_whitespace()).collect();
        assert_eq!(words.join(" "), text);
        assert_eq!(wrap("short", 40, 4), vec!["short"]);
        let long_word = "x".repeat(50);
        assert!(wrap(&long_word, 20, 2)
            .iter()
            .all(|l| visible_width(l) <= 20));
        assert_eq!(visible_width("\x1b[7mab\x1b[27m"), 2);
    }
}
