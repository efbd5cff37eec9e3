//! The one refusal type of command handling, shared by command parsing ([`super::codec`]) and
//! command planning ([`super::command`]) so that neither depends on the other.

/// Why a command is refused: nothing is written.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct Rejection(
    /// The reason, one sentence naming the field and what it accepts (`gear must be an
    /// integer 1–10, got 11`).
    pub String,
);
