//! [`Profile`], the validated device profile, and the questions the rest of the gateway asks
//! it: its fields and blocks, how an answer decodes into field values, how a command becomes
//! one bus slot's plan, and what a write frame did to a simulated device's raw image.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;

use rtu2mqtt_modbus::{Request, Response};

use crate::{
    codec, command, compile, identification, model, number, BlockImage, FieldError, FieldInfo,
    FieldKind, Limits, ProfileError, ProfileErrors, RawPatch, ReadBlock, Rejection, Value,
};

/// Last known decoded values of one device, by field name.
pub type DeviceState = HashMap<String, Value>;

/// A validated device profile: made by [`Profile::from_toml`] or
/// [`registry`](crate::registry), never invalid, and cheap to clone (the compiled form is
/// shared, also with its command plans).
#[derive(Debug, Clone)]
pub struct Profile {
    // Shared with the command plans made from it.
    pub(crate) inner: Arc<model::Compiled>,
}

/// One field's value from a block, or why it has none.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldReading {
    /// The field's `name` in the profile (its MQTT topic's last level).
    pub field: String,
    /// The decoded value, or why the answer holds none for this field (invalid BCD, an answer
    /// that does not fit the block, a `scale_by` exponent that was not read).
    pub value: Result<Value, codec::FieldError>,
}

impl Profile {
    /// Parses and validates a profile from TOML text; `source` (a path or `built-in NAME`)
    /// prefixes the place of every problem.
    pub fn from_toml(text: &str, source: &str) -> Result<Self, ProfileErrors> {
        compile::compile(text, source).map(|compiled| Self {
            inner: Arc::new(compiled),
        })
    }

    /// The profile's name (`ruiwan-dust-collector`).
    pub fn name(&self) -> &str {
        &self.inner.name
    }

    /// The maker as the profile's `device.manufacturer` names it (Home Assistant's `mf`).
    pub fn manufacturer(&self) -> &str {
        &self.inner.manufacturer
    }

    /// The device model from `device.model` (Home Assistant's `mdl`).
    pub fn model(&self) -> &str {
        &self.inner.model
    }

    /// What the device reports when asked what it is (`device.identification`), if the
    /// profile says.
    pub fn identification(&self) -> Option<&identification::Identification> {
        self.inner.identification.as_ref()
    }

    /// The free text of `device.description`; empty when the profile has none.
    pub(crate) fn description(&self) -> &str {
        &self.inner.description
    }

    /// The address the device usually has (the air shower's fixed 0x81), if the profile says.
    pub fn default_address(&self) -> Option<u8> {
        self.inner.default_address
    }

    /// What the profile's compilation warns about: it loads, but something in it is likely a
    /// mistake (a block `start` that looks like a Modicon number of a manual). Shown by
    /// `check` and `profiles`.
    pub fn warnings(&self) -> &[ProfileError] {
        &self.inner.warnings
    }

    /// The `[line]` section: line defaults, the address range and the device's transaction
    /// limits, with the defaults filled in.
    pub fn limits(&self) -> &Limits {
        &self.inner.limits
    }

    /// Every field in the order of the file's `[[fields]]`.
    pub fn fields(&self) -> &[FieldInfo] {
        &self.inner.infos
    }

    /// The field named `name`; `None` when the profile has no such field.
    pub fn field(&self, name: &str) -> Option<&FieldInfo> {
        self.fields().iter().find(|f| f.name == name)
    }

    /// The `[[blocks]]` the device is polled with, in file order; a block's index here is the
    /// `block` every other method takes.
    pub fn read_blocks(&self) -> &[ReadBlock] {
        &self.inner.blocks
    }

    /// Names of the fields decoded from `read_blocks()[block]`.
    pub fn block_fields(&self, block: usize) -> Vec<&str> {
        self.field_names_where(|def| def.block == block)
    }

    /// Names of the fields whose compiled definition passes `keep`, in file order.
    pub(crate) fn field_names_where(&self, keep: impl Fn(&model::FieldDef) -> bool) -> Vec<&str> {
        self.inner
            .defs
            .iter()
            .zip(&self.inner.infos)
            .filter(|(def, _)| keep(def))
            .map(|(_, info)| info.name.as_str())
            .collect()
    }

