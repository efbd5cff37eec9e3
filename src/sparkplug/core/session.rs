//! The Sparkplug B edge node session as a pure state machine: handlers take an event and the
//! time (`now`, milliseconds since the Unix epoch) and return the [`Action`]s to carry out
//! (publish, subscribe, disconnect, hand a command to the gateway). It owns the rules of the
//! specification: topics, `bdSeq` per MQTT connection (the NDEATH Will of a connection and its
//! NBIRTH carry the same number), `seq` 0–255 across every message of the node, births and
//! deaths of devices as they come and go, DDATA with only what changed, rebirth on request,
//! waiting for the primary host's STATE, and refusing every command that is not a known
//! writable metric. Change sets replayed from the history journal wait here until their device
//! is born in the current session and then go out as historical DDATA (store and forward).
//! No I/O, no clock, no tokio.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;

use super::metrics::{DeviceMetrics, Refusal};
use super::protobuf::{DataType, Metric, MetricValue, Payload};
pub use super::session_interface::{
    Action, Delivery, ExternalCommand, HistoricalValues, NodeMetricSpec, SessionSettings, Will,
    BD_SEQ, DEVICES, DEVICES_ONLINE, HISTORY_QUEUE, NAMESPACE, REBIRTH, VERSION,
};
use crate::bus::{LineEvent, Origin};
use rtu2mqtt_profile::{Profile, Value};

/// Aliases of a device's metrics start at this multiple of its (1-based) place in the list;
/// node metrics use the aliases below the first.
const ALIAS_STRIDE: u64 = 1000;

/// One device's place in the session.
#[derive(Debug)]
struct DeviceSession {
    metrics: DeviceMetrics,
    online: bool,
    /// Its DBIRTH went out in the current node session (and no DDEATH since).
    born: bool,
    /// Last known values.
    values: HashMap<String, Value>,
    /// Values as the host knows them (last birth or data).
    published: HashMap<String, Value>,
    /// When its first values (since it was last offline) arrived.
    first_values_at: Option<u64>,
}

impl DeviceSession {
    /// A device is born once it has a value for every field (a line reads a device block by
    /// block), or with nulls for the missing ones once `wait` has passed since its first
    /// values (a block that keeps failing must not keep it unborn).
    fn ready_for_birth(&self, now: u64, wait: u64) -> bool {
        let Some(first) = self.first_values_at else {
            return false;
        };
        self.online
            && (now.saturating_sub(first) >= wait
                || self
                    .metrics
                    .defs()
                    .iter()
                    .all(|def| def.action || self.values.contains_key(&def.name)))
    }
}

/// The edge node session.
#[derive(Debug)]
pub struct Session {
    settings: SessionSettings,
    devices: Vec<DeviceSession>,
    /// The bdSeq of the current (or last) connection.
    bd_seq: u8,
    /// The bdSeq the next connection's Will gets.
    next_bd_seq: u8,
    /// The next `seq`.
    seq: u8,
    connected: bool,
    /// NBIRTH published on this connection.
    node_born: bool,
    /// The primary host is online (always true without a primary host).
    host_online: bool,
    /// Timestamp of the newest STATE message taken into account.
    host_state_timestamp: Option<u64>,
    /// The node's own metrics besides bdSeq, in NBIRTH order.
    node_metrics: Vec<NodeMetric>,
    /// How long a device's birth may wait for its missing fields, in milliseconds.
    birth_wait: u64,
    /// Replayed change sets waiting for their device's birth, oldest first.
    history: VecDeque<HistoricalValues>,
    /// Replayed change sets dropped by [`HISTORY_QUEUE`].
    history_dropped: u64,
}

/// A node metric with its current and last published value.
#[derive(Debug, Clone)]
struct NodeMetric {
    name: String,
    alias: u64,
    datatype: DataType,
    value: Option<MetricValue>,
    published: Option<MetricValue>,
}

impl NodeMetric {
    /// Alias, datatype and value (or the null flag); births add the name.
    fn data_form(&self, now: u64) -> Metric {
        Metric {
            alias: Some(self.alias),
            timestamp: Some(now),
            datatype: Some(self.datatype.number()),
            is_null: self.value.is_none().then_some(true),
            value: self.value.clone(),
            ..Default::default()
        }
    }
}

impl Session {
    /// A session whose first connection uses `bd_seq`.
    pub fn new(settings: SessionSettings, bd_seq: u8) -> Self {
        let devices: Vec<DeviceSession> = settings
            .devices
            .iter()
            .enumerate()
            .map(|(index, (name, profile))| DeviceSession {
                metrics: DeviceMetrics::new(
                    name,
                    Arc::clone(profile),
                    alias_base(index, &settings.devices),
                ),
                online: false,
                born: false,
                values: HashMap::new(),
                published: HashMap::new(),
                first_values_at: None,
            })
            .collect();
        let host_online = settings.primary_host_id.is_none();
        let fixed = [
            (REBIRTH, DataType::Boolean, MetricValue::Boolean(false)),
            (DEVICES, DataType::UInt32, count_value(devices.len() as u64)),
            (DEVICES_ONLINE, DataType::UInt32, count_value(0)),
            (
                VERSION,
                DataType::String,
                MetricValue::String(settings.version.clone()),
            ),
        ];
        let mut node_metrics: Vec<NodeMetric> = fixed
            .into_iter()
            .zip(1u64..)
            .map(|((name, datatype, value), alias)| NodeMetric {
                name: name.to_string(),
                alias,
                datatype,
                value: Some(value),
                published: None,
            })
            .collect();
        node_metrics.extend(settings.node_metrics.iter().zip(FIRST_GATEWAY_ALIAS..).map(
            |(spec, alias)| NodeMetric {
                name: spec.name.clone(),
                alias,
                datatype: spec.datatype,
                value: None,
                published: None,
            },
        ));
        Session {
            settings,
            devices,
            bd_seq,
            next_bd_seq: bd_seq,
            seq: 0,
            connected: false,
            node_born: false,
            host_online,
            host_state_timestamp: None,
            node_metrics,
            birth_wait: 0,
            history: VecDeque::new(),
            history_dropped: 0,
        }
    }

    /// Lets each DBIRTH wait up to `wait` for the device's first complete set of values
    /// (default: born with its first values, the missing ones null).
    pub fn with_birth_wait(mut self, wait: std::time::Duration) -> Self {
        self.birth_wait = u64::try_from(wait.as_millis()).unwrap_or(u64::MAX);
        self
    }

    /// `spBv1.0/<group>/<kind>/<edge node>`.
    pub fn node_topic(&self, kind: &str) -> String {
        format!(
            "{NAMESPACE}/{}/{kind}/{}",
            self.settings.group_id, self.settings.edge_node_id
        )
    }

