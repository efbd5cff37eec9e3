//! `rtu2mqtt read`: one raw read on a serial port or over TCP (`--url`), shown as hex and
//! decoded every way a profile could (u16, i16, u32/i32/f32 in both word orders, packed BCD,
//! characters, bits), to help write a profile.
//!
//! Read functions only: this module never builds a write request.

use std::fmt::Write as _;
use std::process::ExitCode;

use anyhow::{bail, Context as _};

use super::target::Target;
use crate::cli::{parse_parity, ReadArgs};
use rtu2mqtt_modbus::codec::{encode_answer, encode_request, hex};
use rtu2mqtt_modbus::{Request, Response, SlaveId, Transact};
use rtu2mqtt_profile::bcd;

/// The read request for `function` 1–4 (anything else is refused: this tool never writes).
pub fn read_request(function: u8, start: u16, quantity: u16) -> anyhow::Result<Request> {
    Ok(match function {
        1 => Request::ReadCoils { start, quantity },
        2 => Request::ReadDiscreteInputs { start, quantity },
        3 => Request::ReadHoldingRegisters { start, quantity },
        4 => Request::ReadInputRegisters { start, quantity },
        other => bail!("function {other}: only the read functions 1, 2, 3 and 4 are allowed"),
    })
}

pub fn read(args: &ReadArgs) -> anyhow::Result<ExitCode> {
    let parity = parse_parity(&args.parity)?;
    let request = read_request(args.function, args.start, args.count)?;
    let frame = encode_request(args.address, &request).context("the read cannot be sent")?;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the runtime")?;
    let result = runtime.block_on(async {
        // The serial stream registers with the runtime's reactor: opened inside it.
        let target = Target::of(args.link.port.as_deref(), args.link.url.as_deref())?;
        let mut master = target.open(args.baud, parity).await?;
        anyhow::Ok(master.transact(args.address, &request, args.timeout).await)
    })?;
    println!("request  {}", hex(&frame));
    match result {
        Ok(Ok(response)) => {
            print!("{}", render(args.address, &request, &response));
            Ok(ExitCode::SUCCESS)
        }
        Ok(Err(code)) => {
            println!("answer   device answered {code}");
            Ok(ExitCode::from(2))
        }
        Err(error) => bail!("no valid answer: {error}"),
    }
}

/// The answer as hex, then every decoding a profile could use.
pub fn render(slave: SlaveId, request: &Request, response: &Response) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "answer   {}", hex(&encode_answer(slave, response)));
    let start = request.read_span().map_or(0, |(start, _)| start);
    if let Some(words) = response.registers() {
        out.push_str(&render_registers(start, words));
    } else if let Some(bits) = response.bits() {
        out.push_str(&render_bits(start, bits));
    }
    out
}

/// A bus address as the manuals' two readers look for it: hex and decimal (`0x0c83  3203`).
fn place(address: u16) -> String {
    format!("{address:#06x} {address:>5}")
}

/// One line per register, then one per register pair, then the block as characters.
pub fn render_registers(start: u16, words: &[u16]) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "\nregister          hex      u16     i16  bits                 bcd  chars"
    );
    for (i, &word) in words.iter().enumerate() {
        let bcd =
            bcd::decode(word, bcd::WORD_DIGITS).map_or_else(|_| "-".to_string(), |v| v.to_string());
        let _ = writeln!(
            out,
            "{}    {word:#06x}  {word:>7}  {:>6}  {:04b} {:04b} {:04b} {:04b}  {bcd:>4}  \"{}\"",
            place(start.wrapping_add(i as u16)),
            word as i16,
            word >> 12,
            (word >> 8) & 0xF,
            (word >> 4) & 0xF,
            word & 0xF,
            printable(&word.to_be_bytes()),
        );
    }
    if words.len() >= 2 {
        let _ = writeln!(
            out,
            "\npair           u32 (high word first)  i32             f32  | u32 (low word first)  i32             f32"
        );
        for (i, pair) in words.windows(2).enumerate() {
            let high_first = (u32::from(pair[0]) << 16) | u32::from(pair[1]);
            let low_first = (u32::from(pair[1]) << 16) | u32::from(pair[0]);
            let _ = writeln!(
                out,
                "{}    {high_first:>21}  {:>11}  {:>14}  | {low_first:>20}  {:>11}  {:>14}",
                place(start.wrapping_add(i as u16)),
                high_first as i32,
                float(high_first),
                low_first as i32,
                float(low_first),
            );
        }
    }
    if words.len() >= 4 {
        let _ = writeln!(
            out,
            "\nfour           u64 (high word first)            i64                   f64  | u64 (low word first)             i64                   f64"
        );
        for (i, four) in words.windows(4).enumerate() {
            let high_first = four.iter().fold(0u64, |acc, &w| (acc << 16) | u64::from(w));
            let low_first = four
                .iter()
                .rev()
                .fold(0u64, |acc, &w| (acc << 16) | u64::from(w));
            let _ = writeln!(
                out,
                "{}    {high_first:>20}  {:>20}  {:>20}  | {low_first:>20}  {:>20}  {:>20}",
                place(start.wrapping_add(i as u16)),
                high_first as i64,
                crate::web::decode::float(f64::from_bits(high_first)),
                low_first as i64,
                crate::web::decode::float(f64::from_bits(low_first)),
            );
        }
    }
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_be_bytes()).collect();
    let swapped: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    let _ = writeln!(out, "\ntext (high byte first) \"{}\"", printable(&bytes));
    let _ = writeln!(out, "text (low byte first)  \"{}\"", printable(&swapped));
    out
}

