//! What the demo shows: the plant as seen from MQTT. [`PlantView`] folds the messages of a
//! `<prefix>/#` subscription into per-device state and renders it either as a compact table
//! (redrawn in place on a terminal) or as one log line per change. Pure: no I/O, no clock
//! (the caller passes the time elapsed since the demo started), so the rendering is testable.
//!
//! A device is `starting` until the gateway has polled it: its first `offline` is the gateway's
//! announcement at connect (or a retained word from an earlier run), not a verdict; it shows
//! `OFFLINE` only when the gateway says so again after that, or when it never came online
//! within its start-up allowance. A value that changed within [`HIGHLIGHT`] is marked for the
//! table.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::Duration;

use rtu2mqtt::topics::{TopicKind, Topics};
use rtu2mqtt_profile::topic_levels::GATEWAY_DEVICE;

/// What one MQTT message meant to the view.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) enum Change {
    /// A field's value appeared or changed.
    Value {
        device: String,
        field: String,
        value: String,
    },
    /// A retained field value was cleared (empty payload): the field is no longer published.
    Cleared {
        device: String,
        field: String,
    },
    Availability {
        device: String,
        status: DeviceStatus,
    },
    GatewayStatus {
        gateway: String,
        status: String,
    },
    /// Somebody asked for a field to change.
    CommandSent {
        device: String,
        field: String,
        value: String,
    },
    /// The gateway reported a command's outcome.
    CommandResult {
        device: String,
        field: String,
        outcome: String,
        value: String,
        detail: String,
    },
}

/// What the view knows of a device's availability.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(super) enum DeviceStatus {
    /// Nothing heard yet.
    #[default]
    Waiting,
    /// Not polled yet (its start-up delay, the first transactions).
    Starting,
    Online,
    /// The gateway says so after having polled it.
    Offline,
}

impl DeviceStatus {
    pub(super) fn word(self) -> &'static str {
        match self {
            DeviceStatus::Waiting => "waiting for the gateway",
            DeviceStatus::Starting => "starting",
            DeviceStatus::Online => "online",
            DeviceStatus::Offline => "OFFLINE",
        }
    }
}

/// How long a changed value stays highlighted in the table.
pub(super) const HIGHLIGHT: Duration = Duration::from_secs(2);

/// Reverse video on, off: how the table marks a value that just changed.
pub(super) const MARK_ON: &str = "\x1b[7m";
pub(super) const MARK_OFF: &str = "\x1b[27m";

/// One field as the view knows it.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub(super) struct FieldView {
    pub name: String,
    /// Empty until first published (and after a clearing).
    pub value: String,
    /// When the value last changed from one value to another (not its first appearance).
    pub changed_at: Option<Duration>,
}

/// One device as the view knows it.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub(super) struct DeviceView {
    /// Fields in display order (the profile's order when known, else first seen).
    pub fields: Vec<FieldView>,
    /// Settings and diagnostics (Home Assistant's entity categories), left out of a compact
    /// table.
    pub secondary: Vec<String>,
    pub status: DeviceStatus,
    /// Live (not retained) `offline` words heard; the first is the gateway's announcement.
    live_offline_words: u32,
    /// Until when (since the demo started) an `offline` before the first `online` still means
    /// "starting".
    starting_until: Duration,
}

impl DeviceView {
    /// The status as of `now`: a device still starting past its allowance is offline.
    pub(super) fn status_at(&self, now: Duration) -> DeviceStatus {
        match self.status {
            DeviceStatus::Starting if now > self.starting_until => DeviceStatus::Offline,
            status => status,
        }
    }

    /// The value of a field (empty when not published).
    #[cfg(test)]
    pub(super) fn value(&self, field: &str) -> Option<&str> {
        self.fields
            .iter()
            .find(|f| f.name == field)
            .map(|f| f.value.as_str())
    }
}

/// A configured device as the view starts with it.
#[derive(Debug, Clone)]
pub(super) struct DeviceOutline {
    pub name: String,
    /// (field, is a setting or diagnostic) in the profile's order.
    pub fields: Vec<(String, bool)>,
    /// How long after the demo's start the device may take to come online (its start-up delay
    /// and the first polls) before an `offline` counts.
    pub starting_allowance: Duration,
}

