//! A validated command on fields as the plan of one bus slot: the reads to make first
//! (read-modify-write), the writes computed from their fresh answers, the read-back and how to
//! judge it; and [`Verification`], what any read-back says about a command.
//!
//! The rules that protect a device live here and nowhere else: bits a command does not change
//! are written back exactly as freshly read; toggle fields are written 1 only to change their
//! state and 0 otherwise; momentary fields are written 1 only when pressed; a forbidden
//! combination is refused again on the fresh read, not only on the last known state.

use std::sync::{Arc, OnceLock};
use std::time::Duration;

use super::codec::{BlockImage, RawPatch};
use super::model::{Behaviour, Compiled, WriteFrame};
use super::numeric::Exponent;
use super::rejection::Rejection;
use crate::value::Value;
use rtu2mqtt_modbus::{Request, Response};

/// What a read-back says about a command.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Verification {
    /// The read-back shows every commanded value (numbers compared by magnitude, so `1.50`
    /// is `1.5`).
    Applied,
    /// The device itself reports the command carried out: an action's result register holds a
    /// success code, or an action without one acknowledged its frame. The text says which.
    Reported(String),
    /// The device acknowledged but shows something else.
    NotApplied(String),
    /// Still moving toward the value (valve opening): read again later, within the settle window.
    Settling,
}

/// One planned command on fields, run as a [`CommandPlan`](crate::CommandPlan) runs.
///
/// A plan carries one field (`plan_command`) or several fields written together in one frame
/// (`plan_group`, e.g. the dust collector's FC10 power-on with its settings).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct FieldPlan {
    profile: Arc<Compiled>,
    /// The field name, or the write frame's name for a group.
    label: String,
    frame: WriteFrame,
    /// (field index, commanded value), parsed and normalised to each field's kind.
    targets: Vec<(usize, Value)>,
    reads_before: Vec<Request>,
    /// Block offset of the first coil or register the first of `reads_before` returns.
    before_base: u16,
    /// Parallel to `reads_before[1..]`: the reads of exponents (`scale_by`) held in other
    /// blocks than the frame's, as (block, block offset of the first register returned).
    exponent_places: Vec<(usize, u16)>,
    /// The reads of the settle conditions' blocks (other than the frame's), then the read of
    /// the targets last: a condition seen to hold is then never older than the value judged.
    readback: Vec<Request>,
    /// Parallel to `readback`: (block, block offset of the first coil or register returned).
    readback_places: Vec<(usize, u16)>,
    /// Set by the first `verify`. That read-back follows the write at once and may predate
    /// the device's reaction to it (a motor not started yet reads "stopped"), so `settle_until`
    /// conditions count from the second read-back on.
    first_readback_judged: OnceLock<()>,
}

