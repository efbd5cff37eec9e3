//! Reading the configuration's [`Tree`] into [`RawConfig`] with serde, strictly, with every
//! problem placed and worded for the user (`lines[0].baud: "fast" is not an integer`).
//! `serde_path_to_error` says where a value is wrong, `serde_ignored` lists every unknown key
//! in one pass, and the tree's error type ([`Complaint`]) keeps what serde's visitors said so
//! that it can be put in our words. A problem does not end the reading: the wrong value is
//! taken out (or stood in for) and the rest is read again, so that every problem is found at
//! once and the rest can still be validated.

use std::fmt;

use serde::de;
use serde_value::{Value, ValueDeserializer};

use super::problem::{Problem, Problems};
use super::schema::{keys_at, shape_at, RawConfig, Shape};
use super::tree::{place_text, Step, Tree};

/// What reading found: every problem of the reading stage (unknown keys, wrong types, missing
/// keys), and the configuration read without the offending keys and values (with stand-ins
/// for required ones) when that is possible, so that validation can report the problems
/// elsewhere too.
#[derive(Debug)]
pub struct Loaded {
    pub raw: Option<RawConfig>,
    pub problems: Vec<Problem>,
}

impl Loaded {
    /// The configuration, or every problem of the reading stage.
    pub fn strict(self) -> Result<RawConfig, Problems> {
        match self.raw {
            Some(raw) if self.problems.is_empty() => Ok(raw),
            Some(_) => Err(Problems(self.problems)),
            None if self.problems.is_empty() => {
                Err(Problems::one("", "the configuration cannot be read"))
            }
            None => Err(Problems(self.problems)),
        }
    }
}

/// What a serde visitor said was wrong with a value (its place is `serde_path_to_error`'s).
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Complaint {
    /// A value of the wrong type or out of range: what the key takes instead, as its visitor
    /// says it (`u16`, `a boolean`, `a duration`, `struct RawMqtt`).
    Expected(String),
    /// Text that is none of an enum's words.
    UnknownWord(&'static [&'static str]),
    /// A key a strict table does not know.
    UnknownKey {
        key: String,
        known: &'static [&'static str],
    },
    MissingKey(&'static str),
    Other(String),
}

impl fmt::Display for Complaint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Complaint::Expected(expected) => write!(f, "expected {expected}"),
            Complaint::UnknownWord(words) => write!(f, "is not one of {}", words.join(", ")),
            Complaint::UnknownKey { key, .. } => write!(f, "{key}: unknown key"),
            Complaint::MissingKey(key) => write!(f, "{key}: required, but not set"),
            Complaint::Other(message) => f.write_str(message),
        }
    }
}

impl std::error::Error for Complaint {}

impl de::Error for Complaint {
    fn custom<T: fmt::Display>(message: T) -> Self {
        Complaint::Other(message.to_string())
    }
    fn invalid_type(_: de::Unexpected<'_>, expected: &dyn de::Expected) -> Self {
        Complaint::Expected(expected.to_string())
    }
    fn invalid_value(_: de::Unexpected<'_>, expected: &dyn de::Expected) -> Self {
        Complaint::Expected(expected.to_string())
    }
    fn invalid_length(_: usize, expected: &dyn de::Expected) -> Self {
        Complaint::Expected(expected.to_string())
    }
    fn unknown_variant(_: &str, expected: &'static [&'static str]) -> Self {
        Complaint::UnknownWord(expected)
    }
    fn unknown_field(key: &str, known: &'static [&'static str]) -> Self {
        Complaint::UnknownKey {
            key: key.to_string(),
            known,
        }
    }
    fn missing_field(key: &'static str) -> Self {
        Complaint::MissingKey(key)
    }
}

/// The first problem one reading met, at its place.
#[derive(Debug)]
struct Fault {
    place: Vec<Step>,
    complaint: Complaint,
}

