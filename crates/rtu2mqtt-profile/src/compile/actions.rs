//! The `[[actions]]` of a profile: each command interface checked (its name against the fields
//! and the contract, its words and parameters, its frame against the device's write limit and
//! the address space, its result register and codes) and compiled into an
//! [`ActionDef`](crate::action::ActionDef).

use std::collections::HashSet;

use super::blocks::bus_address;
use super::problems::Problems;
use crate::action::{ActionDef, ActionInfo, ActionParam, ActionResult, ParamLayout, Word};
use crate::field::FieldInfo;
use crate::format::{ActionSection, ActionWord, ParamSection, ResultSection};
use crate::model::Limits;
use crate::register_numbers::RegisterNumbers;
use crate::topic_levels::{reserved_name_problem, MAX_NAME_LEN};
use rtu2mqtt_modbus::Request;

/// The actions, in file order. A refused action is left out; every problem is added.
pub(super) fn build_actions(
    sections: &[ActionSection],
    fields: &[FieldInfo],
    limits: &Limits,
    numbers: RegisterNumbers,
    problems: &mut Problems<'_>,
) -> Vec<ActionDef> {
    let mut seen = HashSet::new();
    let mut actions = Vec::new();
    for (i, section) in sections.iter().enumerate() {
        let place = format!("actions[{i}] ({})", section.name);
        let before = problems.count();
        check_name(&section.name, &place, problems);
        if fields.iter().any(|field| field.name == section.name) {
            problems.add(
                format!("{place}.name"),
                format!(
                    "field `{}` has this name already: an action is a topic level next to the \
                     fields",
                    section.name
                ),
            );
        }
        if !seen.insert(section.name.as_str()) {
            problems.add(
                format!("{place}.name"),
                format!("duplicate action name `{}`", section.name),
            );
        }
        let action = build_action(section, limits, numbers, &place, problems);
        if problems.count() == before {
            actions.push(action);
        }
    }
    actions
}

/// A name for a topic level: lower-case letters, digits or `_`, short, not reserved.
fn check_name(name: &str, place: &str, problems: &mut Problems<'_>) {
    let topic_level = !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
    if !topic_level {
        problems.add(
            format!("{place}.name"),
            "an action name must be lower-case letters, digits or `_`",
        );
    } else if name.len() > MAX_NAME_LEN {
        problems.add(
            format!("{place}.name"),
            format!("an action name is a topic level of at most {MAX_NAME_LEN} characters"),
        );
    }
    if let Some(reason) = reserved_name_problem(name) {
        problems.add(format!("{place}.name"), reason);
    }
}

/// One action, whatever its problems (they are added; the caller keeps only an action
/// without any).
fn build_action(
    section: &ActionSection,
    limits: &Limits,
    numbers: RegisterNumbers,
    place: &str,
    problems: &mut Problems<'_>,
) -> ActionDef {
    let address = bus_address(
        numbers,
        section.address,
        16,
        &format!("{place}.address"),
        problems,
    );
    let (words, param_names) = build_words(section, place, problems);
    let (params, layouts): (Vec<ActionParam>, Vec<ParamLayout>) = param_names
        .iter()
        .map(|name| {
            let unsaid = ParamSection::default();
            let keys = section.params.get(name.as_str()).unwrap_or(&unsaid);
            build_param(name, keys, &format!("{place}.params.{name}"), problems)
        })
        .unzip();
    for name in section.params.keys() {
        if !param_names.contains(name) {
            problems.add(
                format!("{place}.params.{name}"),
                format!("`{name}` is in no place of `registers`"),
            );
        }
    }
    let count: u32 = words
        .iter()
        .map(|word| match word {
            Word::Fixed(_) => 1,
            Word::Param(index) => layouts
                .get(*index)
                .map_or(1, |layout| layout.ty.number_type().registers())
                .into(),
        })
        .sum();
    check_frame(address, count, limits, place, problems);
    let (result, result_read) = match &section.result {
        Some(keys) => {
            let (result, read) = build_result(keys, numbers, &format!("{place}.result"), problems);
            (Some(result), Some(read))
        }
        None => (None, None),
    };
    ActionDef {
        info: ActionInfo {
            name: section.name.clone(),
            description: section.description.clone(),
            params,
            result,
        },
        address,
        words,
        layouts,
        result_read,
    }
}