/// The plant as seen from the broker.
#[derive(Debug, Clone)]
pub(super) struct PlantView {
    /// The gateway's topics, by which each message is classified.
    topics: Topics,
    /// Devices in configuration order, with a profile-ordered field list.
    devices: Vec<(String, DeviceView)>,
    gateways: BTreeMap<String, String>,
    /// The latest command outcomes, newest last.
    results: Vec<String>,
}

/// How many command outcomes the table keeps.
const RESULTS_SHOWN: usize = 4;

impl PlantView {
    /// A view of the devices under the prefix of `topics`, listed in `devices` order with
    /// their fields in the given order, so the table does not reshuffle as values arrive.
    pub(super) fn new(topics: Topics, devices: &[DeviceOutline]) -> Self {
        PlantView {
            topics,
            devices: devices
                .iter()
                .map(|outline| {
                    let view = DeviceView {
                        fields: outline
                            .fields
                            .iter()
                            .map(|(name, _)| FieldView {
                                name: name.clone(),
                                ..FieldView::default()
                            })
                            .collect(),
                        secondary: outline
                            .fields
                            .iter()
                            .filter(|(_, secondary)| *secondary)
                            .map(|(name, _)| name.clone())
                            .collect(),
                        starting_until: outline.starting_allowance,
                        ..DeviceView::default()
                    };
                    (outline.name.clone(), view)
                })
                .collect(),
            gateways: BTreeMap::new(),
            results: Vec::new(),
        }
    }

    /// Interprets one live message received at `now`; see [`PlantView::apply_at`].
    #[cfg(test)]
    pub(super) fn apply(&mut self, topic: &str, payload: &[u8]) -> Option<Change> {
        self.apply_at(topic, payload, false, Duration::ZERO)
    }

    /// Interprets one message (`retained`: delivered from the broker's store on subscribing,
    /// so possibly from an earlier run) received `now` after the demo started; None when it
    /// changes nothing (same value again, another prefix, a topic the view does not know).
    pub(super) fn apply_at(
        &mut self,
        topic: &str,
        payload: &[u8],
        retained: bool,
        now: Duration,
    ) -> Option<Change> {
        let kind = self.topics.classify(topic);
        let text = String::from_utf8_lossy(payload).trim().to_string();
        match kind {
            TopicKind::GatewayStatus { gateway } => {
                let previous = self.gateways.insert(gateway.to_string(), text.clone());
                (previous.as_deref() != Some(text.as_str())).then(|| Change::GatewayStatus {
                    gateway: gateway.to_string(),
                    status: text,
                })
            }
            // The gateway's own space holds no device.
            kind if kind.device() == Some(GATEWAY_DEVICE) => None,
            TopicKind::Availability { device } => {
                let view = self.device_mut(device);
                let before = view.status_at(now);
                view.status = match text.as_str() {
                    "online" => DeviceStatus::Online,
                    "offline" => {
                        let verdict =
                            matches!(view.status, DeviceStatus::Online | DeviceStatus::Offline)
                                || (!retained && view.live_offline_words > 0);
                        if !retained {
                            view.live_offline_words += 1;
                        }
                        if verdict {
                            DeviceStatus::Offline
                        } else {
                            DeviceStatus::Starting
                        }
                    }
                    _ => return None,
                };
                let status = view.status_at(now);
                (status != before).then(|| Change::Availability {
                    device: device.to_string(),
                    status,
                })
            }
            TopicKind::Command { device, field } => {
                (!text.is_empty()).then(|| Change::CommandSent {
                    device: device.to_string(),
                    field: field.to_string(),
                    value: text,
                })
            }
            TopicKind::Result { device, field } => {
                let result = parse_result(&text);
                let change = Change::CommandResult {
                    device: device.to_string(),
                    field: field.to_string(),
                    outcome: result.0,
                    value: result.1,
                    detail: result.2,
                };
                self.results.push(describe(&change));
                if self.results.len() > RESULTS_SHOWN {
                    self.results.remove(0);
                }
                Some(change)
            }
            TopicKind::State { device, field } => {
                let view = self.device_mut(device);
                let index = match view.fields.iter().position(|f| f.name == field) {
                    Some(index) => index,
                    None => {
                        view.fields.push(FieldView {
                            name: field.to_string(),
                            ..FieldView::default()
                        });
                        view.fields.len() - 1
                    }
                };
                let slot = &mut view.fields[index];
                if slot.value == text {
                    return None;
                }
                if !slot.value.is_empty() && !text.is_empty() {
                    slot.changed_at = Some(now);
                }
                slot.value = text.clone();
                Some(if text.is_empty() {
                    Change::Cleared {
                        device: device.to_string(),
                        field: field.to_string(),
                    }
                } else {
                    Change::Value {
                        device: device.to_string(),
                        field: field.to_string(),
                        value: text,
                    }
                })
            }
            _ => None,
        }
    }

