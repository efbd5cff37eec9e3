//! What the page is pushed, as server-sent events: the plant view (a `snapshot` of every
//! topic's last message, then the messages the bridge hands out, those waiting together in one
//! `publish`) and a line's frames
//! (each decoded: address, function, registers, exception, time since the line's previous
//! frame). A page that falls behind is sent a fresh snapshot, or told how many frames it
//! missed; it never holds anything up. The number of open streams is bounded.

use std::collections::HashMap;
use std::convert::Infallible;
use std::sync::Arc;
use std::time::{Duration, UNIX_EPOCH};

use axum::extract::{Query, State};
use axum::http::StatusCode;
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use futures_util::stream::{self, Stream};
use serde::{Deserialize, Serialize};
use tokio::sync::broadcast::error::RecvError;
use tokio::sync::OwnedSemaphorePermit;

use super::{refusal, Console};
use crate::bridge::observers::plant_view::news_json;
use rtu2mqtt_modbus::codec::{decode_answer, decode_request, Answer};
use rtu2mqtt_modbus::{Request, Response as ModbusResponse, SlaveId};

/// Event streams open at once (pages of the console); more are refused with 503.
pub const MAX_STREAMS: usize = 32;
/// Messages sent in one event at the most.
const BATCH: usize = 2048;
/// How long a message waits for the ones right behind it, to go in one event with them.
const GATHER: Duration = Duration::from_millis(40);
/// A comment line this often keeps proxies from closing a quiet stream.
const KEEP_ALIVE: Duration = Duration::from_secs(15);

/// Every topic's last message, each in the form of a `publish` event's messages
/// ([`news_json`]), so that a page reads both alike.
fn snapshot_event(console: &Console) -> Event {
    let messages: Vec<String> = console
        .view
        .snapshot()
        .iter()
        .map(|published| {
            let at_ms = published
                .at
                .duration_since(UNIX_EPOCH)
                .map_or(0, |since| since.as_millis() as u64);
            news_json(&published.topic, &published.payload, at_ms)
        })
        .collect();
    Event::default()
        .event("snapshot")
        .data(format!("[{}]", messages.join(",")))
}

fn json_event(name: &str, body: &impl Serialize) -> Event {
    let data = serde_json::to_string(body).unwrap_or_else(|_| "null".to_string());
    Event::default().event(name).data(data)
}

/// A place among the open streams, or the 503 that says there is none.
fn stream_place(console: &Console) -> Result<OwnedSemaphorePermit, Box<Response>> {
    Arc::clone(&console.streams)
        .try_acquire_owned()
        .map_err(|_| {
            Box::new(refusal(
                StatusCode::SERVICE_UNAVAILABLE,
                format!("{MAX_STREAMS} console pages are open already: close one"),
            ))
        })
}

/// `GET /api/events`: the plant view, live.
pub async fn plant_events(State(console): State<Arc<Console>>) -> Response {
    let place = match stream_place(&console) {
        Ok(place) => place,
        Err(refused) => return *refused,
    };
    // Subscribed before the snapshot is taken: nothing falls between the two.
    let news = console.view.subscribe();
    let mut layout = console.layout.clone();
    layout.mark_unchanged();
    let first = snapshot_event(&console);
    let state = (Some(first), news, layout, console, place);
    let events = stream::unfold(
        state,
        |(first, mut news, mut layout, console, place)| async move {
            if let Some(first) = first {
                return Some((
                    Ok::<_, Infallible>(first),
                    (None, news, layout, console, place),
                ));
            }
            let next = tokio::select! {
                next = news.recv() => next,
                changed = layout.changed() => {
                    // A reload: the page takes the new model (the gateway never drops the sender
                    // while it serves).
                    if changed.is_err() {
                        return None;
                    }
                    let event = json_event("layout", &"reloaded");
                    return Some((Ok(event), (None, news, layout, console, place)));
                }
            };
            let event = match next {
                Ok(first) => {
                    // What else comes within a moment goes in the same event: one write, one
                    // wake-up of the page, however busy the plant.
                    tokio::time::sleep(GATHER).await;
                    let mut batch = String::from("[");
                    batch.push_str(&first);
                    for _ in 1..BATCH {
                        match news.try_recv() {
                            Ok(next) => {
                                batch.push(',');
                                batch.push_str(&next);
                            }
                            Err(_) => break,
                        }
                    }
                    batch.push(']');
                    Event::default().event("publish").data(batch)
                }
                Err(RecvError::Lagged(_)) => snapshot_event(&console),
                Err(RecvError::Closed) => return None,
            };
            Some((Ok(event), (None, news, layout, console, place)))
        },
    );
    sse(events)
}

