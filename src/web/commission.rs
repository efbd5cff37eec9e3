//! Commissioning through the running line: a scan of addresses (each device found asked what
//! it is, with the built-in profile that fits and the configuration to add), a read shown
//! every way, and a profile tried against a device, all sent as slots of the line's scheduler
//! (between its polls, one request per slot, a due poll between two of them, the line's t3.5
//! kept), so the plant keeps running. Reads only: nothing here builds a write. One run at a
//! time.

use std::sync::Arc;

use axum::extract::{Form, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::{Deserialize, Serialize};
use tokio::sync::oneshot;

use super::decode::{self, Registers};
use super::{refusal, Console};
use crate::bus::serve::ClientRequest;
use crate::config::suggestion::{devices_to_add, Candidates, SuggestedDevice};
use rtu2mqtt_modbus::{ExceptionCode, Reply, Request, Response as ModbusResponse, SlaveId};
use rtu2mqtt_profile::identify::{Heard, Identifier, Identity};
use rtu2mqtt_profile::topic_levels::reserved_name_problem;
use rtu2mqtt_profile::Profile;

/// Addresses one scan may probe: every address a line can carry.
pub const MAX_SCAN: usize = 247;

/// Why a request got no answer of the device: the line had no slot for it, or the gateway
/// answered in the device's place.
fn is_silence(code: ExceptionCode) -> bool {
    matches!(
        code,
        ExceptionCode::GatewayPathUnavailable | ExceptionCode::GatewayTargetFailedToRespond
    )
}

/// Sends `request` to `unit` as a slot of `line` and waits for the reply.
async fn ask(
    console: &Console,
    line: &str,
    unit: SlaveId,
    request: Request,
    probe: bool,
) -> Result<Reply, Response> {
    let Some(handle) = console.line(line) else {
        return Err(refusal(
            StatusCode::NOT_FOUND,
            format!("no line named {line:?}"),
        ));
    };
    let Some(requests) = &handle.requests_tx else {
        return Err(refusal(
            StatusCode::SERVICE_UNAVAILABLE,
            "this line takes no commissioning reads",
        ));
    };
    let (reply, answer) = oneshot::channel();
    let slot = ClientRequest {
        client: "console".to_string(),
        unit,
        request,
        probe,
        reply,
    };
    if requests.send(Box::new(slot)).await.is_err() {
        return Err(refusal(
            StatusCode::SERVICE_UNAVAILABLE,
            format!("line {line} has stopped"),
        ));
    }
    answer.await.map_err(|_| {
        refusal(
            StatusCode::SERVICE_UNAVAILABLE,
            format!("line {line} stopped before it answered"),
        )
    })
}

/// The scan form: `line`, and `addresses` as `1-5,129`.
#[derive(Debug, Deserialize)]
pub struct ScanForm {
    pub line: String,
    pub addresses: String,
}

/// One address that answered.
#[derive(Debug, Serialize)]
pub struct ScanRow {
    pub address: SlaveId,
    /// One entry per read function probed: `FC03 ok`, `FC03 exception 02 (…)`.
    pub answers: Vec<String>,
    /// The configured device at this address on the line, if any.
    pub device: Option<String>,
    /// What the device says it is, and the profile that fits.
    pub identification: ScanIdentity,
}

/// What a device found says it is (absent parts `None`), and the profile that fits.
#[derive(Debug, Serialize)]
pub struct ScanIdentity {
    /// How it answered Read Device Identification: `ok`, the exception, `no answer`.
    pub fc43: String,
    pub vendor: Option<String>,
    pub product_code: Option<String>,
    pub revision: Option<String>,
    /// Its SunSpec map: `40000: models 1, 103`.
    pub sunspec: Option<String>,
    /// The built-in profile that fits, `unknown`, or the SunSpec command to run.
    pub profile: String,
}

impl ScanIdentity {
    fn of(identity: &Identity, candidates: &Candidates) -> Self {
        let id = &identity.device_id;
        Self {
            fc43: id.status(),
            vendor: id.vendor(),
            product_code: id.product_code(),
            revision: id.revision(),
            sunspec: identity.sunspec.as_ref().map(ToString::to_string),
            profile: candidates.choose(identity).describe(),
        }
    }
}

/// What a scan found.
#[derive(Debug, Serialize)]
pub struct ScanReport {
    pub line: String,
    pub scanned: usize,
    pub found: Vec<ScanRow>,
    /// The `[[lines.devices]]` tables of the devices found that the line does not have yet;
    /// `None` when it has them all.
    pub configuration: Option<String>,
}

fn read_request(function: u8, start: u16, quantity: u16) -> Option<Request> {
    Some(match function {
        1 => Request::ReadCoils { start, quantity },
        2 => Request::ReadDiscreteInputs { start, quantity },
        3 => Request::ReadHoldingRegisters { start, quantity },
        4 => Request::ReadInputRegisters { start, quantity },
        _ => return None,
    })
}

fn answer_word(function: u8, reply: &Reply) -> String {
    match reply {
        Ok(_) => format!("FC{function:02} ok"),
        Err(code) => format!("FC{function:02} {code}"),
    }
}

/// Asks the device at `unit` what it is, through the line (reads only).
async fn identify(console: &Console, line: &str, unit: SlaveId) -> Result<Identity, Response> {
    let mut identifier = Identifier::new();
    while let Some(request) = identifier.next_request() {
        let heard = match ask(console, line, unit, request, true).await? {
            Ok(answer) => Heard::Answer(answer),
            Err(code) if is_silence(code) => Heard::Nothing,
            Err(code) => Heard::Exception(code),
        };
        identifier.hear(heard);
    }
    Ok(identifier.identity())
}

/// `POST /api/scan`: probes each address with FC03 (and FC04, FC01 where FC03 is refused),
/// once each, through the line. Only a device's own answer counts: silence, and a gateway's
/// 0A/0B in its place, do not. Each device found is asked what it is.
pub async fn scan(State(console): State<Arc<Console>>, Form(form): Form<ScanForm>) -> Response {
    let addresses = match crate::cli::parse_addresses(&form.addresses) {
        Ok(addresses) if addresses.len() <= MAX_SCAN => addresses,
        Ok(addresses) => {
            return refusal(
                StatusCode::BAD_REQUEST,
                format!(
                    "{} addresses: a scan takes at most {MAX_SCAN}",
                    addresses.len()
                ),
            )
        }
        Err(reason) => return refusal(StatusCode::BAD_REQUEST, reason),
    };
    if console.line(&form.line).is_none() {
        return refusal(
            StatusCode::NOT_FOUND,
            format!("no line named {:?}", form.line),
        );
    }
    let _one_at_a_time = console.commissioning.lock().await;
    tracing::info!(line = %form.line, addresses = %form.addresses, via = "console", "scan");
    let candidates = Candidates::built_in();
    let mut to_add = Vec::new();
    let mut found = Vec::new();
    for &address in &addresses {
        let mut answers = Vec::new();
        for function in [3u8, 4, 1] {
            let Some(request) = read_request(function, 0, 1) else {
                continue;
            };
            let reply = match ask(&console, &form.line, address, request, true).await {
                Ok(reply) => reply,
                Err(refused) => return refused,
            };
            if matches!(reply, Err(code) if is_silence(code)) {
                break;
            }
            let refused = reply.is_err();
            answers.push(answer_word(function, &reply));
            if !refused {
                break;
            }
        }
        if !answers.is_empty() {
            let device = console
                .layout()
                .model
                .devices
                .iter()
                .find(|d| d.line == form.line && d.address == address)
                .map(|d| d.name.clone());
            let identity = match identify(&console, &form.line, address).await {
                Ok(identity) => identity,
                Err(refused) => return refused,
            };
            if device.is_none() {
                to_add.push(SuggestedDevice {
                    address,
                    name: None,
                    profile: candidates.choose(&identity),
                });
            }
            found.push(ScanRow {
                address,
                answers,
                device,
                identification: ScanIdentity::of(&identity, &candidates),
            });
        }
    }
    Json(ScanReport {
        configuration: (!to_add.is_empty()).then(|| devices_to_add(&form.line, &to_add)),
        line: form.line,
        scanned: addresses.len(),
        found,
    })
    .into_response()
}

/// The read form.
#[derive(Debug, Deserialize)]
pub struct ReadForm {
    pub line: String,
    pub address: String,
    /// 1–4.
    pub function: u8,
    pub start: String,
    pub count: u16,
}

/// A read's answer, every way.
#[derive(Debug, Serialize)]
pub struct ReadReport {
    pub request: String,
    /// An exception in words, when the device refused.
    pub exception: Option<String>,
    pub registers: Option<Registers>,
    pub bits: Option<Vec<bool>>,
}

/// A device's address from a form: 1–255, decimal or `0x` hex (0 is the broadcast, which no
/// device answers).
fn device_address(text: &str) -> Result<SlaveId, String> {
    match crate::cli::parse_address(text.trim())? {
        0 => Err("address 0 is the broadcast: nothing answers it".to_string()),
        address => Ok(address),
    }
}

/// A bus address as a manual writes it: decimal, or hex with `0x`.
fn parse_register(text: &str) -> Result<u16, String> {
    let text = text.trim();
    let parsed = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u16::from_str_radix(hex, 16),
        None => text.parse::<u16>(),
    };
    parsed.map_err(|_| format!("`{text}` is not a register address 0–65535 (decimal or 0x hex)"))
}