impl FieldPlan {
    /// A plan for `targets` written through `frame`. The caller has validated that every
    /// target field lies inside the frame.
    pub(crate) fn new(
        profile: Arc<Compiled>,
        label: String,
        frame: WriteFrame,
        targets: Vec<(usize, Value)>,
    ) -> Self {
        // A fresh read is needed unless the targets fill the frame completely and nothing
        // depends on the device's current state (toggles, forbidden combinations).
        let is_bits = profile.block_kinds[frame.block].is_bits();
        let mut covered = vec![0u16; usize::from(frame.count)];
        let mut target_span = (u16::MAX, 0u16);
        for (field, _) in &targets {
            let def = &profile.defs[*field];
            target_span = widen(target_span, def.offset, def.codec.width());
            for (offset, mask) in def.codec.footprint(def.offset) {
                if let Some(slot) = offset
                    .checked_sub(frame.offset)
                    .and_then(|rel| covered.get_mut(usize::from(rel)))
                {
                    *slot |= mask;
                }
            }
        }
        let full = if is_bits { 1 } else { 0xFFFF };
        let frame_filled = covered.iter().all(|mask| *mask == full);
        let mut before_span = (frame.offset, frame.offset + frame.count);
        let mut depends_on_state = false;
        // A `scale_by` target is written and judged with the exponent read in this slot: in
        // the frame's block it widens the reads, elsewhere it gets reads of its own.
        let mut exponent_spans: Vec<(usize, (u16, u16))> = Vec::new();
        for (field, _) in &targets {
            let Some(exponent) = profile.defs[*field].scale_by else {
                continue;
            };
            depends_on_state = true;
            let def = &profile.defs[exponent];
            let width = def.codec.width();
            if def.block == frame.block {
                before_span = widen(before_span, def.offset, width);
                target_span = widen(target_span, def.offset, width);
            } else if let Some((_, span)) = exponent_spans.iter_mut().find(|(b, _)| *b == def.block)
            {
                *span = widen(*span, def.offset, width);
            } else {
                exponent_spans.push((def.block, (def.offset, def.offset + width)));
            }
        }
        for (field, _) in &targets {
            depends_on_state |= profile.defs[*field].behaviour == Behaviour::Toggle;
            for rule in &profile.forbidden {
                if rule
                    .when
                    .iter()
                    .any(|(f, _)| footprints_meet(&profile, *f, *field))
                {
                    depends_on_state = true;
                    for (f, _) in &rule.when {
                        let def = &profile.defs[*f];
                        before_span = widen(before_span, def.offset, def.codec.width());
                    }
                }
            }
        }
        let (mut reads_before, before_base) = if frame_filled && !depends_on_state {
            (Vec::new(), 0)
        } else {
            let (request, base) = run_read(&profile, frame.block, before_span);
            (vec![request], base)
        };
        let mut exponent_places = Vec::new();
        for &(block, span) in &exponent_spans {
            let (request, base) = run_read(&profile, block, span);
            reads_before.push(request);
            exponent_places.push((block, base));
        }
        // Settle conditions in the frame's block widen the targets' read (one answer holds
        // both); those elsewhere get a read of their own, made before the targets' read.
        let mut condition_spans: Vec<(usize, (u16, u16))> = Vec::new();
        for (field, _) in &targets {
            for (condition, _) in &profile.defs[*field].settle_until {
                let def = &profile.defs[*condition];
                let width = def.codec.width();
                if def.block == frame.block {
                    target_span = widen(target_span, def.offset, width);
                } else if let Some((_, span)) =
                    condition_spans.iter_mut().find(|(b, _)| *b == def.block)
                {
                    *span = widen(*span, def.offset, width);
                } else {
                    condition_spans.push((def.block, (def.offset, def.offset + width)));
                }
            }
        }
        for (block, span) in exponent_spans {
            if let Some((_, known)) = condition_spans.iter_mut().find(|(b, _)| *b == block) {
                *known = widen(*known, span.0, span.1 - span.0);
            } else {
                condition_spans.push((block, span));
            }
        }
        let mut readback = Vec::new();
        let mut readback_places = Vec::new();
        for (block, span) in condition_spans {
            let (request, base) = run_read(&profile, block, span);
            readback.push(request);
            readback_places.push((block, base));
        }
        let (request, base) = run_read(&profile, frame.block, target_span);
        readback.push(request);
        readback_places.push((frame.block, base));
        Self {
            profile,
            label,
            frame,
            targets,
            reads_before,
            before_base,
            exponent_places,
            readback,
            readback_places,
            first_readback_judged: OnceLock::new(),
        }
    }

    /// The commanded field (for a group: the write frame's name).
    pub(crate) fn field(&self) -> &str {
        &self.label
    }

    /// The commanded value of the (first) field, parsed and normalised to its kind.
    pub(crate) fn target(&self) -> &Value {
        &self.targets[0].1
    }

    /// Every commanded field with its value.
    pub(crate) fn targets(&self) -> Vec<(&str, &Value)> {
        self.targets
            .iter()
            .map(|(field, value)| (self.profile.infos[*field].name.as_str(), value))
            .collect()
    }

