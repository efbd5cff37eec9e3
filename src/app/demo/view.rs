//! What the demo shows: the plant as seen from MQTT. [`PlantView`] folds the messages of a
//! `<prefix>/#` subscription into per-device state and renders it either as a compact table
//! (redrawn in place on a terminal) or as one log line per change. Pure: no I/O, no clock
//! (the caller passes elapsed time), so the rendering is testable.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::Duration;

/// What one MQTT message meant to the view.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Change {
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
        online: bool,
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

/// One device as the view knows it.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct DeviceView {
    /// Field values in display order (the profile's order when known, else first seen).
    pub fields: Vec<(String, String)>,
    /// Settings and diagnostics (Home Assistant's entity categories), left out of a compact
    /// table.
    pub secondary: Vec<String>,
    pub online: Option<bool>,
}

/// The plant as seen from the broker.
#[derive(Debug, Clone, Default)]
pub struct PlantView {
    prefix: String,
    /// Devices in configuration order, with a profile-ordered field list.
    devices: Vec<(String, DeviceView)>,
    gateways: BTreeMap<String, String>,
    /// The latest command outcomes, newest last.
    results: Vec<String>,
}

/// How many command outcomes the table keeps.
const RESULTS_SHOWN: usize = 4;

impl PlantView {
    /// A view of the devices under `prefix`, listed in `devices` order with their fields
    /// (name, secondary) in the given order, so the table does not reshuffle as values arrive.
    pub fn new(prefix: &str, devices: &[(String, Vec<(String, bool)>)]) -> Self {
        PlantView {
            prefix: prefix.to_string(),
            devices: devices
                .iter()
                .map(|(name, fields)| {
                    let view = DeviceView {
                        fields: fields
                            .iter()
                            .map(|(f, _)| (f.clone(), String::new()))
                            .collect(),
                        secondary: fields
                            .iter()
                            .filter(|(_, secondary)| *secondary)
                            .map(|(f, _)| f.clone())
                            .collect(),
                        online: None,
                    };
                    (name.clone(), view)
                })
                .collect(),
            gateways: BTreeMap::new(),
            results: Vec::new(),
        }
    }

