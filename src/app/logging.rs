//! Logging set-up: `tracing` to stderr, plain for the journal or JSON (`RTU2MQTT_LOG_FORMAT=json`),
//! filtered by `RUST_LOG` (default `info`, with the demo's embedded broker silent).

use tracing_subscriber::EnvFilter;

pub fn init() {
    // rumqttd (the demo's broker) logs every client connection at INFO and ordinary
    // disconnects at ERROR: noise for a demo user. `RUST_LOG=rumqttd=info` brings it back.
    let filter =
        EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info,rumqttd=off"));
    let json = std::env::var("RTU2MQTT_LOG_FORMAT").is_ok_and(|v| v.eq_ignore_ascii_case("json"));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    // A second init (tests) is harmless: keep the first subscriber.
    let _ = if json {
        builder.json().try_init()
    } else {
        builder.try_init()
    };
}