    /// `spBv1.0/<group>/<kind>/<edge node>/<device>`.
    pub fn device_topic(&self, kind: &str, device: &str) -> String {
        format!("{}/{device}", self.node_topic(kind))
    }

    /// `spBv1.0/STATE/<host>`, when a primary host is configured.
    pub fn state_topic(&self) -> Option<String> {
        self.settings
            .primary_host_id
            .as_ref()
            .map(|host| format!("{NAMESPACE}/STATE/{host}"))
    }

    /// The bdSeq of the current (or last) connection.
    pub fn bd_seq(&self) -> u8 {
        self.bd_seq
    }

    /// The bdSeq the next connection takes (what a restart must start from).
    pub fn next_bd_seq(&self) -> u8 {
        self.next_bd_seq
    }

    /// Called before every MQTT CONNECT: takes the connection's bdSeq (one more than the
    /// previous connection's, 255 wrapping to 0) and returns the NDEATH to set as its Will.
    pub fn prepare_connect(&mut self, now: u64) -> Will {
        self.bd_seq = self.next_bd_seq;
        self.next_bd_seq = self.bd_seq.wrapping_add(1);
        self.death(now)
    }

    /// The attempt [`prepare_connect`](Self::prepare_connect) was for ended before its CONNECT
    /// packet went out (no TCP connection, a failed TLS handshake): Sparkplug counts CONNECT
    /// packets, so the next attempt takes the same bdSeq again.
    pub fn connect_not_sent(&mut self) {
        self.next_bd_seq = self.bd_seq;
    }

    /// The NDEATH of the current connection, for the node's own orderly end.
    pub fn death(&self, now: u64) -> Will {
        Will {
            topic: self.node_topic("NDEATH"),
            payload: self.ndeath_payload(now),
        }
    }

    /// The connection is up: subscribe to commands (and the host's STATE), then the births,
    /// unless they wait for the primary host.
    pub fn on_connected(&mut self, now: u64) -> Vec<Action> {
        self.connected = true;
        self.node_born = false;
        let mut actions = vec![
            Action::Subscribe {
                topic: self.node_topic("NCMD"),
            },
            Action::Subscribe {
                topic: format!("{}/+", self.node_topic("DCMD")),
            },
        ];
        if let Some(topic) = self.state_topic() {
            // The host's retained STATE arrives with the subscription and decides.
            self.host_online = false;
            actions.push(Action::Subscribe { topic });
        } else {
            actions.extend(self.births(now));
        }
        actions
    }

    /// The connection is gone (the broker publishes the NDEATH Will).
    pub fn on_disconnected(&mut self) {
        self.connected = false;
        self.node_born = false;
        for device in &mut self.devices {
            device.born = false;
        }
    }

    /// An incoming message on one of the subscribed topics.
    pub fn on_message(&mut self, now: u64, topic: &str, payload: &[u8]) -> Vec<Action> {
        if Some(topic) == self.state_topic().as_deref() {
            return self.on_host_state(now, payload);
        }
        if topic == self.node_topic("NCMD") {
            return self.on_ncmd(now, payload);
        }
        let dcmd_prefix = format!("{}/", self.node_topic("DCMD"));
        if let Some(device) = topic.strip_prefix(&dcmd_prefix) {
            return self.on_dcmd(now, device, payload);
        }
        Vec::new()
    }

    /// Values and availability from a line.
    pub fn on_line_event(&mut self, now: u64, event: &LineEvent) -> Vec<Action> {
        let mut actions = Vec::new();
        match event {
            LineEvent::Values {
                device,
                values,
                origin,
                ..
            } => {
                let Some(index) = self.device_index(device) else {
                    return actions;
                };
                let entry = &mut self.devices[index];
                entry.online = true;
                entry.first_values_at.get_or_insert(now);
                for (field, value) in values {
                    entry.values.insert(field.clone(), value.clone());
                }
                let born = entry.born;
                let ready = entry.ready_for_birth(now, self.birth_wait);
                // A heartbeat goes out as data even where the host knows the value.
                let again = *origin == Origin::Heartbeat;
                let changed: Vec<String> = values
                    .iter()
                    .filter(|(field, value)| again || entry.published.get(field) != Some(value))
                    .map(|(field, _)| field.clone())
                    .collect();
                if self.node_born {
                    if born {
                        actions.extend(self.ddata(now, index, &changed));
                    } else if ready {
                        actions.extend(self.dbirth(now, index));
                    }
                }
            }
            // Outcomes reach the node through the gateway's command path
            // ([`Session::on_command_outcome`]), not from the line.
            LineEvent::CommandFinished { .. }
            | LineEvent::ClientWriteFinished { .. }
            | LineEvent::Written { .. } => {}
            LineEvent::Availability { device, online } => {
                let Some(index) = self.device_index(device) else {
                    return actions;
                };
                let entry = &mut self.devices[index];
                entry.online = *online;
                if !*online {
                    // A returning device is born with fresh values, not those from before.
                    entry.values.clear();
                    entry.first_values_at = None;
                    if entry.born {
                        entry.born = false;
                        entry.published.clear();
                        if self.node_born {
                            let payload = self.sequenced(now, Vec::new());
                            actions
                                .push(self.publish(self.device_topic("DDEATH", device), payload));
                        }
                    }
                } else if self.node_born
                    && !entry.born
                    && entry.ready_for_birth(now, self.birth_wait)
                {
                    actions.extend(self.dbirth(now, index));
                }
            }
        }
        actions.extend(self.node_data(now));
        actions
    }

    /// How a command handed out as [`Action::Command`] ended. A command that was refused or
    /// failed re-publishes the metric with its true value, so the host's view stays the device's.
    pub fn on_command_outcome(
        &mut self,
        now: u64,
        device: &str,
        field: &str,
        applied: bool,
    ) -> Vec<Action> {
        if applied {
            // The read-back arrives as values and is published as data if it changed.
            return Vec::new();
        }
        let Some(index) = self.device_index(device) else {
            return Vec::new();
        };
        if !self.node_born || !self.devices[index].born {
            return Vec::new();
        }
        self.ddata(now, index, &[field.to_string()])
    }

    /// New values of declared gateway figures ([`SessionSettings::node_metrics`]); NDATA with
    /// those that changed. Undeclared names are ignored (a new metric needs a new NBIRTH).
    pub fn on_node_values(&mut self, now: u64, values: &[(String, MetricValue)]) -> Vec<Action> {
        for (name, value) in values {
            let fixed = [REBIRTH, DEVICES, DEVICES_ONLINE, VERSION];
            if !fixed.contains(&name.as_str()) {
                self.set_node_value(name, value.clone());
            }
        }
        self.node_data(now)
    }

