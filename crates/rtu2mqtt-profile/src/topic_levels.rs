//! The words the MQTT topics use as levels of their own (`availability`, `set`, `result`,
//! `refresh`, `history`, the gateway's `status` and `stats`), which no device, field or action
//! may be named, and the longest name a topic level may have. A profile's names are checked
//! against them when it is read; the daemon builds and classifies its topics with them.

/// The device name reserved for the gateway's own topics (`<prefix>/gateway/<client_id>/…`)
/// and its own discovery document.
pub const GATEWAY_DEVICE: &str = "gateway";
/// The last level of a device's availability topic.
pub const AVAILABILITY: &str = "availability";
/// The last level of a device's history stream (`<prefix>/<device>/history`).
pub const HISTORY: &str = "history";
/// The last level of a device's refresh request (`<prefix>/<device>/refresh`).
pub const REFRESH: &str = "refresh";
/// The last level of a command topic (`<prefix>/<device>/<field>/set`).
pub const SET: &str = "set";
/// The last level of a command's outcome (`<prefix>/<device>/<field>/result`).
pub const RESULT: &str = "result";
/// The gateway's status (`<prefix>/gateway/<client_id>/status`), and Home Assistant's
/// (`<discovery_prefix>/status`).
pub const STATUS: &str = "status";
/// The gateway's statistics (`<prefix>/gateway/<client_id>/stats`).
pub const STATS: &str = "stats";

/// Names a device or a field must not have: every word the contract itself uses as a topic
/// level next to device and field names. A field `availability` would publish its values on
/// the device's availability topic; `set` and `result` are the command and outcome levels;
/// `gateway` holds the gateway's own `status` and `stats`; `history` is the history stream;
/// `refresh` asks for a device's every block to be read.
const RESERVED_NAMES: &[&str] = &[
    AVAILABILITY,
    GATEWAY_DEVICE,
    HISTORY,
    REFRESH,
    RESULT,
    SET,
    STATS,
    STATUS,
];

/// Longest device, line or field name (a topic level). Keeps every topic the gateway builds
/// (prefix of at most 128 bytes, device, field, `/result`) far below the longest topic it
/// looks at and MQTT's 65,535-byte limit, and below the broker's and Home Assistant's
/// practical limits on ids (`<client_id>_<device>_<field>`).
pub const MAX_NAME_LEN: usize = 64;

/// Why `name` cannot be a device or field name of the contract, if it cannot, with a name
/// to use instead.
pub fn reserved_name_problem(name: &str) -> Option<String> {
    RESERVED_NAMES.contains(&name).then(|| {
        format!(
            "{name:?} is reserved: the gateway uses it as a topic level of its own (reserved: \
             {}); call it e.g. \"device_{name}\"",
            RESERVED_NAMES.join(", ")
        )
    })
}

/// The names no device or field may have ([`reserved_name_problem`]).
pub fn reserved_names() -> &'static [&'static str] {
    RESERVED_NAMES
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_field_with_a_reserved_name_is_refused_where_any_profile_is_read() {
        for name in reserved_names() {
            let text = format!(
                "[device]\nname = \"x\"\nmanufacturer = \"m\"\nmodel = \"m\"\n\
                 [line]\naddress_range = [1, 247]\n\
                 [[blocks]]\nname = \"b\"\nfunction = 3\nstart = 0\ncount = 1\n\
                 [[fields]]\nname = \"{name}\"\nblock = \"b\"\noffset = 0\ncodec = {{ type = \"u16\" }}\n"
            );
            let errors = crate::Profile::from_toml(&text, "p.toml")
                .unwrap_err()
                .to_string();
            assert!(
                errors.contains(&format!("fields[0] ({name}).name: \"{name}\" is reserved"))
                    && errors.contains(&format!("call it e.g. \"device_{name}\"")),
                "{errors}"
            );
        }
    }

    #[test]
    fn the_profile_format_lists_every_reserved_name() {
        let doc = include_str!("../../../docs/profiles.md");
        let section = doc
            .split("### Reserved names")
            .nth(1)
            .and_then(|rest| rest.split("\n### ").next())
            .unwrap_or_default();
        let listed: Vec<&str> = section
            .split('`')
            .skip(1)
            .step_by(2)
            .take(RESERVED_NAMES.len())
            .collect();
        assert_eq!(listed, RESERVED_NAMES);
    }
}
