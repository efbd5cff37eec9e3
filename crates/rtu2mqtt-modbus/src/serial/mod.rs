//! The RS485 line: [`transport`] opens and configures the serial port (the only code in the
//! crate that touches one) and [`master`] runs one RTU transaction at a time on it with the
//! serial-line specification's timing; [`reception`] is how the master frames an answer from
//! what its port reads and when, without I/O or clock; `answer_onset` is what the master
//! learns of when each device's answers begin.

mod answer_onset;
pub mod master;
pub mod reception;
pub mod transport;
