//! A validated command as the plan of one bus slot: the reads to make first (read-modify-write),
//! the writes computed from their fresh answers, the read-back and how to judge it.

use std::time::Duration;

use crate::rtu::{Request, Response};

/// Why a command is refused: nothing is written.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct Rejection(pub String);

/// What a read-back says about a command.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Verification {
    Applied,
    /// The device acknowledged but shows something else.
    NotApplied(String),
    /// Still moving toward the value (valve opening): read again later, within the settle window.
    Settling,
}

/// One planned command. The line runs: `reads_before()` → `writes(answers)` → the writes →
/// `readback()` → `verify(answers)`, with no other transaction in between.
#[derive(Debug, Clone, PartialEq)]
pub struct CommandPlan {}

impl CommandPlan {
    pub fn field(&self) -> &str {
        todo!("profile helper")
    }

    /// Reads to make in the slot before writing (empty when no read-modify-write is needed).
    pub fn reads_before(&self) -> &[Request] {
        todo!("profile helper")
    }

    /// The write requests, computed from the fresh answers to `reads_before()`. Empty when the
    /// device already is in the commanded state (a toggle field asked for its current state).
    pub fn writes(&self, before: &[Response]) -> Result<Vec<Request>, Rejection> {
        todo!("profile helper")
    }

    /// Reads that verify the command.
    pub fn readback(&self) -> &[Request] {
        todo!("profile helper")
    }

    /// Judges the answers to `readback()`.
    pub fn verify(&self, answers: &[Response]) -> Verification {
        todo!("profile helper")
    }

    /// How long a `Settling` read-back may keep being repeated.
    pub fn settle_window(&self) -> Option<Duration> {
        todo!("profile helper")
    }
}
