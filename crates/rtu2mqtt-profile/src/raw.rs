//! The device side of a profile, for simulated devices: block images seeded with plausible
//! values, and write requests applied to those images through the profile's write frames (so a
//! simulator honours quirks such as the dust collector's FC06 addresses stepping by 2 while its
//! read block is consecutive). Pure: the simulator owns the images and the behaviour.

use super::codec::BlockImage;
use super::model::Behaviour;
use super::{FieldKind, Profile, Value};
use rtu2mqtt_modbus::{Request, Response};

impl Profile {
    /// A plausible value for a field: the middle of a number's range, the first option of an
    /// enumeration, OFF for booleans, a `string` its own name (byte strings none). Always
    /// encodable by the field's codec.
    pub fn plausible_value(&self, field: &str) -> Option<Value> {
        let index = self
            .inner
            .infos
            .iter()
            .position(|info| info.name == field)?;
        let info = &self.inner.infos[index];
        // Scaled integer words only hold whole multiples of their step (in last-place units).
        let step = match &info.step {
            Some(Value::Int(counts)) => *counts,
            Some(Value::Decimal { scaled, .. }) => *scaled,
            _ => 1,
        }
        .max(1);
        Some(match &info.kind {
            FieldKind::Bool | FieldKind::Momentary => Value::Bool(false),
            FieldKind::Integer { min, max } => {
                Value::Int(on_step(min + (max - min) / 2, *min, step))
            }
            FieldKind::Decimal {
                min,
                max,
                precision,
            } => {
                let factor = 10f64.powi(i32::from(*precision));
                // Keep sensor-like magnitudes for unbounded floats.
                let (min, max) = (min.max(-1000.0), max.min(1000.0));
                let (low, middle) = (
                    (min * factor).round() as i128,
                    ((min + max) / 2.0 * factor).round() as i128,
                );
                Value::Decimal {
                    scaled: on_step(middle, low, step),
                    precision: *precision,
                }
            }
            FieldKind::Enum { options } => Value::Enum(options.first()?.clone()),
            // A `string` holds its own name, as much as fits (`MODEL`); byte strings stay zero.
            FieldKind::Text => match self.inner.defs[index].codec {
                super::codec::FieldCodec::Text { registers, .. } => Value::Text(
                    info.name
                        .to_ascii_uppercase()
                        .chars()
                        .take(2 * usize::from(registers))
                        .collect(),
                ),
                _ => return None,
            },
        })
    }

    /// An image of `read_blocks()[block]` with every field at its plausible value (byte strings
    /// and unused places zero). None for an unknown block.
    pub fn initial_image(&self, block: usize) -> Option<BlockImage> {
        let read = self.inner.blocks.get(block)?;
        let mut image = super::command::empty_image(&read.request);
        for (def, info) in self.inner.defs.iter().zip(&self.inner.infos) {
            if def.block != block || def.overlay {
                continue;
            }
            if let Some(patches) = self
                .plausible_value(&info.name)
                .and_then(|value| def.codec.encode(def.offset, &value).ok())
            {
                image.apply(&patches);
            }
        }
        Some(image)
    }

    /// Applies a write request to the block images (one per `read_blocks()` entry) as the
    /// device would store it, through the profile's write frames. Returns false when no write
    /// frame of the profile covers the request (a real device would answer exception 02).
    /// Device behaviour beyond storage (toggles, buttons, standby) is the simulator's.
    pub fn apply_write(&self, images: &mut [BlockImage], request: &Request) -> bool {
        let (function, address, values): (u8, u16, Vec<u16>) = match request {
            Request::WriteSingleCoil { address, value } => (5, *address, vec![u16::from(*value)]),
            Request::WriteSingleRegister { address, value } => (6, *address, vec![*value]),
            Request::WriteMultipleCoils { start, values } => {
                (15, *start, values.iter().map(|b| u16::from(*b)).collect())
            }
            Request::WriteMultipleRegisters { start, values } => (16, *start, values.clone()),
            _ => return false,
        };
        let frame = self
            .inner
            .defs
            .iter()
            .filter_map(|d| d.write.as_ref())
            .find(|frame| {
                let end = u32::from(frame.address) + u32::from(frame.count);
                frame.function == function
                    && address >= frame.address
                    && u32::from(address) + values.len() as u32 <= end
            });
        let Some(frame) = frame else {
            return false;
        };
        let Some(image) = images.get_mut(frame.block) else {
            return false;
        };
        let first = frame.offset + (address - frame.address);
        for (i, value) in values.iter().enumerate() {
            let index = usize::from(first) + i;
            match image {
                BlockImage::Words(words) => match words.get_mut(index) {
                    Some(word) => *word = *value,
                    None => return false,
                },
                BlockImage::Bits(bits) => match bits.get_mut(index) {
                    Some(bit) => *bit = *value != 0,
                    None => return false,
                },
            }
        }
        true
    }

    /// Answers a read request from the block images (one per `read_blocks()` entry) when one
    /// block of the same kind covers it: the whole block or any part of it. None otherwise (a
    /// real device would answer exception 02).
    pub fn answer_read(&self, images: &[BlockImage], request: &Request) -> Option<Response> {
        let quantity = usize::from(request.read_span()?.1);
        self.inner
            .blocks
            .iter()
            .zip(images)
            .find_map(|(block, image)| {
                let offset = block.request.offset_of(request)?;
                let from = usize::from(offset);
                let to = from + quantity;
                Some(match (request, image) {
                    (Request::ReadCoils { .. }, BlockImage::Bits(bits)) => {
                        Response::Coils(bits.get(from..to)?.to_vec())
                    }
                    (Request::ReadDiscreteInputs { .. }, BlockImage::Bits(bits)) => {
                        Response::DiscreteInputs(bits.get(from..to)?.to_vec())
                    }
                    (Request::ReadHoldingRegisters { .. }, BlockImage::Words(words)) => {
                        Response::HoldingRegisters(words.get(from..to)?.to_vec())
                    }
                    (Request::ReadInputRegisters { .. }, BlockImage::Words(words)) => {
                        Response::InputRegisters(words.get(from..to)?.to_vec())
                    }
                    _ => return None,
                })
            })
    }

    /// Names of the toggle fields (write 1 flips the state), for simulators.
    pub fn toggle_fields(&self) -> Vec<&str> {
        self.field_names_where(|def| def.behaviour == Behaviour::Toggle)
    }

    /// Names of the momentary fields (buttons), for simulators.
    pub fn momentary_fields(&self) -> Vec<&str> {
        self.field_names_where(|def| def.behaviour == Behaviour::Momentary)
    }
}

/// `value` moved down to a multiple of `step`, or up when that falls below `min`.
fn on_step(value: i128, min: i128, step: i128) -> i128 {
    let down = value - value.rem_euclid(step);
    if down < min {
        down + step
    } else {
        down
    }
}
