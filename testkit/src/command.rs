//! What a profile makes of a command's text, for the tests of its command grammar and rules.

use rtu2mqtt_profile::{DeviceState, Profile, Rejection};

/// The reason `profile` gives for refusing `text` for `field` on a device with no state yet;
/// an accepted command fails the test.
pub fn refused(profile: &Profile, field: &str, text: &str) -> String {
    match profile.plan_command(field, text, &DeviceState::new()) {
        Err(Rejection(reason)) => reason,
        Ok(plan) => panic!("{field}={text:?} accepted: {plan:?}"),
    }
}
