//! How a simulated line hands an answer's bytes to the master: at once, whole after its wire
//! time, one byte at a time at the character rate (a UART without a deep FIFO, a pty), or in
//! the chunks a USB adapter delivers (whatever is on the wire so far, once per polling
//! interval). The schedule is pure: byte offsets and the instants they become readable.

use std::fmt;
use std::ops::Range;
use std::str::FromStr;
use std::time::{Duration, Instant};

use rtu2mqtt_modbus::timing::LineTiming;

/// The longest polling interval a USB serial adapter is given (its latency timer's default).
pub const USB_MAX_INTERVAL: Duration = Duration::from_millis(16);

/// When an answer's bytes become readable on the master's side.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Pace {
    /// As soon as the device has decided the answer (a pty's own behaviour, no wire time).
    #[default]
    Instant,
    /// Whole, once its last byte would be on the wire.
    Frame,
    /// Byte by byte, each once it would be on the wire.
    Bytes,
    /// Every `every`, all bytes that are on the wire by then (a USB adapter's polling).
    Usb { every: Duration },
}

impl Pace {
    /// Whether frames take their wire time (everything but [`Pace::Instant`]).
    pub fn takes_wire_time(self) -> bool {
        self != Pace::Instant
    }

    /// The parts of a `len`-byte answer and when each becomes readable: the first byte starts
    /// at `starts`; after every `burst` bytes the device pauses for `gap` (a fault: a pause
    /// inside the answer); USB polling ticks are counted from `epoch`.
    pub fn schedule(
        self,
        timing: &LineTiming,
        starts: Instant,
        len: usize,
        burst: usize,
        gap: Duration,
        epoch: Instant,
    ) -> Vec<(Instant, Range<usize>)> {
        let burst = burst.max(1);
        let char_time = if self.takes_wire_time() {
            timing.char_time
        } else {
            Duration::ZERO
        };
        // When byte `i` is complete on the wire, and when its burst began.
        let on_wire = |i: usize| starts + gap * (i / burst) as u32 + char_time * (i + 1) as u32;
        let burst_start = |i: usize| starts + gap * (i / burst) as u32 + char_time * i as u32;
        let ready = |i: usize| match self {
            Pace::Instant => burst_start(i),
            Pace::Frame => on_wire(((i / burst + 1) * burst).min(len) - 1),
            Pace::Bytes => on_wire(i),
            Pace::Usb { every } => next_tick(epoch, every, on_wire(i)),
        };
        let mut parts: Vec<(Instant, Range<usize>)> = Vec::new();
        for i in 0..len {
            let at = ready(i);
            match parts.last_mut() {
                Some((last_at, range)) if *last_at == at => range.end = i + 1,
                _ => parts.push((at, i..i + 1)),
            }
        }
        parts
    }
}

/// The first instant `epoch + k·every` (k ≥ 0) at or after `at`.
fn next_tick(epoch: Instant, every: Duration, at: Instant) -> Instant {
    let every_ns = every.as_nanos().max(1);
    let since = at.saturating_duration_since(epoch).as_nanos();
    let ticks = since.div_ceil(every_ns);
    epoch + Duration::from_nanos(u64::try_from(ticks * every_ns).unwrap_or(u64::MAX))
}

impl fmt::Display for Pace {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Pace::Instant => f.write_str("instant"),
            Pace::Frame => f.write_str("frame"),
            Pace::Bytes => f.write_str("bytes"),
            Pace::Usb { every } => write!(f, "usb:{}ms", every.as_millis()),
        }
    }
}

impl FromStr for Pace {
    type Err = String;

