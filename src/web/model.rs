//! The plant as the page draws it, from the configuration: lines, their devices, and each
//! field with its label, unit and the control its profile's rules allow (a toggle, a button, a
//! choice of words, a number within its range and step). The page builds every element from
//! this and the plant view; the rules themselves stay in the profile and the command book.

use std::sync::Arc;

use axum::extract::State;
use axum::Json;
use serde::Serialize;

use super::Console;
use crate::bridge::core::discovery::entity_name;
use crate::config::Config;
use rtu2mqtt_profile::{FieldInfo, FieldKind};

/// Everything the page needs to lay out the plant.
#[derive(Debug, Clone, Serialize)]
pub struct PlantModel {
    pub prefix: String,
    /// No token is set: the page offers no command.
    pub read_only: bool,
    pub version: &'static str,
    pub gateway_id: String,
    pub lines: Vec<LineModel>,
    pub devices: Vec<DeviceModel>,
}

/// One line.
#[derive(Debug, Clone, Serialize)]
pub struct LineModel {
    pub name: String,
    /// What it talks through, in words (`serial port /dev/ttyUSB0`).
    pub link: String,
    pub baud: u32,
    /// `8N1`, `8E1`, …
    pub format: String,
    /// A Modbus TCP line: baud and format mean nothing on it.
    pub tcp: bool,
    pub devices: Vec<String>,
}

/// One device.
#[derive(Debug, Clone, Serialize)]
pub struct DeviceModel {
    pub name: String,
    pub line: String,
    pub address: u8,
    pub profile: String,
    pub manufacturer: String,
    pub model: String,
    pub poll_interval_ms: u64,
    pub fields: Vec<FieldModel>,
}

/// One field and its control.
#[derive(Debug, Clone, Serialize)]
pub struct FieldModel {
    pub name: String,
    pub label: String,
    pub description: String,
    pub unit: Option<String>,
    pub writable: bool,
    /// `bool`, `button`, `integer`, `decimal`, `enum` or `text`.
    pub kind: &'static str,
    /// Range of a number (as text, exactly as the profile bounds it).
    pub min: Option<String>,
    pub max: Option<String>,
    /// Smallest change of a number.
    pub step: Option<String>,
    /// The words of an enumeration.
    pub options: Vec<String>,
    /// Integers allowed besides the range.
    pub also: Vec<String>,
}

impl FieldModel {
    fn of(field: &FieldInfo) -> FieldModel {
        let (kind, min, max, options) = match &field.kind {
            FieldKind::Bool => ("bool", None, None, Vec::new()),
            FieldKind::Momentary => ("button", None, None, Vec::new()),
            FieldKind::Integer { min, max } => (
                "integer",
                Some(min.to_string()),
                Some(max.to_string()),
                Vec::new(),
            ),
            FieldKind::Decimal { min, max, .. } => (
                "decimal",
                Some(min.to_string()),
                Some(max.to_string()),
                Vec::new(),
            ),
            FieldKind::Enum { options } => ("enum", None, None, options.clone()),
            FieldKind::Text => ("text", None, None, Vec::new()),
        };
        FieldModel {
            name: field.name.clone(),
            label: entity_name(field),
            description: field.description.clone(),
            unit: field.unit.clone(),
            writable: field.writable,
            kind,
            min,
            max,
            step: field.step.as_ref().map(|step| step.to_text()),
            options,
            also: field.also.iter().map(i64::to_string).collect(),
        }
    }
}

impl PlantModel {
    /// The model of `config`'s lines and devices.
    pub fn of(config: &Config, read_only: bool) -> PlantModel {
        let mut devices = Vec::new();
        let lines = config
            .lines
            .iter()
            .map(|line| {
                for device in &line.devices {
                    let profile = &device.profile;
                    devices.push(DeviceModel {
                        name: device.name.clone(),
                        line: line.name.clone(),
                        address: device.address,
                        profile: profile.name().to_string(),
                        manufacturer: profile.manufacturer().to_string(),
                        model: profile.model().to_string(),
                        poll_interval_ms: device.poll_interval.as_millis() as u64,
                        fields: profile.fields().iter().map(FieldModel::of).collect(),
                    });
                }
                LineModel {
                    name: line.name.clone(),
                    link: line.transport.describe(&line.serial),
                    baud: line.serial.baud,
                    format: line.serial.format.to_string(),
                    tcp: !matches!(line.transport, crate::bus::Transport::Serial),
                    devices: line.devices.iter().map(|d| d.name.clone()).collect(),
                }
            })
            .collect();
        PlantModel {
            prefix: config.mqtt.prefix.clone(),
            read_only,
            version: env!("CARGO_PKG_VERSION"),
            gateway_id: config.mqtt.client_id.clone(),
            lines,
            devices,
        }
    }
}

/// `GET /api/model`.
pub async fn serve_model(State(console): State<Arc<Console>>) -> Json<PlantModel> {
    Json(console.layout().model.clone())
}
