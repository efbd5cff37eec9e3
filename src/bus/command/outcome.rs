//! Why a command failed on the bus, as a typed cause: the device's exception answer kept apart
//! from the transport's failures and from the line's own state (port closed, shutdown). Its
//! `Display` is the detail the bridge reports; a command's whole outcome reads as words in the
//! line's log. Nothing here runs frames.

use rtu2mqtt_modbus::ExceptionCode;
use rtu2mqtt_modbus::{Error as MasterError, PortFault};

use crate::bus::transaction::Failure;
use rtu2mqtt_profile::CommandPlan;

/// How a command ended on the bus.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CommandOutcome {
    /// Written, and the read-back shows the value (an action: the device reports success).
    Applied { detail: String },
    /// Acknowledged, but the read-back differs (an action: its result code is no success).
    NotApplied { detail: String },
    /// Refused by the profile's rules on the fresh state: nothing written.
    Rejected { detail: String },
    /// An exception answer, no answer after the retries, or the port is gone.
    Failed { cause: CommandFailure },
}

/// A command for the line's queue. Its end comes back as [`LineEvent::CommandFinished`](crate::bus::LineEvent::CommandFinished) with
/// the same `id`, on the line's events channel.
#[derive(Debug)]
pub struct Command {
    /// Chosen by the sender; the line only echoes it.
    pub id: u64,
    pub device: String,
    pub plan: CommandPlan,
}

/// The cause carried by [`CommandOutcome::Failed`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CommandFailure {
    /// The device answered with an exception: it is there and refused.
    Exception(ExceptionCode),
    /// No usable answer to a read of the slot after the retries: the last problem.
    NoAnswer(MasterError),
    /// No usable answer to a write, after the slot ran again on fresh reads.
    WriteUnanswered(MasterError),
    /// A broadcast write could not be sent.
    BroadcastFailed(MasterError),
    /// The port failed during the command's slot.
    PortFailed(PortFault),
    /// The port failed while the command's read-back was waiting for the device to settle.
    PortFailedWhileSettling(PortFault),
    /// The port was not open when the command's turn came.
    PortNotOpen,
    /// The port is closed and the line is waiting to reopen it.
    PortReopening,
    /// The gateway stopped before the command's turn came.
    ShuttingDown,
    /// The command names a device the line does not have.
    UnknownDevice { device: String, line: String },
}

impl From<Failure> for CommandFailure {
    fn from(failure: Failure) -> Self {
        match failure {
            Failure::NoAnswer(last) => CommandFailure::NoAnswer(last),
            Failure::PortGone(fault) => CommandFailure::PortFailed(fault),
        }
    }
}

impl std::fmt::Display for CommandFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Exception(code) => write!(f, "device answered {code}"),
            Self::NoAnswer(last) => write!(f, "no answer after the retries: {last}"),
            Self::WriteUnanswered(last) => write!(f, "no answer to the write: {last}"),
            Self::BroadcastFailed(error) => write!(f, "broadcast failed: {error}"),
            Self::PortFailed(fault) => write!(f, "the port failed: {fault}"),
            Self::PortFailedWhileSettling(fault) => {
                write!(f, "the port failed before the read-back settled: {fault}")
            }
            Self::PortNotOpen => f.write_str("the port is not open"),
            Self::PortReopening => f.write_str("the port is not open (reopening)"),
            Self::ShuttingDown => f.write_str("the gateway is shutting down"),
            Self::UnknownDevice { device, line } => {
                write!(f, "no device {device:?} on line {line}")
            }
        }
    }
}

/// `applied: read-back confirms the value`, `failed: device answered exception 02 (…)`: how the
/// line's log says how a command ended.
impl std::fmt::Display for CommandOutcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Applied { detail } => write!(f, "applied: {detail}"),
            Self::NotApplied { detail } => write!(f, "not applied: {detail}"),
            Self::Rejected { detail } => write!(f, "rejected: {detail}"),
            Self::Failed { cause } => write!(f, "failed: {cause}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

    #[test]
    fn outcomes_read_as_words() {
        let applied = CommandOutcome::Applied {
            detail: "read-back confirms the value".to_string(),
        };
        assert_eq!(applied.to_string(), "applied: read-back confirms the value");
        let failed = CommandOutcome::Failed {
            cause: CommandFailure::PortNotOpen,
        };
        assert_eq!(failed.to_string(), "failed: the port is not open");
    }

    #[test]
    fn causes_read_as_the_outcome_details_always_did() {
        assert_eq!(
            CommandFailure::Exception(ExceptionCode::IllegalDataAddress).to_string(),
            "device answered exception 02 (illegal data address)"
        );
        assert_eq!(
            CommandFailure::NoAnswer(MasterError::Timeout(Duration::from_millis(300))).to_string(),
            "no answer after the retries: no answer within 300ms"
        );
        assert_eq!(
            CommandFailure::WriteUnanswered(MasterError::Crc).to_string(),
            "no answer to the write: bad CRC"
        );
        let fault = PortFault::from(std::io::Error::from(std::io::ErrorKind::UnexpectedEof));
        assert_eq!(
            CommandFailure::from(Failure::PortGone(fault.clone())),
            CommandFailure::PortFailed(fault)
        );
        assert_eq!(
            CommandFailure::UnknownDevice {
                device: "pump".into(),
                line: "line-a".into()
            }
            .to_string(),
            "no device \"pump\" on line line-a"
        );
    }
}
