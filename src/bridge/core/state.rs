//! The bridge's memory of every configured device: last decoded values (the state commands are
//! planned against), availability, and what has been published, so that state goes out on
//! change, in full after every (re)connect, and in full when a device comes back online.
//! Bounded by the configuration: only configured devices are kept, one value per field.
//! A device keeps its values in the order of its profile's fields, found by name through an
//! index its profile's devices share, instead of a map of its own; what was published is kept
//! as the value, not its text: a poll compares values, and the text is rendered only for what
//! goes out.

use std::collections::HashMap;
use std::sync::Arc;

use rtu2mqtt_profile::{DeviceState, Profile, Value};

/// Where a device keeps each field: a slot per field name. Built once per profile and shared
/// by its devices; a field the profile does not have gets a slot in the device's own copy.
#[derive(Debug, Default, Clone)]
struct FieldSlots {
    by_name: HashMap<String, usize>,
}

impl FieldSlots {
    fn of(profile: &Profile) -> Self {
        let by_name = profile
            .fields()
            .iter()
            .enumerate()
            .map(|(slot, field)| (field.name.clone(), slot))
            .collect();
        FieldSlots { by_name }
    }

    fn get(&self, field: &str) -> Option<usize> {
        self.by_name.get(field).copied()
    }
}

/// One field of a device: its latest value and the value last handed to MQTT.
#[derive(Debug, Default, Clone)]
struct FieldEntry {
    value: Option<Value>,
    published: Option<Value>,
}

#[derive(Debug, Default)]
struct DeviceCache {
    slots: Arc<FieldSlots>,
    /// Per slot of `slots`.
    fields: Vec<FieldEntry>,
    /// None until the line has said anything about the device.
    online: Option<bool>,
    /// Publish every field with the next values (the device just came back).
    republish_next: bool,
    /// The device's turn to be published in full is still to come
    /// ([`StateCache::set_awaiting_turn`]): its values are kept, not published one by one.
    awaiting_turn: bool,
}

impl DeviceCache {
    fn new(slots: Arc<FieldSlots>) -> Self {
        DeviceCache {
            fields: vec![FieldEntry::default(); slots.by_name.len()],
            slots,
            ..DeviceCache::default()
        }
    }

    fn entry(&self, field: &str) -> Option<&FieldEntry> {
        self.slots.get(field).and_then(|slot| self.fields.get(slot))
    }

    /// The field's entry, given a slot if the device has none for it yet.
    fn entry_mut(&mut self, field: &str) -> &mut FieldEntry {
        let slot = match self.slots.get(field) {
            Some(slot) => slot,
            None => {
                let slot = self.fields.len();
                Arc::make_mut(&mut self.slots)
                    .by_name
                    .insert(field.to_string(), slot);
                slot
            }
        };
        if slot >= self.fields.len() {
            self.fields.resize_with(slot + 1, FieldEntry::default);
        }
        &mut self.fields[slot]
    }

    /// The same device on `slots` (a reload's profile): each value moves to its field's slot
    /// there, fields the new slots do not have are dropped.
    fn moved_to(mut self, slots: Arc<FieldSlots>) -> Self {
        let mut fields = vec![FieldEntry::default(); slots.by_name.len()];
        for (name, &old) in &self.slots.by_name {
            let entry = self.fields.get_mut(old).map(std::mem::take);
            if let (Some(new), Some(entry)) = (slots.get(name), entry) {
                if let Some(place) = fields.get_mut(new) {
                    *place = entry;
                }
            }
        }
        DeviceCache {
            slots,
            fields,
            ..self
        }
    }
}

/// The known values of one device, looked up by field name.
#[derive(Debug, Clone, Copy)]
pub struct Known<'c>(&'c DeviceCache);

impl<'c> Known<'c> {
    pub fn get(&self, field: &str) -> Option<&'c Value> {
        self.0.entry(field).and_then(|entry| entry.value.as_ref())
    }
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

/// The shared slots of each profile among `devices`, by the profile's address.
fn slots_by_profile<'a>(
    devices: impl IntoIterator<Item = &'a Arc<Profile>>,
) -> HashMap<*const Profile, Arc<FieldSlots>> {
    let mut shared = HashMap::new();
    for profile in devices {
        shared
            .entry(Arc::as_ptr(profile))
            .or_insert_with(|| Arc::new(FieldSlots::of(profile)));
    }
    shared
}

impl StateCache {
    /// A cache of `devices` whose fields are not known beforehand (each gets its slots as its
    /// values arrive).
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