    fn device_mut(&mut self, device: &str) -> &mut DeviceView {
        let index = match self.devices.iter().position(|(name, _)| name == device) {
            Some(index) => index,
            None => {
                self.devices
                    .push((device.to_string(), DeviceView::default()));
                self.devices.len() - 1
            }
        };
        &mut self.devices[index].1
    }

    /// A device's state.
    #[cfg(test)]
    pub(super) fn device(&self, name: &str) -> Option<&DeviceView> {
        self.devices
            .iter()
            .find(|(device, _)| device == name)
            .map(|(_, view)| view)
    }

    /// Fields with a value, over all devices.
    pub(super) fn published_fields(&self) -> usize {
        self.devices
            .iter()
            .map(|(_, view)| view.fields.iter().filter(|f| !f.value.is_empty()).count())
            .sum()
    }

    /// Whether some value is highlighted at `now` (the table must be redrawn when it fades).
    pub(super) fn highlights_at(&self, now: Duration) -> bool {
        self.devices
            .iter()
            .flat_map(|(_, view)| &view.fields)
            .any(|field| is_fresh(field, now))
    }

    /// Devices whose start-up allowance ran out at `now` without an `online`: their status
    /// changes as time passes.
    pub(super) fn expired_starts(&mut self, now: Duration) -> Vec<Change> {
        let mut changes = Vec::new();
        for (name, view) in &mut self.devices {
            if view.status == DeviceStatus::Starting && view.status_at(now) == DeviceStatus::Offline
            {
                view.status = DeviceStatus::Offline;
                changes.push(Change::Availability {
                    device: name.clone(),
                    status: DeviceStatus::Offline,
                });
            }
        }
        changes
    }

    /// The table as sections: a header line, then per device a heading (its name and status)
    /// with its fields as `name value` cells in aligned columns fitting `width` (values that
    /// changed within [`HIGHLIGHT`] of `now` marked), then the latest outcomes. `compact`
    /// leaves settings and diagnostics out (counted in the device's heading).
    pub(super) fn render_sections(
        &self,
        header: &str,
        width: usize,
        compact: bool,
        now: Duration,
    ) -> Vec<Section> {
        let width = width.max(40);
        let mut heading = header.to_string();
        for (gateway, status) in &self.gateways {
            let _ = write!(heading, "  (gateway {gateway} {status})");
        }
        let mut sections = vec![Section {
            heading,
            rows: Vec::new(),
        }];
        for (name, view) in &self.devices {
            let shown: Vec<&FieldView> = view
                .fields
                .iter()
                .filter(|field| !compact || !view.secondary.contains(&field.name))
                .collect();
            let hidden = view.fields.len() - shown.len();
            let mut heading = format!("{name} [{}]", view.status_at(now).word());
            if hidden > 0 {
                let _ = write!(heading, "  + {hidden} settings and diagnostics not shown");
            }
            let cells: Vec<Cell> = shown
                .iter()
                .map(|field| {
                    let value = if field.value.is_empty() {
                        "·"
                    } else {
                        field.value.as_str()
                    };
                    Cell {
                        name: field.name.clone(),
                        value: value.to_string(),
                        marked: is_fresh(field, now),
                    }
                })
                .collect();
            let rows = grid(&cells, width - 2)
                .into_iter()
                .map(|line| format!("  {line}"))
                .collect();
            sections.push(Section { heading, rows });
        }
        if !self.results.is_empty() {
            sections.push(Section {
                heading: "latest commands:".to_string(),
                rows: self.results.iter().map(|r| format!("  {r}")).collect(),
            });
        }
        sections
    }

