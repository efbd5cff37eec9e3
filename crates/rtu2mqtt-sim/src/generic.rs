//! A generic simulated device built from a profile's read blocks alone: memory for every
//! coil, discrete input and register the blocks cover, seeded with plausible values, and
//! FC01–06/0F/10 on it. Places no field uses get small numbers whose hex digits are all
//! decimal; each field then gets a value inside its range (the middle of a number's range,
//! an enumeration's first word, OFF), put in place by the profile's own encoder.
//!
//! Reads outside the memory give exception 02. Writes land anywhere in the coil and holding
//! register tables (a profile may write at addresses it reads elsewhere, like the dust
//! collector); a write to a read-only table does not exist in Modbus. A device may also have a
//! [`CommandInterface`]: an FC16 frame written at its first register is a command, and its
//! result code lands in the result register.
//!
//! Read Device Identification (FC43/14) is answered from the objects given with
//! [`GenericDevice::with_identification`] (basic, regular and extended streams, with "more
//! follows" where they do not fit one answer, and single objects); without them the device
//! does not implement the function and answers exception 01, as most devices do.

use std::collections::BTreeMap;
use std::time::Instant;

use super::command_interface::CommandInterface;
use super::device::{Reply, SimDevice};
use rtu2mqtt_modbus::device_id::{DeviceIdObject, DeviceIdentification};
use rtu2mqtt_modbus::frame::{ExceptionCode, Request, Response, SlaveId};
use rtu2mqtt_profile::{FieldKind, Profile, RawPatch, ReadBlock};

/// The four Modbus tables.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Table {
    Coils,
    DiscreteInputs,
    Holding,
    Input,
}

/// The simulated generic device.
#[derive(Debug, Clone)]
pub struct GenericDevice {
    address: SlaveId,
    memory: BTreeMap<(Table, u16), u16>,
    writes: u32,
    interface: Option<CommandInterface>,
    /// The identification objects FC43/14 reads, ordered by id; `None`: no FC43.
    identification: Option<Vec<DeviceIdObject>>,
}

/// The conformity level of a device holding `objects`: the highest category it has (basic
/// 01, regular 02, extended 03), with individual access (0x80).
fn conformity_level(objects: &[DeviceIdObject]) -> u8 {
    let category = match objects.iter().map(|o| o.id).max() {
        Some(0x80..) => 0x03,
        Some(0x03..=0x7F) => 0x02,
        _ => 0x01,
    };
    0x80 | category
}

impl GenericDevice {
    /// A device at `address` with memory for the profile's read blocks and every field seeded
    /// with a plausible value.
    pub fn from_profile(profile: &Profile, address: SlaveId) -> Self {
        let mut device = Self::from_blocks(profile.read_blocks(), address);
        for field in profile.fields() {
            // A button has no state to seed.
            if field.kind == FieldKind::Momentary {
                continue;
            }
            let Some(value) = profile.plausible_value(&field.name) else {
                continue;
            };
            let Ok((block, patches)) = profile.encode_value_raw(&field.name, &value) else {
                continue;
            };
            if let Some(read) = profile.read_blocks().get(block) {
                device.patch(&read.request, &patches);
            }
        }
        device
    }

    /// Applies a profile's raw patches to the block read by `request`.
    fn patch(&mut self, request: &Request, patches: &[RawPatch]) {
        let Some((table, start, _)) = block_place(request) else {
            return;
        };
        for patch in patches {
            let Some(at) = start.checked_add(patch.offset) else {
                continue;
            };
            let Some(word) = self.memory.get_mut(&(table, at)) else {
                continue;
            };
            *word = match table {
                Table::Coils | Table::DiscreteInputs if patch.mask & 1 != 0 => patch.bits & 1,
                Table::Coils | Table::DiscreteInputs => *word,
                Table::Holding | Table::Input => (*word & !patch.mask) | (patch.bits & patch.mask),
            };
        }
    }

    /// A device at `address` with memory for `blocks`.
    pub fn from_blocks(blocks: &[ReadBlock], address: SlaveId) -> Self {
        let mut memory = BTreeMap::new();
        for block in blocks {
            let Some((table, start, quantity)) = block_place(&block.request) else {
                continue;
            };
            for offset in 0..quantity {
                let Some(at) = start.checked_add(offset) else {
                    break;
                };
                memory.entry((table, at)).or_insert_with(|| seed(table, at));
            }
        }
        Self {
            address,
            memory,
            writes: 0,
            interface: None,
            identification: None,
        }
    }

