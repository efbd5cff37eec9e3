//! The bridge core's part of a configuration reload: it learns the new device set and line
//! order, forgets removed devices and clears what they left retained in the broker (state,
//! availability, JSON view, discovery), fails their waiting commands, and announces the devices
//! that are new. Waiting commands of devices that stay are kept. Pure, like the rest of
//! [`super`]: the driver executes the returned actions.

use std::collections::{HashMap, HashSet};
use std::time::Instant;

use super::{Action, BridgeDevice, Core};
use crate::bridge::payload::{CommandResult, Outcome};
use crate::contract::availability_word;

impl Core {
    /// The configuration was reloaded: `devices` (in configuration order) on the lines named
    /// `line_names` (in the order the driver's line handles now have). The topics and gateway
    /// options stay those of the start.
    pub fn on_reconfigure(
        &mut self,
        line_names: Vec<String>,
        devices: Vec<BridgeDevice>,
        now: Instant,
    ) -> Vec<Action> {
        let new: HashMap<&str, &BridgeDevice> = devices
            .iter()
            .map(|device| (device.name.as_str(), device))
            .collect();
        for name in self.cache.devices().to_vec() {
            let Some(old) = self.devices.get(&name).cloned() else {
                continue;
            };
            match new.get(name.as_str()) {
                None => self.forget_device(&old),
                Some(kept) => {
                    // Fields the device's new profile no longer has: their state goes too.
                    let fields: HashSet<&str> = kept
                        .profile
                        .fields()
                        .iter()
                        .map(|f| f.name.as_str())
                        .collect();
                    for field in old.profile.fields() {
                        if !fields.contains(field.name.as_str()) {
                            let topic = self.topics.state_topic(&name, &field.name);
                            self.publish_or_keep(topic, String::new(), true);
                        }
                    }
                }
            }
        }
        let added: Vec<String> = devices
            .iter()
            .filter(|device| !self.devices.contains_key(&device.name))
            .map(|device| device.name.clone())
            .collect();
        self.cache
            .reconfigure(devices.iter().map(|device| device.name.as_str()));
        self.devices = devices
            .into_iter()
            .map(|device| (device.name.clone(), device))
            .collect();
        self.line_names = line_names;
        self.publish_discovery();
        for device in added {
            tracing::info!(%device, "device added by the reload");
            let word = availability_word(self.cache.is_online(&device));
            let topic = self.topics.availability_topic(&device);
            self.publish(topic, word.to_string(), true);
        }
        self.dispatch_ready(now);
        self.take()
    }

    /// A device removed by a reload: its waiting commands fail, its retained topics are
    /// cleared (state of every field, availability, JSON view, discovery document). Results are
    /// not retained, so none is left to clear.
    fn forget_device(&mut self, device: &BridgeDevice) {
        let name = device.name.as_str();
        tracing::info!(device = %name, "device removed by the reload: clearing its retained topics");
        for command in self.book.drain_device(name) {
            self.plans.remove(&command.id);
            self.counters.commands_failed += 1;
            let detail = format!("device {name} is no longer configured (configuration reloaded)");
            let result = CommandResult::new(&command.value, Outcome::Failed, detail);
            self.finish_with(name, &command.field, result);
        }
        let mut cleared = Vec::new();
        for field in device.profile.fields() {
            cleared.push(self.topics.state_topic(name, &field.name));
        }
        cleared.push(self.topics.availability_topic(name));
        if self.options.json_view {
            let topic = self.topics.json_view_topic(name);
            self.json_views.remove(&topic);
            cleared.push(topic);
        }
        if self.discovery {
            cleared.push(self.topics.config_topic(name));
        }
        for topic in cleared {
            self.publish_or_keep(topic, String::new(), true);
        }
    }
}
