//! `rtu2mqtt scan`: which device answers at which address, baud rate and parity on a serial
//! port or behind a serial device server (`--url tcp://…`; on `modbus-tcp://` only addresses,
//! the gateway's serial setting being its own). Read-only: every probe is a read of one register or bit at 0.
//!
//! The probe is FC03 (one holding register at 0). Any valid answer means a device is there,
//! including an exception: a device that does not have register 0 answers 02, one without
//! FC03 answers 01. Only where the first probe was refused with an exception are FC04 and FC01
//! tried too (the device is known to be there, so two more probes cost little and show which
//! reads it serves). A timeout is not probed further: a conforming device answers an
//! unsupported function with exception 01, and trying three functions at every silent address
//! would triple a scan of 247 addresses. An answer with a bad CRC or the wrong shape is noted
//! as "garbled" (something is there at another setting, or the line is noisy), never as a
//! device. Most answers heard at the wrong baud rate no longer start with the probed address
//! and are ignored like another device's frame, so they end as timeouts.
//!
//! On a pseudo-terminal the kernel does not enforce the baud rate; the simulators can compare
//! the rate the master set on the pty with their own and garble their answers
//! (`sim::ServeOptions::enforce_baud`). Parity is not observable on a Linux pty, so a
//! scan over ptys finds a device at every parity tried.
//!
//! On a serial port a silent address costs little: the probe's wire time plus the longest a
//! device may take to start answering ([`quick_wait`], 20 ms at 9600 baud), not the full
//! `--timeout` (once an answer has started, the master waits for its end whatever the wait).
//! A device that starts answering after that is not lost: the master hears its late answer
//! before or during the next probe, and the address is probed again with the full timeout
//! (the last address of a setting always gets the full timeout, as nothing follows it). Behind
//! a TCP link the network's delay is unknown, so every probe waits the full timeout there.
//!
//! Each device found is asked what it is, once, at the setting it first answered at
//! ([`identities`]: its Read Device Identification and the SunSpec marker, reads only), and
//! the scan ends with the table of what the devices said, the profile that fits each (a
//! built-in one, or one of `--profiles DIR`) and a configuration to copy. A silent address
//! costs nothing more.
//!
//! Progress goes to stderr, and at the end how long the scan took; Ctrl-C stops the scan and
//! prints the table found so far. The scan itself is [`sweep`].

mod identities;
mod sweep;

pub use sweep::{parse_addresses, quick_wait, scan, table, Found};