/// The frame's words and the parameter names in the order they first appear.
fn build_words(
    section: &ActionSection,
    place: &str,
    problems: &mut Problems<'_>,
) -> (Vec<Word>, Vec<String>) {
    let mut words = Vec::new();
    let mut names: Vec<String> = Vec::new();
    if section.registers.is_empty() {
        problems.add(
            format!("{place}.registers"),
            "an action writes at least one register",
        );
    }
    for (i, entry) in section.registers.iter().enumerate() {
        let at = format!("{place}.registers[{i}]");
        match entry {
            ActionWord::Fixed(value) => match u16::try_from(*value) {
                Ok(word) => words.push(Word::Fixed(word)),
                Err(_) => problems.add(at, format!("{value} is no register value (0–65535)")),
            },
            ActionWord::Param(name) => {
                if names.contains(name) {
                    problems.add(at, format!("parameter `{name}` has a place already"));
                    continue;
                }
                if !is_param_name(name) {
                    problems.add(
                        at,
                        format!(
                            "`{name}` is no parameter name (lower-case letters, digits or `_`)"
                        ),
                    );
                    continue;
                }
                words.push(Word::Param(names.len()));
                names.push(name.clone());
            }
        }
    }
    (words, names)
}

fn is_param_name(name: &str) -> bool {
    name.starts_with(|c: char| c.is_ascii_lowercase())
        && name
            .chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
}

/// A parameter's face and layout: its range inside its type's (problems added).
fn build_param(
    name: &str,
    keys: &ParamSection,
    place: &str,
    problems: &mut Problems<'_>,
) -> (ActionParam, ParamLayout) {
    let ty = keys.ty.number_type();
    // Every parameter type is an integer type.
    let (low, high) = ty.raw_range().unwrap_or_default();
    let (min, max) = match keys.range {
        Some([min, max]) => (i128::from(min), i128::from(max)),
        None => (low, high),
    };
    if min > max || min < low || max > high {
        problems.add(
            format!("{place}.range"),
            format!("[{min}, {max}] is no range inside the parameter's type ({low}–{high})"),
        );
    }
    if keys.word_order.is_some() && ty.registers() == 1 {
        problems.add(
            format!("{place}.word_order"),
            "a one-register parameter has no word order",
        );
    }
    let param = ActionParam {
        name: name.to_string(),
        description: keys.description.clone(),
        unit: keys.unit.clone(),
        min,
        max,
    };
    let layout = ParamLayout {
        ty: keys.ty,
        words: keys.word_order.unwrap_or_default(),
    };
    (param, layout)
}

/// The frame fits one FC16 of the device and the address space.
fn check_frame(
    address: u16,
    count: u32,
    limits: &Limits,
    place: &str,
    problems: &mut Problems<'_>,
) {
    let limit = limits.max_write_registers;
    if count > u32::from(limit) {
        problems.add(
            format!("{place}.registers"),
            format!("{count} registers exceed the device's write limit {limit}"),
        );
    }
    if u32::from(address) + count > 0x1_0000 {
        problems.add(
            format!("{place}.address"),
            format!("{count} registers from {address} go past the last register address (65535)"),
        );
    }
}

