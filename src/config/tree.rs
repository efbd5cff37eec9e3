//! The configuration as a tree of values ([`Node`]) and a strict serde deserializer over it
//! ([`read`]) that names the place of the first problem it meets, in our words
//! (`lines[0].baud: "fast" is not an integer`). The serde structs of `schema` are the only
//! declaration of the keys: their names, types, defaults and which of them are required all
//! come from the derived `Deserialize`, and [`keys_of`] lists a struct's keys from it.
//!
//! Strict, because the `config` crate's own deserializer reads `2` as `true`, `1.5` as `2` and
//! `5` as `"5"`, which would hide a mistake in the file; text from the environment, which has
//! no types, is read as whatever its key takes (`RTU2MQTT__MQTT__INFLIGHT=10` as an integer).

use std::cell::RefCell;
use std::collections::HashMap;
use std::fmt;

use serde::de::value::StrDeserializer;
use serde::de::{self, DeserializeOwned, DeserializeSeed, IntoDeserializer, Unexpected, Visitor};
use serde::forward_to_deserialize_any;

/// One step of a place: a key of a table or an index in a list.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Step {
    Key(String),
    Index(usize),
}

/// A place as the user reads it: `lines[0].devices[1].address`.
pub fn place_text(place: &[Step]) -> String {
    let mut text = String::new();
    for step in place {
        match step {
            Step::Key(key) if text.is_empty() => text.push_str(key),
            Step::Key(key) => {
                text.push('.');
                text.push_str(key);
            }
            Step::Index(index) => text.push_str(&format!("[{index}]")),
        }
    }
    text
}

/// One value of the configuration, with tables in the order the layering gave them.
#[derive(Debug, Clone, PartialEq)]
pub enum Node {
    /// Text; `from_env` when an environment variable set it (then it may stand for a number or
    /// a boolean).
    Text {
        text: String,
        from_env: bool,
    },
    Integer(i64),
    Float(f64),
    Bool(bool),
    Table(Vec<(String, Node)>),
    List(Vec<Node>),
    /// Stands in for a value that is missing or wrong and already reported: it reads as the
    /// emptiest value of whatever type its key takes, so that the rest can still be read.
    StandIn,
}

impl Node {
    fn at_mut(&mut self, place: &[Step]) -> Option<&mut Node> {
        let Some((step, rest)) = place.split_first() else {
            return Some(self);
        };
        let child = match (self, step) {
            (Node::Table(entries), Step::Key(key)) => entries
                .iter_mut()
                .find(|(name, _)| name == key)
                .map(|(_, node)| node),
            (Node::List(items), Step::Index(index)) => items.get_mut(*index),
            _ => None,
        }?;
        child.at_mut(rest)
    }

    /// Takes the value at `place` out: a key of a table goes, an item of a list becomes a
    /// [`Node::StandIn`] (the places of the items after it stay as the user wrote them).
    /// False when there is nothing at `place`.
    pub fn remove(&mut self, place: &[Step]) -> bool {
        let Some((last, parent)) = place.split_last() else {
            return false;
        };
        match (self.at_mut(parent), last) {
            (Some(Node::Table(entries)), Step::Key(key)) => {
                let before = entries.len();
                entries.retain(|(name, _)| name != key);
                entries.len() < before
            }
            (Some(Node::List(items)), Step::Index(index)) if *index < items.len() => {
                items[*index] = Node::StandIn;
                true
            }
            _ => false,
        }
    }

    /// Puts a [`Node::StandIn`] at `place` (a key its table lacks). False when its table is
    /// not there or already has the key.
    pub fn stand_in(&mut self, place: &[Step]) -> bool {
        let Some((Step::Key(key), parent)) = place.split_last() else {
            return false;
        };
        if let Some(node @ Node::StandIn) = self.at_mut(parent) {
            // A stand-in table that lacks a required key becomes a table of stand-ins.
            *node = Node::Table(Vec::new());
        }
        match self.at_mut(parent) {
            Some(Node::Table(entries)) if entries.iter().all(|(name, _)| name != key) => {
                entries.push((key.clone(), Node::StandIn));
                true
            }
            _ => false,
        }
    }

    /// The value as the user wrote it: text in quotes, numbers as they are.
    fn shown(&self) -> String {
        match self {
            Node::Text { text, .. } => format!("{text:?}"),
            Node::Integer(number) => number.to_string(),
            Node::Float(number) => number.to_string(),
            Node::Bool(value) => value.to_string(),
            Node::Table(_) => "a table".to_string(),
            Node::List(_) => "a list".to_string(),
            Node::StandIn => "nothing".to_string(),
        }
    }