    /// Running the command twice leaves the device as running it once: every commanded field
    /// is a state (a momentary button or a toggle is an action, not a state).
    pub(crate) fn is_idempotent(&self) -> bool {
        self.targets
            .iter()
            .all(|(field, _)| self.profile.defs[*field].behaviour == Behaviour::State)
    }

    /// Reads to make in the slot before writing (empty when no read-modify-write is needed).
    pub(crate) fn reads_before(&self) -> &[Request] {
        &self.reads_before
    }

    /// An image of the whole of `block`, all zero.
    fn empty_image(&self, block: usize) -> BlockImage {
        empty_image(&self.profile.blocks[block].request)
    }

    /// The answer to `request` (a part of `block` from offset `base`) placed in an image of
    /// the whole block, zeros elsewhere. None when the answer does not fit the request.
    fn place(
        &self,
        block: usize,
        answer: &Response,
        request: &Request,
        base: u16,
    ) -> Option<BlockImage> {
        let len = usize::from(request.read_span()?.1);
        let part = image_of(answer, len)?;
        let mut image = self.empty_image(block);
        let base = usize::from(base);
        match (&mut image, part) {
            (BlockImage::Words(all), BlockImage::Words(words)) => {
                all.get_mut(base..base + len)?
                    .copy_from_slice(words.get(..len)?);
            }
            (BlockImage::Bits(all), BlockImage::Bits(bits)) => {
                all.get_mut(base..base + len)?
                    .copy_from_slice(bits.get(..len)?);
            }
            _ => return None,
        }
        Some(image)
    }

    /// The write requests, computed from the fresh answers to `reads_before()`. Empty when the
    /// device already is in the commanded state (a toggle field asked for its current state).
    pub(crate) fn writes(&self, before: &[Response]) -> Result<Vec<Request>, Rejection> {
        let profile = &self.profile;
        let frame = &self.frame;
        let name = &self.label;
        let fresh = if self.reads_before.is_empty() {
            self.empty_image(frame.block)
        } else {
            before
                .first()
                .and_then(|answer| {
                    self.place(frame.block, answer, &self.reads_before[0], self.before_base)
                })
                .ok_or_else(|| {
                    Rejection(format!(
                        "{name}: the read before the write did not return block `{}`",
                        profile.blocks[frame.block].name
                    ))
                })?
        };

        // The exponents of `scale_by` targets held in other blocks, as read in this slot.
        let mut images = vec![(frame.block, fresh.clone())];
        for ((block, base), (request, answer)) in self
            .exponent_places
            .iter()
            .zip(self.reads_before.iter().zip(before).skip(1))
        {
            if let Some(image) = self.place(*block, answer, request, *base) {
                images.push((*block, image));
            }
        }

        // Toggles already in the commanded state are left alone (written 0).
        let mut pressed = Vec::new();
        let mut intended = fresh.clone();
        let mut encodings = Vec::new();
        for (field, target) in &self.targets {
            let def = &profile.defs[*field];
            let field_name = &profile.infos[*field].name;
            let exponent = self.exponent(*field, &images);
            let encoded = def
                .codec
                .encode_with(def.offset, target, &exponent)
                .map_err(|why| Rejection(format!("{field_name}: {why}")))?;
            encodings.push(encoded.clone());
            match def.behaviour {
                Behaviour::State => {}
                Behaviour::Momentary => pressed.push(*field),
                Behaviour::Toggle => {
                    let current = def.codec.decode(&fresh, def.offset).map_err(|err| {
                        Rejection(format!(
                            "{field_name}: the fresh read is not usable ({err})"
                        ))
                    })?;
                    if current != *target {
                        pressed.push(*field);
                    }
                }
            }
            intended.apply(&encoded);
        }
        let only_toggles = self
            .targets
            .iter()
            .all(|(field, _)| profile.defs[*field].behaviour == Behaviour::Toggle);
        if only_toggles && pressed.is_empty() {
            return Ok(Vec::new());
        }

        // The state the device would be in: refuse forbidden combinations on the fresh read.
        for (field, target) in &self.targets {
            check_forbidden(profile, *field, target, |index| {
                let other = &profile.defs[index];
                (other.block == frame.block)
                    .then(|| other.codec.decode(&intended, other.offset).ok())
                    .flatten()
            })?;
        }

        // What goes on the wire: as read, with buttons and toggles at rest, then the command.
        let mut image = fresh;
        for other in &profile.defs {
            if other.block == frame.block
                && other.behaviour != Behaviour::State
                && inside_frame(other.offset, other.codec.width(), frame)
            {
                image.apply(&rest_patches(other.codec.footprint(other.offset)));
            }
        }
        for ((field, _), encoded) in self.targets.iter().zip(&encodings) {
            if profile.defs[*field].behaviour == Behaviour::State {
                image.apply(encoded);
            }
        }
        for field in pressed {
            // Writing 1 is the action itself, whatever the bit's sense when read.
            let def = &profile.defs[field];
            let press: Vec<RawPatch> = def
                .codec
                .footprint(def.offset)
                .into_iter()
                .map(|(offset, mask)| RawPatch {
                    offset,
                    mask,
                    bits: mask,
                })
                .collect();
            image.apply(&press);
        }
        Ok(frame_requests(frame, &image))
    }

