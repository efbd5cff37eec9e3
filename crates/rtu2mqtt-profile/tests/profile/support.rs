//! What the profile tests share: where the repository keeps its profiles, a command's refusal by
//! a profile, and frames written as spaced hex text.

use rtu2mqtt_profile::{DeviceState, Profile, Rejection};

/// The repository's `config/`.
pub const CONFIG_DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../config");

/// The repository's `config/profiles/`, the files the built-in profiles are made from.
pub const PROFILE_DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../config/profiles");

/// The reason `profile` gives for refusing `text` for `field` on a device with no state yet;
/// an accepted command fails the test.
pub fn refused(profile: &Profile, field: &str, text: &str) -> String {
    match profile.plan_command(field, text, &DeviceState::new()) {
        Err(Rejection(reason)) => reason,
        Ok(plan) => panic!("{field}={text:?} accepted: {plan:?}"),
    }
}

/// The bytes of spaced hex text written in a test (`01 06 00 B3`).
pub fn frame(text: &str) -> Vec<u8> {
    text.split_whitespace()
        .map(|byte| u8::from_str_radix(byte, 16).expect("a hex byte"))
        .collect()
}
