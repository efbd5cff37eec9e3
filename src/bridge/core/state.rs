//! The bridge's memory of every configured device: last decoded values (the state commands are
//! planned against), availability, and what has been published, so that state goes out on
//! change, in full after every (re)connect, and in full when a device comes back online.
//! Bounded by the configuration: only configured devices are kept, one value per field.
//! What was published is kept as the value, not its text: a poll compares values, and the text
//! is rendered only for what goes out.

use std::collections::HashMap;

use rtu2mqtt_profile::{DeviceState, Value};

#[derive(Debug, Default)]
struct DeviceCache {
    state: DeviceState,
    /// Value last handed to MQTT per field.
    published: HashMap<String, Value>,
    /// None until the line has said anything about the device.
    online: Option<bool>,
    /// Publish every field with the next values (the device just came back).
    republish_next: bool,
    /// The device's turn to be published in full is still to come
    /// ([`StateCache::set_awaiting_turn`]): its values are kept, not published one by one.
    awaiting_turn: bool,
}

/// Latest values and availability of the configured devices.
#[derive(Debug, Default)]
pub struct StateCache {
    devices: HashMap<String, DeviceCache>,
    /// Device names in configuration order, for stable republishing.
    order: Vec<String>,
}

/// One state message to publish.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StateUpdate {
    pub device: String,
    pub field: String,
    pub text: String,
}

