//! Payloads of the contract: the command payload as received on `…/set`
//! (bounded, UTF-8, trimmed; empty is the clearing of a retained command) and the outcome JSON
//! on `…/result`. Pure.

use serde::Serialize;

/// How much of a payload is echoed back in `value` and shown in logs.
const MAX_ECHO_CHARS: usize = 64;
/// Bytes enough for [`MAX_ECHO_CHARS`] characters and one more (UTF-8 needs at most 4 each), so
/// a huge payload is never converted whole.
const MAX_ECHO_BYTES: usize = (MAX_ECHO_CHARS + 1) * 4;

/// The outcome word of one command.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// Written, and the read-back shows the value (an action: the device reports success).
    Applied,
    /// Acknowledged, but the read-back differs (an action: its result code is no success).
    NotApplied,
    /// Invalid: nothing sent.
    Rejected,
    /// An exception answer, or no answer after the retries.
    Failed,
    /// The device stayed offline past the command's time to live.
    Expired,
    /// A newer command for the same field replaced this one before it reached the bus.
    Superseded,
}

impl Outcome {
    /// Every outcome, in the order of the contract.
    pub const ALL: [Outcome; 6] = [
        Outcome::Applied,
        Outcome::NotApplied,
        Outcome::Rejected,
        Outcome::Failed,
        Outcome::Expired,
        Outcome::Superseded,
    ];

    pub fn word(self) -> &'static str {
        match self {
            Outcome::Applied => "applied",
            Outcome::NotApplied => "not_applied",
            Outcome::Rejected => "rejected",
            Outcome::Failed => "failed",
            Outcome::Expired => "expired",
            Outcome::Superseded => "superseded",
        }
    }
}

/// The JSON on `…/result`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct CommandResult {
    /// The command exactly as sent (lossy UTF-8, shortened when it was long): see [`echo`].
    pub value: String,
    pub outcome: Outcome,
    pub detail: String,
}

impl CommandResult {
    pub fn new(value: &str, outcome: Outcome, detail: impl Into<String>) -> Self {
        CommandResult {
            value: value.to_string(),
            outcome,
            detail: detail.into(),
        }
    }

    pub fn to_json(&self) -> String {
        // Serialising three strings cannot fail; keep a valid document even if it ever did.
        serde_json::to_string(self).unwrap_or_else(|_| {
            format!(
                r#"{{"value":"","outcome":"{}","detail":""}}"#,
                self.outcome.word()
            )
        })
    }
}

/// What a `…/set` payload is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CommandPayload {
    /// Empty: a retained command being cleared. No command, no result.
    Clear,
    /// The command text, trimmed of whitespace and a byte-order mark.
    Text(String),
    /// Refused before any profile sees it.
    Refused { shown: String, reason: String },
}

/// Classifies a `…/set` payload; `max_len` is the configured payload limit in bytes.
pub fn decode_command(payload: &[u8], max_len: usize) -> CommandPayload {
    if payload.is_empty() {
        return CommandPayload::Clear;
    }
    if payload.len() > max_len {
        return CommandPayload::Refused {
            shown: echo(payload),
            reason: format!(
                "payload of {} bytes is over the limit of {max_len}",
                payload.len()
            ),
        };
    }
    let Ok(text) = std::str::from_utf8(payload) else {
        return CommandPayload::Refused {
            shown: echo(payload),
            reason: "payload is not UTF-8 text".to_string(),
        };
    };
    let text = text.trim_start_matches('\u{feff}').trim();
    if text.is_empty() {
        return CommandPayload::Refused {
            shown: echo(payload),
            reason: "payload is only whitespace".to_string(),
        };
    }
    if let Some(control) = text.chars().find(|c| c.is_control()) {
        return CommandPayload::Refused {
            shown: echo(payload),
            reason: format!("payload contains the control character {control:?}"),
        };
    }
    CommandPayload::Text(text.to_string())
}

/// The payload as the client sent it, for `value` in `…/result`: untrimmed, invalid UTF-8
/// replaced, at most [`MAX_ECHO_CHARS`] characters (marked with `…` when cut). Control
/// characters stay: JSON escapes them. For logs, format it with `{:?}`.
pub fn echo(payload: &[u8]) -> String {
    shortened(&String::from_utf8_lossy(
        &payload[..payload.len().min(MAX_ECHO_BYTES)],
    ))
}

/// At most [`MAX_ECHO_CHARS`] characters, marked when cut.
pub fn shortened(text: &str) -> String {
    let mut chars = text.chars();
    let head: String = chars.by_ref().take(MAX_ECHO_CHARS).collect();
    if chars.next().is_some() {
        format!("{head}…")
    } else {
        head
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn result_json_has_the_contract_shape() {
        let json = CommandResult::new("8", Outcome::NotApplied, "device in standby").to_json();
        let parsed: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert_eq!(
            parsed,
            serde_json::json!({"value": "8", "outcome": "not_applied", "detail": "device in standby"})
        );
    }

    #[test]
    fn outcome_words_match_serde() {
        for outcome in Outcome::ALL {
            assert_eq!(
                serde_json::to_value(outcome).unwrap(),
                serde_json::json!(outcome.word())
            );
        }
    }

    #[test]
    fn payloads_are_classified() {
        assert_eq!(decode_command(b"", 16), CommandPayload::Clear);
        assert_eq!(
            decode_command(b" ON\n", 16),
            CommandPayload::Text("ON".into())
        );
        assert_eq!(
            decode_command("\u{feff}45.67".as_bytes(), 16),
            CommandPayload::Text("45.67".into())
        );
        assert!(matches!(
            decode_command(&[0xff, 0xfe, 0x00], 16),
            CommandPayload::Refused { reason, .. } if reason.contains("UTF-8")
        ));
        assert!(matches!(
            decode_command(&[b'1'; 17], 16),
            CommandPayload::Refused { reason, .. } if reason.contains("17 bytes")
        ));
        assert!(matches!(
            decode_command(b" \n\t", 16),
            CommandPayload::Refused { .. }
        ));
        assert!(matches!(
            decode_command(b"O\x00N", 16),
            CommandPayload::Refused { .. }
        ));
    }

    #[test]
    fn the_echo_is_the_payload_as_sent() {
        assert_eq!(echo(b" ON\n"), " ON\n");
        assert_eq!(echo("\u{feff}45.67".as_bytes()), "\u{feff}45.67");
        assert_eq!(echo(&[b'O', 0xff, b'N']), "O\u{fffd}N");
        let CommandPayload::Refused { shown, .. } = decode_command(b"O\x00N\r", 16) else {
            panic!("accepted")
        };
        assert_eq!(shown, "O\x00N\r");
        // Long multi-byte text is cut on a character, and marked.
        let long = "é".repeat(MAX_ECHO_CHARS + 10);
        let shown = echo(long.as_bytes());
        assert_eq!(shown.chars().count(), MAX_ECHO_CHARS + 1);
        assert!(shown.starts_with(&"é".repeat(MAX_ECHO_CHARS)));
        assert!(shown.ends_with('…'));
        let exact = "é".repeat(MAX_ECHO_CHARS);
        assert_eq!(echo(exact.as_bytes()), exact);
    }

    #[test]
    fn a_huge_payload_is_echoed_short() {
        let CommandPayload::Refused { shown, .. } = decode_command(&[b'x'; 100_000], 1024) else {
            panic!("accepted")
        };
        assert!(shown.chars().count() <= MAX_ECHO_CHARS + 1);
        assert!(shown.ends_with('…'));
    }
}
