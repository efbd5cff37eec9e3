//! A profile's actions (`[[actions]]`): command interfaces written as one FC16 frame of fixed
//! words and parameters, optionally followed by the read of a result register whose codes the
//! profile names. This module owns what an action is ([`ActionInfo`] for the outside world,
//! [`ActionDef`] for planning), how a command payload becomes its parameter values (a bare
//! value for an action of one parameter, else a JSON object of named parameters) and the words
//! of its frame, and how a result code is judged. Planning the bus slot is `plan`'s.

use serde::Deserialize;
use serde_json::Value as Json;

use super::number;
use super::numeric::NumberType;
use super::registers::{RegisterLayout, WordOrder};
use super::rejection::Rejection;
use super::value::Value;
use rtu2mqtt_modbus::Request;

/// How a parameter is laid in the frame's registers (`type` of a parameter; `u16` when
/// unsaid).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub(crate) enum ParamType {
    /// One register, 0–65535.
    #[default]
    U16,
    /// One register, two's complement.
    I16,
    /// Two registers, in the parameter's word order.
    U32,
    /// Two registers, two's complement, in the parameter's word order.
    I32,
}

impl ParamType {
    /// The register number type of the same width and sign.
    pub(crate) fn number_type(self) -> NumberType {
        match self {
            Self::U16 => NumberType::U16,
            Self::I16 => NumberType::I16,
            Self::U32 => NumberType::U32,
            Self::I32 => NumberType::I32,
        }
    }
}

/// One parameter of an action as the outside world sees it: its name (a key of the command's
/// JSON object) and the integers it takes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ActionParam {
    /// The parameter's name, as `registers` and the command's JSON object name it.
    pub name: String,
    /// The parameter's `description`; empty when the profile gives none.
    pub description: String,
    /// The parameter's `unit`, if any.
    pub unit: Option<String>,
    /// The smallest value taken: the `range` low end, else the type's smallest.
    pub min: i128,
    /// The largest value taken: the `range` high end, else the type's largest.
    pub max: i128,
}

/// An action's result register as the outside world sees it: the codes the profile names and
/// those that mean success.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ActionResult {
    /// Bus address of the result register.
    pub address: u16,
    /// 3 (holding register, the default) or 4 (input register): how it is read.
    pub function: u8,
    /// The named codes (`0 = "ok"`), in code order.
    pub codes: Vec<(u16, String)>,
    /// The codes that mean the device carried the command out (`success`, default `[0]`).
    pub success: Vec<u16>,
}

impl ActionResult {
    /// The code as words: `3001 (invalid parameter)`, or `12 (a code the profile does not
    /// name)`.
    pub fn describe(&self, code: u16) -> String {
        match self.codes.iter().find(|(named, _)| *named == code) {
            Some((_, name)) => format!("{code} ({name})"),
            None => format!("{code} (a code the profile does not name)"),
        }
    }

    /// Whether `code` means success.
    pub fn is_success(&self, code: u16) -> bool {
        self.success.contains(&code)
    }
}

/// An action as the outside world sees it: what a command on `…/<name>/set` takes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ActionInfo {
    /// The action's `name`: a topic level next to the device's fields.
    pub name: String,
    /// The action's `description`; empty when the profile gives none.
    pub description: String,
    /// The parameters in the order the frame holds them. None: any payload runs the action;
    /// one: a bare value or a JSON object; several: a JSON object naming each.
    pub params: Vec<ActionParam>,
    /// The result register read after the frame, if the action has one; without it the
    /// acknowledged write is the whole outcome.
    pub result: Option<ActionResult>,
}

/// One word of an action's frame, as the profile lists them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Word {
    /// A fixed word (the command number, a reserved 0).
    Fixed(u16),
    /// The parameter at this index of [`ActionInfo::params`] (one or two registers).
    Param(usize),
}

/// How a parameter is written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct ParamLayout {
    pub(crate) ty: ParamType,
    pub(crate) words: WordOrder,
}

impl ParamLayout {
    /// The registers of `value` (inside the parameter's range, checked before).
    fn encode(self, value: i128) -> Vec<u16> {
        let ty = self.ty.number_type();
        let bits = ty.raw_bits_of(value).unwrap_or(0);
        let layout = RegisterLayout {
            words: self.words,
            ..RegisterLayout::default()
        };
        layout.split(bits, ty.registers())
    }
}

/// A compiled action: its face ([`ActionInfo`]), its frame and its result read.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ActionDef {
    pub(crate) info: ActionInfo,
    /// Bus address of the frame's first register.
    pub(crate) address: u16,
    pub(crate) words: Vec<Word>,
    /// Parallel to `info.params`.
    pub(crate) layouts: Vec<ParamLayout>,
    /// The read of the result register.
    pub(crate) result_read: Option<Request>,
}