/// The bits in groups of eight, first bit first, with their addresses.
pub fn render_bits(start: u16, bits: &[bool]) -> String {
    let mut out = String::from("\nbit            values (first bit first)\n");
    for (i, group) in bits.chunks(8).enumerate() {
        let text: String = group.iter().map(|&on| if on { '1' } else { '0' }).collect();
        let _ = writeln!(out, "{}    {text}", place(start.wrapping_add(8 * i as u16)));
    }
    let on: Vec<String> = bits
        .iter()
        .enumerate()
        .filter(|(_, on)| **on)
        .map(|(i, _)| {
            let address = start.wrapping_add(i as u16);
            format!("{address:#06x} ({address})")
        })
        .collect();
    let _ = writeln!(
        out,
        "on: {}",
        if on.is_empty() {
            "none".into()
        } else {
            on.join(", ")
        }
    );
    out
}

/// An f32 from its bits: plain for ordinary magnitudes, with an exponent for tiny or huge
/// ones (register pairs that are no float show up as such), non-finite values by name.
fn float(bits: u32) -> String {
    let value = f32::from_bits(bits);
    let magnitude = value.abs();
    if !value.is_finite() {
        format!("{value:?}")
    } else if magnitude != 0.0 && !(1e-4..1e9).contains(&magnitude) {
        format!("{value:e}")
    } else {
        format!("{value}")
    }
}

/// Printable ASCII as itself, anything else as `.`.
fn printable(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|&b| {
            if (0x20..0x7F).contains(&b) && b != b'"' {
                b as char
            } else {
                '.'
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_are_refused() {
        assert!(read_request(6, 0, 1).is_err());
        assert!(read_request(16, 0, 1).is_err());
        assert!(read_request(3, 0x1000, 6).is_ok());
    }

    #[test]
    fn registers_decoded_every_way() {
        let text = render_registers(0x1000, &[0x4148, 0x0000, 0x1234, 0xFFFE]);
        // u16 and i16
        assert!(text.contains("0xfffe    65534      -2"), "{text}");
        // f32 high word first: 0x41480000 = 12.5
        assert!(
            text.contains("1095237632   1095237632            12.5"),
            "{text}"
        );
        // BCD
        assert!(text.contains(" 1234  \".4\""), "{text}");
        assert!(
            text.contains("text (high byte first) \"AH...4..\""),
            "{text}"
        );
    }

    #[test]
    fn four_registers_read_as_64_bits_in_both_word_orders() {
        // An energy counter of 65,538 Wh, high word first; and 2.5 as f64 (0x4004_0000_0000_0000).
        let counter = render_registers(0, &[0x0000, 0x0000, 0x0001, 0x0002]);
        assert!(
            counter.contains("0x0000     0                   65538"),
            "{counter}"
        );
        let swapped = render_registers(0, &[0x0002, 0x0001, 0x0000, 0x0000]);
        assert!(swapped.contains("|                65538"), "{swapped}");
        let float = render_registers(0, &[0x4004, 0x0000, 0x0000, 0x0000]);
        assert!(float.contains("                   2.5  |"), "{float}");
        let negative = render_registers(0, &[0xFFFF, 0xFFFF, 0xFFFF, 0xFFFE]);
        assert!(
            negative.contains("18446744073709551614                    -2"),
            "{negative}"
        );
    }

    #[test]
    fn bits_listed() {
        let text = render_bits(
            0,
            &[true, false, false, true, false, false, false, false, true],
        );
        assert!(text.contains("0x0000     0    10010000"));
        assert!(text.contains("0x0008     8    1"));
        assert!(
            text.contains("on: 0x0000 (0), 0x0003 (3), 0x0008 (8)"),
            "{text}"
        );
    }
}
