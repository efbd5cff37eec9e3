//! A validated command as the plan of one bus slot: the reads to make first (read-modify-write),
//! the writes computed from their fresh answers, the read-back and how to judge it.
//!
//! The rules that protect a device live here and nowhere else: bits a command does not change
//! are written back exactly as freshly read; toggle fields are written 1 only to change their
//! state and 0 otherwise; momentary fields are written 1 only when pressed; a forbidden
//! combination is refused again on the fresh read, not only on the last known state.

use std::sync::Arc;
use std::time::Duration;

use super::codec::{BlockImage, RawPatch};
use super::schema::{Behaviour, Compiled, WriteFrame};
use super::Value;
use crate::rtu::{Request, Response};

/// Why a command is refused: nothing is written.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct Rejection(pub String);

/// What a read-back says about a command.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Verification {
    Applied,
    /// The device acknowledged but shows something else.
    NotApplied(String),
    /// Still moving toward the value (valve opening): read again later, within the settle window.
    Settling,
}

/// One planned command. The line runs: `reads_before()` → `writes(answers)` → the writes →
/// `readback()` → `verify(answers)`, with no other transaction in between.
#[derive(Debug, Clone, PartialEq)]
pub struct CommandPlan {
    profile: Arc<Compiled>,
    /// Index of the commanded field.
    field: usize,
    target: Value,
    reads_before: Vec<Request>,
    readback: Vec<Request>,
}

/// The image of a block from a read answer, if the answer has the block's shape.
pub(crate) fn image_of(answer: &Response, expected_len: usize) -> Option<BlockImage> {
    let image = match answer {
        Response::HoldingRegisters(words) | Response::InputRegisters(words) => {
            BlockImage::Words(words.clone())
        }
        Response::Coils(bits) | Response::DiscreteInputs(bits) => BlockImage::Bits(bits.clone()),
        _ => return None,
    };
    let len = match &image {
        BlockImage::Words(words) => words.len(),
        BlockImage::Bits(bits) => bits.len(),
    };
    (len >= expected_len).then_some(image)
}

impl CommandPlan {
    pub(crate) fn new(profile: Arc<Compiled>, field: usize, target: Value) -> Self {
        let def = &profile.defs[field];
        let block_request = profile.blocks[def.block].request.clone();
        let needs_fresh_read = match &def.write {
            Some(frame) => {
                let field_bits = def.codec.footprint(def.offset);
                let frame_is_field = field_bits.len() == usize::from(frame.count)
                    && field_bits.iter().all(|(_, mask)| {
                        *mask == 0xFFFF || profile.block_kinds[def.block].is_bits()
                    });
                !frame_is_field
                    || def.behaviour == Behaviour::Toggle
                    || profile.forbidden.iter().any(|rule| {
                        rule.when
                            .iter()
                            .any(|(f, _)| footprints_meet(&profile, *f, field))
                    })
            }
            None => false,
        };
        let reads_before = if needs_fresh_read {
            vec![block_request.clone()]
        } else {
            Vec::new()
        };
        Self {
            profile,
            field,
            target,
            reads_before,
            readback: vec![block_request],
        }
    }

    pub fn field(&self) -> &str {
        &self.profile.infos[self.field].name
    }

    /// The commanded value, parsed and normalised to the field's kind.
    pub fn target(&self) -> &Value {
        &self.target
    }

    /// Reads to make in the slot before writing (empty when no read-modify-write is needed).
    pub fn reads_before(&self) -> &[Request] {
        &self.reads_before
    }

    fn block_len(&self) -> usize {
        let def = &self.profile.defs[self.field];
        super::schema::block_quantity(&self.profile.blocks[def.block].request) as usize
    }

    /// The write requests, computed from the fresh answers to `reads_before()`. Empty when the
    /// device already is in the commanded state (a toggle field asked for its current state).
    pub fn writes(&self, before: &[Response]) -> Result<Vec<Request>, Rejection> {
        let profile = &self.profile;
        let def = &profile.defs[self.field];
        let name = self.field();
        let Some(frame) = &def.write else {
            return Err(Rejection(format!("{name} is read-only")));
        };
        let block_len = self.block_len();
        let fresh = if self.reads_before.is_empty() {
            if profile.block_kinds[def.block].is_bits() {
                BlockImage::Bits(vec![false; block_len])
            } else {
                BlockImage::Words(vec![0; block_len])
            }
        } else {
            before
                .first()
                .and_then(|answer| image_of(answer, block_len))
                .ok_or_else(|| {
                    Rejection(format!(
                        "{name}: the read before the write did not return block `{}`",
                        profile.blocks[def.block].name
                    ))
                })?
        };
        let encoded = def
            .codec
            .encode(def.offset, &self.target)
            .map_err(|why| Rejection(format!("{name}: {why}")))?;

        if def.behaviour == Behaviour::Toggle {
            let current = def.codec.decode(&fresh, def.offset).map_err(|err| {
                Rejection(format!("{name}: the fresh read is not usable ({err})"))
            })?;
            if current == self.target {
                return Ok(Vec::new());
            }
        }

        // The state the device would be in: refuse forbidden combinations on the fresh read.
        let mut intended = fresh.clone();
        intended.apply(&encoded);
        check_forbidden(profile, self.field, &self.target, |index| {
            let other = &profile.defs[index];
            (other.block == def.block)
                .then(|| other.codec.decode(&intended, other.offset).ok())
                .flatten()
        })?;

        // What goes on the wire: as read, with buttons and toggles at rest, then the command.
        let mut image = fresh;
        for (index, other) in profile.defs.iter().enumerate() {
            if index == self.field
                || other.block != def.block
                || other.behaviour == Behaviour::State
                || !inside_frame(other.offset, other.codec.width(), frame)
            {
                continue;
            }
            image.apply(&rest_patches(other.codec.footprint(other.offset)));
        }
        match def.behaviour {
            Behaviour::State => image.apply(&encoded),
            Behaviour::Toggle | Behaviour::Momentary => {
                // Writing 1 is the action itself, whatever the bit's sense when read.
                let pressed: Vec<RawPatch> = def
                    .codec
                    .footprint(def.offset)
                    .into_iter()
                    .map(|(offset, mask)| RawPatch {
                        offset,
                        mask,
                        bits: mask,
                    })
                    .collect();
                image.apply(&pressed);
            }
        }
        Ok(frame_requests(frame, &image))
    }