    fn unexpected(&self) -> Unexpected<'_> {
        match self {
            Node::Text { text, .. } => Unexpected::Str(text),
            Node::Integer(number) => Unexpected::Signed(*number),
            Node::Float(number) => Unexpected::Float(*number),
            Node::Bool(value) => Unexpected::Bool(*value),
            Node::Table(_) => Unexpected::Map,
            Node::List(_) => Unexpected::Seq,
            Node::StandIn => Unexpected::Unit,
        }
    }

    /// The integer this value is, or that environment text spells.
    fn integer(&self) -> Option<i64> {
        match self {
            Node::Integer(number) => Some(*number),
            Node::Text {
                text,
                from_env: true,
            } => text.trim().parse().ok(),
            _ => None,
        }
    }
}

/// The first problem [`read`] met.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Fault {
    pub place: Vec<Step>,
    pub reason: String,
    /// A required key is not set (there is no value at `place` to blame).
    pub missing: bool,
}

/// The keys each table read so far declares, by the table's place: the order of the keys in
/// the serde structs, for listing problems in that order.
#[derive(Debug, Default)]
pub struct Declared(RefCell<HashMap<Vec<Step>, &'static [&'static str]>>);

impl Declared {
    /// Where `place` sorts among places: table by table in the order their keys are declared,
    /// keys no table declares first (alphabetically), items of a list by index.
    pub fn order(&self, place: &[Step]) -> Vec<(usize, String)> {
        let declared = self.0.borrow();
        place
            .iter()
            .enumerate()
            .map(|(depth, step)| match step {
                Step::Index(index) => (*index, String::new()),
                Step::Key(key) => {
                    let keys = declared.get(&place[..depth]).copied().unwrap_or_default();
                    match keys.iter().position(|known| known == key) {
                        Some(position) => (position + 1, String::new()),
                        None => (0, key.clone()),
                    }
                }
            })
            .collect()
    }
}

/// Reads `T` from `tree`, or names the first problem (with its place, in our words).
pub fn read<T: DeserializeOwned>(tree: &Node, declared: &Declared) -> Result<T, Fault> {
    let reader = Reader {
        node: tree,
        place: &[],
        declared,
    };
    T::deserialize(reader).map_err(|error| match error.fault {
        Some(fault) => fault,
        None => Fault {
            place: Vec::new(),
            reason: error.kind.to_string(),
            missing: false,
        },
    })
}

/// The keys the serde struct `T` declares, in order (`#[derive(Deserialize)]` names them).
pub fn keys_of<T: DeserializeOwned>() -> &'static [&'static str] {
    match T::deserialize(KeyNames) {
        Err(Error {
            kind: Kind::Declared(keys),
            ..
        }) => keys,
        _ => &[],
    }
}

/// Asks a type for its struct's key names and nothing else.
struct KeyNames;

impl<'de> de::Deserializer<'de> for KeyNames {
    type Error = Error;

    fn deserialize_struct<V: Visitor<'de>>(
        self,
        _name: &'static str,
        fields: &'static [&'static str],
        _visitor: V,
    ) -> Result<V::Value, Error> {
        Err(Error::from(Kind::Declared(fields)))
    }

    fn deserialize_any<V: Visitor<'de>>(self, _visitor: V) -> Result<V::Value, Error> {
        Err(de::Error::custom("not a struct"))
    }

    forward_to_deserialize_any! {
        bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string bytes byte_buf
        option unit unit_struct newtype_struct seq tuple tuple_struct map enum identifier
        ignored_any
    }
}

/// What a key takes, for wording a problem with its value.
#[derive(Debug, Clone, Copy)]
enum Want {
    Any,
    Text,
    Bool,
    Number,
    Integer { min: i64, max: i64 },
    Word(&'static [&'static str]),
    Table,
    List,
}

const DURATION_EXPECTED: &str = "a duration";

/// What went wrong, as serde's visitors say it.
#[derive(Debug)]
enum Kind {
    /// `invalid_type`, `invalid_value`, `invalid_length`: what the key expected instead.
    Expected(String),
    UnknownWord(&'static [&'static str]),
    UnknownKey {
        key: String,
        known: &'static [&'static str],
    },
    MissingKey(&'static str),
    Declared(&'static [&'static str]),
    Other(String),
}