/// Reads [`RawConfig`] from `tree`, again and again, each time taking out the value the
/// previous reading stopped at (a wrong value) or standing in for a missing one, until it
/// reads: every problem of the reading stage is reported, and the rest can still be validated
/// (a wrong type must not hide an address out of range elsewhere). Problems are listed table by
/// table in the order the structs declare their keys, unknown keys first.
pub(crate) fn read_leniently(tree: Tree) -> Loaded {
    let mut reading = Reading {
        tree,
        found: Vec::new(),
        stood_in: Vec::new(),
    };
    for place in lists_where_tables_go(reading.tree.root(), &mut Vec::new()) {
        reading.report_wrong_value(&place, "is not a table");
    }
    let (raw, unknown_keys) = loop {
        let (result, unknown_keys) = read_once(&reading.tree);
        match result {
            Ok(raw) => break (Some(raw), unknown_keys),
            Err(fault) => {
                if !reading.settle(fault) {
                    break (None, unknown_keys);
                }
            }
        }
    };
    for place in unknown_keys {
        if let Some((Step::Key(key), table)) = place.split_last() {
            reading.report(&place, unknown_key_reason(key, keys_at(table)));
        }
    }
    let mut found = reading.found;
    found.sort_by_cached_key(|(place, _)| declared_order(place));
    Loaded {
        raw,
        problems: found.into_iter().map(|(_, problem)| problem).collect(),
    }
}

/// The tree as edited so far and what its readings found.
struct Reading {
    tree: Tree,
    found: Vec<(Vec<Step>, Problem)>,
    /// Places given a stand-in: what fails inside them was reported already.
    stood_in: Vec<Vec<Step>>,
}

impl Reading {
    /// Deals with the problem a reading stopped at, so that the next reading goes past it;
    /// false when the tree cannot be changed to go past it.
    fn settle(&mut self, Fault { place, complaint }: Fault) -> bool {
        let in_stand_in = self
            .stood_in
            .iter()
            .any(|stand_in| place.starts_with(stand_in));
        match &complaint {
            Complaint::MissingKey(_) => {
                // A required key whose wrong value was taken out is reported already.
                let reported = self.found.iter().any(|(at, _)| *at == place);
                if !in_stand_in && !reported {
                    self.report(&place, "required, but not set");
                }
                self.stood_in.push(place.clone());
                self.tree.set(&place, Value::Unit)
            }
            Complaint::UnknownKey { key, known } => {
                self.report(&place, unknown_key_reason(key, known));
                self.tree.remove(&place)
            }
            complaint => {
                let want = Want::of(&self.tree, &place, complaint);
                if in_stand_in {
                    return want
                        .emptiest()
                        .is_some_and(|value| self.tree.set(&place, value));
                }
                // Environment text the `config` crate typed by its look, typed by its key
                // instead (a password `1e5` is text): no problem yet.
                let retyped = self
                    .tree
                    .env_text(&place)
                    .and_then(|text| want.type_env_text(text));
                if retyped.is_some_and(|value| self.tree.set(&place, value)) {
                    return true;
                }
                let reason = want.reason(&self.tree, &place, complaint);
                self.report_wrong_value(&place, &reason)
            }
        }
    }

    fn report(&mut self, place: &[Step], reason: impl Into<String>) {
        self.found
            .push((place.to_vec(), Problem::new(place_text(place), reason)));
    }

    /// Reports the value at `place`, shown, and takes it out: a key goes from its table (its
    /// default applies, or a required key is stood in for); an item of a list is stood in
    /// for, so that the places of the items after it stay as the user wrote them.
    fn report_wrong_value(&mut self, place: &[Step], reason: &str) -> bool {
        self.report(place, format!("{} {reason}", shown(&self.tree, place)));
        match place.last() {
            Some(Step::Key(_)) => self.tree.remove(place),
            Some(Step::Index(_)) => {
                self.stood_in.push(place.to_vec());
                self.tree.set(place, Value::Unit)
            }
            None => false,
        }
    }
}

/// The places inside `value` (at `place`) where a list stands for a table: serde would read the
/// table's keys from it by position.
fn lists_where_tables_go(value: &Value, place: &mut Vec<Step>) -> Vec<Vec<Step>> {
    let mut found = Vec::new();
    let children: Vec<(Step, &Value)> = match value {
        Value::Seq(_) if matches!(shape_at(place), Shape::Table(_)) => return vec![place.clone()],
        Value::Seq(items) => items
            .iter()
            .enumerate()
            .map(|(index, item)| (Step::Index(index), item))
            .collect(),
        Value::Map(entries) => entries
            .iter()
            .filter_map(|(key, item)| match key {
                Value::String(key) => Some((Step::Key(key.clone()), item)),
                _ => None,
            })
            .collect(),
        _ => Vec::new(),
    };
    for (step, child) in children {
        place.push(step);
        found.extend(lists_where_tables_go(child, place));
        place.pop();
    }
    found
}

