//! The layered configuration as one typed value: the `config` crate's tree (file < environment)
//! turned into a [`serde_value::Value`], which serde reads strictly (a number is never taken
//! for a boolean, `1.5` never for an integer), together with the text of every value the
//! environment set. Places ([`Step`]) name a value the way the user reads it
//! (`lines[0].devices[1].address`), and the reading edits the tree at a place to go on past a
//! problem: it takes a wrong value out or stands in for a missing one.

use std::collections::btree_map::Entry;
use std::collections::{BTreeMap, HashMap};

use config::ValueKind;
use serde_value::Value;

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

/// The configuration to read, and the text each environment variable gave its key.
#[derive(Debug, Clone, PartialEq)]
pub struct Tree {
    root: Value,
    /// By place (`mqtt.inflight`): the `config` crate typed this text by its look (`10` an
    /// integer, `true` a boolean); the reading types it again by the key it sets.
    env_text: HashMap<String, String>,
}

impl Tree {
    /// The layered value; `env_text` holds the text of each place an environment variable set.
    pub fn new(layered: config::Value, env_text: HashMap<String, String>) -> Self {
        Tree {
            root: typed(layered.kind),
            env_text,
        }
    }

    /// The whole value, to be read.
    pub fn root(&self) -> &Value {
        &self.root
    }

    /// The environment text behind the value at `place`, when a variable set it.
    pub fn env_text(&self, place: &[Step]) -> Option<&str> {
        if self.env_text.is_empty() {
            return None;
        }
        self.env_text.get(&place_text(place)).map(String::as_str)
    }

    /// The value at `place`.
    pub fn get(&self, place: &[Step]) -> Option<&Value> {
        place
            .iter()
            .try_fold(&self.root, |value, step| match (value, step) {
                (Value::Map(entries), Step::Key(key)) => entries.get(&Value::String(key.clone())),
                (Value::Seq(items), Step::Index(index)) => items.get(*index),
                _ => None,
            })
    }

    fn get_mut(&mut self, place: &[Step]) -> Option<&mut Value> {
        place
            .iter()
            .try_fold(&mut self.root, |value, step| match (value, step) {
                (Value::Map(entries), Step::Key(key)) => {
                    entries.get_mut(&Value::String(key.clone()))
                }
                (Value::Seq(items), Step::Index(index)) => items.get_mut(*index),
                _ => None,
            })
    }

    /// Puts `value` at `place`: a key of a table (added when missing) or an item of a list.
    /// False when its table or list is not there or the value is already `value`.
    pub fn set(&mut self, place: &[Step], value: Value) -> bool {
        let Some((last, parent)) = place.split_last() else {
            return false;
        };
        let slot = match (self.get_mut(parent), last) {
            (Some(Value::Map(entries)), Step::Key(key)) => {
                match entries.entry(Value::String(key.clone())) {
                    Entry::Occupied(entry) => entry.into_mut(),
                    Entry::Vacant(entry) => {
                        entry.insert(value);
                        return true;
                    }
                }
            }
            (Some(Value::Seq(items)), Step::Index(index)) => match items.get_mut(*index) {
                Some(item) => item,
                None => return false,
            },
            _ => return false,
        };
        if *slot == value {
            return false;
        }
        *slot = value;
        true
    }

    /// Takes the key at `place` out of its table. False when there is no such key.
    pub fn remove(&mut self, place: &[Step]) -> bool {
        let Some((Step::Key(key), parent)) = place.split_last() else {
            return false;
        };
        match self.get_mut(parent) {
            Some(Value::Map(entries)) => entries.remove(&Value::String(key.clone())).is_some(),
            _ => false,
        }
    }
}

/// The `config` crate's value as serde reads it. Nil (never from TOML) is a unit; an integer
/// too wide for 64 bits (never from TOML either) reads as the number it is.
fn typed(kind: ValueKind) -> Value {
    match kind {
        ValueKind::Nil => Value::Unit,
        ValueKind::Boolean(value) => Value::Bool(value),
        ValueKind::I64(number) => Value::I64(number),
        ValueKind::U64(number) => Value::U64(number),
        ValueKind::I128(number) => {
            i64::try_from(number).map_or(Value::F64(number as f64), Value::I64)
        }
        ValueKind::U128(number) => {
            u64::try_from(number).map_or(Value::F64(number as f64), Value::U64)
        }
        ValueKind::Float(number) => Value::F64(number),
        ValueKind::String(text) => Value::String(text),
        ValueKind::Table(table) => Value::Map(
            table
                .into_iter()
                .map(|(key, value)| (Value::String(key), typed(value.kind)))
                .collect::<BTreeMap<_, _>>(),
        ),
        ValueKind::Array(items) => {
            Value::Seq(items.into_iter().map(|item| typed(item.kind)).collect())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(name: &str) -> Step {
        Step::Key(name.to_string())
    }

    fn tree(text: &str) -> Tree {
        let layered = config::Config::builder()
            .add_source(config::File::from_str(text, config::FileFormat::Toml))
            .build()
            .unwrap_or_else(|error| panic!("{error}"));
        Tree::new(layered.cache, HashMap::new())
    }

    #[test]
    fn toml_values_keep_their_types() {
        let tree = tree("a = 2\nb = 1.5\nc = true\nd = \"x\"\ne = [{ f = 0x81 }]");
        assert_eq!(tree.get(&[key("a")]), Some(&Value::I64(2)));
        assert_eq!(tree.get(&[key("b")]), Some(&Value::F64(1.5)));
        assert_eq!(tree.get(&[key("c")]), Some(&Value::Bool(true)));
        assert_eq!(tree.get(&[key("d")]), Some(&Value::String("x".into())));
        let f = [key("e"), Step::Index(0), key("f")];
        assert_eq!(tree.get(&f), Some(&Value::I64(0x81)));
        assert_eq!(place_text(&f), "e[0].f");
    }

    #[test]
    fn values_are_set_and_taken_out_at_their_place() {
        let mut tree = tree("a = 2\ne = [{ f = 1 }]");
        assert!(tree.remove(&[key("a")]));
        assert!(!tree.remove(&[key("a")]));
        assert!(tree.set(&[key("e"), Step::Index(0)], Value::Unit));
        assert!(!tree.set(&[key("e"), Step::Index(0)], Value::Unit));
        assert!(!tree.set(&[key("e"), Step::Index(1)], Value::Unit));
        assert!(tree.set(&[key("g")], Value::Bool(false)));
        assert!(tree.set(&[key("h")], Value::Unit));
        assert!(!tree.set(&[key("x"), key("y")], Value::Unit));
        assert_eq!(tree.get(&[key("g")]), Some(&Value::Bool(false)));
        assert_eq!(tree.get(&[key("a")]), None);
    }
}
