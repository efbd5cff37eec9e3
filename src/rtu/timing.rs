//! Line timing from the character format: character time, t1.5, t3.5 (fixed at 750 µs and
//! 1.75 ms above 19200 baud, as the serial-line specification says), frame wire times and a
//! default response timeout.

use std::time::Duration;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Parity {
    None,
    Even,
    Odd,
}

/// Bits of one character on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CharFormat {
    pub data_bits: u8,
    pub parity: Parity,
    pub stop_bits: u8,
}

/// The timing of one serial line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LineTiming {
    pub baud: u32,
    /// Time of one character (start + data + parity + stop bits).
    pub char_time: Duration,
    /// Longest gap allowed between two characters of one frame.
    pub t1_5: Duration,
    /// Silence that ends a frame; the line is never driven sooner after the last byte.
    pub t3_5: Duration,
}

impl LineTiming {
    pub fn new(baud: u32, format: CharFormat) -> Self {
        todo!("rtu helper")
    }

    /// Wire time of a frame of `bytes` characters.
    pub fn frame_time(&self, bytes: usize) -> Duration {
        todo!("rtu helper")
    }
}
