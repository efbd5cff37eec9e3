//! A command on the line, from the queue it arrives on to its outcome:
//!
//! - [`queue`]: the line's command queue (commands travel boxed).
//! - [`slots`]: [`slots::CommandSlots`], the queue's receiving side with the commands still
//!   settling or held for a write interval; it runs a command's slot when the scheduler gives
//!   it its turn and says what the line must do after it ([`slots::SlotReport`]).
//! - [`run`]: the frames of one slot on a [`run::SlotLink`] (reads, writes computed from them,
//!   read-back, verification), and a settling device's read-back.
//! - [`outcome`]: how a command ended, with the typed cause of a failure.
//!
//! The line task's side of it (taking commands and refreshes in, carrying out what a slot
//! reports) is `impl Line` in `bus::line::command_side`, on the line's own state.

pub(crate) mod outcome;
pub mod queue;
pub(crate) mod run;
pub(crate) mod slots;

pub use outcome::{Command, CommandFailure, CommandOutcome};