/// One reading of the whole tree: the configuration or the first problem, and the places of
/// the unknown keys it passed.
fn read_once(tree: &Tree) -> (Result<RawConfig, Fault>, Vec<Vec<Step>>) {
    let mut unknown_keys = Vec::new();
    let value = ValueDeserializer::<Complaint>::new(tree.root().clone());
    let mut note_unknown_key = |path: serde_ignored::Path<'_>| {
        unknown_keys.push(ignored_place(&path));
    };
    let noting_unknown_keys = serde_ignored::Deserializer::new(value, &mut note_unknown_key);
    let result = serde_path_to_error::deserialize(noting_unknown_keys).map_err(|error| {
        let mut place: Vec<Step> = error
            .path()
            .iter()
            .filter_map(|segment| match segment {
                serde_path_to_error::Segment::Seq { index } => Some(Step::Index(*index)),
                serde_path_to_error::Segment::Map { key } => Some(Step::Key(key.clone())),
                _ => None,
            })
            .collect();
        let complaint = error.into_inner();
        if let Complaint::MissingKey(key) = &complaint {
            // The path is the table's; the problem is its key's.
            place.push(Step::Key(key.to_string()));
        }
        Fault { place, complaint }
    });
    (result, unknown_keys)
}

/// The place `serde_ignored` names (an `Option`'s or a newtype's value at its own place).
fn ignored_place(path: &serde_ignored::Path<'_>) -> Vec<Step> {
    let (parent, step) = match path {
        serde_ignored::Path::Root => return Vec::new(),
        serde_ignored::Path::Seq { parent, index } => (parent, Some(Step::Index(*index))),
        serde_ignored::Path::Map { parent, key } => (parent, Some(Step::Key(key.clone()))),
        serde_ignored::Path::Some { parent }
        | serde_ignored::Path::NewtypeStruct { parent }
        | serde_ignored::Path::NewtypeVariant { parent } => (parent, None),
    };
    let mut place = ignored_place(parent);
    place.extend(step);
    place
}

/// What a key takes, told from what its visitor expected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Want {
    Text,
    Duration,
    Bool,
    Number,
    Integer {
        min: i64,
        max: i64,
    },
    /// One of an enum's words.
    Word(&'static [&'static str]),
    Table,
    List,
    Other,
}

impl Want {
    fn of(tree: &Tree, place: &[Step], complaint: &Complaint) -> Want {
        let expected = match complaint {
            Complaint::UnknownWord(words) => return Want::Word(words),
            Complaint::Expected(expected) => expected.as_str(),
            _ => return Want::Other,
        };
        match expected {
            "a string" | "path string" => Want::Text,
            "a duration" => Want::Duration,
            "a boolean" => Want::Bool,
            "f32" | "f64" => Want::Number,
            "a sequence" => Want::List,
            "a map" => Want::Table,
            // An enum met something other than text: its words are what it says of an empty one.
            "string or map" => words_at(tree, place).map_or(Want::Other, Want::Word),
            _ if expected.starts_with("struct ") => Want::Table,
            _ => {
                integer_range(expected).map_or(Want::Other, |(min, max)| Want::Integer { min, max })
            }
        }
    }

    /// The emptiest value of this kind, standing in for one that is missing or wrong.
    fn emptiest(self) -> Option<Value> {
        Some(match self {
            Want::Text => Value::String(String::new()),
            Want::Duration => Value::String("0s".to_string()),
            Want::Bool => Value::Bool(false),
            Want::Number => Value::F64(0.0),
            Want::Integer { min, .. } => Value::I64(min.max(0)),
            Want::Word(words) => Value::String(words.first()?.to_string()),
            Want::Table => Value::Map(Default::default()),
            Want::List => Value::Seq(Vec::new()),
            Want::Other => return None,
        })
    }

    /// Environment text as this kind of value; the words for a boolean are the `config`
    /// crate's.
    fn type_env_text(self, text: &str) -> Option<Value> {
        match self {
            Want::Text | Want::Duration | Want::Word(_) => Some(Value::String(text.to_string())),
            Want::Bool => match text.trim().to_lowercase().as_str() {
                "1" | "true" | "on" | "yes" => Some(Value::Bool(true)),
                "0" | "false" | "off" | "no" => Some(Value::Bool(false)),
                _ => None,
            },
            Want::Integer { .. } => text.trim().parse().ok().map(Value::I64),
            Want::Number => text.trim().parse().ok().map(Value::F64),
            Want::Table | Want::List | Want::Other => None,
        }
    }