    /// The device answering Read Device Identification with `objects` (their ids in any
    /// order; VendorName 0x00, ProductCode 0x01 and MajorMinorRevision 0x02 are the basic
    /// ones).
    pub fn with_identification(mut self, mut objects: Vec<DeviceIdObject>) -> Self {
        objects.sort_by_key(|object| object.id);
        self.identification = Some(objects);
        self
    }

    /// A device at `address` with no memory yet: registers are added with [`Self::set_holding`]
    /// and [`Self::set_input_register`] (the device library's register maps).
    pub fn empty(address: SlaveId) -> Self {
        Self {
            address,
            memory: BTreeMap::new(),
            writes: 0,
            interface: None,
            identification: None,
        }
    }

    /// The same device with a command interface; its result register reads 0 until the
    /// first command.
    pub fn with_command_interface(mut self, interface: CommandInterface) -> Self {
        self.memory
            .entry((Table::Holding, interface.result()))
            .or_insert(0);
        self.interface = Some(interface);
        self
    }

    /// The device's command interface, if it has one.
    pub fn command_interface(&self) -> Option<&CommandInterface> {
        self.interface.as_ref()
    }

    /// A register's value (holding registers).
    pub fn holding(&self, address: u16) -> Option<u16> {
        self.memory.get(&(Table::Holding, address)).copied()
    }

    pub fn set_holding(&mut self, address: u16, value: u16) {
        self.memory.insert((Table::Holding, address), value);
    }

    pub fn input_register(&self, address: u16) -> Option<u16> {
        self.memory.get(&(Table::Input, address)).copied()
    }

    pub fn set_input_register(&mut self, address: u16, value: u16) {
        self.memory.insert((Table::Input, address), value);
    }

    pub fn coil(&self, address: u16) -> Option<bool> {
        self.memory.get(&(Table::Coils, address)).map(|v| *v != 0)
    }

    pub fn set_coil(&mut self, address: u16, on: bool) {
        self.memory.insert((Table::Coils, address), u16::from(on));
    }

    pub fn set_discrete_input(&mut self, address: u16, on: bool) {
        self.memory
            .insert((Table::DiscreteInputs, address), u16::from(on));
    }

    /// Accepted writes so far.
    pub fn writes(&self) -> u32 {
        self.writes
    }

    fn read(
        &self,
        table: Table,
        start: u16,
        quantity: u16,
        limit: u16,
    ) -> Result<Vec<u16>, ExceptionCode> {
        if quantity == 0 || quantity > limit {
            return Err(ExceptionCode::IllegalDataValue);
        }
        (0..quantity)
            .map(|offset| {
                start
                    .checked_add(offset)
                    .and_then(|at| self.memory.get(&(table, at)).copied())
                    .ok_or(ExceptionCode::IllegalDataAddress)
            })
            .collect()
    }

    fn store(&mut self, table: Table, start: u16, values: &[u16]) -> Result<(), ExceptionCode> {
        if usize::from(start) + values.len() > 0x1_0000 {
            return Err(ExceptionCode::IllegalDataAddress);
        }
        for (offset, value) in values.iter().enumerate() {
            self.memory.insert((table, start + offset as u16), *value);
        }
        self.writes += 1;
        Ok(())
    }

    /// A frame written at the command interface's first register is a command: its result
    /// code lands in the result register.
    fn run_command(&mut self, start: u16, values: &[u16]) {
        let Some(interface) = self.interface.as_mut() else {
            return;
        };
        if let Some(code) = interface.take(start, values) {
            self.memory
                .insert((Table::Holding, interface.result()), code);
        }
    }
}

/// The table, start and quantity a read request covers.
fn block_place(request: &Request) -> Option<(Table, u16, u16)> {
    Some(match *request {
        Request::ReadCoils { start, quantity } => (Table::Coils, start, quantity),
        Request::ReadDiscreteInputs { start, quantity } => (Table::DiscreteInputs, start, quantity),
        Request::ReadHoldingRegisters { start, quantity } => (Table::Holding, start, quantity),
        Request::ReadInputRegisters { start, quantity } => (Table::Input, start, quantity),
        _ => return None,
    })
}

/// A plausible starting value: small, with decimal hex digits, different per address.
fn seed(table: Table, address: u16) -> u16 {
    match table {
        Table::Coils | Table::DiscreteInputs => u16::from(address % 3 == 0),
        Table::Holding | Table::Input => {
            let n = address % 90 + 10;
            // n < 100 always fits two BCD digits.
            rtu2mqtt_profile::bcd::encode(n, 2).unwrap_or(0x10)
        }
    }
}

