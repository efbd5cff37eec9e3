//! Line timing from the character format: character time, t1.5, t3.5 (fixed at 750 µs and
//! 1.75 ms above 19200 baud, as the serial-line specification says), frame wire times and a
//! default response timeout.

use std::time::Duration;

/// The parity bit of each character. The serial-line specification's default is even parity;
/// without parity it asks for two stop bits, though many devices ship with 8N1.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "serde", derive(serde::Deserialize, serde::Serialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "lowercase"))]
pub enum Parity {
    /// No parity bit.
    None,
    /// A parity bit making the count of ones even.
    Even,
    /// A parity bit making the count of ones odd.
    Odd,
}

/// `none`, `even`, `odd`: the word the configuration uses.
impl std::fmt::Display for Parity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Parity::None => "none",
            Parity::Even => "even",
            Parity::Odd => "odd",
        })
    }
}

/// Bits of one character on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CharFormat {
    /// Data bits per character: 8 for Modbus RTU (5–7 only for other protocols).
    pub data_bits: u8,
    /// The parity bit, if any.
    pub parity: Parity,
    /// Stop bits: 1 or 2 (any value above 1 opens the port with 2).
    pub stop_bits: u8,
}

/// `8N1`, `8E1`: the way serial settings are written on device labels.
impl std::fmt::Display for CharFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let parity = match self.parity {
            Parity::None => 'N',
            Parity::Even => 'E',
            Parity::Odd => 'O',
        };
        write!(f, "{}{parity}{}", self.data_bits, self.stop_bits)
    }
}

impl CharFormat {
    /// Bits of one character: one start bit, the data bits, a parity bit if any, stop bits.
    pub(crate) fn bits_per_char(&self) -> u32 {
        let parity = if self.parity == Parity::None { 0 } else { 1 };
        1 + u32::from(self.data_bits) + parity + u32::from(self.stop_bits)
    }
}

/// Above this rate the specification fixes t1.5 and t3.5 instead of scaling them.
pub(crate) const FIXED_TIMING_ABOVE_BAUD: u32 = 19_200;
/// t1.5 above 19200 baud.
pub(crate) const FIXED_T1_5: Duration = Duration::from_micros(750);
/// t3.5 above 19200 baud.
pub(crate) const FIXED_T3_5: Duration = Duration::from_micros(1750);
/// Allowance in [`LineTiming::default_response_timeout`] for what is neither wire time nor the
/// device: USB serial adapters hand received bytes over in 1–16 ms latency-timer batches and a
/// busy host schedules late.
pub(crate) const HOST_LATENCY_ALLOWANCE: Duration = Duration::from_millis(20);

/// The timing of one serial line, from its baud rate and character format
/// ([`LineTiming::new`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LineTiming {
    /// Bits per second (at least 1).
    pub baud: u32,
    /// Time of one character (start + data + parity + stop bits).
    pub char_time: Duration,
    /// Longest gap allowed between two characters of one frame: 1.5 character times, 750 µs
    /// above 19200 baud.
    pub(crate) t1_5: Duration,
    /// Silence that ends a frame; the line is never driven sooner after the last byte: 3.5
    /// character times, 1.75 ms above 19200 baud.
    pub t3_5: Duration,
}

impl LineTiming {
    /// The timing of a line at `baud` with `format`. A baud of 0 is treated as 1 so that a bad
    /// setting gives absurdly slow timing rather than a division by zero.
    pub fn new(baud: u32, format: CharFormat) -> Self {
        let baud = baud.max(1);
        let char_nanos = u64::from(format.bits_per_char()) * 1_000_000_000u64 / u64::from(baud);
        let char_time = Duration::from_nanos(char_nanos);
        let (t1_5, t3_5) = if baud > FIXED_TIMING_ABOVE_BAUD {
            (FIXED_T1_5, FIXED_T3_5)
        } else {
            (
                Duration::from_nanos(char_nanos * 3 / 2),
                Duration::from_nanos(char_nanos * 7 / 2),
            )
        };
        LineTiming {
            baud,
            char_time,
            t1_5,
            t3_5,
        }
    }