    /// Why the value at `place` is not this kind, in our words.
    fn reason(self, tree: &Tree, place: &[Step], complaint: &Complaint) -> String {
        match self {
            Want::Duration => "is not a duration (such as \"300ms\", \"2s\" or \"5m\")".to_string(),
            Want::Word(words) => format!("is not one of {}", words.join(", ")),
            Want::Integer { min, max } if is_integer(tree, place) => {
                format!("is out of range ({min} to {max})")
            }
            Want::Integer { .. } => "is not an integer".to_string(),
            Want::Number => "is not a number".to_string(),
            Want::Bool => "is not true or false".to_string(),
            Want::Text => "is not text (write it in quotes)".to_string(),
            Want::Table => "is not a table".to_string(),
            Want::List => "is not a list of tables".to_string(),
            Want::Other => format!("is not valid ({complaint})"),
        }
    }
}

/// The range of serde's integer of this name (`u16`); larger bounds are shown as i64's.
fn integer_range(name: &str) -> Option<(i64, i64)> {
    Some(match name {
        "i8" => (i8::MIN.into(), i8::MAX.into()),
        "i16" => (i16::MIN.into(), i16::MAX.into()),
        "i32" => (i32::MIN.into(), i32::MAX.into()),
        "i64" | "isize" => (i64::MIN, i64::MAX),
        "u8" => (0, u8::MAX.into()),
        "u16" => (0, u16::MAX.into()),
        "u32" => (0, u32::MAX.into()),
        "u64" | "usize" => (0, i64::MAX),
        _ => return None,
    })
}

/// The words of the enum at `place`: what it says when given text that is none of them.
fn words_at(tree: &Tree, place: &[Step]) -> Option<&'static [&'static str]> {
    let mut probe = tree.clone();
    probe.set(place, Value::String(String::new()));
    match read_once(&probe).0 {
        Err(Fault {
            place: at,
            complaint: Complaint::UnknownWord(words),
        }) if at == place => Some(words),
        _ => None,
    }
}

fn is_integer(tree: &Tree, place: &[Step]) -> bool {
    match tree.env_text(place) {
        Some(text) => text.trim().parse::<i64>().is_ok(),
        None => matches!(tree.get(place), Some(Value::I64(_) | Value::U64(_))),
    }
}

/// The value at `place` as the user wrote it: text in quotes (environment text always), numbers
/// as they are; a secret never, not even a mistyped one.
fn shown(tree: &Tree, place: &[Step]) -> String {
    if place.last() == Some(&Step::Key("password".to_string())) {
        return "the value (not shown)".to_string();
    }
    if let Some(text) = tree.env_text(place) {
        return format!("{text:?}");
    }
    match tree.get(place) {
        Some(Value::String(text)) => format!("{text:?}"),
        Some(Value::I64(number)) => number.to_string(),
        Some(Value::U64(number)) => number.to_string(),
        Some(Value::F64(number)) => number.to_string(),
        Some(Value::Bool(value)) => value.to_string(),
        Some(Value::Map(_)) => "a table".to_string(),
        Some(Value::Seq(_)) => "a list".to_string(),
        _ => "nothing".to_string(),
    }
}

/// An unknown key, with the keys its table knows and the one it is most likely a typo of.
fn unknown_key_reason(key: &str, known: &[&str]) -> String {
    let known_here = known.join(", ");
    let nearest = known
        .iter()
        .map(|candidate| (strsim::levenshtein(key, candidate), candidate))
        .filter(|(distance, _)| *distance <= 2)
        .min();
    match nearest {
        Some((_, near)) => {
            format!("unknown key, did you mean `{near}`? (known here: {known_here})")
        }
        None => format!("unknown key (known here: {known_here})"),
    }
}