    /// A cache of `devices` (name and profile, in configuration order), each with a slot for
    /// every field of its profile.
    pub fn with_profiles<'a>(
        devices: impl IntoIterator<Item = (&'a str, &'a Arc<Profile>)>,
    ) -> Self {
        let devices: Vec<(&str, &Arc<Profile>)> = devices.into_iter().collect();
        let shared = slots_by_profile(devices.iter().map(|(_, profile)| *profile));
        let mut cache = StateCache::default();
        for (name, profile) in devices {
            let slots = shared
                .get(&Arc::as_ptr(profile))
                .cloned()
                .unwrap_or_default();
            cache.order.push(name.to_string());
            cache
                .devices
                .insert(name.to_string(), DeviceCache::new(slots));
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

    /// The last known values of `device`, for looking fields up (None when it is not
    /// configured).
    pub fn known(&self, device: &str) -> Option<Known<'_>> {
        self.devices.get(device).map(Known)
    }

    /// The last known values of `device` as a state (None when it is not configured).
    pub fn state(&self, device: &str) -> Option<DeviceState> {
        let cache = self.devices.get(device)?;
        let state = cache
            .slots
            .by_name
            .iter()
            .filter_map(|(name, &slot)| {
                let value = cache.fields.get(slot)?.value.clone()?;
                Some((name.clone(), value))
            })
            .collect();
        Some(state)
    }

    /// The text last handed to MQTT for this field, if any.
    pub fn published_text(&self, device: &str, field: &str) -> Option<String> {
        self.devices
            .get(device)
            .and_then(|cache| cache.entry(field))
            .and_then(|entry| entry.published.as_ref())
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
    /// records them as published. A value the device marks unavailable is published as such
    /// (`unavailable`; `null` in the JSON view), once, so no stale number stays on the topic.
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
            let entry = cache.entry_mut(&field);
            let changed = everything || entry.published.as_ref() != Some(&value);
            if publishing && changed {
                entry.published = Some(value.clone());
                let text = value.to_text();
                entry.value = Some(value);
                updates.push(StateUpdate {
                    device: device.to_string(),
                    field,
                    text,
                });
            } else {
                entry.value = Some(value);
            }
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
                if let Some(slot) = cache.slots.get(field) {
                    if let Some(entry) = cache.fields.get_mut(slot) {
                        entry.published = None;
                    }
                }
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

    /// The configured devices (name and profile) after a reload, in their new order: devices
    /// that stay keep what is known about the fields their profile still has, new ones start
    /// unknown, removed ones are forgotten.
    pub fn reconfigure<'a>(
        &mut self,
        devices: impl IntoIterator<Item = (&'a str, &'a Arc<Profile>)>,
    ) {
        let devices: Vec<(&str, &Arc<Profile>)> = devices.into_iter().collect();
        let shared = slots_by_profile(devices.iter().map(|(_, profile)| *profile));
        let mut kept = HashMap::new();
        let mut order = Vec::new();
        for (name, profile) in devices {
            let slots = shared
                .get(&Arc::as_ptr(profile))
                .cloned()
                .unwrap_or_default();
            let cache = match self.devices.remove(name) {
                Some(cache) => cache.moved_to(slots),
                None => DeviceCache::new(slots),
            };
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
        if cache.fields.iter().any(|entry| entry.value.is_some()) {
            cache.republish_next = false;
        }
        let slots = Arc::clone(&cache.slots);
        let mut fields: Vec<(&String, usize)> = slots
            .by_name
            .iter()
            .map(|(name, &slot)| (name, slot))
            .collect();
        fields.sort();
        let mut updates = Vec::new();
        for (field, slot) in fields {
            let Some(entry) = cache.fields.get_mut(slot) else {
                continue;
            };
            let Some(value) = entry.value.as_ref() else {
                continue;
            };
            if entry.published.as_ref() == Some(value) {
                continue;
            }
            let text = value.to_text();
            entry.published = Some(value.clone());
            updates.push(StateUpdate {
                device: device.to_string(),
                field: field.clone(),
                text,
            });
        }
        updates
    }

    /// A new connection: nothing is published on it yet, so each value goes out with its
    /// device's next reading or in the device's turn, whichever comes first.
    pub fn forget_all_published(&mut self) {
        for cache in self.devices.values_mut() {
            for entry in &mut cache.fields {
                entry.published = None;
            }
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
        assert_eq!(
            cache.known("dust").unwrap().get("gear"),
            Some(&Value::Int(6))
        );
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
    fn an_unavailable_value_is_published_once_as_unavailable_never_as_the_stale_number() {
        let mut cache = StateCache::new(["meter"]);
        cache.update("meter", values(&[("power", 1500)]), true);
        let marked = || vec![("power".to_string(), Value::Unavailable)];
        let gone = cache.update("meter", marked(), true);
        assert_eq!(texts(&gone), [("power", "unavailable")]);
        assert!(cache.update("meter", marked(), true).is_empty(), "once");
        assert_eq!(cache.state("meter").unwrap()["power"], Value::Unavailable);
        assert_eq!(
            cache.published_text("meter", "power").as_deref(),
            Some("unavailable")
        );
        // A new connection is told too.
        assert_eq!(texts(&cache.republish_all()), [("power", "unavailable")]);
        // The value coming back is published again.
        let back = cache.update("meter", values(&[("power", 1500)]), true);
        assert_eq!(texts(&back), [("power", "1500")]);
    }

    fn texts(updates: &[StateUpdate]) -> Vec<(&str, &str)> {
        updates
            .iter()
            .map(|update| (update.field.as_str(), update.text.as_str()))
            .collect()
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
    fn devices_of_a_profile_share_its_slots_and_keep_their_values_across_a_reload() {
        let profile = Arc::new(rtu2mqtt_profile::registry::built_in("wuzhou-valve").unwrap());
        let mut cache = StateCache::with_profiles([("v1", &profile), ("v2", &profile)]);
        let first = cache.update("v1", values(&[("opening", 40)]), true);
        assert_eq!(fields(&first), ["opening"]);
        assert!(Arc::ptr_eq(
            &cache.devices["v1"].slots,
            &cache.devices["v2"].slots
        ));
        assert_eq!(cache.known("v2").unwrap().get("opening"), None);
        // A reload loads the profile again: the value stays, and is not published again.
        let reloaded = Arc::new(rtu2mqtt_profile::registry::built_in("wuzhou-valve").unwrap());
        cache.reconfigure([("v1", &reloaded)]);
        assert_eq!(
            cache.known("v1").unwrap().get("opening"),
            Some(&Value::Int(40))
        );
        assert!(cache
            .update("v1", values(&[("opening", 40)]), true)
            .is_empty());
        assert!(!cache.contains("v2"));
        assert_eq!(cache.devices(), ["v1"]);
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