    /// Decodes the answer to `read_blocks()[block]` into its fields' values. An answer of the
    /// wrong kind or length gives every field of the block an error; a bad field (invalid BCD)
    /// gives an error for that field only. A `scale_by` field whose exponent lies in another
    /// block is invalid this way: see [`Profile::decode_block_with`].
    pub fn decode_block(&self, block: usize, answer: &Response) -> Vec<FieldReading> {
        self.decode_block_with(block, answer, |_| None)
    }

    /// The blocks (other than `block`) holding fields whose exponent lies in `block`: their
    /// values change when `block`'s answer does.
    pub fn blocks_scaled_by(&self, block: usize) -> Vec<usize> {
        let defs = &self.inner.defs;
        let mut users: Vec<usize> = defs
            .iter()
            .filter(|def| def.block != block)
            .filter(|def| def.scale_by.is_some_and(|e| defs[e].block == block))
            .map(|def| def.block)
            .collect();
        users.sort_unstable();
        users.dedup();
        users
    }

    /// [`Profile::decode_block`], with `latest(b)` the latest answer to block `b` for the
    /// exponents of `scale_by` fields that lie in other blocks (None: not read; such a field's
    /// value is then invalid data).
    pub fn decode_block_with<'a>(
        &self,
        block: usize,
        answer: &Response,
        latest: impl Fn(usize) -> Option<&'a Response>,
    ) -> Vec<FieldReading> {
        self.decode_fields_of(block, answer, latest, |_| true)
    }

    /// [`Profile::decode_block_with`], for only the fields whose places differ between `answer`
    /// and `previous`, an earlier answer to the same block: the others would decode to what
    /// they did from `previous`, provided every field decoded from it and the exponents in
    /// other blocks are the same. A field scaled by an exponent in this block counts the
    /// exponent's places as its own. Every field when `previous` is `None` or an answer of
    /// another kind or length.
    pub fn decode_block_changes<'a>(
        &self,
        block: usize,
        answer: &Response,
        previous: Option<&Response>,
        latest: impl Fn(usize) -> Option<&'a Response>,
    ) -> Vec<FieldReading> {
        let Some(previous) = previous else {
            return self.decode_block_with(block, answer, latest);
        };
        let defs = &self.inner.defs;
        let moved = |def: &model::FieldDef| {
            command::places_differ(answer, previous, def.offset, def.codec.width())
        };
        self.decode_fields_of(block, answer, latest, |def| {
            moved(def)
                || def
                    .scale_by
                    .map(|exponent| &defs[exponent])
                    .is_some_and(|exponent| exponent.block == block && moved(exponent))
        })
    }

    /// The readings of `block`'s fields that pass `keep`, decoded from `answer`.
    fn decode_fields_of<'a>(
        &self,
        block: usize,
        answer: &Response,
        latest: impl Fn(usize) -> Option<&'a Response>,
        keep: impl Fn(&model::FieldDef) -> bool,
    ) -> Vec<FieldReading> {
        let Some(read) = self.inner.blocks.get(block) else {
            return Vec::new();
        };
        let expected = read
            .request
            .read_span()
            .map_or(0, |(_, quantity)| usize::from(quantity));
        let image = command::image_of(answer, expected).filter(|image| {
            matches!(
                (image, self.inner.block_kinds[block].is_bits()),
                (BlockImage::Bits(_), true) | (BlockImage::Words(_), false)
            )
        });
        let inner = &self.inner;
        let exponent_of = |index: usize, image: &BlockImage| {
            inner.exponent_for(index, |exponent| {
                let def = &inner.defs[exponent];
                if def.block == block {
                    return Some(def.codec.decode(image, def.offset));
                }
                let length = inner.blocks[def.block]
                    .request
                    .read_span()
                    .map_or(0, |(_, quantity)| usize::from(quantity));
                let other = command::image_of(latest(def.block)?, length)?;
                Some(def.codec.decode(&other, def.offset))
            })
        };
        inner
            .defs
            .iter()
            .zip(&inner.infos)
            .enumerate()
            .filter(|(_, (def, _))| def.block == block && keep(def))
            .map(|(index, (def, info))| FieldReading {
                field: info.name.clone(),
                value: match &image {
                    Some(image) => {
                        def.codec
                            .decode_with(image, def.offset, &exponent_of(index, image))
                    }
                    None => Err(FieldError::Invalid(format!(
                        "the answer does not fit block `{}`",
                        read.name
                    ))),
                },
            })
            .collect()
    }

    /// Decodes the answer to any read inside one block (a whole block, one of its used runs,
    /// or a command slot's read): the values of the fields that lie entirely inside the read.
    /// Empty when no block of the profile contains the read.
    pub fn decode_read(&self, request: &Request, answer: &Response) -> Vec<FieldReading> {
        let Some((_, quantity)) = request.read_span() else {
            return Vec::new();
        };
        let inner = &self.inner;
        let Some((block, base)) = inner
            .blocks
            .iter()
            .enumerate()
            .find_map(|(index, block)| Some((index, block.request.offset_of(request)?)))
        else {
            return Vec::new();
        };
        let Some(part) = command::image_of(answer, usize::from(quantity)) else {
            return Vec::new();
        };
        let inside = |def: &model::FieldDef| {
            def.block == block
                && def.offset >= base
                && u32::from(def.offset) + u32::from(def.codec.width())
                    <= u32::from(base) + u32::from(quantity)
        };
        inner
            .defs
            .iter()
            .zip(&inner.infos)
            .enumerate()
            .filter(|(_, (def, _))| inside(def))
            .map(|(index, (def, info))| {
                // An exponent is only taken from the same read.
                let exponent = inner.exponent_for(index, |exponent| {
                    let held = &inner.defs[exponent];
                    inside(held).then(|| held.codec.decode(&part, held.offset - base))
                });
                FieldReading {
                    field: info.name.clone(),
                    value: def.codec.decode_with(&part, def.offset - base, &exponent),
                }
            })
            .collect()
    }

    /// The fields a foreign master's `write` sets, with the values it gives them, found
    /// through the profile's write frames (a write lands at a frame's write address, which need
    /// not be its place in the read block). `None` when no write frame of the profile holds
    /// every register or coil the write touches; the values of fields the write covers whole.
    pub fn decode_write(&self, write: &Request) -> Option<Vec<FieldReading>> {
        let (frame, written) = self.landing(write)?;
        let quantity = u16::try_from(written.count).ok()?;
        let block = self.inner.blocks.get(frame.block)?;
        let read = block
            .request
            .sub_read(frame.offset + (written.start - frame.address), quantity)?;
        Some(self.decode_read(&read, &written.values))
    }

    /// The `scale_by` numbers whose exponent a device polled every `poll_interval` (its fast
    /// blocks; zero is continuous polling at the profile's minimum) would read less often than
    /// the number itself, as (number, exponent field). `check` refuses such a device: the
    /// profile alone is judged at its own default interval.
    pub fn exponents_read_too_rarely(&self, poll_interval: Duration) -> Vec<(String, String)> {
        let inner = &self.inner;
        let fast = if poll_interval.is_zero() {
            inner.limits.min_poll_interval
        } else {
            poll_interval
        };
        inner
            .defs
            .iter()
            .zip(&inner.infos)
            .filter_map(|(def, info)| {
                let exponent = def.scale_by?;
                let held = inner.blocks.get(inner.defs.get(exponent)?.block)?.class;
                let user = inner.blocks.get(def.block)?.class;
                if compile::polled_at_least_as_often(held, user, &inner.limits, fast) {
                    return None;
                }
                Some((info.name.clone(), inner.infos.get(exponent)?.name.clone()))
            })
            .collect()
    }

    /// Every writable field a foreign master's `write` touches, whole or in part, found by
    /// address through the fields' write frames: a raw write of one register of a two-register
    /// value still writes that field (and its EEPROM).
    pub fn fields_touched(&self, write: &Request) -> Vec<String> {
        let Some(written) = Written::of(write) else {
            return Vec::new();
        };
        let first = usize::from(written.start);
        let end = first + written.count;
        let inner = &self.inner;
        inner
            .defs
            .iter()
            .zip(&inner.infos)
            .filter_map(|(def, info)| {
                let frame = def.write.as_ref()?;
                if matches!(frame.function, 6 | 16) != written.registers {
                    return None;
                }
                let at =
                    usize::from(frame.address) + usize::from(def.offset.checked_sub(frame.offset)?);
                let width = usize::from(def.codec.width());
                (at < end && first < at + width).then(|| info.name.clone())
            })
            .collect()
    }

    /// The write frame a foreign master's `write` lands on (the first of the profile's that
    /// holds every register or coil it touches), and what the write sets.
    pub(crate) fn landing(&self, write: &Request) -> Option<(&model::WriteFrame, Written)> {
        let written = Written::of(write)?;
        let start = u32::from(written.start);
        let end = start + u32::try_from(written.count).ok()?;
        let inner = &self.inner;
        let frames = inner
            .defs
            .iter()
            .filter_map(|def| def.write.as_ref())
            .chain(inner.named_frames.iter().map(|(_, frame)| frame));
        let frame = frames
            .filter(|frame| matches!(frame.function, 0x06 | 0x10) == written.registers)
            .find(|frame| {
                let address = u32::from(frame.address);
                start >= address && end <= address + u32::from(frame.count)
            })?;
        Some((frame, written))
    }

    /// How a field behaves when written (a state, a toggle, a button) and whether it is an
    /// overlay (a view over bits other fields own); `None` for an unknown field.
    pub fn write_behaviour(&self, field: &str) -> Option<(model::Behaviour, bool)> {
        let index = self
            .inner
            .infos
            .iter()
            .position(|info| info.name == field)?;
        let def = self.inner.defs.get(index)?;
        Some((def.behaviour, def.overlay))
    }

    /// The field's index and the command text parsed for it; refuses unknown and read-only
    /// fields.
    pub(crate) fn parse_target(
        &self,
        field: &str,
        text: &str,
    ) -> Result<(usize, Value), Rejection> {
        let inner = &self.inner;
        let index = inner
            .infos
            .iter()
            .position(|info| info.name == field)
            .ok_or_else(|| Rejection(format!("unknown field `{field}` for {}", inner.name)))?;
        let info = &inner.infos[index];
        if !info.writable {
            return Err(Rejection(format!("{field} is read-only")));
        }
        let def = &inner.defs[index];
        let target = self.parse_field_value(index, text)?;
        // Kinds and ranges are validated against the codec at load, so this only fails on a
        // profile bug; refuse rather than write something else. A `scale_by` number is
        // encoded in its slot, with the exponent read there.
        if !def.codec.needs_exponent() {
            def.codec
                .encode(def.offset, &target)
                .map_err(|why| Rejection(format!("{field}: {why}")))?;
        }
        Ok((index, target))
    }

    /// `text` as a value of field `index`: of its kind and range, or one of its `also` values.
    fn parse_field_value(&self, index: usize, text: &str) -> Result<Value, Rejection> {
        let (info, def) = (&self.inner.infos[index], &self.inner.defs[index]);
        match codec::parse_command(info, text) {
            Ok(value) => Ok(value),
            Err(rejection) if def.also.is_empty() => Err(rejection),
            Err(rejection) => match number::integer(text) {
                Some(value) if def.also.contains(&value) => Ok(Value::Int(i128::from(value))),
                _ => {
                    let list: Vec<String> = def.also.iter().map(ToString::to_string).collect();
                    let or = format!(" or {}, got ", list.join(", "));
                    Err(Rejection(rejection.0.replacen(", got ", &or, 1)))
                }
            },
        }
    }

    /// Judges forbidden combinations on the last known state with the command applied. Fields
    /// not known yet are left to the fresh read in `CommandPlan::writes`.
    pub(crate) fn check_known_state(
        &self,
        targets: &[(usize, Value)],
        state: &DeviceState,
    ) -> Result<(), Rejection> {
        let inner = &self.inner;
        let block = inner.defs[targets[0].0].block;
        let mut image = command::empty_image(&inner.blocks[block].request);
        let mut known = vec![false; inner.defs.len()];
        for (i, other) in inner.defs.iter().enumerate() {
            if other.block != block || other.overlay {
                continue;
            }
            if let Some(patches) = state
                .get(&inner.infos[i].name)
                .and_then(|value| other.codec.encode(other.offset, value).ok())
            {
                image.apply(&patches);
                known[i] = true;
            }
        }
        let mut touched = Vec::new();
        for (index, target) in targets {
            let def = &inner.defs[*index];
            if let Ok(patches) = def.codec.encode(def.offset, target) {
                image.apply(&patches);
            }
            touched.extend(def.codec.footprint(def.offset));
        }
        for (index, target) in targets {
            command::check_forbidden(inner, *index, target, |i| {
                let other = &inner.defs[i];
                let hit = other
                    .codec
                    .footprint(other.offset)
                    .iter()
                    .any(|(o, m)| touched.iter().any(|(to, tm)| o == to && m & tm != 0));
                (known[i] || hit)
                    .then(|| other.codec.decode(&image, other.offset).ok())
                    .flatten()
            })?;
        }
        Ok(())
    }

    /// The raw change that puts `value` into a field's place: the block index and the patches
    /// to apply to that block's image. For simulators seeding plausible values and for tests;
    /// the value must have the field's kind (e.g. from [`Profile::parse_value`]).
    pub fn encode_value_raw(
        &self,
        field: &str,
        value: &Value,
    ) -> Result<(usize, Vec<RawPatch>), Rejection> {
        let index = self
            .inner
            .infos
            .iter()
            .position(|info| info.name == field)
            .ok_or_else(|| Rejection(format!("unknown field `{field}`")))?;
        let def = &self.inner.defs[index];
        def.codec
            .encode(def.offset, value)
            .map(|patches| (def.block, patches))
            .map_err(|why| Rejection(format!("{field}: {why}")))
    }

    /// Example commands as (field, value text): the ones the profile declares (`example = …` on
    /// a field), or else one made up for its first writable field that holds a state, so that
    /// every writable profile can show how it is commanded.
    pub fn example_commands(&self) -> Vec<(&str, String)> {
        let inner = &self.inner;
        let declared: Vec<(&str, String)> = inner
            .defs
            .iter()
            .zip(&inner.infos)
            .filter_map(|(def, info)| Some((info.name.as_str(), def.example.clone()?)))
            .collect();
        if !declared.is_empty() {
            return declared;
        }
        inner
            .infos
            .iter()
            .filter(|info| info.writable)
            .find_map(|info| Some((info.name.as_str(), made_up_example(&info.kind)?)))
            .into_iter()
            .collect()
    }

    /// Parses text into a value of the field's kind, with the same rules as commands (its
    /// range, or one of its `also` values), whether or not the field is writable.
    pub fn parse_value(&self, field: &str, text: &str) -> Result<Value, Rejection> {
        let index = self
            .inner
            .infos
            .iter()
            .position(|info| info.name == field)
            .ok_or_else(|| Rejection(format!("unknown field `{field}`")))?;
        self.parse_field_value(index, text)
    }
}