impl fmt::Display for Kind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Kind::Expected(expected) => write!(f, "expected {expected}"),
            Kind::UnknownWord(words) => write!(f, "is not one of {}", words.join(", ")),
            Kind::UnknownKey { key, .. } => write!(f, "{key}: unknown key"),
            Kind::MissingKey(key) => write!(f, "{key}: required, but not set"),
            Kind::Declared(keys) => write!(f, "declares {}", keys.join(", ")),
            Kind::Other(message) => f.write_str(message),
        }
    }
}

/// serde's error while reading: the problem, and its place once known.
#[derive(Debug)]
pub struct Error {
    kind: Kind,
    fault: Option<Fault>,
}

impl From<Kind> for Error {
    fn from(kind: Kind) -> Self {
        Error { kind, fault: None }
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.fault {
            Some(fault) => write!(f, "{}: {}", place_text(&fault.place), fault.reason),
            None => self.kind.fmt(f),
        }
    }
}

impl std::error::Error for Error {}

impl de::Error for Error {
    fn custom<T: fmt::Display>(message: T) -> Self {
        Kind::Other(message.to_string()).into()
    }
    fn invalid_type(_: Unexpected<'_>, expected: &dyn de::Expected) -> Self {
        Kind::Expected(expected.to_string()).into()
    }
    fn invalid_value(_: Unexpected<'_>, expected: &dyn de::Expected) -> Self {
        Kind::Expected(expected.to_string()).into()
    }
    fn invalid_length(_: usize, expected: &dyn de::Expected) -> Self {
        Kind::Expected(expected.to_string()).into()
    }
    fn unknown_variant(_: &str, expected: &'static [&'static str]) -> Self {
        Kind::UnknownWord(expected).into()
    }
    fn unknown_field(field: &str, expected: &'static [&'static str]) -> Self {
        Kind::UnknownKey {
            key: field.to_string(),
            known: expected,
        }
        .into()
    }
    fn missing_field(field: &'static str) -> Self {
        Kind::MissingKey(field).into()
    }
}

/// Reads the value at `place`.
#[derive(Clone, Copy)]
struct Reader<'a> {
    node: &'a Node,
    place: &'a [Step],
    declared: &'a Declared,
}

/// Owns the place of a value while it is read (the [`Reader`] borrows it).
struct Placed<'a> {
    node: &'a Node,
    place: Vec<Step>,
    declared: &'a Declared,
}

impl<'a> Placed<'a> {
    fn reader(&self) -> Reader<'_> {
        Reader {
            node: self.node,
            place: &self.place,
            declared: self.declared,
        }
    }
}

impl Reader<'_> {
    /// Gives `error` this value's place, unless a value inside it already took the blame.
    fn blame<T>(&self, want: Want, result: Result<T, Error>) -> Result<T, Error> {
        result.map_err(|mut error| {
            if error.fault.is_none() {
                error.fault = Some(self.fault(want, &error.kind));
            }
            error
        })
    }

    fn fault(&self, want: Want, kind: &Kind) -> Fault {
        let inside = |key: &str| {
            let mut place = self.place.to_vec();
            place.push(Step::Key(key.to_string()));
            place
        };
        match kind {
            Kind::MissingKey(key) => Fault {
                place: inside(key),
                reason: "required, but not set".to_string(),
                missing: true,
            },
            Kind::UnknownKey { key, known } => Fault {
                place: inside(key),
                reason: unknown_key_reason(key, known),
                missing: false,
            },
            kind => Fault {
                place: self.place.to_vec(),
                reason: self.wrong_value_reason(want, kind),
                missing: false,
            },
        }
    }

    fn wrong_value_reason(&self, want: Want, kind: &Kind) -> String {
        let reason = match (want, kind) {
            (_, Kind::Expected(expected)) if expected == DURATION_EXPECTED => {
                "is not a duration (such as \"300ms\", \"2s\" or \"5m\")".to_string()
            }
            (_, Kind::UnknownWord(words)) => format!("is not one of {}", words.join(", ")),
            (Want::Word(words), _) => format!("is not one of {}", words.join(", ")),
            (Want::Integer { min, max }, _) => match self.node.integer() {
                Some(_) => format!("is out of range ({min} to {max})"),
                None => "is not an integer".to_string(),
            },
            (Want::Number, _) => "is not a number".to_string(),
            (Want::Bool, _) => "is not true or false".to_string(),
            (Want::Text, _) => "is not text (write it in quotes)".to_string(),
            (Want::Table, _) => "is not a table".to_string(),
            (Want::List, _) => "is not a list of tables".to_string(),
            (Want::Any, kind) => format!("is not valid ({kind})"),
        };
        // A secret is never echoed, not even a mistyped one.
        let value = if self.place.last() == Some(&Step::Key("password".to_string())) {
            "the value (not shown)".to_string()
        } else {
            self.node.shown()
        };
        format!("{value} {reason}")
    }

    fn wrong_type<T, V: de::Expected>(&self, want: Want, expected: &V) -> Result<T, Error> {
        self.blame(
            want,
            Err(de::Error::invalid_type(self.node.unexpected(), expected)),
        )
    }

    /// The value `node` at `step` inside this one.
    fn child<'b>(&'b self, node: &'b Node, step: Step) -> Placed<'b> {
        let mut place = self.place.to_vec();
        place.push(step);
        Placed {
            node,
            place,
            declared: self.declared,
        }
    }

    fn integer<'de, V: Visitor<'de>>(
        self,
        min: i64,
        max: i64,
        visitor: V,
    ) -> Result<V::Value, Error> {
        let want = Want::Integer { min, max };
        let result = match (self.node, self.node.integer()) {
            (_, Some(number)) => visitor.visit_i64(number),
            (Node::StandIn, _) => visitor.visit_i64(min.max(0)),
            _ => return self.wrong_type(want, &visitor),
        };
        self.blame(want, result)
    }
}