impl ActionDef {
    /// The registers the frame writes with `values` (parallel to the parameters).
    pub(crate) fn frame(&self, values: &[i128]) -> Vec<u16> {
        let mut registers = Vec::new();
        for word in &self.words {
            match word {
                Word::Fixed(fixed) => registers.push(*fixed),
                Word::Param(index) => {
                    let (Some(layout), Some(value)) =
                        (self.layouts.get(*index), values.get(*index))
                    else {
                        continue;
                    };
                    registers.extend(layout.encode(*value));
                }
            }
        }
        registers
    }

    /// The FC16 write of the frame with `values`.
    pub(crate) fn write(&self, values: &[i128]) -> Request {
        Request::WriteMultipleRegisters {
            start: self.address,
            values: self.frame(values),
        }
    }
}

impl ActionInfo {
    /// The parameter values a command's `text` (trimmed, never empty) gives, in the order of
    /// [`ActionInfo::params`]: any text runs an action without parameters; an action of one
    /// parameter takes its bare value or a JSON object; several take a JSON object naming each
    /// of them. Unknown or missing names and values outside a parameter's range are refused.
    pub(crate) fn parse_payload(&self, text: &str) -> Result<Vec<i128>, Rejection> {
        let text = text.trim();
        match self.params.as_slice() {
            [] => Ok(Vec::new()),
            [only] if !text.starts_with('{') => Ok(vec![self.parse_value(only, text)?]),
            _ => self.parse_object(text),
        }
    }

    /// The values of a JSON object naming every parameter once.
    fn parse_object(&self, text: &str) -> Result<Vec<i128>, Rejection> {
        let object: serde_json::Map<String, Json> = serde_json::from_str(text).map_err(|_| {
            Rejection(format!(
                "{} takes a JSON object of its parameters ({}), like {}, got {}",
                self.name,
                self.param_names(),
                self.example_payload(),
                shown(text)
            ))
        })?;
        if let Some(unknown) = object
            .keys()
            .find(|key| !self.params.iter().any(|param| &param.name == *key))
        {
            return Err(Rejection(format!(
                "{} has no parameter {} (its parameters: {})",
                self.name,
                shown(unknown),
                self.param_names()
            )));
        }
        self.params
            .iter()
            .map(|param| {
                let Some(given) = object.get(&param.name) else {
                    return Err(Rejection(format!(
                        "{} needs its parameter `{}` (its parameters: {})",
                        self.name,
                        param.name,
                        self.param_names()
                    )));
                };
                let text = match given {
                    Json::Number(number) => number.to_string(),
                    Json::String(text) => text.clone(),
                    other => other.to_string(),
                };
                self.parse_value(param, &text)
            })
            .collect()
    }

    /// One parameter's value from its text, inside its range.
    fn parse_value(&self, param: &ActionParam, text: &str) -> Result<i128, Rejection> {
        let (min, max) = (param.min, param.max);
        match number::wide_integer(text) {
            Some(value) if (min..=max).contains(&value) => Ok(value),
            _ => Err(Rejection(format!(
                "{}: {} must be an integer {min}–{max}, got {}",
                self.name,
                param.name,
                shown(text)
            ))),
        }
    }

    /// The parameter names, comma separated.
    fn param_names(&self) -> String {
        let names: Vec<&str> = self.params.iter().map(|p| p.name.as_str()).collect();
        names.join(", ")
    }

    /// A payload that runs the action: `PRESS` without parameters, the lowest value of a
    /// single parameter, else a JSON object of every parameter at its lowest value.
    pub fn example_payload(&self) -> String {
        match self.params.as_slice() {
            [] => "PRESS".to_string(),
            [only] => only.min.to_string(),
            params => {
                let pairs: Vec<String> = params
                    .iter()
                    .map(|param| format!("\"{}\": {}", param.name, param.min))
                    .collect();
                format!("{{{}}}", pairs.join(", "))
            }
        }
    }

    /// The commanded values as one [`Value`]: ON for an action without parameters, the value
    /// of a single parameter, else the JSON object of them all.
    pub(crate) fn summary(&self, values: &[i128]) -> Value {
        match (self.params.as_slice(), values) {
            ([], _) => Value::Bool(true),
            ([_], [value]) => Value::Int(*value),
            (params, values) => {
                let object: serde_json::Map<String, Json> = params
                    .iter()
                    .zip(values)
                    .map(|(param, value)| {
                        // Parameters are at most 32 bits wide.
                        let number = i64::try_from(*value).unwrap_or(i64::MAX);
                        (param.name.clone(), Json::from(number))
                    })
                    .collect();
                Value::Text(Json::Object(object).to_string())
            }
        }
    }
}