    /// Keeps a replayed change set for historical DDATA ([`Session::history_batch`]); those of
    /// unknown devices are ignored, and past [`HISTORY_QUEUE`] the oldest is dropped.
    pub fn queue_history(&mut self, record: HistoricalValues) {
        if self.device_index(&record.device).is_none() {
            return;
        }
        if self.history.len() >= HISTORY_QUEUE {
            self.history.pop_front();
            self.history_dropped += 1;
            if self.history_dropped.is_power_of_two() {
                tracing::warn!(
                    dropped = self.history_dropped,
                    "Sparkplug: replayed history waits for births that do not come; the oldest is dropped"
                );
            }
        }
        self.history.push_back(record);
    }

    /// Replayed change sets waiting for their device's birth.
    pub fn history_waiting(&self) -> usize {
        self.history.len()
    }

    /// Historical DDATA for at most `most` waiting change sets whose device is born in this
    /// session, oldest first: each metric carries `is_historical` and the instant it was read,
    /// as does the payload. The others keep waiting.
    pub fn history_batch(&mut self, most: usize) -> Vec<Action> {
        if !self.connected || !self.node_born {
            return Vec::new();
        }
        let mut actions = Vec::new();
        let mut unborn = VecDeque::new();
        while let Some(record) = self.history.pop_front() {
            match self.device_index(&record.device) {
                Some(index) if self.devices[index].born => {
                    actions.extend(self.historical_ddata(index, &record));
                    if actions.len() >= most {
                        break;
                    }
                }
                _ => unborn.push_back(record),
            }
        }
        unborn.append(&mut self.history);
        self.history = unborn;
        actions
    }

    // ---- host STATE and commands ----

    fn on_host_state(&mut self, now: u64, payload: &[u8]) -> Vec<Action> {
        let Some((online, timestamp)) = parse_host_state(payload) else {
            tracing::warn!("Sparkplug: ignoring a malformed STATE message of the primary host");
            return Vec::new();
        };
        // An older STATE than one already seen is stale (delivered late); ignore it.
        if self
            .host_state_timestamp
            .is_some_and(|newest| timestamp < newest)
        {
            return Vec::new();
        }
        self.host_state_timestamp = Some(timestamp);
        self.host_online = online;
        if online {
            if self.connected && !self.node_born {
                return self.births(now);
            }
            return Vec::new();
        }
        if !self.connected || !self.node_born {
            // Still waiting for the host: stay connected, its online STATE ends the wait.
            return Vec::new();
        }
        // The host lost this broker: end the session here (NDEATH, then disconnect); the next
        // connection waits for the host again (a single-broker form of moving to the next
        // broker).
        let death = self.death(now);
        let actions = vec![
            Action::Publish {
                topic: death.topic,
                payload: death.payload,
                delivery: Delivery::AtLeastOnce,
            },
            Action::Disconnect,
        ];
        self.on_disconnected();
        actions
    }

    /// NBIRTH and every DBIRTH again, when the node is born on this connection (the driver
    /// asks for it after missing line events: the births carry the values it still has).
    pub fn rebirth(&mut self, now: u64) -> Vec<Action> {
        if self.connected && self.host_online && self.node_born {
            return self.births(now);
        }
        Vec::new()
    }

    fn on_ncmd(&mut self, now: u64, payload: &[u8]) -> Vec<Action> {
        let Ok(payload) = Payload::decode_bytes(payload) else {
            tracing::warn!("Sparkplug: ignoring an NCMD that is no Sparkplug B payload");
            return Vec::new();
        };
        let rebirth = payload.metrics.iter().any(|metric| {
            let named = metric.name.as_deref() == Some(REBIRTH)
                || (metric.name.is_none() && metric.alias == Some(REBIRTH_ALIAS));
            named && metric.value == Some(MetricValue::Boolean(true))
        });
        if rebirth && self.connected && self.host_online {
            return self.births(now);
        }
        Vec::new()
    }

    fn on_dcmd(&mut self, now: u64, device: &str, payload: &[u8]) -> Vec<Action> {
        let refused = |field: Option<String>, reason: String| Action::Refused {
            device: device.to_string(),
            field,
            reason,
        };
        let Some(index) = self.device_index(device) else {
            return vec![refused(None, format!("unknown device `{device}`"))];
        };
        let Ok(payload) = Payload::decode_bytes(payload) else {
            return vec![refused(
                None,
                "the DCMD is no Sparkplug B payload".to_string(),
            )];
        };
        if !self.node_born || !self.devices[index].born {
            return vec![refused(None, format!("{device} is offline"))];
        }
        let mut actions = Vec::new();
        let mut republish = Vec::new();
        for metric in &payload.metrics {
            match self.devices[index].metrics.command_text(metric) {
                Ok((def, text)) => actions.push(Action::Command(ExternalCommand {
                    device: device.to_string(),
                    field: def.name.clone(),
                    text,
                })),
                Err(Refusal(reason)) => {
                    let known = self.devices[index].metrics.named_by(metric);
                    if let Some(def) = known {
                        republish.push(def.name.clone());
                    }
                    actions.push(refused(known.map(|def| def.name.clone()), reason));
                }
            }
        }
        if !republish.is_empty() {
            actions.extend(self.ddata(now, index, &republish));
        }
        actions
    }

    // ---- births, deaths and data ----

    /// NBIRTH (seq reset to 0), then a DBIRTH for every online device with values.
    fn births(&mut self, now: u64) -> Vec<Action> {
        self.seq = 0;
        self.node_born = true;
        for device in &mut self.devices {
            device.born = false;
        }
        self.set_node_value(DEVICES_ONLINE, count_value(self.devices_online()));
        let mut metrics = vec![Metric {
            name: Some(BD_SEQ.to_string()),
            timestamp: Some(now),
            datatype: Some(DataType::UInt64.number()),
            value: Some(MetricValue::Long(u64::from(self.bd_seq))),
            ..Default::default()
        }];
        for metric in &mut self.node_metrics {
            metric.published.clone_from(&metric.value);
            metrics.push(Metric {
                name: Some(metric.name.clone()),
                ..metric.data_form(now)
            });
        }
        let payload = self.sequenced(now, metrics);
        let mut actions = vec![self.publish(self.node_topic("NBIRTH"), payload)];
        for index in 0..self.devices.len() {
            let device = &self.devices[index];
            if device.ready_for_birth(now, self.birth_wait) {
                actions.extend(self.dbirth(now, index));
            }
        }
        actions
    }

    fn dbirth(&mut self, now: u64, index: usize) -> Vec<Action> {
        let device = &mut self.devices[index];
        device.born = true;
        device.published = device.values.clone();
        let metrics = device
            .metrics
            .defs()
            .iter()
            .map(|def| DeviceMetrics::birth_metric(def, device.values.get(&def.name), now))
            .collect();
        let topic = self.device_topic("DBIRTH", &self.devices[index].metrics.device);
        let payload = self.sequenced(now, metrics);
        vec![self.publish(topic, payload)]
    }

