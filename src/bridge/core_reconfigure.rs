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

#[cfg(test)]
mod tests {
    use std::sync::Arc;
    use std::time::Duration;

    use rumqttc::QoS;

    use super::super::{CoreSettings, Incoming};
    use super::*;
    use crate::bus::LineEvent;
    use crate::config::GatewayOptions;
    use crate::contract::Topics;
    use crate::profile::registry;

    fn device(name: &str, profile: &str, line: usize) -> BridgeDevice {
        BridgeDevice {
            name: name.to_string(),
            profile: Arc::new(registry::built_in(profile).unwrap()),
            line,
        }
    }

    fn retained_clears(actions: &[Action]) -> Vec<String> {
        actions
            .iter()
            .filter_map(|action| match action {
                Action::Publish(p) if p.retain && p.payload.is_empty() => Some(p.topic.clone()),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn a_removed_device_is_cleared_and_a_kept_ones_waiting_command_stays() {
        let now = Instant::now();
        let options = GatewayOptions {
            command_ttl: Duration::from_secs(60),
            json_view: true,
            stats_interval: Duration::from_secs(3600),
            metrics_listen: None,
            frame_log: None,
            allow_raw_writes: false,
            max_payload: 256,
        };
        let valve = device("valve", "wuzhou-valve", 1);
        let dust = device("dust_collector", "ruiwan-dust-collector", 0);
        let mut core = Core::new(
            CoreSettings {
                topics: Topics::new("edge1", "plant"),
                discovery: true,
                options,
                line_names: vec!["a".into(), "b".into()],
                devices: vec![dust.clone(), valve.clone()],
            },
            now,
        );
        core.on_connected();
        core.on_line_event(
            LineEvent::Availability {
                device: "dust_collector".into(),
                online: false,
            },
            now,
        );
        // Commands for two offline devices wait.
        for topic in ["plant/valve/opening/set", "plant/dust_collector/gear/set"] {
            core.on_message(
                Incoming {
                    topic,
                    payload: b"3",
                    qos: QoS::AtLeastOnce,
                    pkid: 1,
                    dup: false,
                    retain: false,
                },
                now,
            );
        }
        assert_eq!(core.book.waiting_count(), 2);

        // The dust collector's line is gone; the valve's line is now the first.
        let moved = BridgeDevice { line: 0, ..valve };
        let actions = core.on_reconfigure(vec!["b".into()], vec![moved], now);
        let cleared = retained_clears(&actions);
        for topic in [
            "plant/dust_collector/gear",
            "plant/dust_collector/availability",
            "plant/dust_collector",
            "homeassistant/device/edge1_dust_collector/config",
            "plant/dust_collector/gear/set",
        ] {
            assert!(
                cleared.iter().any(|t| t == topic),
                "{topic} not cleared: {cleared:?}"
            );
        }
        assert!(cleared.iter().all(|t| !t.contains("valve")), "{cleared:?}");
        let failed = actions.iter().any(|action| {
            matches!(action, Action::Publish(p) if p.topic == "plant/dust_collector/gear/result"
                && p.payload.contains("no longer configured"))
        });
        assert!(failed, "no result for the removed device's command");
        assert_eq!(core.book.waiting_count(), 1, "the valve's command was lost");

        // Once the valve is online, its command goes to its new line index.
        let actions = core.on_line_event(
            LineEvent::Availability {
                device: "valve".into(),
                online: true,
            },
            now,
        );
        assert!(actions
            .iter()
            .any(|action| matches!(action, Action::Send { line: 0, .. })));
    }
}
