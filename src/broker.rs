//! The embedded MQTT broker of the demo (rumqttd) (demo helper).