/// An unknown key, with the keys its table knows and the one it is most likely a typo of.
fn unknown_key_reason(key: &str, known: &[&str]) -> String {
    let known_here = known.join(", ");
    let nearest = known
        .iter()
        .map(|candidate| (edit_distance(key, candidate), candidate))
        .filter(|(distance, _)| *distance <= 2)
        .min();
    match nearest {
        Some((_, near)) => {
            format!("unknown key, did you mean `{near}`? (known here: {known_here})")
        }
        None => format!("unknown key (known here: {known_here})"),
    }
}

/// Letters to insert, delete or change to turn `a` into `b` (Levenshtein).
fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, a_char) in a.chars().enumerate() {
        let mut diagonal = row[0];
        row[0] = i + 1;
        for (j, b_char) in b.iter().enumerate() {
            let changed = diagonal + usize::from(a_char != *b_char);
            diagonal = row[j + 1];
            row[j + 1] = changed.min(row[j] + 1).min(diagonal + 1);
        }
    }
    row[b.len()]
}

macro_rules! integers {
    ($($method:ident: $type:ty),*) => {$(
        fn $method<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
            // Every bound used here fits an i64; larger ones are shown as i64::MAX.
            let max = i64::try_from(<$type>::MAX).unwrap_or(i64::MAX);
            self.integer(<$type>::MIN as i64, max, visitor)
        }
    )*};
}

