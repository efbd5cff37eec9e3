//! The one refusal type of command handling, shared by command parsing ([`super::codec`]) and
//! command planning ([`super::command`]) so that neither depends on the other.

/// Why a command is refused: nothing is written.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct Rejection(pub String);
