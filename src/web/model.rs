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
use rtu2mqtt_profile::{FieldInfo, FieldKind, Profile};

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
    /// The profiles the devices use, each once (a plant of a thousand meters has one).
    pub profiles: Vec<ProfileModel>,
}

/// One profile's fields, shared by the devices that use it.
#[derive(Debug, Clone, Serialize)]
pub struct ProfileModel {
    pub name: String,
    pub fields: Vec<FieldModel>,
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
    /// Its profile's place in [`PlantModel::profiles`].
    pub profile: usize,
    pub manufacturer: String,
    pub model: String,
    pub poll_interval_ms: u64,
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
        let mut profiles: Vec<(Arc<Profile>, ProfileModel)> = Vec::new();
        let lines = config
            .lines
            .iter()
            .map(|line| {
                for device in &line.devices {
                    let profile = &device.profile;
                    let index = match profiles.iter().position(|(p, _)| Arc::ptr_eq(p, profile)) {
                        Some(index) => index,
                        None => {
                            let fields = profile.fields().iter().map(FieldModel::of).collect();
                            let name = profile.name().to_string();
                            profiles.push((Arc::clone(profile), ProfileModel { name, fields }));
                            profiles.len() - 1
                        }
                    };
                    devices.push(DeviceModel {
                        name: device.name.clone(),
                        line: line.name.clone(),
                        address: device.address,
                        profile: index,
                        manufacturer: profile.manufacturer().to_string(),
                        model: profile.model().to_string(),
                        poll_interval_ms: device.poll_interval.as_millis() as u64,
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
            profiles: profiles.into_iter().map(|(_, model)| model).collect(),
        }
    }
}

/// `GET /api/model`.
pub async fn serve_model(State(console): State<Arc<Console>>) -> Json<PlantModel> {
    Json(console.layout().model.clone())
}