impl StateCache {
    pub fn new<'a>(devices: impl IntoIterator<Item = &'a str>) -> Self {
        let mut cache = StateCache::default();
        for name in devices {
            cache.order.push(name.to_string());
            cache
                .devices
                .insert(name.to_string(), DeviceCache::default());
        }
        cache
    }

    pub fn contains(&self, device: &str) -> bool {
        self.devices.contains_key(device)
    }

    /// Device names in configuration order.
    pub fn devices(&self) -> &[String] {
        &self.order
    }

    /// The last known values of `device` (empty when unknown).
    pub fn state(&self, device: &str) -> Option<&DeviceState> {
        self.devices.get(device).map(|cache| &cache.state)
    }

    /// The text last handed to MQTT for this field, if any.
    pub fn published_text(&self, device: &str, field: &str) -> Option<String> {
        self.devices
            .get(device)
            .and_then(|cache| cache.published.get(field))
            .map(Value::to_text)
    }

    /// Whether `device`'s values wait for its turn to be published in full.
    pub fn awaits_turn(&self, device: &str) -> bool {
        self.devices
            .get(device)
            .is_some_and(|cache| cache.awaiting_turn)
    }

    /// Marks `device` as waiting (or no longer waiting) for its turn to be published in full
    /// ([`StateCache::republish`]): until then [`StateCache::update`] keeps its values without
    /// publishing them, so that a connection's first values of a thousand devices go out in
    /// their devices' turns rather than all at once, and each field once, with its newest value.
    pub fn set_awaiting_turn(&mut self, device: &str, awaiting: bool) {
        if let Some(cache) = self.devices.get_mut(device) {
            cache.awaiting_turn = awaiting;
        }
    }

    /// No device waits for its turn any more (the connection is gone).
    pub fn clear_awaiting_turns(&mut self) {
        for cache in self.devices.values_mut() {
            cache.awaiting_turn = false;
        }
    }

    pub fn is_online(&self, device: &str) -> bool {
        self.devices
            .get(device)
            .and_then(|cache| cache.online)
            .unwrap_or(false)
    }

    /// Stores fresh values. When `connected` and the device does not wait for its turn, returns
    /// the fields to publish (changed ones, or all of them right after the device came back) and
    /// records them as published. A value the device marks unavailable is kept (the JSON view
    /// shows it as `null`) but never published: the field's topic keeps the last value it had.
    pub fn update(
        &mut self,
        device: &str,
        values: Vec<(String, Value)>,
        connected: bool,
    ) -> Vec<StateUpdate> {
        let Some(cache) = self.devices.get_mut(device) else {
            return Vec::new();
        };
        let mut updates = Vec::new();
        let publishing = connected && !cache.awaiting_turn;
        let everything = cache.republish_next;
        for (field, value) in values {
            let changed = everything || cache.published.get(&field) != Some(&value);
            if publishing && value.is_available() && changed {
                cache.published.insert(field.clone(), value.clone());
                updates.push(StateUpdate {
                    device: device.to_string(),
                    text: value.to_text(),
                    field: field.clone(),
                });
            }
            cache.state.insert(field, value);
        }
        if publishing {
            cache.republish_next = false;
        }
        updates
    }

    /// Forgets what was published for these fields of `device`: their next values go out
    /// even when equal (a heartbeat).
    pub fn forget_published<'a>(
        &mut self,
        device: &str,
        fields: impl IntoIterator<Item = &'a str>,
    ) {
        if let Some(cache) = self.devices.get_mut(device) {
            for field in fields {
                cache.published.remove(field);
            }
        }
    }

    /// Records availability; true when it changed. A device coming back gets every field
    /// republished with its next values.
    pub fn set_online(&mut self, device: &str, online: bool) -> bool {
        let Some(cache) = self.devices.get_mut(device) else {
            return false;
        };
        let changed = cache.online != Some(online);
        if changed && online {
            cache.republish_next = true;
        }
        cache.online = Some(online);
        changed
    }

    /// The configured devices after a reload, in their new order: devices that stay keep what
    /// is known about them, new ones start unknown, removed ones are forgotten.
    pub fn reconfigure<'a>(&mut self, devices: impl IntoIterator<Item = &'a str>) {
        let mut kept = HashMap::new();
        let mut order = Vec::new();
        for name in devices {
            let cache = self.devices.remove(name).unwrap_or_default();
            kept.insert(name.to_string(), cache);
            order.push(name.to_string());
        }
        self.devices = kept;
        self.order = order;
    }

    /// Every known value, for the full republish after a (re)connect; recorded as published.
    pub fn republish_all(&mut self) -> Vec<StateUpdate> {
        self.forget_all_published();
        let order = std::mem::take(&mut self.order);
        let updates = order
            .iter()
            .flat_map(|device| self.republish(device))
            .collect();
        self.order = order;
        updates
    }

    /// The known values of `device` not published on this connection yet (every one after
    /// [`StateCache::forget_all_published`]), in the order of their field names; recorded as
    /// published. This is the device's turn: it no longer waits for it, and every value it
    /// has is published now, so the device coming back needs no second round.
    pub fn republish(&mut self, device: &str) -> Vec<StateUpdate> {
        let Some(cache) = self.devices.get_mut(device) else {
            return Vec::new();
        };
        cache.awaiting_turn = false;
        if !cache.state.is_empty() {
            cache.republish_next = false;
        }
        let mut fields: Vec<&String> = cache.state.keys().collect();
        fields.sort();
        let mut updates = Vec::new();
        for field in fields {
            let value = &cache.state[field];
            if !value.is_available() {
                continue;
            }
            if cache.published.get(field) == Some(value) {
                continue;
            }
            cache.published.insert(field.clone(), value.clone());
            updates.push(StateUpdate {
                device: device.to_string(),
                field: field.clone(),
                text: value.to_text(),
            });
        }
        updates
    }

    /// A new connection: nothing is published on it yet, so each value goes out with its
    /// device's next reading or in the device's turn, whichever comes first.
    pub fn forget_all_published(&mut self) {
        for cache in self.devices.values_mut() {
            cache.published.clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values(pairs: &[(&str, i128)]) -> Vec<(String, Value)> {
        pairs
            .iter()
            .map(|(field, value)| (field.to_string(), Value::Int(*value)))
            .collect()
    }

    fn fields(updates: &[StateUpdate]) -> Vec<&str> {
        updates.iter().map(|u| u.field.as_str()).collect()
    }

    #[test]
    fn publishes_changes_only() {
        let mut cache = StateCache::new(["dust"]);
        let first = cache.update("dust", values(&[("gear", 5), ("fan_speed", 0)]), true);
        assert_eq!(fields(&first), ["gear", "fan_speed"]);
        let second = cache.update("dust", values(&[("gear", 5), ("fan_speed", 1200)]), true);
        assert_eq!(fields(&second), ["fan_speed"]);
        assert_eq!(second[0].text, Value::Int(1200).to_text());
    }

    #[test]
    fn caches_while_disconnected_and_republishes_everything() {
        let mut cache = StateCache::new(["dust", "valve"]);
        assert!(cache
            .update("dust", values(&[("gear", 5)]), false)
            .is_empty());
        cache.update("valve", values(&[("opening", 40)]), false);
        cache.update("dust", values(&[("gear", 6)]), false);
        let all = cache.republish_all();
        assert_eq!(all.len(), 2);
        assert_eq!(all[0].device, "dust");
        assert_eq!(all[0].text, Value::Int(6).to_text());
        // Already published: no change, nothing new.
        assert!(cache
            .update("dust", values(&[("gear", 6)]), true)
            .is_empty());
        assert_eq!(cache.state("dust").unwrap()["gear"], Value::Int(6));
    }

    #[test]
    fn a_device_coming_back_republishes_its_fields() {
        let mut cache = StateCache::new(["dust"]);
        assert!(!cache.is_online("dust"));
        assert!(cache.set_online("dust", true));
        cache.update("dust", values(&[("gear", 5)]), true);
        assert!(cache.set_online("dust", false));
        assert!(!cache.set_online("dust", false));
        assert!(cache.set_online("dust", true));
        let again = cache.update("dust", values(&[("gear", 5)]), true);
        assert_eq!(fields(&again), ["gear"]);
        assert!(cache
            .update("dust", values(&[("gear", 5)]), true)
            .is_empty());
    }

    #[test]
    fn an_unavailable_value_is_kept_but_never_published() {
        let mut cache = StateCache::new(["meter"]);
        cache.update("meter", values(&[("power", 1500)]), true);
        let marked = vec![("power".to_string(), Value::Unavailable)];
        assert!(cache.update("meter", marked, true).is_empty());
        assert_eq!(cache.state("meter").unwrap()["power"], Value::Unavailable);
        assert_eq!(
            cache.published_text("meter", "power").as_deref(),
            Some("1500")
        );
        assert!(cache.republish_all().is_empty());
        // The value coming back is published again.
        let back = cache.update("meter", values(&[("power", 1500)]), true);
        assert_eq!(fields(&back), ["power"]);
    }

    #[test]
    fn a_device_awaiting_its_turn_is_published_in_it_once() {
        let mut cache = StateCache::new(["dust"]);
        cache.set_online("dust", true);
        cache.set_awaiting_turn("dust", true);
        assert!(cache
            .update("dust", values(&[("gear", 5)]), true)
            .is_empty());
        assert!(cache
            .update("dust", values(&[("gear", 6)]), true)
            .is_empty());
        let turn = cache.republish("dust");
        assert_eq!(fields(&turn), ["gear"]);
        assert_eq!(turn[0].text, "6");
        assert!(!cache.awaits_turn("dust"));
        // Its coming online went out in the turn: the same value is not sent again.
        assert!(cache
            .update("dust", values(&[("gear", 6)]), true)
            .is_empty());
        let moved = cache.update("dust", values(&[("gear", 7)]), true);
        assert_eq!(fields(&moved), ["gear"]);
        // A lost connection ends every wait.
        cache.set_awaiting_turn("dust", true);
        cache.clear_awaiting_turns();
        assert!(!cache.awaits_turn("dust"));
    }

    #[test]
    fn unknown_devices_are_not_kept() {
        let mut cache = StateCache::new(["dust"]);
        assert!(cache
            .update("intruder", values(&[("x", 1)]), true)
            .is_empty());
        assert!(!cache.set_online("intruder", true));
        assert!(cache.state("intruder").is_none());
    }
}