impl<'de> de::Deserializer<'de> for Reader<'_> {
    type Error = Error;

    fn deserialize_any<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
        let result = match self.node {
            Node::Text { text, .. } => visitor.visit_str(text),
            Node::Integer(number) => visitor.visit_i64(*number),
            Node::Float(number) => visitor.visit_f64(*number),
            Node::Bool(value) => visitor.visit_bool(*value),
            Node::Table(_) => return self.deserialize_map(visitor),
            Node::List(_) => return self.deserialize_seq(visitor),
            Node::StandIn => visitor.visit_unit(),
        };
        self.blame(Want::Any, result)
    }

    integers!(
        deserialize_i8: i8, deserialize_i16: i16, deserialize_i32: i32, deserialize_i64: i64,
        deserialize_u8: u8, deserialize_u16: u16, deserialize_u32: u32, deserialize_u64: u64
    );

    fn deserialize_f64<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
        let number = match self.node {
            Node::Float(number) => Some(*number),
            Node::Integer(number) => Some(*number as f64),
            Node::Text {
                text,
                from_env: true,
            } => text.trim().parse().ok(),
            Node::StandIn => Some(0.0),
            _ => None,
        };
        match number {
            Some(number) => {
                let result = visitor.visit_f64(number);
                self.blame(Want::Number, result)
            }
            None => self.wrong_type(Want::Number, &visitor),
        }
    }

    fn deserialize_f32<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
        self.deserialize_f64(visitor)
    }

    fn deserialize_bool<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
        let value = match self.node {
            Node::Bool(value) => Some(*value),
            // The words the `config` crate takes for a boolean in the environment.
            Node::Text {
                text,
                from_env: true,
            } => match text.trim().to_lowercase().as_str() {
                "1" | "true" | "on" | "yes" => Some(true),
                "0" | "false" | "off" | "no" => Some(false),
                _ => None,
            },
            Node::StandIn => Some(false),
            _ => None,
        };
        match value {
            Some(value) => {
                let result = visitor.visit_bool(value);
                self.blame(Want::Bool, result)
            }
            None => self.wrong_type(Want::Bool, &visitor),
        }
    }

    fn deserialize_str<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
        let result = match self.node {
            Node::Text { text, .. } => visitor.visit_str(text),
            Node::StandIn => visitor.visit_str(""),
            _ => return self.wrong_type(Want::Text, &visitor),
        };
        self.blame(Want::Text, result)
    }

    fn deserialize_string<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
        self.deserialize_str(visitor)
    }

    fn deserialize_option<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
        match self.node {
            Node::StandIn => visitor.visit_none(),
            _ => visitor.visit_some(self),
        }
    }

    fn deserialize_newtype_struct<V: Visitor<'de>>(
        self,
        _name: &'static str,
        visitor: V,
    ) -> Result<V::Value, Error> {
        visitor.visit_newtype_struct(self)
    }

    fn deserialize_seq<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
        let items: &[Node] = match self.node {
            Node::List(items) => items,
            Node::StandIn => &[],
            _ => return self.wrong_type(Want::List, &visitor),
        };
        let result = visitor.visit_seq(ListAccess {
            items,
            next: 0,
            reader: self,
        });
        self.blame(Want::List, result)
    }

    fn deserialize_map<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
        let entries: &[(String, Node)] = match self.node {
            Node::Table(entries) => entries,
            Node::StandIn => &[],
            _ => return self.wrong_type(Want::Table, &visitor),
        };
        let result = visitor.visit_map(TableAccess {
            entries,
            next: 0,
            reader: self,
        });
        self.blame(Want::Table, result)
    }

    fn deserialize_struct<V: Visitor<'de>>(
        self,
        _name: &'static str,
        fields: &'static [&'static str],
        visitor: V,
    ) -> Result<V::Value, Error> {
        self.declared
            .0
            .borrow_mut()
            .insert(self.place.to_vec(), fields);
        self.deserialize_map(visitor)
    }

    fn deserialize_enum<V: Visitor<'de>>(
        self,
        _name: &'static str,
        variants: &'static [&'static str],
        visitor: V,
    ) -> Result<V::Value, Error> {
        let want = Want::Word(variants);
        let word = match self.node {
            Node::Text { text, .. } => text.as_str(),
            Node::StandIn => variants.first().copied().unwrap_or_default(),
            _ => return self.wrong_type(want, &visitor),
        };
        let result = visitor.visit_enum(IntoDeserializer::<Error>::into_deserializer(word));
        self.blame(want, result)
    }

    fn deserialize_ignored_any<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
        visitor.visit_unit()
    }

    forward_to_deserialize_any! {
        i128 u128 char bytes byte_buf unit unit_struct tuple tuple_struct identifier
    }
}

/// The items of a list, each read at its index.
struct ListAccess<'a> {
    items: &'a [Node],
    next: usize,
    reader: Reader<'a>,
}

impl<'de> de::SeqAccess<'de> for ListAccess<'_> {
    type Error = Error;

    fn next_element_seed<T: DeserializeSeed<'de>>(
        &mut self,
        seed: T,
    ) -> Result<Option<T::Value>, Error> {
        let Some(item) = self.items.get(self.next) else {
            return Ok(None);
        };
        let placed = self.reader.child(item, Step::Index(self.next));
        self.next += 1;
        seed.deserialize(placed.reader()).map(Some)
    }
}

/// The keys of a table, each value read at its key.
struct TableAccess<'a> {
    entries: &'a [(String, Node)],
    next: usize,
    reader: Reader<'a>,
}