impl SimDevice for GenericDevice {
    fn address(&self) -> SlaveId {
        self.address
    }

    fn handle(&mut self, request: &Request, _now: Instant) -> Reply {
        let bits = |words: Vec<u16>| words.into_iter().map(|w| w != 0).collect::<Vec<bool>>();
        let result = match request {
            Request::ReadCoils { start, quantity } => self
                .read(Table::Coils, *start, *quantity, 2000)
                .map(|w| Response::Coils(bits(w))),
            Request::ReadDiscreteInputs { start, quantity } => self
                .read(Table::DiscreteInputs, *start, *quantity, 2000)
                .map(|w| Response::DiscreteInputs(bits(w))),
            Request::ReadHoldingRegisters { start, quantity } => self
                .read(Table::Holding, *start, *quantity, 125)
                .map(Response::HoldingRegisters),
            Request::ReadInputRegisters { start, quantity } => self
                .read(Table::Input, *start, *quantity, 125)
                .map(Response::InputRegisters),
            Request::WriteSingleCoil { address, value } => self
                .store(Table::Coils, *address, &[u16::from(*value)])
                .map(|()| Response::WriteSingleCoil {
                    address: *address,
                    value: *value,
                }),
            Request::WriteSingleRegister { address, value } => self
                .store(Table::Holding, *address, &[*value])
                .map(|()| Response::WriteSingleRegister {
                    address: *address,
                    value: *value,
                }),
            Request::WriteMultipleCoils { start, values } => {
                let words: Vec<u16> = values.iter().map(|on| u16::from(*on)).collect();
                if words.is_empty() || words.len() > 1968 {
                    Err(ExceptionCode::IllegalDataValue)
                } else {
                    self.store(Table::Coils, *start, &words).map(|()| {
                        Response::WriteMultipleCoils {
                            start: *start,
                            quantity: words.len() as u16,
                        }
                    })
                }
            }
            Request::WriteMultipleRegisters { start, values } => {
                if values.is_empty() || values.len() > 123 {
                    Err(ExceptionCode::IllegalDataValue)
                } else {
                    let stored = self.store(Table::Holding, *start, values);
                    if stored.is_ok() {
                        self.run_command(*start, values);
                    }
                    stored.map(|()| Response::WriteMultipleRegisters {
                        start: *start,
                        quantity: values.len() as u16,
                    })
                }
            }
            Request::ReadDeviceIdentification { code, object_id } => match &self.identification {
                None => Err(ExceptionCode::IllegalFunction),
                Some(objects) => DeviceIdentification::answer_from(
                    objects,
                    *code,
                    conformity_level(objects),
                    *object_id,
                )
                .map(Response::DeviceIdentification)
                .ok_or(ExceptionCode::IllegalDataAddress),
            },
        };
        match result {
            Ok(response) => Reply::Normal(response),
            Err(code) => Reply::Exception(code),
        }
    }

    fn kind(&self) -> &'static str {
        "generic"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rtu2mqtt_profile::PollClass;

    fn block(request: Request) -> ReadBlock {
        ReadBlock {
            name: "b".into(),
            request,
            class: PollClass::Fast,
            used_runs: vec![],
            reads_linearly: true,
        }
    }

    #[test]
    fn built_in_profiles_read_back_plausible_values() {
        for name in rtu2mqtt_profile::registry::built_in_names() {
            let profile = rtu2mqtt_profile::registry::built_in(name).unwrap();
            let mut device = GenericDevice::from_profile(&profile, 1);
            for (index, block) in profile.read_blocks().iter().enumerate() {
                let Reply::Normal(answer) = device.handle(&block.request, Instant::now()) else {
                    panic!("{name}: block {} refused", block.name);
                };
                for reading in profile.decode_block(index, &answer) {
                    let field = profile.field(&reading.field).unwrap();
                    let value = reading
                        .value
                        .unwrap_or_else(|e| panic!("{name}.{}: {e}", reading.field));
                    if let (FieldKind::Integer { min, max }, rtu2mqtt_profile::Value::Int(n)) =
                        (&field.kind, &value)
                    {
                        assert!((min..=max).contains(&n), "{name}.{}: {n}", field.name);
                    }
                }
            }
        }
    }