    /// Interprets one message; None when it changes nothing (same value again, another
    /// prefix, a topic the view does not know).
    pub fn apply(&mut self, topic: &str, payload: &[u8]) -> Option<Change> {
        let rest = topic.strip_prefix(&self.prefix)?.strip_prefix('/')?;
        let levels: Vec<&str> = rest.split('/').collect();
        let text = String::from_utf8_lossy(payload).trim().to_string();
        match levels.as_slice() {
            ["gateway", gateway, "status"] => {
                let previous = self.gateways.insert(gateway.to_string(), text.clone());
                (previous.as_deref() != Some(text.as_str())).then(|| Change::GatewayStatus {
                    gateway: gateway.to_string(),
                    status: text,
                })
            }
            ["gateway", ..] => None,
            [device, "availability"] => {
                let online = match text.as_str() {
                    "online" => true,
                    "offline" => false,
                    _ => return None,
                };
                let view = self.device_mut(device);
                let changed = view.online != Some(online);
                view.online = Some(online);
                changed.then(|| Change::Availability {
                    device: device.to_string(),
                    online,
                })
            }
            [device, field, "set"] => (!text.is_empty()).then(|| Change::CommandSent {
                device: device.to_string(),
                field: field.to_string(),
                value: text,
            }),
            [device, field, "result"] => {
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
            [device, field] => {
                let view = self.device_mut(device);
                let slot = match view.fields.iter_mut().find(|(name, _)| name == field) {
                    Some((_, value)) => value,
                    None => {
                        view.fields.push((field.to_string(), String::new()));
                        let last = view.fields.len() - 1;
                        &mut view.fields[last].1
                    }
                };
                if *slot == text {
                    return None;
                }
                *slot = text.clone();
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
    pub fn device(&self, name: &str) -> Option<&DeviceView> {
        self.devices
            .iter()
            .find(|(device, _)| device == name)
            .map(|(_, view)| view)
    }

    /// Fields with a value, over all devices.
    pub fn published_fields(&self) -> usize {
        self.devices
            .iter()
            .map(|(_, view)| view.fields.iter().filter(|(_, v)| !v.is_empty()).count())
            .sum()
    }

    /// The table: a header line, then per device its availability and its fields as
    /// `name value` cells in aligned columns fitting `width`, then the latest outcomes.
    /// `compact` leaves settings and diagnostics out (counted on the device's line).
    pub fn render_table(&self, header: &str, width: usize, compact: bool) -> String {
        let width = width.max(40);
        let mut out = String::new();
        let _ = write!(out, "{header}");
        for (gateway, status) in &self.gateways {
            let _ = write!(out, "  (gateway {gateway} {status})");
        }
        out.push('\n');
        for (name, view) in &self.devices {
            let availability = match view.online {
                Some(true) => "online",
                Some(false) => "OFFLINE",
                None => "waiting for the first poll",
            };
            let shown: Vec<&(String, String)> = view
                .fields
                .iter()
                .filter(|(field, _)| !compact || !view.secondary.contains(field))
                .collect();
            let hidden = view.fields.len() - shown.len();
            let _ = write!(out, "{name} [{availability}]");
            if hidden > 0 {
                let _ = write!(out, "  + {hidden} settings and diagnostics not shown");
            }
            out.push('\n');
            let cells: Vec<String> = shown
                .iter()
                .map(|(field, value)| {
                    let value = if value.is_empty() { "·" } else { value };
                    format!("{field} {value}")
                })
                .collect();
            for line in grid(&cells, width - 2) {
                let _ = writeln!(out, "  {line}");
            }
        }
        if !self.results.is_empty() {
            let _ = writeln!(out, "latest commands:");
            for result in &self.results {
                let _ = writeln!(out, "  {result}");
            }
        }
        out
    }
}

/// `cells` in as many aligned columns as fit `width` (each column as wide as its widest cell,
/// two spaces apart), row by row.
fn grid(cells: &[String], width: usize) -> Vec<String> {
    let lengths: Vec<usize> = cells.iter().map(|c| c.chars().count()).collect();
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
                let _ = write!(line, "{cell:<cell_width$}  ");
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
pub fn describe(change: &Change) -> String {
    match change {
        Change::Value {
            device,
            field,
            value,
        } => format!("{device}/{field} = {value}"),
        Change::Cleared { device, field } => format!("{device}/{field} cleared"),
        Change::Availability { device, online } => {
            format!("{device} is {}", if *online { "online" } else { "OFFLINE" })
        }
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
pub fn log_line(elapsed: Duration, change: &Change) -> String {
    format!("{:>8.2}s  {}", elapsed.as_secs_f64(), describe(change))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view() -> PlantView {
        PlantView::new(
            "plant",
            &[
                (
                    "dust_collector".to_string(),
                    vec![("power".to_string(), false), ("gear".to_string(), false)],
                ),
                (
                    "valve".to_string(),
                    vec![
                        ("opening".to_string(), false),
                        ("setpoint".to_string(), true),
                    ],
                ),
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
        assert_eq!(
            view.device("dust_collector").unwrap().fields,
            vec![
                ("power".to_string(), String::new()),
                ("gear".to_string(), "8".to_string())
            ]
        );
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
                online: true
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
        let dust = table.find("dust_collector [waiting").unwrap();
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
        let fields: Vec<(String, bool)> = (0..12).map(|i| (format!("field_{i}"), false)).collect();
        let mut view = PlantView::new("p", &[("d".to_string(), fields)]);
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
        let cells: Vec<String> = ["a 1", "long_name 2", "b 3", "c 4"]
            .iter()
            .map(|c| c.to_string())
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
}