impl<'de> de::MapAccess<'de> for TableAccess<'_> {
    type Error = Error;

    fn next_key_seed<K: DeserializeSeed<'de>>(
        &mut self,
        seed: K,
    ) -> Result<Option<K::Value>, Error> {
        let Some((key, _)) = self.entries.get(self.next) else {
            return Ok(None);
        };
        seed.deserialize(StrDeserializer::<Error>::new(key))
            .map(Some)
    }

    fn next_value_seed<V: DeserializeSeed<'de>>(&mut self, seed: V) -> Result<V::Value, Error> {
        let Some((key, node)) = self.entries.get(self.next) else {
            return Err(de::Error::custom("a value without a key"));
        };
        self.next += 1;
        let placed = self.reader.child(node, Step::Key(key.clone()));
        seed.deserialize(placed.reader())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::schema::{RawDevice, RawRs485};

    fn text(text: &str, from_env: bool) -> Node {
        Node::Text {
            text: text.to_string(),
            from_env,
        }
    }

    fn table(entries: &[(&str, Node)]) -> Node {
        Node::Table(
            entries
                .iter()
                .map(|(key, node)| (key.to_string(), node.clone()))
                .collect(),
        )
    }

    fn reason_for<T: DeserializeOwned + fmt::Debug>(tree: &Node) -> String {
        let fault = read::<T>(tree, &Declared::default()).unwrap_err();
        format!("{}: {}", place_text(&fault.place), fault.reason)
    }

    #[test]
    fn the_keys_are_the_structs_declaration() {
        assert_eq!(
            keys_of::<RawDevice>(),
            ["name", "profile", "address", "poll_interval", "publish"]
        );
        assert_eq!(
            keys_of::<RawRs485>(),
            ["rts_on_send", "delay_before_send", "delay_after_send"]
        );
        assert!(keys_of::<String>().is_empty());
    }

    #[test]
    fn file_values_are_taken_only_as_their_own_type() {
        let device = |address: Node, name: Node| {
            table(&[
                ("name", name),
                ("profile", text("wuzhou-valve", false)),
                ("address", address),
            ])
        };
        assert_eq!(
            reason_for::<RawDevice>(&device(text("3", false), text("valve", false))),
            "address: \"3\" is not an integer"
        );
        assert_eq!(
            reason_for::<RawDevice>(&device(Node::Integer(3), Node::Integer(5))),
            "name: 5 is not text (write it in quotes)"
        );
        assert_eq!(
            reason_for::<RawRs485>(&table(&[("rts_on_send", Node::Integer(1))])),
            "rts_on_send: 1 is not true or false"
        );
    }

    #[test]
    fn environment_text_is_read_as_its_key_takes() {
        let tree = table(&[
            ("name", text("7", true)),
            ("profile", text("wuzhou-valve", true)),
            ("address", text(" 3 ", true)),
            ("poll_interval", text("2s", true)),
        ]);
        let device: RawDevice = read(&tree, &Declared::default()).unwrap();
        assert_eq!(device.name, "7");
        assert_eq!(device.address, 3);
        assert_eq!(
            device.poll_interval,
            Some(std::time::Duration::from_secs(2))
        );
        let tree = table(&[("rts_on_send", text("off", true))]);
        let rs485: RawRs485 = read(&tree, &Declared::default()).unwrap();
        assert!(!rs485.rts_on_send);
    }

    #[test]
    fn an_unknown_key_names_the_key_it_is_likely_a_typo_of() {
        let tree = table(&[("name", text("valve", false)), ("adress", Node::Integer(3))]);
        assert_eq!(
            reason_for::<RawDevice>(&tree),
            "adress: unknown key, did you mean `address`? \
             (known here: name, profile, address, poll_interval, publish)"
        );
        let tree = table(&[("colour", Node::Integer(3))]);
        assert_eq!(
            reason_for::<RawDevice>(&tree),
            "colour: unknown key (known here: name, profile, address, poll_interval, publish)"
        );
        assert_eq!(edit_distance("intervall", "interval"), 1);
        assert_eq!(edit_distance("", "url"), 3);
    }

    #[test]
    fn a_stand_in_reads_as_the_emptiest_value_and_grows_into_a_table() {
        let mut tree = table(&[("devices", Node::List(vec![Node::Integer(5)]))]);
        let place = [Step::Key("devices".into()), Step::Index(0)];
        assert!(tree.remove(&place));
        let mut name = place.to_vec();
        name.push(Step::Key("name".into()));
        assert!(tree.stand_in(&name));
        assert_eq!(
            tree,
            table(&[(
                "devices",
                Node::List(vec![table(&[("name", Node::StandIn)])])
            )])
        );
        assert_eq!(place_text(&name), "devices[0].name");
    }
}