    /// `instant`, `frame`, `bytes` or `usb:Nms` (N from 1 to 16).
    fn from_str(text: &str) -> Result<Self, String> {
        match text {
            "instant" => Ok(Pace::Instant),
            "frame" => Ok(Pace::Frame),
            "bytes" => Ok(Pace::Bytes),
            _ => {
                let expected = || {
                    format!("`{text}`: expected instant, frame, bytes or usb:Nms (N from 1 to 16)")
                };
                let millis = text
                    .strip_prefix("usb:")
                    .and_then(|rest| rest.strip_suffix("ms"))
                    .and_then(|n| n.parse::<u64>().ok())
                    .ok_or_else(expected)?;
                let every = Duration::from_millis(millis);
                if every.is_zero() || every > USB_MAX_INTERVAL {
                    return Err(expected());
                }
                Ok(Pace::Usb { every })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rtu2mqtt_modbus::timing::{CharFormat, Parity};

    fn timing() -> LineTiming {
        LineTiming::new(
            9600,
            CharFormat {
                data_bits: 8,
                parity: Parity::None,
                stop_bits: 1,
            },
        )
    }

    #[test]
    fn paces_parse_and_print_back() {
        for text in ["instant", "frame", "bytes", "usb:1ms", "usb:16ms"] {
            assert_eq!(text.parse::<Pace>().unwrap().to_string(), text);
        }
        for wrong in ["", "usb", "usb:0ms", "usb:17ms", "usb:4", "byte"] {
            assert!(wrong.parse::<Pace>().is_err(), "{wrong}");
        }
    }

    #[test]
    fn bytes_come_one_character_time_apart() {
        let t = timing();
        let start = Instant::now();
        let parts = Pace::Bytes.schedule(&t, start, 5, 5, Duration::ZERO, start);
        assert_eq!(parts.len(), 5);
        for (i, (at, range)) in parts.iter().enumerate() {
            assert_eq!(*range, i..i + 1);
            assert_eq!(*at, start + t.char_time * (i as u32 + 1));
        }
    }

    #[test]
    fn a_frame_comes_whole_after_its_wire_time() {
        let t = timing();
        let start = Instant::now();
        let parts = Pace::Frame.schedule(&t, start, 8, 8, Duration::ZERO, start);
        assert_eq!(parts, vec![(start + t.char_time * 8, 0..8)]);
        let instant = Pace::Instant.schedule(&t, start, 8, 8, Duration::ZERO, start);
        assert_eq!(instant, vec![(start, 0..8)]);
    }

    #[test]
    fn a_pause_inside_the_answer_delays_the_second_half() {
        let t = timing();
        let start = Instant::now();
        let pause = Duration::from_millis(5);
        let parts = Pace::Frame.schedule(&t, start, 8, 4, pause, start);
        assert_eq!(
            parts,
            vec![
                (start + t.char_time * 4, 0..4),
                (start + pause + t.char_time * 8, 4..8)
            ]
        );
        let bytes = Pace::Bytes.schedule(&t, start, 8, 4, pause, start);
        assert_eq!(bytes[4], (start + pause + t.char_time * 5, 4..5));
    }

    #[test]
    fn usb_delivers_what_is_on_the_wire_at_each_tick() {
        let t = timing();
        let epoch = Instant::now();
        let every = Duration::from_millis(4);
        // 17 bytes at 9600 baud take 17.7 ms: ticks at 4, 8, 12, 16 and 20 ms.
        let parts = Pace::Usb { every }.schedule(&t, epoch, 17, 17, Duration::ZERO, epoch);
        let ticks: Vec<Instant> = parts.iter().map(|(at, _)| *at).collect();
        assert_eq!(
            ticks,
            (1..=5).map(|k| epoch + every * k).collect::<Vec<_>>()
        );
        assert_eq!(parts.first().map(|p| p.1.clone()), Some(0..3));
        assert_eq!(parts.last().map(|p| p.1.end), Some(17));
        for (at, range) in &parts {
            // Every byte handed over is complete on the wire, and no tick holds one back.
            assert!(epoch + t.char_time * range.end as u32 <= *at);
            assert!(epoch + t.char_time * (range.end as u32 + 1) > *at || range.end == 17);
        }
    }
}