    /// Reads that verify the command, made right after the writes; their answers go to
    /// [`FieldPlan::verify`].
    pub(crate) fn readback(&self) -> &[Request] {
        &self.readback
    }

    /// The profile's read blocks (indices into its `read_blocks()`) whose data the command can
    /// change, as the profile knows it: those its read-back looks at (the targets' block and
    /// the blocks of its settle conditions).
    pub(crate) fn readback_blocks(&self) -> impl Iterator<Item = usize> + '_ {
        self.readback_places.iter().map(|&(block, _)| block)
    }

    /// The answers to `readback()` placed in images of their blocks, by block.
    fn readback_images(&self, answers: &[Response]) -> Vec<(usize, BlockImage)> {
        answers
            .iter()
            .zip(&self.readback)
            .zip(&self.readback_places)
            .filter_map(|((answer, request), &(block, base))| {
                self.place(block, answer, request, base)
                    .map(|image| (block, image))
            })
            .collect()
    }

    /// Judges the answers to `readback()`. The first call judges the read-back right after the
    /// write; later calls the repeated read-backs of a settling command.
    pub(crate) fn verify(&self, answers: &[Response]) -> Verification {
        let repeated = self.first_readback_judged.set(()).is_err();
        let profile = &self.profile;
        let images = self.readback_images(answers);
        let Some(image) = images
            .iter()
            .find(|(block, _)| *block == self.frame.block)
            .map(|(_, image)| image)
        else {
            return Verification::NotApplied(format!("{}: no usable read-back", self.label));
        };
        let mut differences = Vec::new();
        for (field, target) in &self.targets {
            let def = &profile.defs[*field];
            let name = &profile.infos[*field].name;
            if def.behaviour == Behaviour::Momentary {
                // A button has no state to show; the acknowledged write is the whole effect.
                continue;
            }
            let exponent = self.exponent(*field, &images);
            match def.codec.decode_with(image, def.offset, &exponent) {
                Ok(value) if value.same_number(target) => {}
                Ok(value) => differences.push(format!(
                    "{name} reads {} after writing {}",
                    value.to_text(),
                    target.to_text()
                )),
                Err(err) => differences.push(format!("{name} read-back invalid: {err}")),
            }
        }
        if differences.is_empty() {
            Verification::Applied
        } else if self.settle_window().is_none() {
            Verification::NotApplied(differences.join("; "))
        } else if let Some(stopped) = repeated.then(|| self.settled_short(&images)).flatten() {
            Verification::NotApplied(format!(
                "{} and {stopped}: it stopped short of the commanded value",
                differences.join("; ")
            ))
        } else {
            Verification::Settling
        }
    }

    /// The exponent a target is written and judged with, from the images of this slot's reads.
    fn exponent(&self, field: usize, images: &[(usize, BlockImage)]) -> Exponent {
        let profile = &self.profile;
        profile.exponent_for(field, |exponent| {
            let def = &profile.defs[exponent];
            let (_, image) = images.iter().find(|(block, _)| *block == def.block)?;
            Some(def.codec.decode(image, def.offset))
        })
    }

    /// When the targets' `settle_until` conditions all hold on a repeated read-back (the motor
    /// has stopped), the conditions as text (`motor reads stopped`); None while any does not hold
    /// or cannot be read, and when there are none (then only the settle window ends it).
    fn settled_short(&self, images: &[(usize, BlockImage)]) -> Option<String> {
        let profile = &self.profile;
        let mut conditions = Vec::new();
        for (field, _) in &self.targets {
            for (condition, expected) in &profile.defs[*field].settle_until {
                let def = &profile.defs[*condition];
                let (_, image) = images.iter().find(|(block, _)| *block == def.block)?;
                let value = def.codec.decode(image, def.offset).ok()?;
                if value != *expected {
                    return None;
                }
                conditions.push(format!(
                    "{} reads {}",
                    profile.infos[*condition].name,
                    value.to_text()
                ));
            }
        }
        (!conditions.is_empty()).then(|| conditions.join(" and "))
    }

    /// How long a `Settling` read-back may keep being repeated.
    pub(crate) fn settle_window(&self) -> Option<Duration> {
        self.targets
            .iter()
            .filter_map(|(field, _)| self.profile.defs[*field].settle_window)
            .max()
    }
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