fn sse(events: impl Stream<Item = Result<Event, Infallible>> + Send + 'static) -> Response {
    Sse::new(events)
        .keep_alive(KeepAlive::new().interval(KEEP_ALIVE))
        .into_response()
}

/// Which frames a page watches.
#[derive(Debug, Deserialize)]
pub struct FrameFilter {
    /// The line's name; all lines when absent.
    pub line: Option<String>,
}

/// One frame as the page shows it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FrameRow {
    pub line: String,
    /// When the link recorded it, as the frame log writes it (`<unix seconds>.<µs>`).
    pub at: String,
    /// The same in microseconds since the Unix epoch.
    pub at_us: u64,
    /// `tx` (the gateway's request) or `rx` (the answer).
    pub dir: String,
    /// The bytes, lower-case hex without spaces.
    pub hex: String,
    pub address: Option<u8>,
    pub function: Option<u8>,
    /// The frame in words (`read holding 4096 ×6`, `answer 6 registers`, `exception 02`).
    pub summary: String,
    /// The exception code of an exception answer.
    pub exception: Option<u8>,
    /// Microseconds since the line's previous frame (the silence before a request, the
    /// device's latency before an answer).
    pub gap_us: Option<u64>,
}

/// What a frame stream remembers of each line: the last request (to decode its answer) and
/// when its last frame was.
#[derive(Debug, Default)]
pub struct FrameDecoder {
    lines: HashMap<String, (Option<(SlaveId, Request)>, u64)>,
}

impl FrameDecoder {
    /// Decodes one record of the frame log's format (`<line> <µs> <tx|rx> <hex>`); None for
    /// a record of another shape.
    pub fn decode(&mut self, record: &str) -> Option<FrameRow> {
        let mut parts = record.split(' ');
        let (line, at, dir, hex) = (parts.next()?, parts.next()?, parts.next()?, parts.next()?);
        let at_us = micros(at)?;
        let bytes = from_hex(hex)?;
        let (last_request, last_at) = self.lines.entry(line.to_string()).or_default();
        let gap_us = (*last_at > 0).then(|| at_us.saturating_sub(*last_at));
        *last_at = at_us;
        let mut row = FrameRow {
            line: line.to_string(),
            at: at.to_string(),
            at_us,
            dir: dir.to_string(),
            hex: hex.to_ascii_lowercase(),
            address: bytes.first().copied(),
            function: bytes.get(1).copied(),
            summary: String::new(),
            exception: None,
            gap_us,
        };
        match dir {
            "tx" => match decode_request(&bytes) {
                Ok((slave, request)) => {
                    row.summary = describe_request(&request);
                    *last_request = Some((slave, request));
                }
                Err(error) => {
                    row.summary = format!("not a request: {error}");
                    *last_request = None;
                }
            },
            _ => match last_request.take() {
                Some((slave, request)) => match decode_answer(slave, &request, &bytes) {
                    Ok(Answer::Normal(response)) => row.summary = describe_response(&response),
                    Ok(Answer::Exception(code)) => {
                        row.exception = Some(code.value());
                        row.summary = format!("{code}");
                    }
                    Err(error) => row.summary = format!("bad answer: {error}"),
                },
                None => row.summary = "answer to no request".to_string(),
            },
        }
        Some(row)
    }
}

/// `<seconds>.<six digits>` (the frame log's time) in microseconds.
fn micros(text: &str) -> Option<u64> {
    let (seconds, fraction) = text.split_once('.').unwrap_or((text, "0"));
    if fraction.len() > 6 || !fraction.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let fraction: u64 = format!("{fraction:0<6}").parse().ok()?;
    seconds
        .parse::<u64>()
        .ok()?
        .checked_mul(1_000_000)?
        .checked_add(fraction)
}

fn from_hex(text: &str) -> Option<Vec<u8>> {
    if text.len() % 2 != 0 {
        return None;
    }
    (0..text.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(text.get(i..i + 2)?, 16).ok())
        .collect()
}