/// `POST /api/read`: one read through the line, shown every way.
pub async fn read(State(console): State<Arc<Console>>, Form(form): Form<ReadForm>) -> Response {
    let address = match device_address(&form.address) {
        Ok(address) => address,
        Err(reason) => return refusal(StatusCode::BAD_REQUEST, reason),
    };
    let start = match parse_register(&form.start) {
        Ok(start) => start,
        Err(reason) => return refusal(StatusCode::BAD_REQUEST, reason),
    };
    let limit = if form.function <= 2 { 2000 } else { 125 };
    if form.count == 0 || form.count > limit {
        return refusal(
            StatusCode::BAD_REQUEST,
            format!(
                "count {}: 1 to {limit} for function {}",
                form.count, form.function
            ),
        );
    }
    let Some(request) = read_request(form.function, start, form.count) else {
        return refusal(
            StatusCode::BAD_REQUEST,
            format!(
                "function {}: only the read functions 1, 2, 3 and 4",
                form.function
            ),
        );
    };
    if start.checked_add(form.count - 1).is_none() {
        return refusal(StatusCode::BAD_REQUEST, "the read runs past address 65535");
    }
    let _one_at_a_time = console.commissioning.lock().await;
    tracing::info!(line = %form.line, address, ?request, via = "console", "read");
    let described = super::live::describe_request(&request);
    let reply = match ask(&console, &form.line, address, request, false).await {
        Ok(reply) => reply,
        Err(refused) => return refused,
    };
    let report = match reply {
        Ok(response) => ReadReport {
            request: described,
            exception: None,
            registers: response
                .registers()
                .map(|words| decode::registers(start, words)),
            bits: response.bits().map(<[bool]>::to_vec),
        },
        Err(code) if is_silence(code) => {
            return refusal(
                StatusCode::GATEWAY_TIMEOUT,
                format!("address {address} did not answer on line {}", form.line),
            )
        }
        Err(code) => ReadReport {
            request: described,
            exception: Some(format!("{code}")),
            registers: None,
            bits: None,
        },
    };
    Json(report).into_response()
}