    /// Reads that verify the command.
    pub fn readback(&self) -> &[Request] {
        &self.readback
    }

    /// Judges the answers to `readback()`.
    pub fn verify(&self, answers: &[Response]) -> Verification {
        let def = &self.profile.defs[self.field];
        let name = self.field();
        if def.behaviour == Behaviour::Momentary {
            // A button has no state to show; the acknowledged write is the whole effect.
            return Verification::Applied;
        }
        let Some(image) = answers
            .first()
            .and_then(|answer| image_of(answer, self.block_len()))
        else {
            return Verification::NotApplied(format!("{name}: no usable read-back"));
        };
        match def.codec.decode(&image, def.offset) {
            Ok(value) if value == self.target => Verification::Applied,
            _ if def.settle_window.is_some() => Verification::Settling,
            Ok(value) => Verification::NotApplied(format!(
                "{name} reads {} after writing {}",
                value.to_text(),
                self.target.to_text()
            )),
            Err(err) => Verification::NotApplied(format!("{name} read-back invalid: {err}")),
        }
    }

    /// How long a `Settling` read-back may keep being repeated.
    pub fn settle_window(&self) -> Option<Duration> {
        self.profile.defs[self.field].settle_window
    }
}

fn inside_frame(offset: u16, width: u16, frame: &WriteFrame) -> bool {
    offset >= frame.offset
        && u32::from(offset) + u32::from(width) <= u32::from(frame.offset) + u32::from(frame.count)
}

fn rest_patches(footprint: Vec<(u16, u16)>) -> Vec<RawPatch> {
    footprint
        .into_iter()
        .map(|(offset, mask)| RawPatch {
            offset,
            mask,
            bits: 0,
        })
        .collect()
}

/// True when two fields share a block and at least one bit.
fn footprints_meet(profile: &Compiled, a: usize, b: usize) -> bool {
    let (da, db) = (&profile.defs[a], &profile.defs[b]);
    if da.block != db.block {
        return false;
    }
    let fb = db.codec.footprint(db.offset);
    da.codec
        .footprint(da.offset)
        .iter()
        .any(|(oa, ma)| fb.iter().any(|(ob, mb)| oa == ob && ma & mb != 0))
}

/// Refuses the command when, with it applied, every condition of a forbidden combination holds.
/// `value_of` gives a field's value in the intended state, or None when it is not known (then
/// the combination cannot be judged and is left to the fresh read).
pub(crate) fn check_forbidden(
    profile: &Compiled,
    field: usize,
    target: &Value,
    value_of: impl Fn(usize) -> Option<Value>,
) -> Result<(), Rejection> {
    for rule in &profile.forbidden {
        if !rule
            .when
            .iter()
            .any(|(f, _)| footprints_meet(profile, *f, field))
        {
            continue;
        }
        let all_hold = rule
            .when
            .iter()
            .all(|(f, value)| value_of(*f).as_ref() == Some(value));
        if all_hold {
            // The commanded field's own condition first: "strong_wind ON and breeze ON".
            let mut conditions: Vec<(bool, String)> = rule
                .when
                .iter()
                .map(|(f, value)| {
                    (
                        !footprints_meet(profile, *f, field),
                        format!("{} {}", profile.infos[*f].name, value.to_text()),
                    )
                })
                .collect();
            conditions.sort();
            let conditions: Vec<String> = conditions.into_iter().map(|(_, c)| c).collect();
            return Err(Rejection(format!(
                "{} {} refused: it would make {} at once ({})",
                profile.infos[field].name,
                target.to_text(),
                conditions.join(" and "),
                rule.reason
            )));
        }
    }
    Ok(())
}

/// The write requests for a frame from the block image.
fn frame_requests(frame: &WriteFrame, image: &BlockImage) -> Vec<Request> {
    let start = usize::from(frame.offset);
    let end = start + usize::from(frame.count);
    match image {
        BlockImage::Bits(bits) => {
            let values = bits
                .get(start..end)
                .map(<[bool]>::to_vec)
                .unwrap_or_default();
            match frame.function {
                5 => vec![Request::WriteSingleCoil {
                    address: frame.address,
                    value: values.first().copied().unwrap_or(false),
                }],
                _ => vec![Request::WriteMultipleCoils {
                    start: frame.address,
                    values,
                }],
            }
        }
        BlockImage::Words(words) => {
            let values = words
                .get(start..end)
                .map(<[u16]>::to_vec)
                .unwrap_or_default();
            match frame.function {
                // One standard FC06 per register, back to back in the slot.
                6 => values
                    .iter()
                    .enumerate()
                    .map(|(i, value)| Request::WriteSingleRegister {
                        address: frame.address.wrapping_add(i as u16),
                        value: *value,
                    })
                    .collect(),
                _ => vec![Request::WriteMultipleRegisters {
                    start: frame.address,
                    values,
                }],
            }
        }
    }
}