/// True when `width` places from `offset` differ between two answers, or when the answers
/// are not of one kind and length (nothing of one says what the other holds).
pub(crate) fn places_differ(
    answer: &Response,
    previous: &Response,
    offset: u16,
    width: u16,
) -> bool {
    fn differ<T: PartialEq>(now: &[T], then: &[T], offset: u16, width: u16) -> bool {
        let start = usize::from(offset);
        let end = start + usize::from(width);
        now.len() != then.len() || now.get(start..end) != then.get(start..end)
    }
    match (answer, previous) {
        (Response::HoldingRegisters(now), Response::HoldingRegisters(then))
        | (Response::InputRegisters(now), Response::InputRegisters(then)) => {
            differ(now, then, offset, width)
        }
        (Response::Coils(now), Response::Coils(then))
        | (Response::DiscreteInputs(now), Response::DiscreteInputs(then)) => {
            differ(now, then, offset, width)
        }
        _ => true,
    }
}

/// An all-zero image of the block `request` reads (an empty word image for a write).
pub(crate) fn empty_image(request: &Request) -> BlockImage {
    request
        .empty_answer()
        .and_then(|answer| image_of(&answer, 0))
        .unwrap_or(BlockImage::Words(Vec::new()))
}

/// `span` (start, end) widened to cover `width` places from `offset`.
fn widen(span: (u16, u16), offset: u16, width: u16) -> (u16, u16) {
    (span.0.min(offset), span.1.max(offset + width))
}

/// The read that covers `span` of a block using only the block's used runs (the reads the
/// device is known to accept even when it refuses the merged block), and its block offset.
fn run_read(profile: &Compiled, block: usize, span: (u16, u16)) -> (Request, u16) {
    let read = &profile.blocks[block];
    let (mut start, mut end) = span;
    for &(run_start, run_len) in &read.used_runs {
        let run_end = run_start + run_len;
        if run_start < span.1 && span.0 < run_end {
            start = start.min(run_start);
            end = end.max(run_end);
        }
    }
    let quantity = end.saturating_sub(start);
    let request = read
        .request
        .sub_read(start, quantity)
        .unwrap_or_else(|| read.request.clone());
    (request, start)
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