/// Where `place` sorts among places: table by table in the order their keys are declared,
/// keys no table declares first (alphabetically), items of a list by index.
fn declared_order(place: &[Step]) -> Vec<(usize, String)> {
    place
        .iter()
        .enumerate()
        .map(|(depth, step)| match step {
            Step::Index(index) => (*index, String::new()),
            Step::Key(key) => match keys_at(&place[..depth])
                .iter()
                .position(|known| known == key)
            {
                Some(position) => (position + 1, String::new()),
                None => (0, key.clone()),
            },
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

    use super::super::load::{load_file_with_env, load_str, load_str_lenient};
    use super::super::schema::{keys_of, RawDevice, RawMqtt};

    const BASE: &str = "[mqtt]\nurl = \"mqtt://127.0.0.1\"\nclient_id = \"edge1\"\n\
                        [[lines]]\nname = \"a\"\nport = \"/dev/ttyS1\"\n\
                        [[lines.devices]]\nname = \"valve\"\nprofile = \"wuzhou-valve\"\n";

    /// The problems of reading `BASE` with `device` as the device's last keys.
    fn problems_with_device(device: &str) -> Vec<String> {
        match load_str(&format!("{BASE}{device}\n")) {
            Ok(_) => Vec::new(),
            Err(problems) => problems.0.iter().map(ToString::to_string).collect(),
        }
    }

    #[test]
    fn file_values_are_taken_only_as_their_own_type() {
        assert_eq!(
            problems_with_device("address = \"3\""),
            ["lines[0].devices[0].address: \"3\" is not an integer"]
        );
        assert_eq!(
            problems_with_device("address = 1.5"),
            ["lines[0].devices[0].address: 1.5 is not an integer"]
        );
        assert_eq!(
            problems_with_device("address = 2.0"),
            ["lines[0].devices[0].address: 2 is not an integer"]
        );
        let text = BASE.replace("name = \"valve\"", "name = 5") + "address = 3\n";
        let problems = load_str(&text).unwrap_err().to_string();
        assert!(
            problems.contains("lines[0].devices[0].name: 5 is not text (write it in quotes)"),
            "{problems}"
        );
        let line = |keys: &str| {
            let text = BASE.replace(
                "port = \"/dev/ttyS1\"",
                &format!("port = \"/dev/ttyS1\"\n{keys}"),
            );
            load_str(&format!("{text}address = 3\n"))
                .unwrap_err()
                .to_string()
        };
        assert!(line("echo = 2").contains("lines[0].echo: 2 is not true or false"));
        assert!(line("rs485 = { rts_on_send = 1 }")
            .contains("lines[0].rs485.rts_on_send: 1 is not true or false"));
        assert!(line("parity = 1").contains("lines[0].parity: 1 is not one of none, even, odd"));
        assert!(
            line("stop_bits = 300").contains("lines[0].stop_bits: 300 is out of range (0 to 255)")
        );
        let mqtt = "[mqtt]\nurl = \"mqtt://h\"\nclient_id = \"e\"";
        for (text, place) in [
            ("mqtt = [\"mqtt://h\", \"edge1\"]".to_string(), "mqtt"),
            (format!("history = [{{}}]\n{mqtt}"), "history"),
            (format!("{mqtt}\n[[history]]"), "history"),
            (format!("lines = [[]]\n{mqtt}"), "lines[0]"),
        ] {
            let problems = load_str(&text).unwrap_err().to_string();
            assert!(
                problems.contains(&format!("{place}: a list is not a table")),
                "{problems}"
            );
        }
        let text = BASE.replace("[[lines.devices]]", "devices = 5\n[extra]");
        let problems = load_str(&text).unwrap_err().to_string();
        assert!(
            problems.contains("lines[0].devices: 5 is not a list of tables"),
            "{problems}"
        );
    }

    fn with_env(vars: &[(&str, &str)]) -> Result<super::RawConfig, crate::config::Problems> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("config.toml");
        std::fs::write(&path, format!("{BASE}address = 3\n")).unwrap();
        let env: HashMap<String, String> = vars
            .iter()
            .map(|(name, value)| (name.to_string(), value.to_string()))
            .collect();
        load_file_with_env(&path, Some(env))
    }

    #[test]
    fn environment_text_is_read_as_its_key_takes() {
        let raw = with_env(&[
            ("RTU2MQTT__MQTT__CLIENT_ID", "7"),
            ("RTU2MQTT__MQTT__PREFIX", "true"),
            ("RTU2MQTT__MQTT__INFLIGHT", " 10 "),
            ("RTU2MQTT__MQTT__KEEP_ALIVE", "45s"),
            ("RTU2MQTT__MQTT__CLEAN_SESSION", "1"),
            ("RTU2MQTT__GATEWAY__JSON_VIEW", "on"),
            ("RTU2MQTT__GATEWAY__ALLOW_RAW_WRITES", "No"),
            ("RTU2MQTT__GATEWAY__MAX_PAYLOAD", "2048"),
        ])
        .unwrap_or_else(|problems| panic!("{problems}"));
        assert_eq!(raw.mqtt.client_id, "7");
        assert_eq!(raw.mqtt.prefix, "true");
        assert_eq!(raw.mqtt.inflight, 10);
        assert_eq!(raw.mqtt.keep_alive, std::time::Duration::from_secs(45));
        assert!(raw.mqtt.clean_session);
        assert!(raw.gateway.json_view);
        assert!(!raw.gateway.allow_raw_writes);
        assert_eq!(raw.gateway.max_payload, 2048);

        let problems = with_env(&[
            ("RTU2MQTT__GATEWAY__JSON_VIEW", "2"),
            ("RTU2MQTT__MQTT__INFLIGHT", "70000"),
        ])
        .unwrap_err()
        .to_string();
        assert!(
            problems.contains(
                "RTU2MQTT__MQTT__INFLIGHT (environment, mqtt.inflight): \"70000\" is out of range (0 to 65535)"
            ),
            "{problems}"
        );
        assert!(
            problems.contains(
                "RTU2MQTT__GATEWAY__JSON_VIEW (environment, gateway.json_view): \"2\" is not true or false"
            ),
            "{problems}"
        );
    }

    #[test]
    fn an_unknown_key_names_the_key_it_is_likely_a_typo_of() {
        assert_eq!(
            problems_with_device("address = 3\nadress = 3"),
            [
                "lines[0].devices[0].adress: unknown key, did you mean `address`? \
              (known here: name, profile, address, poll_interval, publish)"
            ]
        );
        assert_eq!(
            problems_with_device("address = 3\ncolour = 3"),
            ["lines[0].devices[0].colour: unknown key \
              (known here: name, profile, address, poll_interval, publish)"]
        );
    }

    #[test]
    fn every_table_names_its_own_keys() {
        let text = "colour = 1\n\
                    [mqtt]\nurl = \"mqtt://x\"\nclient_id = \"e\"\nprefixx = \"p\"\n\
                    [gateway]\njson_vew = true\n\
                    [health]\nintervall = \"5s\"\n\
                    [history]\npath = \"/x\"\nmax_sise = \"1MiB\"\n\
                    [sparkplug]\ngroup = \"g\"\ngroup_id = \"g\"\n\
                    [sparkplug.mqtt]\nurl = \"mqtt://x\"\nclient_id = \"s\"\nkeepalive = \"5s\"\n\
                    [[lines]]\nname = \"a\"\nport = \"/dev/x\"\nbaudrate = 9600\n\
                    rs485 = { delay_before = \"1ms\" }\n\
                    serve = { listen = \"tcp://0.0.0.0:5020\", acces = \"raw\" }\n\
                    [[lines.devices]]\nname = \"d\"\nprofile = \"p\"\naddress = 1\n\
                    publish = { deadbnd = 1 }\n";
        let problems = load_str(text).unwrap_err();
        let shown: Vec<String> = problems
            .0
            .iter()
            .map(|problem| {
                let near = problem.reason.split('`').nth(1).unwrap_or("none");
                format!("{} → {near}", problem.place)
            })
            .collect();
        assert_eq!(
            shown,
            [
                "colour → none",
                "mqtt.prefixx → prefix",
                "gateway.json_vew → json_view",
                "health.intervall → interval",
                "lines[0].baudrate → none",
                "lines[0].rs485.delay_before → none",
                "lines[0].serve.acces → access",
                "lines[0].devices[0].publish.deadbnd → deadband",
                "sparkplug.group → none",
                "sparkplug.mqtt.keepalive → keep_alive",
                "history.max_sise → max_size",
            ],
            "{problems}"
        );
        assert!(
            problems.0[9].reason.ends_with(&format!(
                "(known here: {})",
                keys_of::<RawMqtt>().join(", ")
            )),
            "{problems}"
        );
    }

    #[test]
    fn a_missing_or_wrong_required_value_is_stood_in_for_so_the_rest_is_read() {
        let text = BASE.replace("name = \"valve\"", "name = []")
            + "address = 3\n[[lines.devices]]\nprofile = \"wuzhou-valve\"\naddress = \"x\"\n";
        let loaded = load_str_lenient(&text).unwrap_or_else(|problems| panic!("{problems}"));
        let shown: Vec<String> = loaded.problems.iter().map(ToString::to_string).collect();
        assert_eq!(
            shown,
            [
                "lines[0].devices[0].name: a list is not text (write it in quotes)",
                "lines[0].devices[1].name: required, but not set",
                "lines[0].devices[1].address: \"x\" is not an integer",
            ]
        );
        let raw = loaded.raw.expect("read with stand-ins");
        let devices: Vec<(&str, i64)> = raw.lines[0]
            .devices
            .iter()
            .map(|device: &RawDevice| (device.name.as_str(), device.address))
            .collect();
        assert_eq!(devices, [("", 3), ("", 0)]);
    }
}