    /// DDATA with the given fields' current values (nothing when the list is empty).
    fn ddata(&mut self, now: u64, index: usize, fields: &[String]) -> Vec<Action> {
        let device = &mut self.devices[index];
        let mut metrics = Vec::new();
        for field in fields {
            let Some(def) = device.metrics.by_name(field) else {
                continue;
            };
            let value = device.values.get(field);
            metrics.push(DeviceMetrics::data_metric(def, value, now));
            match value {
                Some(value) => device.published.insert(field.clone(), value.clone()),
                None => device.published.remove(field),
            };
        }
        if metrics.is_empty() {
            return Vec::new();
        }
        let topic = self.device_topic("DDATA", &self.devices[index].metrics.device);
        let payload = self.sequenced(now, metrics);
        vec![self.publish(topic, payload)]
    }

    /// DDATA of one replayed change set; the host's view of current values is not touched.
    fn historical_ddata(&mut self, index: usize, record: &HistoricalValues) -> Vec<Action> {
        let metrics: Vec<Metric> = record
            .values
            .iter()
            .filter_map(|(field, value)| {
                let def = self.devices[index].metrics.by_name(field)?;
                Some(DeviceMetrics::historical_metric(def, value, record.read_at))
            })
            .collect();
        if metrics.is_empty() {
            return Vec::new();
        }
        let topic = self.device_topic("DDATA", &record.device);
        let payload = self.sequenced(record.read_at, metrics);
        vec![self.publish(topic, payload)]
    }

    /// NDATA with the node metrics that changed since they were last published.
    fn node_data(&mut self, now: u64) -> Vec<Action> {
        self.set_node_value(DEVICES_ONLINE, count_value(self.devices_online()));
        if !self.node_born {
            return Vec::new();
        }
        let mut metrics = Vec::new();
        for metric in &mut self.node_metrics {
            if metric.value != metric.published {
                metric.published.clone_from(&metric.value);
                metrics.push(metric.data_form(now));
            }
        }
        if metrics.is_empty() {
            return Vec::new();
        }
        let payload = self.sequenced(now, metrics);
        vec![self.publish(self.node_topic("NDATA"), payload)]
    }

    fn set_node_value(&mut self, name: &str, value: MetricValue) {
        if let Some(metric) = self.node_metrics.iter_mut().find(|m| m.name == name) {
            metric.value = Some(value);
        }
    }

    fn ndeath_payload(&self, now: u64) -> Vec<u8> {
        Payload {
            timestamp: Some(now),
            metrics: vec![Metric {
                name: Some(BD_SEQ.to_string()),
                timestamp: Some(now),
                datatype: Some(DataType::UInt64.number()),
                value: Some(MetricValue::Long(u64::from(self.bd_seq))),
                ..Default::default()
            }],
            ..Default::default()
        }
        .encode_to_bytes()
    }

    /// A payload with the next `seq` (wrapping 255 → 0).
    fn sequenced(&mut self, now: u64, metrics: Vec<Metric>) -> Vec<u8> {
        let seq = self.seq;
        self.seq = self.seq.wrapping_add(1);
        Payload {
            timestamp: Some(now),
            metrics,
            seq: Some(u64::from(seq)),
            ..Default::default()
        }
        .encode_to_bytes()
    }

    /// Births, data and deaths go at QoS 0 (the specification's rule).
    fn publish(&self, topic: String, payload: Vec<u8>) -> Action {
        Action::Publish {
            topic,
            payload,
            delivery: Delivery::AtMostOnce,
        }
    }

    fn device_index(&self, name: &str) -> Option<usize> {
        self.devices.iter().position(|d| d.metrics.device == name)
    }

    fn devices_online(&self) -> u64 {
        self.devices.iter().filter(|d| d.online).count() as u64
    }
}

/// The alias of `Node Control/Rebirth` (the first node metric).
const REBIRTH_ALIAS: u64 = 1;
/// Declared gateway figures follow the fixed node metrics from here.
const FIRST_GATEWAY_ALIAS: u64 = 16;

/// A count as a UInt32 metric value (saturating).
fn count_value(count: u64) -> MetricValue {
    MetricValue::Int(u32::try_from(count).unwrap_or(u32::MAX))
}

/// The first alias of the device at `index`: a multiple of [`ALIAS_STRIDE`] (of a larger power
/// of ten when a profile has that many fields), so aliases never collide across the node.
fn alias_base(index: usize, devices: &[(String, Arc<Profile>)]) -> u64 {
    let most = devices
        .iter()
        .map(|(_, profile)| (profile.fields().len() + profile.actions().len()) as u64)
        .max()
        .unwrap_or(0);
    let mut stride = ALIAS_STRIDE;
    while stride <= most {
        stride *= 10;
    }
    (index as u64 + 1) * stride
}