    /// The whole table as text (every section's heading and rows).
    #[cfg(test)]
    pub(super) fn render_table(&self, header: &str, width: usize, compact: bool) -> String {
        let mut out = String::new();
        for section in self.render_sections(header, width, compact, Duration::ZERO) {
            let _ = writeln!(out, "{}", section.heading);
            for row in section.rows {
                let _ = writeln!(out, "{row}");
            }
        }
        out
    }
}

/// A part of the table: a heading line (the header, a device, the outcomes) and its rows.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct Section {
    pub heading: String,
    pub rows: Vec<String>,
}

fn is_fresh(field: &FieldView, now: Duration) -> bool {
    field
        .changed_at
        .is_some_and(|at| now.saturating_sub(at) < HIGHLIGHT && at <= now)
}

/// One `name value` cell of the table.
struct Cell {
    name: String,
    value: String,
    /// Changed a moment ago: the value is shown in reverse video.
    marked: bool,
}

impl Cell {
    fn width(&self) -> usize {
        self.name.chars().count() + 1 + self.value.chars().count()
    }
}

/// `cells` in as many aligned columns as fit `width` (each column as wide as its widest cell,
/// two spaces apart), row by row. Marks take no room on screen, so they are added around the
/// value after the widths are measured.
fn grid(cells: &[Cell], width: usize) -> Vec<String> {
    let lengths: Vec<usize> = cells.iter().map(Cell::width).collect();
    let mut columns = cells.len().max(1);
    let widths = loop {
        let widths: Vec<usize> = (0..columns)
            .map(|column| {
                lengths
                    .iter()
                    .skip(column)
                    .step_by(columns)
                    .max()
                    .copied()
                    .unwrap_or(0)
            })
            .collect();
        let total = widths.iter().sum::<usize>() + 2 * (columns - 1);
        if total <= width || columns == 1 {
            break widths;
        }
        columns -= 1;
    };
    cells
        .chunks(columns)
        .map(|row| {
            let mut line = String::new();
            for (cell, cell_width) in row.iter().zip(&widths) {
                let padding = " ".repeat(cell_width.saturating_sub(cell.width()) + 2);
                let (on, off) = if cell.marked {
                    (MARK_ON, MARK_OFF)
                } else {
                    ("", "")
                };
                let _ = write!(line, "{} {on}{}{off}{padding}", cell.name, cell.value);
            }
            line.trim_end().to_string()
        })
        .collect()
}

/// `(outcome, value, detail)` of a `…/result` payload; a payload that is not the contract's
/// JSON is shown as its text.
fn parse_result(text: &str) -> (String, String, String) {
    let field = |json: &serde_json::Value, key: &str| {
        json.get(key)
            .and_then(|v| v.as_str())
            .unwrap_or_default()
            .to_string()
    };
    match serde_json::from_str::<serde_json::Value>(text) {
        Ok(json) if json.is_object() => (
            field(&json, "outcome"),
            field(&json, "value"),
            field(&json, "detail"),
        ),
        _ => (text.to_string(), String::new(), String::new()),
    }
}

/// One change as a human sentence.
pub(super) fn describe(change: &Change) -> String {
    match change {
        Change::Value {
            device,
            field,
            value,
        } => format!("{device}/{field} = {value}"),
        Change::Cleared { device, field } => format!("{device}/{field} cleared"),
        Change::Availability { device, status } => match status {
            DeviceStatus::Starting => format!("{device} is starting (not polled yet)"),
            status => format!("{device} is {}", status.word()),
        },
        Change::GatewayStatus { gateway, status } => format!("gateway {gateway} is {status}"),
        Change::CommandSent {
            device,
            field,
            value,
        } => format!("{device}/{field} ← {value} (command)"),
        Change::CommandResult {
            device,
            field,
            outcome,
            value,
            detail,
        } => {
            let mut text = format!("{device}/{field} ← {value}: {outcome}");
            if !detail.is_empty() {
                let _ = write!(text, " ({detail})");
            }
            text
        }
    }
}