/// The result register's read and the codes it is judged by (problems added).
fn build_result(
    keys: &ResultSection,
    numbers: RegisterNumbers,
    place: &str,
    problems: &mut Problems<'_>,
) -> (ActionResult, Request) {
    let address = bus_address(
        numbers,
        keys.address,
        keys.function,
        &format!("{place}.address"),
        problems,
    );
    let read = match keys.function {
        3 => Request::ReadHoldingRegisters {
            start: address,
            quantity: 1,
        },
        4 => Request::ReadInputRegisters {
            start: address,
            quantity: 1,
        },
        other => {
            problems.add(
                format!("{place}.function"),
                format!("a result register is read with function 3 or 4, not {other}"),
            );
            Request::ReadHoldingRegisters {
                start: address,
                quantity: 1,
            }
        }
    };
    let mut codes = Vec::new();
    for (key, name) in &keys.codes {
        match parse_code(key) {
            Some(code) if !name.trim().is_empty() => codes.push((code, name.clone())),
            Some(_) => problems.add(
                format!("{place}.codes.{key}"),
                "a code's name says what it means",
            ),
            None => problems.add(
                format!("{place}.codes.{key}"),
                format!("`{key}` is no register value (0–65535)"),
            ),
        }
    }
    codes.sort_unstable();
    let success = match &keys.success {
        None => vec![0],
        Some(list) if list.is_empty() => {
            problems.add(
                format!("{place}.success"),
                "at least one code means success",
            );
            Vec::new()
        }
        Some(list) => list
            .iter()
            .filter_map(|code| {
                let word = u16::try_from(*code).ok();
                if word.is_none() {
                    problems.add(
                        format!("{place}.success"),
                        format!("{code} is no register value (0–65535)"),
                    );
                }
                word
            })
            .collect(),
    };
    let result = ActionResult {
        address,
        function: keys.function,
        codes,
        success,
    };
    (result, read)
}

/// A code written as a TOML key: decimal or `0x` hex.
fn parse_code(key: &str) -> Option<u16> {
    match key.strip_prefix("0x") {
        Some(hex) => u16::from_str_radix(hex, 16).ok(),
        None => key.parse().ok(),
    }
}

#[cfg(test)]
mod tests {
    use crate::action::Word;
    use crate::compile::compile;

    const DEVICE: &str = "[device]\nname = \"t\"\nmanufacturer = \"m\"\nmodel = \"x\"\n\
        [line]\nmax_write_registers = 6\n\
        [[blocks]]\nname = \"hold\"\nfunction = 3\nstart = 0\ncount = 2\n\
        [[fields]]\nname = \"tariff\"\nblock = \"hold\"\noffset = 0\ncodec = { type = \"u16\" }\n";

    fn problems(actions: &str) -> Vec<(String, String)> {
        match compile(&format!("{DEVICE}{actions}"), "p") {
            Ok(_) => Vec::new(),
            Err(errors) => errors.0.into_iter().map(|e| (e.place, e.reason)).collect(),
        }
    }

    #[test]
    fn the_contract_compiles_to_its_frame_and_result() {
        let compiled = compile(
            &format!(
                "{DEVICE}[[actions]]\nname = \"set_tariff\"\naddress = 5249\n\
                 registers = [2060, 0, \"rate\"]\nparams = {{ rate = {{ range = [1, 4] }} }}\n\
                 result = {{ address = 5375, codes = {{ 0 = \"ok\", 3000 = \"invalid command\" }} }}\n\
                 [[actions]]\nname = \"reset_energy\"\naddress = 0x1000\nregisters = [1, \"key\"]\n\
                 params = {{ key = {{ type = \"u32\", word_order = \"low_first\" }} }}\n"
            ),
            "p",
        )
        .expect("a valid profile");
        let [tariff, reset] = compiled.actions.as_slice() else {
            panic!("two actions: {:?}", compiled.actions);
        };
        assert_eq!(tariff.address, 5249);
        assert_eq!(
            tariff.words,
            [Word::Fixed(2060), Word::Fixed(0), Word::Param(0)]
        );
        assert_eq!(
            (tariff.info.params[0].min, tariff.info.params[0].max),
            (1, 4)
        );
        let result = tariff.info.result.as_ref().expect("a result register");
        assert_eq!(
            result.codes,
            [(0, "ok".to_string()), (3000, "invalid command".to_string())]
        );
        assert_eq!(result.success, [0]);
        assert_eq!(reset.frame(&[0x0001_0002]), [1, 2, 1]);
        assert_eq!(reset.info.params[0].max, i128::from(u32::MAX));
        assert!(reset.info.result.is_none());
    }

