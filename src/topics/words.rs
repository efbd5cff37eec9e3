//! The payload words of availability and status (`online`, `offline`) and the limits of the
//! topics: the default discovery prefix, and the longest topic the gateway looks at.

/// Availability and status payload of something that is there.
pub const ONLINE: &str = "online";
/// Availability and status payload of something that is gone (also the gateway's Will).
pub const OFFLINE: &str = "offline";

/// The default Home Assistant discovery prefix.
pub const DEFAULT_DISCOVERY_PREFIX: &str = "homeassistant";

/// Longest topic looked at; anything longer is classified as no topic of the contract.
pub const MAX_TOPIC_LEN: usize = 512;

/// Whether a payload on Home Assistant's status topic is its birth message.
pub fn is_ha_online(payload: &[u8]) -> bool {
    std::str::from_utf8(payload)
        .map(|text| text.trim().eq_ignore_ascii_case(ONLINE))
        .unwrap_or(false)
}

/// The availability word of `online`.
pub fn availability_word(online: bool) -> &'static str {
    if online {
        ONLINE
    } else {
        OFFLINE
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn words() {
        assert!(is_ha_online(b" Online\n"));
        assert!(!is_ha_online(b"offline"));
        assert!(!is_ha_online(&[0xff]));
        assert_eq!(availability_word(true), ONLINE);
        assert_eq!(availability_word(false), OFFLINE);
    }
}