/// A request in words, addresses in decimal and hex.
pub fn describe_request(request: &Request) -> String {
    let span = |what: &str, start: u16, quantity: u16| {
        format!("read {what} {start} (0x{start:04x}) ×{quantity}")
    };
    match request {
        Request::ReadCoils { start, quantity } => span("coils", *start, *quantity),
        Request::ReadDiscreteInputs { start, quantity } => span("inputs", *start, *quantity),
        Request::ReadHoldingRegisters { start, quantity } => span("holding", *start, *quantity),
        Request::ReadInputRegisters { start, quantity } => span("input regs", *start, *quantity),
        Request::WriteSingleCoil { address, value } => {
            format!(
                "write coil {address} (0x{address:04x}) = {}",
                if *value { "on" } else { "off" }
            )
        }
        Request::WriteSingleRegister { address, value } => {
            format!("write register {address} (0x{address:04x}) = {value}")
        }
        other => format!("{other:?}"),
    }
}

/// An answer in words.
pub fn describe_response(response: &ModbusResponse) -> String {
    if let Some(words) = response.registers() {
        let shown: Vec<String> = words.iter().take(8).map(u16::to_string).collect();
        let more = if words.len() > 8 { " …" } else { "" };
        return format!("{} registers: {}{more}", words.len(), shown.join(" "));
    }
    if let Some(bits) = response.bits() {
        let shown: String = bits
            .iter()
            .take(32)
            .map(|&on| if on { '1' } else { '0' })
            .collect();
        return format!("{} bits: {shown}", bits.len());
    }
    format!("echo {response:?}")
}

/// `GET /api/frames?line=…`: the line's frames (every line's without `line`), decoded, live.
pub async fn frame_events(
    State(console): State<Arc<Console>>,
    Query(filter): Query<FrameFilter>,
) -> Response {
    if let Some(line) = &filter.line {
        if console.line(line).is_none() {
            return refusal(StatusCode::NOT_FOUND, format!("no line named {line:?}"));
        }
    }
    let place = match stream_place(&console) {
        Ok(place) => place,
        Err(refused) => return *refused,
    };
    let records = console.frames.subscribe();
    let state = (records, FrameDecoder::default(), filter.line, place);
    let events = stream::unfold(
        state,
        |(mut records, mut decoder, line, place)| async move {
            loop {
                let event = match records.recv().await {
                    Ok(record) => {
                        let wanted = line.as_deref().map_or(true, |line| {
                            record
                                .strip_prefix(line)
                                .is_some_and(|r| r.starts_with(' '))
                        });
                        match decoder.decode(&record).filter(|_| wanted) {
                            Some(row) => json_event("frame", &row),
                            None => continue,
                        }
                    }
                    Err(RecvError::Lagged(missed)) => json_event("missed", &missed),
                    Err(RecvError::Closed) => return None,
                };
                return Some((Ok::<_, Infallible>(event), (records, decoder, line, place)));
            }
        },
    );
    sse(events)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_request_and_its_answer_decode_with_their_gap() {
        let mut decoder = FrameDecoder::default();
        let tx = decoder
            .decode("line-a 1.000000 tx 010310000006C108")
            .unwrap();
        assert_eq!(tx.address, Some(1));
        assert_eq!(tx.function, Some(3));
        assert_eq!(tx.summary, "read holding 4096 (0x1000) ×6");
        assert_eq!(tx.gap_us, None);
        let answer = rtu2mqtt_modbus::codec::encode_answer(
            1,
            &ModbusResponse::HoldingRegisters(vec![1, 2, 3, 4, 5, 6]),
        );
        let hex: String = answer.iter().map(|b| format!("{b:02X}")).collect();
        let rx = decoder
            .decode(&format!("line-a 1.020000 rx {hex}"))
            .unwrap();
        assert_eq!(rx.gap_us, Some(20_000));
        assert_eq!(rx.summary, "6 registers: 1 2 3 4 5 6");
        assert_eq!(rx.hex, hex.to_lowercase());
    }

    #[test]
    fn an_exception_answer_is_named() {
        let mut decoder = FrameDecoder::default();
        decoder.decode("l 1.000001 tx 010310000006c108").unwrap();
        // 01 83 02 + CRC
        let rx = decoder.decode("l 1.000002 rx 018302c0f1").unwrap();
        assert_eq!(rx.exception, Some(2));
        assert!(rx.summary.starts_with("exception 02"), "{}", rx.summary);
    }

    #[test]
    fn records_of_another_shape_are_skipped() {
        let mut decoder = FrameDecoder::default();
        assert!(decoder.decode("frame-log 3 records dropped").is_none());
        assert!(decoder.decode("l 1.0 tx 0g").is_none());
        assert!(decoder.decode("l 1.1234567 tx 01").is_none());
        assert!(decoder.decode("").is_none());
    }
}