/// `{"online": true, "timestamp": 1668114759262}` (Sparkplug 3.0 STATE payload).
fn parse_host_state(payload: &[u8]) -> Option<(bool, u64)> {
    let json: serde_json::Value = serde_json::from_slice(payload).ok()?;
    let online = json.get("online")?.as_bool()?;
    let timestamp = json.get("timestamp")?.as_u64()?;
    Some((online, timestamp))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rtu2mqtt_profile::registry;
    use rtu2mqtt_profile::FieldKind;
    use serde_json::Value as Json;

    const T: u64 = 1_700_000_000_000;

    fn profile(name: &str) -> Arc<Profile> {
        match registry::built_in(name) {
            Ok(profile) => Arc::new(profile),
            Err(error) => panic!("{error}"),
        }
    }

    fn settings(primary_host_id: Option<&str>) -> SessionSettings {
        SessionSettings {
            group_id: "plant".into(),
            edge_node_id: "gw1".into(),
            primary_host_id: primary_host_id.map(str::to_string),
            devices: vec![
                ("dust".into(), profile("ruiwan-dust-collector")),
                ("valve".into(), profile("wuzhou-valve")),
            ],
            version: "1.2.3".into(),
            node_metrics: vec![NodeMetricSpec {
                name: "Lines/line-a/Bus Load".into(),
                datatype: DataType::Float,
            }],
        }
    }

    /// A session connected without a primary host, its NBIRTH taken.
    fn connected() -> Session {
        let mut session = Session::new(settings(None), 0);
        session.prepare_connect(T);
        session.on_connected(T);
        session
    }

    fn dust_values(gear: i64) -> LineEvent {
        LineEvent::Values {
            device: "dust".into(),
            values: vec![
                ("power".into(), Value::Bool(true)),
                ("gear".into(), Value::Int(i128::from(gear))),
                ("fan_speed".into(), Value::Int(1450)),
            ],
            read_at: std::time::SystemTime::UNIX_EPOCH,
            origin: Origin::Poll,
        }
    }

    /// The published messages as (topic, decoded payload).
    fn published(actions: &[Action]) -> Vec<(String, Payload)> {
        actions
            .iter()
            .filter_map(|action| match action {
                Action::Publish { topic, payload, .. } => match Payload::decode_bytes(payload) {
                    Ok(decoded) => Some((topic.clone(), decoded)),
                    Err(error) => panic!("{topic}: {error}"),
                },
                _ => None,
            })
            .collect()
    }

    fn topics(actions: &[Action]) -> Vec<String> {
        published(actions)
            .into_iter()
            .map(|(topic, _)| topic)
            .collect()
    }

    fn metric<'a>(payload: &'a Payload, name: &str) -> &'a Metric {
        match payload
            .metrics
            .iter()
            .find(|m| m.name.as_deref() == Some(name))
        {
            Some(metric) => metric,
            None => panic!("no metric {name} in {payload:?}"),
        }
    }

    fn bd_seq_of(payload: &Payload) -> Option<MetricValue> {
        metric(payload, BD_SEQ).value.clone()
    }

    fn command(metrics: Vec<Metric>) -> Vec<u8> {
        Payload {
            timestamp: Some(T),
            metrics,
            ..Default::default()
        }
        .encode_to_bytes()
    }

    fn named(name: &str, datatype: DataType, value: MetricValue) -> Metric {
        Metric {
            name: Some(name.into()),
            datatype: Some(datatype.number()),
            value: Some(value),
            ..Default::default()
        }
    }

    #[test]
    fn connecting_subscribes_to_commands_and_publishes_the_nbirth() {
        let mut session = Session::new(settings(None), 0);
        let will = session.prepare_connect(T);
        assert_eq!(will.topic, "spBv1.0/plant/NDEATH/gw1");
        let actions = session.on_connected(T);
        assert_eq!(
            actions[..2],
            [
                Action::Subscribe {
                    topic: "spBv1.0/plant/NCMD/gw1".into()
                },
                Action::Subscribe {
                    topic: "spBv1.0/plant/DCMD/gw1/+".into()
                },
            ]
        );
        let births = published(&actions);
        assert_eq!(births.len(), 1, "no device is online yet");
        let (topic, nbirth) = &births[0];
        assert_eq!(topic, "spBv1.0/plant/NBIRTH/gw1");
        assert_eq!(nbirth.seq, Some(0));
        assert_eq!(nbirth.timestamp, Some(T));
        assert_eq!(bd_seq_of(nbirth), Some(MetricValue::Long(0)));
        let rebirth = metric(nbirth, REBIRTH);
        assert_eq!(rebirth.value, Some(MetricValue::Boolean(false)));
        assert_eq!(rebirth.datatype, Some(DataType::Boolean.number()));
        assert_eq!(metric(nbirth, DEVICES).value, Some(MetricValue::Int(2)));
    }

    #[test]
    fn a_device_is_born_with_every_field_typed_then_sends_only_changes() {
        let mut session = connected();
        let actions = session.on_line_event(T + 1, &dust_values(3));
        let messages = published(&actions);
        assert_eq!(
            topics(&actions),
            ["spBv1.0/plant/DBIRTH/gw1/dust", "spBv1.0/plant/NDATA/gw1"]
        );
        let dbirth = &messages[0].1;
        assert_eq!(dbirth.seq, Some(1));
        assert_eq!(
            dbirth.metrics.len(),
            profile("ruiwan-dust-collector").fields().len()
        );
        let gear = metric(dbirth, "gear");
        assert_eq!(gear.datatype, Some(DataType::UInt8.number()));
        assert_eq!(gear.value, Some(MetricValue::Int(3)));
        assert_eq!(gear.alias, Some(1005));
        let power = metric(dbirth, "power");
        assert_eq!(power.value, Some(MetricValue::Boolean(true)));
        let unit = metric(dbirth, "pulse_interval").properties.as_ref();
        assert_eq!(unit.and_then(|set| set.string("engUnit")), Some("min"));
        // Not read yet: born as null.
        let temperature = metric(dbirth, "temperature");
        assert_eq!(
            (temperature.is_null, &temperature.value),
            (Some(true), &None)
        );
        // The count of online devices went from 0 to 1.
        assert_eq!(messages[1].1.seq, Some(2));
        assert_eq!(messages[1].1.metrics[0].value, Some(MetricValue::Int(1)));

        assert!(session.on_line_event(T + 2, &dust_values(3)).is_empty());
        let actions = session.on_line_event(T + 3, &dust_values(4));
        let messages = published(&actions);
        assert_eq!(topics(&actions), ["spBv1.0/plant/DDATA/gw1/dust"]);
        let ddata = &messages[0].1;
        assert_eq!(ddata.seq, Some(3));
        assert_eq!(ddata.metrics.len(), 1, "only the gear changed");
        assert_eq!(ddata.metrics[0].name, None, "data goes by alias");
        assert_eq!(ddata.metrics[0].alias, Some(1005));
        assert_eq!(ddata.metrics[0].value, Some(MetricValue::Int(4)));

        // A heartbeat: its values go out as data though the host knows them.
        let mut heartbeat = dust_values(4);
        if let LineEvent::Values { values, origin, .. } = &mut heartbeat {
            values.retain(|(field, _)| field == "gear");
            *origin = Origin::Heartbeat;
        }
        let actions = session.on_line_event(T + 4, &heartbeat);
        let messages = published(&actions);
        assert_eq!(topics(&actions), ["spBv1.0/plant/DDATA/gw1/dust"]);
        let ddata = &messages[0].1;
        assert_eq!(ddata.metrics.len(), 1, "the gear again");
        assert_eq!(ddata.metrics[0].alias, Some(1005));
        assert_eq!(ddata.metrics[0].value, Some(MetricValue::Int(4)));
    }

    #[test]
    fn aliases_are_unique_across_the_node() {
        let session = connected();
        let mut aliases: Vec<u64> = session.node_metrics.iter().map(|m| m.alias).collect();
        for device in &session.devices {
            aliases.extend(device.metrics.defs().iter().map(|def| def.alias));
        }
        let count = aliases.len();
        aliases.sort_unstable();
        aliases.dedup();
        assert_eq!(aliases.len(), count);
    }

    #[test]
    fn seq_runs_across_all_messages_and_wraps_after_255() {
        let mut session = connected();
        let mut seqs = Vec::new();
        for step in 0..300 {
            let actions = session.on_line_event(T, &dust_values(1 + step % 10));
            seqs.extend(published(&actions).iter().filter_map(|(_, p)| p.seq));
        }
        // NBIRTH had 0; everything after counts on from 1 and wraps 255 → 0.
        let expected: Vec<u64> = (1..=seqs.len() as u64).map(|n| n % 256).collect();
        assert_eq!(seqs, expected);
        assert!(seqs.len() > 256);
    }

    #[test]
    fn bd_seq_counts_connections_and_the_will_matches_the_nbirth() {
        let mut session = Session::new(settings(None), 254);
        for expected in [254u64, 255, 0, 1] {
            let will = session.prepare_connect(T);
            let will = match Payload::decode_bytes(&will.payload) {
                Ok(will) => will,
                Err(error) => panic!("{error}"),
            };
            assert_eq!(bd_seq_of(&will), Some(MetricValue::Long(expected)));
            assert_eq!(will.seq, None, "an NDEATH carries no seq");
            let births = published(&session.on_connected(T));
            assert_eq!(bd_seq_of(&births[0].1), Some(MetricValue::Long(expected)));
            assert_eq!(births[0].1.seq, Some(0), "NBIRTH resets seq");
            session.on_line_event(T, &dust_values(expected as i64 % 10 + 1));
            session.on_disconnected();
        }
    }

    #[test]
    fn an_attempt_that_sent_no_connect_leaves_bd_seq_where_it_was() {
        let mut session = Session::new(settings(None), 6);
        session.prepare_connect(T);
        session.on_connected(T);
        session.on_disconnected();
        assert_eq!(session.next_bd_seq(), 7);
        // Refused TCP connections during an outage: each takes 7 and gives it back.
        for _ in 0..5 {
            let will = session.prepare_connect(T);
            assert_eq!(session.next_bd_seq(), 8, "kept before the attempt");
            let will = match Payload::decode_bytes(&will.payload) {
                Ok(will) => will,
                Err(error) => panic!("{error}"),
            };
            assert_eq!(bd_seq_of(&will), Some(MetricValue::Long(7)));
            session.connect_not_sent();
            assert_eq!(session.next_bd_seq(), 7);
        }
        session.prepare_connect(T);
        let births = published(&session.on_connected(T));
        assert_eq!(bd_seq_of(&births[0].1), Some(MetricValue::Long(7)));
        assert_eq!(session.next_bd_seq(), 8);
    }

    #[test]
    fn rebirth_republishes_nbirth_and_every_dbirth() {
        let mut session = connected();
        session.on_line_event(T, &dust_values(3));
        let rebirth = |on| {
            command(vec![named(
                REBIRTH,
                DataType::Boolean,
                MetricValue::Boolean(on),
            )])
        };
        let actions = session.on_message(T, "spBv1.0/plant/NCMD/gw1", &rebirth(true));
        let messages = published(&actions);
        assert_eq!(
            topics(&actions),
            ["spBv1.0/plant/NBIRTH/gw1", "spBv1.0/plant/DBIRTH/gw1/dust"]
        );
        assert_eq!(messages[0].1.seq, Some(0));
        assert_eq!(messages[1].1.seq, Some(1));
        assert_eq!(
            bd_seq_of(&messages[0].1),
            Some(MetricValue::Long(0)),
            "same connection"
        );
        assert_eq!(
            metric(&messages[1].1, "gear").value,
            Some(MetricValue::Int(3))
        );
        // By alias, as hosts may send it.
        let by_alias = command(vec![Metric {
            alias: Some(REBIRTH_ALIAS),
            value: Some(MetricValue::Boolean(true)),
            ..Default::default()
        }]);
        assert_eq!(
            published(&session.on_message(T, "spBv1.0/plant/NCMD/gw1", &by_alias)).len(),
            2
        );
        assert!(session
            .on_message(T, "spBv1.0/plant/NCMD/gw1", &rebirth(false))
            .is_empty());
        assert!(session
            .on_message(T, "spBv1.0/plant/NCMD/gw1", b"\xff\xff")
            .is_empty());
    }

    #[test]
    fn births_wait_for_the_primary_host_and_follow_its_state() {
        let mut session = Session::new(settings(Some("scada")), 0);
        session.prepare_connect(T);
        session.on_line_event(T, &dust_values(2));
        let actions = session.on_connected(T);
        assert!(
            published(&actions).is_empty(),
            "no birth before the host is online"
        );
        assert!(actions.contains(&Action::Subscribe {
            topic: "spBv1.0/STATE/scada".into()
        }));
        let state = |online: bool, timestamp: u64| {
            format!("{{\"online\":{online},\"timestamp\":{timestamp}}}").into_bytes()
        };
        let topic = "spBv1.0/STATE/scada";
        assert!(session.on_message(T, topic, &state(false, 10)).is_empty());
        assert!(
            session.on_message(T, topic, b"ONLINE").is_empty(),
            "not the 3.0 form"
        );
        let actions = session.on_message(T, topic, &state(true, 20));
        assert_eq!(
            topics(&actions),
            ["spBv1.0/plant/NBIRTH/gw1", "spBv1.0/plant/DBIRTH/gw1/dust"]
        );
        // An older offline STATE arriving late changes nothing.
        assert!(session.on_message(T, topic, &state(false, 15)).is_empty());
        // The host goes offline: NDEATH with this connection's bdSeq, then disconnect.
        let actions = session.on_message(T, topic, &state(false, 30));
        assert_eq!(actions.last(), Some(&Action::Disconnect));
        let deaths = published(&actions);
        assert_eq!(deaths[0].0, "spBv1.0/plant/NDEATH/gw1");
        assert_eq!(bd_seq_of(&deaths[0].1), Some(MetricValue::Long(0)));
        assert!(
            session.on_line_event(T, &dust_values(5)).is_empty(),
            "no data after the death"
        );
        // The next connection waits for the host again.
        session.prepare_connect(T);
        assert!(published(&session.on_connected(T)).is_empty());
        let births = published(&session.on_message(T, topic, &state(true, 40)));
        assert_eq!(bd_seq_of(&births[0].1), Some(MetricValue::Long(1)));
    }

    #[test]
    fn dcmd_on_a_writable_metric_becomes_a_command() {
        let mut session = connected();
        session.on_line_event(T, &dust_values(3));
        let topic = "spBv1.0/plant/DCMD/gw1/dust";
        let actions = session.on_message(
            T,
            topic,
            &command(vec![
                named("gear", DataType::UInt8, MetricValue::Int(8)),
                Metric {
                    alias: Some(1000),
                    value: Some(MetricValue::Boolean(false)),
                    ..Default::default()
                },
            ]),
        );
        assert_eq!(
            actions,
            [
                Action::Command(ExternalCommand {
                    device: "dust".into(),
                    field: "gear".into(),
                    text: "8".into()
                }),
                Action::Command(ExternalCommand {
                    device: "dust".into(),
                    field: "power".into(),
                    text: "OFF".into()
                }),
            ]
        );
    }

    #[test]
    fn refused_dcmds_reach_nothing_and_republish_the_true_value() {
        let mut session = connected();
        session.on_line_event(T, &dust_values(3));
        let topic = "spBv1.0/plant/DCMD/gw1/dust";
        let cases = [
            // Read-only.
            (
                named("fan_speed", DataType::UInt16, MetricValue::Int(1)),
                Some("fan_speed"),
            ),
            // Wrong value kind for the metric's type.
            (
                named("gear", DataType::UInt8, MetricValue::String("8".into())),
                Some("gear"),
            ),
            // A datatype other than the birth's.
            (
                named("gear", DataType::Int64, MetricValue::Long(8)),
                Some("gear"),
            ),
            // Outside the type's width.
            (
                named("gear", DataType::UInt8, MetricValue::Int(256)),
                Some("gear"),
            ),
            // Unknown metric.
            (
                named("nonsense", DataType::Boolean, MetricValue::Boolean(true)),
                None,
            ),
        ];
        for (metric, republished) in cases {
            let actions = session.on_message(T, topic, &command(vec![metric.clone()]));
            assert!(
                !actions.iter().any(|a| matches!(a, Action::Command(_))),
                "{metric:?} reached the command path"
            );
            assert!(matches!(actions[0], Action::Refused { .. }), "{actions:?}");
            let messages = published(&actions);
            match republished {
                Some(field) => {
                    assert_eq!(messages.len(), 1, "{metric:?}");
                    assert_eq!(messages[0].0, "spBv1.0/plant/DDATA/gw1/dust");
                    let alias = session.devices[0].metrics.by_name(field).map(|d| d.alias);
                    assert_eq!(messages[0].1.metrics[0].alias, alias);
                }
                None => assert!(messages.is_empty()),
            }
        }
        let unknown_device = session.on_message(
            T,
            "spBv1.0/plant/DCMD/gw1/boiler",
            &command(vec![named("gear", DataType::UInt8, MetricValue::Int(8))]),
        );
        assert!(matches!(
            &unknown_device[..],
            [Action::Refused { field: None, .. }]
        ));
        // The valve never reported: not born, so no command for it.
        let offline = session.on_message(T, "spBv1.0/plant/DCMD/gw1/valve", &command(vec![]));
        assert!(matches!(&offline[..], [Action::Refused { .. }]));
        let garbage = session.on_message(T, topic, b"\x0a\xff");
        assert!(matches!(&garbage[..], [Action::Refused { .. }]));
    }

    #[test]
    fn a_failed_command_republishes_the_true_value() {
        let mut session = connected();
        session.on_line_event(T, &dust_values(3));
        assert!(session
            .on_command_outcome(T, "dust", "gear", true)
            .is_empty());
        let messages = published(&session.on_command_outcome(T, "dust", "gear", false));
        assert_eq!(messages.len(), 1);
        assert_eq!(messages[0].0, "spBv1.0/plant/DDATA/gw1/dust");
        assert_eq!(messages[0].1.metrics[0].value, Some(MetricValue::Int(3)));
    }

    #[test]
    fn a_device_going_offline_dies_and_is_born_again_when_it_returns() {
        let mut session = connected();
        session.on_line_event(T, &dust_values(3));
        let offline = LineEvent::Availability {
            device: "dust".into(),
            online: false,
        };
        let actions = session.on_line_event(T, &offline);
        let messages = published(&actions);
        assert_eq!(
            topics(&actions),
            ["spBv1.0/plant/DDEATH/gw1/dust", "spBv1.0/plant/NDATA/gw1"]
        );
        assert_eq!(messages[0].1.seq, Some(3));
        assert!(messages[0].1.metrics.is_empty());
        // Online again, but no values yet: the birth waits for fresh values.
        let online = LineEvent::Availability {
            device: "dust".into(),
            online: true,
        };
        assert_eq!(
            topics(&session.on_line_event(T, &online)),
            ["spBv1.0/plant/NDATA/gw1"]
        );
        let actions = session.on_line_event(T, &dust_values(6));
        let messages = published(&actions);
        assert_eq!(topics(&actions), ["spBv1.0/plant/DBIRTH/gw1/dust"]);
        assert_eq!(
            metric(&messages[0].1, "gear").value,
            Some(MetricValue::Int(6))
        );
        assert!(session.on_line_event(T, &offline).len() == 2);
        assert!(session.on_line_event(T, &offline).is_empty(), "dead once");
    }

    #[test]
    fn gateway_figures_are_born_null_and_sent_when_they_change() {
        let mut session = Session::new(settings(None), 0);
        session.prepare_connect(T);
        let births = published(&session.on_connected(T));
        let load = metric(&births[0].1, "Lines/line-a/Bus Load");
        assert_eq!(load.datatype, Some(DataType::Float.number()));
        assert_eq!((load.is_null, &load.value), (Some(true), &None));
        assert_eq!(load.alias, Some(FIRST_GATEWAY_ALIAS));
        let values = [(
            "Lines/line-a/Bus Load".to_string(),
            MetricValue::Float(0.25),
        )];
        let actions = session.on_node_values(T, &values);
        let messages = published(&actions);
        assert_eq!(topics(&actions), ["spBv1.0/plant/NDATA/gw1"]);
        assert_eq!(messages[0].1.metrics.len(), 1);
        assert_eq!(messages[0].1.metrics[0].alias, Some(FIRST_GATEWAY_ALIAS));
        assert_eq!(
            messages[0].1.metrics[0].value,
            Some(MetricValue::Float(0.25))
        );
        assert!(session.on_node_values(T, &values).is_empty(), "unchanged");
        let undeclared = [
            ("Lines/line-z/Bus Load".to_string(), MetricValue::Float(1.0)),
            (DEVICES.to_string(), MetricValue::Int(99)),
        ];
        assert!(session.on_node_values(T, &undeclared).is_empty());
    }

    fn dbirths(actions: &[Action]) -> Vec<(String, Payload)> {
        published(actions)
            .into_iter()
            .filter(|(topic, _)| topic.contains("/DBIRTH/"))
            .collect()
    }

    #[test]
    fn a_birth_waits_for_every_field_or_for_its_bound() {
        let wait = std::time::Duration::from_secs(10);
        let mut session = Session::new(settings(None), 0).with_birth_wait(wait);
        session.prepare_connect(T);
        session.on_connected(T);
        // The first block: not every field yet, no birth.
        assert!(dbirths(&session.on_line_event(T + 1, &dust_values(3))).is_empty());
        // The rest of the device's fields: born with all of them.
        let fields = profile("ruiwan-dust-collector").fields().to_vec();
        let rest = LineEvent::Values {
            device: "dust".into(),
            values: fields
                .iter()
                .map(|info| {
                    let value = match &info.kind {
                        FieldKind::Enum { options } => {
                            Value::Enum(options.first().cloned().unwrap_or_default())
                        }
                        FieldKind::Text => Value::Text("1".into()),
                        FieldKind::Bool | FieldKind::Momentary => Value::Bool(false),
                        _ => Value::Int(1),
                    };
                    (info.name.clone(), value)
                })
                .filter(|(name, _)| !["power", "gear", "fan_speed"].contains(&name.as_str()))
                .collect(),
            read_at: std::time::SystemTime::UNIX_EPOCH,
            origin: Origin::Poll,
        };
        let births = dbirths(&session.on_line_event(T + 2, &rest));
        assert_eq!(births.len(), 1);
        assert_eq!(births[0].0, "spBv1.0/plant/DBIRTH/gw1/dust");
        assert!(births[0].1.metrics.iter().all(|m| m.is_null != Some(true)));
        assert_eq!(
            metric(&births[0].1, "gear").value,
            Some(MetricValue::Int(3))
        );

        // The valve never sends its other blocks: born at the bound, the rest null.
        let valve = |gear| LineEvent::Values {
            device: "valve".into(),
            values: vec![("opening".into(), Value::Int(gear))],
            read_at: std::time::SystemTime::UNIX_EPOCH,
            origin: Origin::Poll,
        };
        assert!(dbirths(&session.on_line_event(T + 3, &valve(10))).is_empty());
        assert!(dbirths(&session.on_line_event(T + 9_000, &valve(11))).is_empty());
        let late = dbirths(&session.on_line_event(T + 10_003, &valve(12)));
        assert_eq!(late.len(), 1);
        assert_eq!(late[0].0, "spBv1.0/plant/DBIRTH/gw1/valve");
        assert_eq!(
            metric(&late[0].1, "opening").value,
            Some(MetricValue::Int(12))
        );
        assert_eq!(metric(&late[0].1, "station_address").is_null, Some(true));
    }

    #[test]
    fn a_rebirth_after_missed_events_is_only_for_a_born_node() {
        let mut session = Session::new(settings(Some("scada")), 0);
        session.prepare_connect(T);
        session.on_connected(T);
        assert!(
            session.rebirth(T).is_empty(),
            "not born yet: the host's STATE decides"
        );
        let mut session = connected();
        session.on_line_event(T, &dust_values(3));
        let topics = topics(&session.rebirth(T + 1));
        assert_eq!(topics[0], "spBv1.0/plant/NBIRTH/gw1");
        assert!(topics.contains(&"spBv1.0/plant/DBIRTH/gw1/dust".to_string()));
    }

    fn replayed(device: &str, read_at: u64, gear: i64) -> HistoricalValues {
        HistoricalValues {
            device: device.into(),
            read_at,
            values: vec![
                ("gear".into(), Json::from(gear)),
                ("power".into(), Json::Bool(true)),
            ],
        }
    }

    #[test]
    fn replayed_history_waits_for_the_births_then_goes_out_as_historical_ddata() {
        let mut session = Session::new(settings(None), 0);
        session.queue_history(replayed("dust", T - 5_000, 2));
        session.queue_history(replayed("dust", T - 4_000, 5));
        session.queue_history(replayed("boiler", T - 3_000, 1));
        assert_eq!(
            session.history_waiting(),
            2,
            "an unknown device's are not kept"
        );
        assert!(session.history_batch(10).is_empty(), "not connected");
        session.prepare_connect(T);
        session.on_connected(T);
        assert!(session.history_batch(10).is_empty(), "dust is not born yet");
        let birth = published(&session.on_line_event(T + 1, &dust_values(3)));
        let dbirth = &birth[0].1;
        let messages = published(&session.history_batch(10));
        assert_eq!(messages.len(), 2);
        for ((topic, payload), (read_at, gear)) in
            messages.iter().zip([(T - 5_000, 2), (T - 4_000, 5)])
        {
            assert_eq!(topic, "spBv1.0/plant/DDATA/gw1/dust");
            assert_eq!(payload.timestamp, Some(read_at));
            for metric in &payload.metrics {
                assert_eq!(metric.is_historical, Some(true));
                assert_eq!(metric.timestamp, Some(read_at));
                assert_eq!(metric.name, None, "by alias, as the DBIRTH declared");
                let declared = dbirth.metrics.iter().find(|m| m.alias == metric.alias);
                assert_eq!(declared.and_then(|m| m.datatype), metric.datatype);
            }
            let gear_alias = session.devices[0].metrics.by_name("gear").map(|d| d.alias);
            let gear_metric = payload.metrics.iter().find(|m| m.alias == gear_alias);
            assert_eq!(
                gear_metric.and_then(|m| m.value.clone()),
                Some(MetricValue::Int(gear as u32))
            );
        }
        assert_eq!(messages[0].1.seq.map(|seq| seq + 1), messages[1].1.seq);
        assert_eq!(session.history_waiting(), 0);
        // The live view is untouched: the current gear is still the one published.
        let live = published(&session.on_line_event(T + 2, &dust_values(3)));
        assert!(
            live.iter().all(|(topic, _)| !topic.contains("DDATA")),
            "{live:?}"
        );
    }

    #[test]
    fn replayed_history_goes_out_in_batches_and_waits_again_after_a_lost_connection() {
        let mut session = connected();
        session.on_line_event(T, &dust_values(3));
        for n in 0..5 {
            session.queue_history(replayed("dust", T - 100 + n, n as i64));
        }
        assert_eq!(published(&session.history_batch(2)).len(), 2);
        session.on_disconnected();
        assert!(session.history_batch(10).is_empty());
        session.prepare_connect(T + 10);
        let births = topics(&session.on_connected(T + 10));
        assert!(
            births.contains(&"spBv1.0/plant/DBIRTH/gw1/dust".to_string()),
            "{births:?}"
        );
        let rest = published(&session.history_batch(10));
        let stamps: Vec<_> = rest.iter().map(|(_, p)| p.timestamp).collect();
        assert_eq!(stamps, [Some(T - 98), Some(T - 97), Some(T - 96)]);
    }

    #[test]
    fn replayed_history_past_its_bound_drops_the_oldest() {
        let mut session = Session::new(settings(None), 0);
        for n in 0..=HISTORY_QUEUE as u64 {
            session.queue_history(replayed("dust", n, 1));
        }
        assert_eq!(session.history_waiting(), HISTORY_QUEUE);
        assert_eq!(session.history.front().map(|r| r.read_at), Some(1));
    }
}