/// The try-out form: a profile's TOML and where the device is.
#[derive(Debug, Deserialize)]
pub struct TryoutForm {
    pub line: String,
    pub address: String,
    pub profile: String,
}

/// One field as the profile decodes it from the device's answer.
#[derive(Debug, Serialize)]
pub struct TryoutField {
    pub field: String,
    pub label: String,
    pub unit: Option<String>,
    pub block: String,
    /// The MQTT payload it would be published as.
    pub value: Option<String>,
    /// Why there is none.
    pub error: Option<String>,
}

/// The try-out's verdict.
#[derive(Debug, Serialize)]
pub struct TryoutReport {
    /// The profile is valid: its blocks were read.
    pub valid: bool,
    /// Every problem `check` would name, with its place.
    pub problems: Vec<String>,
    pub name: Option<String>,
    pub fields: Vec<TryoutField>,
}

/// The profile's problems, as `check` names them.
fn verdict(text: &str) -> Result<Profile, Vec<String>> {
    let profile = Profile::from_toml(text, "the pasted profile")
        .map_err(|errors| errors.0.iter().map(ToString::to_string).collect::<Vec<_>>())?;
    let reserved: Vec<String> = profile
        .fields()
        .iter()
        .filter_map(|field| {
            reserved_name_problem(&field.name)
                .map(|problem| format!("the pasted profile: field {}: {problem}", field.name))
        })
        .collect();
    if reserved.is_empty() {
        Ok(profile)
    } else {
        Err(reserved)
    }
}