/// What a foreign master's write sets: where, how many registers or coils, and their values
/// as the answer to a read of the same place would hold them.
pub(crate) struct Written {
    /// The first address written.
    start: u16,
    /// Registers or coils written.
    count: usize,
    /// Registers (FC 06/10), else coils (FC 05/0F).
    registers: bool,
    /// The values, as `HoldingRegisters` or `Coils`.
    values: Response,
}

impl Written {
    /// `write`'s values; None for a request that writes nothing.
    fn of(write: &Request) -> Option<Self> {
        Some(match write {
            Request::WriteSingleRegister { address, value } => {
                Self::registers(*address, vec![*value])
            }
            Request::WriteMultipleRegisters { start, values } => {
                Self::registers(*start, values.clone())
            }
            Request::WriteSingleCoil { address, value } => Self::coils(*address, vec![*value]),
            Request::WriteMultipleCoils { start, values } => Self::coils(*start, values.clone()),
            _ => return None,
        })
    }

    fn registers(start: u16, words: Vec<u16>) -> Self {
        Self {
            start,
            count: words.len(),
            registers: true,
            values: Response::HoldingRegisters(words),
        }
    }

    fn coils(start: u16, bits: Vec<bool>) -> Self {
        Self {
            start,
            count: bits.len(),
            registers: false,
            values: Response::Coils(bits),
        }
    }
}

/// A valid command value for a field of this kind: a state to switch on, the top of a range, the
/// last option (the first is usually the resting state: `off`, `manual`). None for buttons and
/// text.
fn made_up_example(kind: &FieldKind) -> Option<String> {
    match kind {
        FieldKind::Bool => Some("ON".to_string()),
        FieldKind::Integer { max, .. } => Some(max.to_string()),
        FieldKind::Decimal { max, precision, .. } => Some(format!(
            "{max:.precision$}",
            precision = usize::from(*precision)
        )),
        FieldKind::Enum { options } => options.last().cloned(),
        FieldKind::Momentary | FieldKind::Text => None,
    }
}
