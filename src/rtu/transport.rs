//! The serial port: the only code in the crate that opens or touches one (tokio-serial).
//! Opens a line with its character format (a pseudo-terminal that refuses parity runs with a
//! warning; a real UART that refuses a setting is an error), writes a frame and waits until the
//! transmit buffer has drained (tcdrain), reads bytes with deadlines, discards stray input, and
//! optionally switches the kernel's RS485 mode on.

use std::time::Duration;

use super::timing::CharFormat;

/// Kernel RS485 mode (TIOCSRS485) for boards whose UART drives the transceiver.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rs485Settings {
    pub rts_on_send: bool,
    pub delay_before_send: Duration,
    pub delay_after_send: Duration,
}

/// Everything needed to open one line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SerialSettings {
    pub path: String,
    pub baud: u32,
    pub format: CharFormat,
    pub rs485: Option<Rs485Settings>,
}

#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    #[error("cannot open {path}: {source}")]
    Open {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: {setting} refused by the port: {source}")]
    SettingRefused {
        path: String,
        setting: &'static str,
        source: std::io::Error,
    },
    #[error("i/o error: {0}")]
    Io(#[from] std::io::Error),
}

/// An open serial line.
pub struct Port {}

impl Port {
    /// Opens the port with `settings`.
    pub fn open(settings: &SerialSettings) -> Result<Port, TransportError> {
        todo!("rtu helper")
    }
}