/// `POST /api/tryout`: checks the pasted profile and reads its blocks once from the device,
/// decoded as the gateway would publish them; the running configuration is not touched.
pub async fn tryout(State(console): State<Arc<Console>>, Form(form): Form<TryoutForm>) -> Response {
    let address = match device_address(&form.address) {
        Ok(address) => address,
        Err(reason) => return refusal(StatusCode::BAD_REQUEST, reason),
    };
    if console.line(&form.line).is_none() {
        return refusal(
            StatusCode::NOT_FOUND,
            format!("no line named {:?}", form.line),
        );
    }
    let profile = match verdict(&form.profile) {
        Ok(profile) => profile,
        Err(problems) => {
            return Json(TryoutReport {
                valid: false,
                problems,
                name: None,
                fields: Vec::new(),
            })
            .into_response()
        }
    };
    let _one_at_a_time = console.commissioning.lock().await;
    tracing::info!(line = %form.line, address, profile = %profile.name(), via = "console", "profile try-out");
    let mut fields = Vec::new();
    for (index, block) in profile.read_blocks().iter().enumerate() {
        let reply = match ask(&console, &form.line, address, block.request.clone(), false).await {
            Ok(reply) => reply,
            Err(refused) => return refused,
        };
        let answer: Result<ModbusResponse, String> = match reply {
            Ok(response) => Ok(response),
            Err(code) if is_silence(code) => Err("no answer".to_string()),
            Err(code) => Err(format!("{code}")),
        };
        let names = profile.block_fields(index);
        match answer {
            Ok(response) => {
                for reading in profile.decode_block(index, &response) {
                    let info = profile.field(&reading.field);
                    let (value, error) = match reading.value {
                        Ok(value) if value.is_available() => (Some(value.to_text()), None),
                        Ok(_) => (None, Some("the device has no value here".to_string())),
                        Err(error) => (None, Some(error.to_string())),
                    };
                    fields.push(TryoutField {
                        label: info.map_or_else(
                            || reading.field.clone(),
                            crate::bridge::core::discovery::entity_name,
                        ),
                        unit: info.and_then(|i| i.unit.clone()),
                        field: reading.field,
                        block: block.name.clone(),
                        value,
                        error,
                    });
                }
            }
            Err(why) => {
                for name in names {
                    let info = profile.field(name);
                    fields.push(TryoutField {
                        field: name.to_string(),
                        label: info.map_or_else(
                            || name.to_string(),
                            crate::bridge::core::discovery::entity_name,
                        ),
                        unit: info.and_then(|i| i.unit.clone()),
                        block: block.name.clone(),
                        value: None,
                        error: Some(why.clone()),
                    });
                }
            }
        }
    }
    Json(TryoutReport {
        valid: true,
        problems: Vec::new(),
        name: Some(profile.name().to_string()),
        fields,
    })
    .into_response()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_profile_s_problems_come_with_their_places() {
        let problems = verdict("name = \"x\"\n[[blocks]]\nname = 1\n").unwrap_err();
        assert!(!problems.is_empty());
        assert!(
            problems[0].starts_with("the pasted profile"),
            "{problems:?}"
        );
    }

    #[test]
    fn register_addresses_read_as_a_manual_writes_them() {
        assert_eq!(parse_register("4096"), Ok(4096));
        assert_eq!(parse_register("0x1000"), Ok(4096));
        assert!(parse_register("65536").is_err());
        assert!(parse_register("x").is_err());
    }
}