/// A log line: elapsed time since the demo started, then the change.
pub(super) fn log_line(elapsed: Duration, change: &Change) -> String {
    format!("{:>8.2}s  {}", elapsed.as_secs_f64(), describe(change))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn outline(name: &str, fields: &[(&str, bool)]) -> DeviceOutline {
        DeviceOutline {
            name: name.to_string(),
            fields: fields.iter().map(|(f, s)| (f.to_string(), *s)).collect(),
            starting_allowance: Duration::from_secs(10),
        }
    }

    fn view() -> PlantView {
        PlantView::new(
            Topics::new("rtu2mqtt-demo", "plant"),
            &[
                outline("dust_collector", &[("power", false), ("gear", false)]),
                outline("valve", &[("opening", false), ("setpoint", true)]),
            ],
        )
    }

    #[test]
    fn values_change_once() {
        let mut view = view();
        assert_eq!(
            view.apply("plant/dust_collector/gear", b"5"),
            Some(Change::Value {
                device: "dust_collector".into(),
                field: "gear".into(),
                value: "5".into()
            })
        );
        assert_eq!(view.apply("plant/dust_collector/gear", b"5"), None);
        assert!(view.apply("plant/dust_collector/gear", b"8").is_some());
        assert_eq!(view.published_fields(), 1);
        let dust = view.device("dust_collector").unwrap();
        assert_eq!(dust.value("power"), Some(""));
        assert_eq!(dust.value("gear"), Some("8"));
        assert_eq!(view.apply("other/dust_collector/gear", b"1"), None);
        assert_eq!(view.apply("plantx/dust_collector/gear", b"1"), None);
    }

    #[test]
    fn topics_are_classified() {
        let mut view = view();
        assert_eq!(
            view.apply("plant/valve/availability", b"online"),
            Some(Change::Availability {
                device: "valve".into(),
                status: DeviceStatus::Online
            })
        );
        assert_eq!(view.apply("plant/valve/availability", b"maybe"), None);
        assert!(matches!(
            view.apply("plant/gateway/rtu2mqtt-demo/status", b"online"),
            Some(Change::GatewayStatus { .. })
        ));
        assert_eq!(
            view.apply("plant/gateway/rtu2mqtt-demo/stats/x", b"1"),
            None
        );
        assert!(matches!(
            view.apply("plant/valve/opening/set", b"40"),
            Some(Change::CommandSent { .. })
        ));
        assert_eq!(view.apply("plant/valve/opening/set", b""), None);
        let result = view.apply(
            "plant/valve/opening/result",
            br#"{"value":"40","outcome":"applied","detail":"read back 40"}"#,
        );
        assert_eq!(
            describe(&result.unwrap()),
            "valve/opening ← 40: applied (read back 40)"
        );
        let garbage = view.apply("plant/valve/opening/result", b"\xff\xfe");
        assert!(garbage.is_some());
        assert_eq!(view.apply("plant/a/b/c/d", b"1"), None);
    }

    #[test]
    fn table_lists_devices_in_order_with_placeholders() {
        let mut view = view();
        view.apply("plant/valve/opening", b"40");
        view.apply("plant/valve/availability", b"online");
        view.apply("plant/new_device/x", b"1");
        let table = view.render_table("header", 80, false);
        let dust = table
            .find("dust_collector [waiting for the gateway]")
            .unwrap();
        let valve = table.find("valve [online]").unwrap();
        let new = table.find("new_device").unwrap();
        assert!(dust < valve && valve < new, "{table}");
        assert!(table.contains("power ·"), "{table}");
        assert!(table.contains("opening 40"), "{table}");
        assert!(
            table.lines().all(|line| line.chars().count() <= 80),
            "{table}"
        );
    }

    #[test]
    fn table_wraps_to_the_width() {
        let names: Vec<String> = (0..12).map(|i| format!("field_{i}")).collect();
        let fields: Vec<(&str, bool)> = names.iter().map(|n| (n.as_str(), false)).collect();
        let mut view = PlantView::new(Topics::new("rtu2mqtt-demo", "p"), &[outline("d", &fields)]);
        for i in 0..12 {
            view.apply(&format!("p/d/field_{i}"), b"123");
        }
        let narrow = view.render_table("h", 40, false);
        let wide = view.render_table("h", 200, false);
        assert!(narrow.lines().count() > wide.lines().count());
        assert!(
            narrow.lines().all(|line| line.chars().count() <= 40),
            "{narrow}"
        );
    }

    #[test]
    fn grid_columns_take_their_own_widths() {
        let cells: Vec<Cell> = [("a", "1"), ("long_name", "2"), ("b", "3"), ("c", "4")]
            .iter()
            .map(|(name, value)| Cell {
                name: name.to_string(),
                value: value.to_string(),
                marked: false,
            })
            .collect();
        assert_eq!(grid(&cells, 100), vec!["a 1  long_name 2  b 3  c 4"]);
        assert_eq!(grid(&cells, 16), vec!["a 1  long_name 2", "b 3  c 4"]);
        assert_eq!(grid(&cells, 5).len(), 4);
        assert!(grid(&[], 10).is_empty());
    }

    #[test]
    fn log_lines_carry_time_and_change() {
        let change = Change::Value {
            device: "valve".into(),
            field: "opening".into(),
            value: "40".into(),
        };
        assert_eq!(
            log_line(Duration::from_millis(3_210), &change),
            "    3.21s  valve/opening = 40"
        );
    }

    #[test]
    fn a_device_is_starting_until_the_gateway_has_polled_it() {
        let mut view = view();
        let second = Duration::from_secs(1);
        // A retained word from an earlier run, then the gateway's announcement at connect.
        let change = view.apply_at(
            "plant/dust_collector/availability",
            b"offline",
            true,
            second,
        );
        assert_eq!(
            change,
            Some(Change::Availability {
                device: "dust_collector".into(),
                status: DeviceStatus::Starting
            })
        );
        assert_eq!(
            view.apply_at(
                "plant/dust_collector/availability",
                b"offline",
                false,
                second
            ),
            None
        );
        assert!(view
            .render_table("h", 80, false)
            .contains("dust_collector [starting]"));
        // The gateway says it again after having polled: now it is offline.
        let change = view.apply_at(
            "plant/dust_collector/availability",
            b"offline",
            false,
            2 * second,
        );
        assert_eq!(describe(&change.unwrap()), "dust_collector is OFFLINE");
        // A device that was online and goes offline is offline at once.
        view.apply_at("plant/valve/availability", b"online", false, second);
        let change = view.apply_at("plant/valve/availability", b"offline", false, 2 * second);
        assert!(matches!(
            change,
            Some(Change::Availability {
                status: DeviceStatus::Offline,
                ..
            })
        ));
    }

    #[test]
    fn a_start_that_never_ends_becomes_offline() {
        let mut view = view();
        view.apply_at("plant/valve/availability", b"offline", true, Duration::ZERO);
        assert!(view.expired_starts(Duration::from_secs(5)).is_empty());
        let changes = view.expired_starts(Duration::from_secs(11));
        assert_eq!(
            changes,
            vec![Change::Availability {
                device: "valve".into(),
                status: DeviceStatus::Offline
            }]
        );
        assert!(view.expired_starts(Duration::from_secs(12)).is_empty());
    }

    #[test]
    fn changed_values_are_marked_for_a_moment() {
        let mut view = view();
        let at = |s: u64| Duration::from_secs(s);
        view.apply_at("plant/dust_collector/gear", b"5", false, at(1));
        // A first value is news, not a change.
        assert!(!view.highlights_at(at(1)));
        view.apply_at("plant/dust_collector/gear", b"8", false, at(3));
        assert!(view.highlights_at(at(4)));
        let sections = view.render_sections("h", 80, false, at(4));
        let marked = format!("gear {MARK_ON}8{MARK_OFF}");
        assert!(sections[1].rows[0].contains(&marked), "{sections:?}");
        assert!(!view.highlights_at(at(5)));
        let sections = view.render_sections("h", 80, false, at(5));
        assert!(sections[1].rows[0].contains("gear 8"), "{sections:?}");
        assert!(!sections[1].rows[0].contains(MARK_ON));
    }
}