    /// Wire time of a frame of `bytes` characters.
    pub fn frame_time(&self, bytes: usize) -> Duration {
        self.char_time
            .saturating_mul(u32::try_from(bytes).unwrap_or(u32::MAX))
    }

    /// A response timeout for a device whose longest answer is `longest_answer_bytes`: the
    /// answer's wire time, the device's own turnaround `device_margin` (from its document or
    /// measured), t3.5 and 20 ms for the host (USB serial adapters hand received bytes over in
    /// 1–16 ms latency-timer batches, and a busy host schedules late). Measured from the
    /// instant our request left the transmit buffer to the last byte of the answer.
    pub fn default_response_timeout(
        &self,
        longest_answer_bytes: usize,
        device_margin: Duration,
    ) -> Duration {
        self.frame_time(longest_answer_bytes) + self.t3_5 + device_margin + HOST_LATENCY_ALLOWANCE
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const EIGHT_N_ONE: CharFormat = CharFormat {
        data_bits: 8,
        parity: Parity::None,
        stop_bits: 1,
    };
    const EIGHT_E_ONE: CharFormat = CharFormat {
        data_bits: 8,
        parity: Parity::Even,
        stop_bits: 1,
    };

    #[test]
    fn nine_thousand_six_hundred_eight_n_one() {
        let timing = LineTiming::new(9600, EIGHT_N_ONE);
        // 10 bits at 9600 baud: 1041.666 µs.
        assert_eq!(timing.char_time, Duration::from_nanos(1_041_666));
        assert_eq!(timing.t1_5, Duration::from_nanos(1_562_499));
        assert_eq!(timing.t3_5, Duration::from_nanos(3_645_831));
        assert_eq!(timing.frame_time(8), Duration::from_nanos(8 * 1_041_666));
    }

    #[test]
    fn formats_read_as_on_device_labels() {
        assert_eq!(EIGHT_E_ONE.to_string(), "8E1");
        assert_eq!(Parity::Even.to_string(), "even");
        let none_two = CharFormat {
            parity: Parity::None,
            stop_bits: 2,
            ..EIGHT_E_ONE
        };
        assert_eq!(none_two.to_string(), "8N2");
    }

    #[test]
    fn parity_adds_a_bit() {
        let timing = LineTiming::new(9600, EIGHT_E_ONE);
        // 11 bits at 9600 baud: 1145.833 µs.
        assert_eq!(timing.char_time, Duration::from_nanos(1_145_833));
        let two_stop = LineTiming::new(
            9600,
            CharFormat {
                stop_bits: 2,
                ..EIGHT_E_ONE
            },
        );
        assert_eq!(two_stop.char_time, Duration::from_nanos(1_250_000));
    }

    #[test]
    fn fixed_above_19200() {
        let at_19200 = LineTiming::new(19_200, EIGHT_N_ONE);
        assert_eq!(at_19200.t3_5, Duration::from_nanos(520_833 * 7 / 2));
        let at_38400 = LineTiming::new(38_400, EIGHT_N_ONE);
        assert_eq!(at_38400.t1_5, Duration::from_micros(750));
        assert_eq!(at_38400.t3_5, Duration::from_micros(1750));
        assert_eq!(at_38400.char_time, Duration::from_nanos(260_416));
    }

    #[test]
    fn zero_baud_does_not_divide_by_zero() {
        let timing = LineTiming::new(0, EIGHT_N_ONE);
        assert_eq!(timing.char_time, Duration::from_secs(10));
    }

    #[test]
    fn response_timeout_adds_wire_time_and_margins() {
        let timing = LineTiming::new(9600, EIGHT_N_ONE);
        let timeout = timing.default_response_timeout(17, Duration::from_millis(50));
        assert_eq!(
            timeout,
            timing.frame_time(17)
                + timing.t3_5
                + Duration::from_millis(50)
                + HOST_LATENCY_ALLOWANCE
        );
    }
}
