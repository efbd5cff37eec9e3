//! Profiles end to end, through the gateway (the profile crate's own tests are in
//! crates/rtu2mqtt-profile/tests):
//!
//! - `profile_codecs`: the profile language's codecs, from a device's registers to MQTT.
//! - `library`: the device library's profiles against their vendors' examples and simulators.
//! - `actions`: a profile's command interfaces.
//! - `unavailable_values`: "no value" marks, NaN and unknown codes.
//! - `publish`: publishing by exception.

mod actions;
mod library;
mod profile_codecs;
mod publish;
mod unavailable_values;