/// A refused text as a refusal shows it: a number as sent, anything else quoted, shortened.
fn shown(text: &str) -> String {
    let short: String = text.trim().chars().take(40).collect();
    if number::is_number(&short) {
        short
    } else {
        format!("{short:?}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn param(name: &str, min: i128, max: i128) -> ActionParam {
        ActionParam {
            name: name.to_string(),
            description: String::new(),
            unit: None,
            min,
            max,
        }
    }

    fn action(params: Vec<ActionParam>) -> ActionInfo {
        ActionInfo {
            name: "set_tariff".to_string(),
            description: String::new(),
            params,
            result: None,
        }
    }

    fn refusal(info: &ActionInfo, text: &str) -> String {
        match info.parse_payload(text) {
            Ok(values) => panic!("{text:?} accepted as {values:?}"),
            Err(rejection) => rejection.0,
        }
    }

    #[test]
    fn an_action_without_parameters_runs_on_any_payload() {
        let press = action(Vec::new());
        for text in ["PRESS", "{}", "1", "go"] {
            assert_eq!(press.parse_payload(text), Ok(Vec::new()), "{text}");
        }
        assert_eq!(press.summary(&[]), Value::Bool(true));
        assert_eq!(press.example_payload(), "PRESS");
    }

    #[test]
    fn one_parameter_is_a_bare_value_or_an_object() {
        let tariff = action(vec![param("tariff", 1, 4)]);
        assert_eq!(tariff.parse_payload("2"), Ok(vec![2]));
        assert_eq!(tariff.parse_payload(" 3.0 "), Ok(vec![3]));
        assert_eq!(tariff.parse_payload(r#"{"tariff": 4}"#), Ok(vec![4]));
        assert_eq!(tariff.parse_payload(r#"{"tariff": "1"}"#), Ok(vec![1]));
        let range = "set_tariff: tariff must be an integer 1–4, got";
        for (text, reason) in [
            ("9", format!("{range} 9")),
            (r#"{"tariff": 9}"#, format!("{range} 9")),
            ("two", format!("{range} \"two\"")),
            (r#"{"tariff": true}"#, format!("{range} \"true\"")),
            (
                r#"{"tarif": 2}"#,
                "set_tariff has no parameter \"tarif\" (its parameters: tariff)".to_string(),
            ),
        ] {
            assert_eq!(refusal(&tariff, text), reason, "{text}");
        }
        assert_eq!(tariff.summary(&[2]), Value::Int(2));
        assert_eq!(tariff.example_payload(), "1");
    }

    #[test]
    fn several_parameters_take_an_object_naming_each() {
        let clock = action(vec![param("hour", 0, 23), param("minute", 0, 59)]);
        assert_eq!(
            clock.parse_payload(r#"{"minute": 30, "hour": 7}"#),
            Ok(vec![7, 30])
        );
        assert_eq!(
            refusal(&clock, r#"{"hour": 7}"#),
            "set_tariff needs its parameter `minute` (its parameters: hour, minute)"
        );
        assert_eq!(
            refusal(&clock, "7"),
            "set_tariff takes a JSON object of its parameters (hour, minute), like \
             {\"hour\": 0, \"minute\": 0}, got 7"
        );
        assert_eq!(
            refusal(&clock, r#"{"hour": 7, "minute": 60}"#),
            "set_tariff: minute must be an integer 0–59, got 60"
        );
        assert_eq!(
            clock.summary(&[7, 30]),
            Value::Text(r#"{"hour":7,"minute":30}"#.to_string())
        );
    }

    #[test]
    fn a_frame_lays_fixed_words_and_parameters_in_order() {
        let def = ActionDef {
            info: action(vec![param("tariff", 1, 4), param("limit", -70_000, 70_000)]),
            address: 5249,
            words: vec![
                Word::Fixed(2060),
                Word::Fixed(0),
                Word::Param(0),
                Word::Param(1),
            ],
            layouts: vec![
                ParamLayout {
                    ty: ParamType::U16,
                    words: WordOrder::HighFirst,
                },
                ParamLayout {
                    ty: ParamType::I32,
                    words: WordOrder::LowFirst,
                },
            ],
            result_read: None,
        };
        assert_eq!(
            def.write(&[2, -70_000]),
            Request::WriteMultipleRegisters {
                start: 5249,
                values: vec![2060, 0, 2, 0xEE90, 0xFFFE],
            }
        );
    }

    #[test]
    fn result_codes_read_as_their_names() {
        let result = ActionResult {
            address: 5375,
            function: 3,
            codes: vec![(0, "ok".into()), (3000, "invalid command".into())],
            success: vec![0],
        };
        assert_eq!(result.describe(3000), "3000 (invalid command)");
        assert_eq!(result.describe(7), "7 (a code the profile does not name)");
        assert!(result.is_success(0));
        assert!(!result.is_success(3000));
    }
}