    #[test]
    fn an_action_is_refused_at_its_keys_with_the_reason() {
        assert_eq!(
            problems(
                "[[actions]]\nname = \"tariff\"\naddress = 10\n\
                 registers = [70000, \"a\", \"a\"]\nparams = { a = { range = [1, 70000] } }\n"
            ),
            [
                (
                    "p: actions[0] (tariff).name".to_string(),
                    "field `tariff` has this name already: an action is a topic level next to \
                     the fields"
                        .to_string()
                ),
                (
                    "p: actions[0] (tariff).registers[0]".into(),
                    "70000 is no register value (0–65535)".into()
                ),
                (
                    "p: actions[0] (tariff).registers[2]".into(),
                    "parameter `a` has a place already".into()
                ),
                (
                    "p: actions[0] (tariff).params.a.range".into(),
                    "[1, 70000] is no range inside the parameter's type (0–65535)".into()
                ),
            ]
        );
        assert_eq!(
            problems(
                "[[actions]]\nname = \"set\"\naddress = 65534\nregisters = [1, 2, \"b\", 4, 5, 6, 7]\n\
                 params = { c = {} }\n\
                 result = { address = 1, function = 6, codes = { x = \"?\" }, success = [] }\n"
            ),
            [
                (
                    "p: actions[0] (set).name".to_string(),
                    "\"set\" is reserved: the gateway uses it as a topic level of its own \
                     (reserved: availability, gateway, history, refresh, result, set, stats, \
                     status); call it e.g. \"device_set\""
                        .to_string()
                ),
                (
                    "p: actions[0] (set).params.c".into(),
                    "`c` is in no place of `registers`".into()
                ),
                (
                    "p: actions[0] (set).registers".into(),
                    "7 registers exceed the device's write limit 6".into()
                ),
                (
                    "p: actions[0] (set).address".into(),
                    "7 registers from 65534 go past the last register address (65535)".into()
                ),
                (
                    "p: actions[0] (set).result.function".into(),
                    "a result register is read with function 3 or 4, not 6".into()
                ),
                (
                    "p: actions[0] (set).result.codes.x".into(),
                    "`x` is no register value (0–65535)".into()
                ),
                (
                    "p: actions[0] (set).result.success".into(),
                    "at least one code means success".into()
                ),
            ]
        );
    }

    #[test]
    fn two_actions_of_one_name_and_a_name_no_topic_can_carry_are_refused() {
        assert_eq!(
            problems(
                "[[actions]]\nname = \"go\"\naddress = 1\nregisters = [1]\n\
                 [[actions]]\nname = \"go\"\naddress = 2\nregisters = [1]\n\
                 [[actions]]\nname = \"Go-Now\"\naddress = 3\nregisters = [1, \"X\"]\n"
            ),
            [
                (
                    "p: actions[1] (go).name".to_string(),
                    "duplicate action name `go`".to_string()
                ),
                (
                    "p: actions[2] (Go-Now).name".into(),
                    "an action name must be lower-case letters, digits or `_`".into()
                ),
                (
                    "p: actions[2] (Go-Now).registers[1]".into(),
                    "`X` is no parameter name (lower-case letters, digits or `_`)".into()
                ),
            ]
        );
    }

    #[test]
    fn an_actions_addresses_are_in_the_profiles_register_numbers() {
        let one_based = DEVICE
            .replace(
                "model = \"x\"",
                "model = \"x\"\nregister_numbers = \"one_based\"",
            )
            .replace("start = 0", "start = 1");
        let compiled = compile(
            &format!(
                "{one_based}[[actions]]\nname = \"set_tariff\"\naddress = 5250\n\
                 registers = [2060, 0, \"rate\"]\nresult = {{ address = 5376 }}\n"
            ),
            "p",
        )
        .expect("a valid profile");
        let tariff = &compiled.actions[0];
        assert_eq!(tariff.address, 5249);
        assert_eq!(
            tariff.result_read,
            Some(rtu2mqtt_modbus::Request::ReadHoldingRegisters {
                start: 5375,
                quantity: 1
            })
        );
        let refused = compile(
            &format!("{one_based}[[actions]]\nname = \"go\"\naddress = 0\nregisters = [1]\n"),
            "p",
        )
        .expect_err("register number 0");
        assert_eq!(refused.0[0].place, "p: actions[0] (go).address");
    }
}
