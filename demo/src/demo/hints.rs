//! The words around the plant: what runs where, and example commands to try. The commands come
//! from the devices' profiles ([`rtu2mqtt_profile::Profile::example_commands`]), so a profile
//! change shows up here without touching the demo.

use super::endpoint::BrokerEndpoint;
use rtu2mqtt::config::Config;

/// One `mosquitto_pub` line per example command of every configured device, in line order.
fn example_commands(endpoint: &BrokerEndpoint, config: &Config) -> Vec<String> {
    let options = endpoint.client_options();
    let prefix = &config.mqtt.prefix;
    config
        .lines
        .iter()
        .flat_map(|line| &line.devices)
        .flat_map(|device| {
            device
                .profile
                .example_commands()
                .into_iter()
                .map(move |(field, value)| (device.name.as_str(), field.to_string(), value))
        })
        .map(|(device, field, value)| {
            format!("mosquitto_pub {options}-t {prefix}/{device}/{field}/set -m {value}")
        })
        .collect()
}

/// What is running and how to poke it.
pub(super) fn introduction(endpoint: &BrokerEndpoint, config: &Config) -> String {
    let options = endpoint.client_options();
    let prefix = &config.mqtt.prefix;
    let mut text = format!(
        "rtu2mqtt-demo: the seed plant, simulated, on {} ({}).\n",
        endpoint.url(),
        endpoint.origin
    );
    for line in &config.lines {
        let devices: Vec<String> = line
            .devices
            .iter()
            .map(|d| format!("{} at address {}", d.name, address_text(d.address)))
            .collect();
        text.push_str(&format!(
            "  {} on {} ({} {}): {}\n",
            line.name,
            line.serial.path,
            line.serial.baud,
            line.serial.format,
            devices.join(", ")
        ));
    }
    if let Some(web) = &config.web {
        let access = if web.token.is_some() {
            ""
        } else {
            ", read-only"
        };
        text.push_str(&format!(
            "The console: http://{}/ in a browser on this machine{access}.\n",
            web.listen
        ));
    }
    text.push_str(&format!(
        "Try, in another terminal:\n  mosquitto_sub {options}-v -t '{prefix}/#'\n"
    ));
    for command in example_commands(endpoint, config) {
        text.push_str(&format!("  {command}\n"));
    }
    text.push_str("Ctrl-C stops.\n");
    text
}

/// The table's lines under the plant: where things run and how to poke them (the footer says
/// how to stop).
pub(super) fn table_hints(endpoint: &BrokerEndpoint, config: &Config) -> String {
    let lines: Vec<String> = config
        .lines
        .iter()
        .map(|line| format!("{} {} {}", line.name, line.serial.path, line.serial.format))
        .collect();
    let mut text = format!(
        "{} ({}) · {}\n",
        endpoint.url(),
        endpoint.origin,
        lines.join(" · ")
    );
    for (index, command) in example_commands(endpoint, config).iter().enumerate() {
        let lead = if index == 0 { "try: " } else { "     " };
        text.push_str(&format!("{lead}{command}\n"));
    }
    text
}

/// `1`, `129 (0x81)`: decimal, with hex where the device's documents use it.
pub(super) fn address_text(address: u8) -> String {
    if address > 9 {
        format!("{address} (0x{address:02X})")
    } else {
        address.to_string()
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;
    use crate::demo::endpoint::{Placement, SHARED_BROKER_PREFIX};
    use crate::demo::plant::{demo_config, DEMO_CLIENT_ID};

    /// A broker on this host at `port`, chosen the way `origin` says.
    fn local_endpoint(port: u16, origin: &'static str) -> BrokerEndpoint {
        BrokerEndpoint {
            host: "127.0.0.1".to_string(),
            port,
            origin,
        }
    }

    /// The demo's configuration with the simulated lines at two made-up pty paths.
    fn seed_config(endpoint: &BrokerEndpoint, placement: Placement) -> Config {
        let (line_a, line_b) = (Path::new("/dev/pts/98"), Path::new("/dev/pts/99"));
        demo_config(endpoint, &placement, line_a, line_b).unwrap()
    }

    #[test]
    fn the_example_configuration_is_the_seed_plant() {
        let endpoint = local_endpoint(18830, "test");
        let config = seed_config(
            &endpoint,
            Placement {
                prefix: None,
                notice: None,
            },
        );
        assert_eq!(config.lines[0].serial.path, "/dev/pts/98");
        assert_eq!(config.lines[1].serial.path, "/dev/pts/99");
        assert_eq!(config.mqtt.port, 18830);
        assert_eq!(config.mqtt.client_id, DEMO_CLIENT_ID);
        let hints = introduction(&endpoint, &config);
        assert!(hints.contains("mosquitto_pub -p 18830 -t plant/dust_collector/gear/set -m 8"));
        // Every seed device offers its profile's example command.
        for command in [
            "mosquitto_pub -p 18830 -t plant/valve/opening/set -m 40",
            "mosquitto_pub -p 18830 -t plant/air_shower/emergency_stop/set -m ON",
        ] {
            assert!(hints.contains(command), "{hints}");
            assert!(table_hints(&endpoint, &config).contains(command));
        }
        assert!(hints.contains("(9600 8E1): valve at address 1"), "{hints}");
        assert!(
            hints.contains("air_shower at address 129 (0x81)"),
            "{hints}"
        );
    }

    #[test]
    fn a_moved_demo_publishes_under_its_own_prefix_without_discovery() {
        let endpoint = local_endpoint(1883, "--broker");
        let config = seed_config(
            &endpoint,
            Placement {
                prefix: Some(SHARED_BROKER_PREFIX.to_string()),
                notice: Some("moved".to_string()),
            },
        );
        assert_eq!(config.mqtt.prefix, "demo");
        assert!(!config.mqtt.discovery);
        let hints = introduction(&endpoint, &config);
        assert!(
            hints.contains("mosquitto_pub -t demo/dust_collector/gear/set -m 8"),
            "{hints}"
        );
        assert!(!hints.contains("plant/"), "{hints}");
    }
}
