//! The RS485 line: [`transport`] opens and configures the serial port (the only code in the
//! crate that touches one) and [`master`] runs one RTU transaction at a time on it with the
//! serial-line specification's timing.

pub mod master;
pub mod transport;