    #[test]
    fn a_command_frame_leaves_its_result_code() {
        let interface = CommandInterface::new(5249, 5375).command(2060, vec![0..=0, 1..=4]);
        let mut device = GenericDevice::empty(1).with_command_interface(interface);
        let now = Instant::now();
        let result = Request::ReadHoldingRegisters {
            start: 5375,
            quantity: 1,
        };
        let reads = |code: u16| Reply::Normal(Response::HoldingRegisters(vec![code]));
        assert_eq!(device.handle(&result, now), reads(0));
        for (tariff, code) in [(9, 3001), (2, 0)] {
            let frame = Request::WriteMultipleRegisters {
                start: 5249,
                values: vec![2060, 0, tariff],
            };
            assert_eq!(
                device.handle(&frame, now),
                Reply::Normal(Response::WriteMultipleRegisters {
                    start: 5249,
                    quantity: 3
                })
            );
            assert_eq!(device.handle(&result, now), reads(code));
        }
        let executed = device.command_interface().map(|i| i.executed().to_vec());
        assert_eq!(executed, Some(vec![(2060, vec![0, 2])]));
    }

    #[test]
    fn identification_is_answered_only_by_a_device_given_its_objects() {
        use rtu2mqtt_modbus::device_id::ReadDeviceIdCode;
        let now = Instant::now();
        let basic = Request::ReadDeviceIdentification {
            code: ReadDeviceIdCode::Basic,
            object_id: 0,
        };
        let mut plain = GenericDevice::empty(1);
        assert_eq!(
            plain.handle(&basic, now),
            Reply::Exception(ExceptionCode::IllegalFunction)
        );
        let mut meter = GenericDevice::empty(1).with_identification(vec![
            DeviceIdObject::text(2, "1.4.2"),
            DeviceIdObject::text(0, "Sim Metering"),
            DeviceIdObject::text(1, "SM-3P"),
        ]);
        let Reply::Normal(Response::DeviceIdentification(answer)) = meter.handle(&basic, now)
        else {
            panic!("no identification");
        };
        let ids: Vec<u8> = answer.objects.iter().map(|o| o.id).collect();
        assert_eq!(ids, [0, 1, 2]);
        assert_eq!(answer.text_of(1).as_deref(), Some("SM-3P"));
        let missing = Request::ReadDeviceIdentification {
            code: ReadDeviceIdCode::Individual,
            object_id: 0x42,
        };
        assert_eq!(
            meter.handle(&missing, now),
            Reply::Exception(ExceptionCode::IllegalDataAddress)
        );
    }

    #[test]
    fn memory_follows_blocks() {
        let blocks = [
            block(Request::ReadHoldingRegisters {
                start: 100,
                quantity: 4,
            }),
            block(Request::ReadCoils {
                start: 0,
                quantity: 10,
            }),
        ];
        let mut device = GenericDevice::from_blocks(&blocks, 5);
        let now = Instant::now();
        let reply = device.handle(
            &Request::ReadHoldingRegisters {
                start: 100,
                quantity: 4,
            },
            now,
        );
        let Reply::Normal(Response::HoldingRegisters(words)) = reply else {
            panic!("{reply:?}")
        };
        assert!(words
            .iter()
            .all(|w| rtu2mqtt_profile::bcd::decode(*w, 4).is_ok()));
        assert_eq!(
            device.handle(
                &Request::ReadHoldingRegisters {
                    start: 100,
                    quantity: 5
                },
                now
            ),
            Reply::Exception(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            device.handle(
                &Request::ReadInputRegisters {
                    start: 100,
                    quantity: 1
                },
                now
            ),
            Reply::Exception(ExceptionCode::IllegalDataAddress)
        );
        device.handle(
            &Request::WriteSingleRegister {
                address: 101,
                value: 0x4242,
            },
            now,
        );
        device.handle(
            &Request::WriteMultipleCoils {
                start: 2,
                values: vec![true, false],
            },
            now,
        );
        assert_eq!(device.holding(101), Some(0x4242));
        assert_eq!(device.coil(2), Some(true));
        assert_eq!(device.coil(3), Some(false));
        assert_eq!(device.writes(), 2);
        let reply = device.handle(
            &Request::ReadCoils {
                start: 0,
                quantity: 10,
            },
            now,
        );
        let Reply::Normal(Response::Coils(bits)) = reply else {
            panic!("{reply:?}")
        };
        assert_eq!(bits.len(), 10);
    }
}
