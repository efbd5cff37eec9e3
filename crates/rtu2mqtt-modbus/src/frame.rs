//! Modbus PDU types with the specification's names: function codes, exception codes, requests
//! and answers. No byte work here (see `codec`, and `device_id` for FC43/14).

use crate::device_id::{DeviceIdentification, ReadDeviceIdCode};

/// Longest RTU frame the serial-line specification allows, in bytes: address, a PDU of at
/// most 253 bytes, CRC.
pub const MAX_FRAME_LEN: usize = 256;

/// A device address on a serial line: 1–247 in the standard (some devices allow up to 253),
/// 0 for broadcast.
pub type SlaveId = u8;

/// The function codes this crate frames, each with its number in the application protocol
/// specification (the first byte of a PDU).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FunctionCode {
    /// 0x01: reads 1–2000 contiguous coils (read-write bits).
    ReadCoils = 0x01,
    /// 0x02: reads 1–2000 contiguous discrete inputs (read-only bits).
    ReadDiscreteInputs = 0x02,
    /// 0x03: reads 1–125 contiguous holding registers (read-write 16-bit words).
    ReadHoldingRegisters = 0x03,
    /// 0x04: reads 1–125 contiguous input registers (read-only 16-bit words).
    ReadInputRegisters = 0x04,
    /// 0x05: sets one coil on or off; the answer echoes the request.
    WriteSingleCoil = 0x05,
    /// 0x06: writes one holding register; the answer echoes the request.
    WriteSingleRegister = 0x06,
    /// 0x0F: sets 1–1968 contiguous coils; the answer repeats start and quantity.
    WriteMultipleCoils = 0x0F,
    /// 0x10: writes 1–123 contiguous holding registers; the answer repeats start and quantity.
    WriteMultipleRegisters = 0x10,
    /// 0x2B: Encapsulated Interface Transport; framed here with MEI type 0x0E, Read Device
    /// Identification (the answer's length is in its bytes).
    EncapsulatedInterface = 0x2B,
}

impl FunctionCode {
    /// The function of code `code`; `None` for a code this crate does not frame (another
    /// function, or an exception answer's `code | 0x80`).
    pub fn from_u8(code: u8) -> Option<Self> {
        Some(match code {
            0x01 => Self::ReadCoils,
            0x02 => Self::ReadDiscreteInputs,
            0x03 => Self::ReadHoldingRegisters,
            0x04 => Self::ReadInputRegisters,
            0x05 => Self::WriteSingleCoil,
            0x06 => Self::WriteSingleRegister,
            0x0F => Self::WriteMultipleCoils,
            0x10 => Self::WriteMultipleRegisters,
            0x2B => Self::EncapsulatedInterface,
            _ => return None,
        })
    }

    /// The code as it goes on the wire.
    pub fn value(self) -> u8 {
        self as u8
    }
}

/// An exception code from a device's exception answer (function | 0x80).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ExceptionCode {
    /// 0x01: the device does not support the function.
    IllegalFunction,
    /// 0x02: an address in the request's span does not exist on the device.
    IllegalDataAddress,
    /// 0x03: a value in the request (a quantity, a written value) is not allowed.
    IllegalDataValue,
    /// 0x04: the device failed while carrying the request out.
    ServerDeviceFailure,
    /// 0x05: the device took the request and needs long to carry it out; ask again later.
    Acknowledge,
    /// 0x06: the device is busy with a long command; send the request again later.
    ServerDeviceBusy,
    /// 0x08: the device found a parity error in its own memory (file records).
    MemoryParityError,
    /// 0x0A: a gateway has no path to the addressed device (misconfigured or overloaded).
    GatewayPathUnavailable,
    /// 0x0B: a gateway got no answer from the addressed device.
    GatewayTargetFailedToRespond,
    /// A code outside the specification's list, kept as sent.
    Other(u8),
}

impl ExceptionCode {
    /// The exception of code `code` (the byte after `function | 0x80`); a code outside the
    /// specification's list is kept as [`ExceptionCode::Other`].
    pub fn from_u8(code: u8) -> Self {
        match code {
            0x01 => Self::IllegalFunction,
            0x02 => Self::IllegalDataAddress,
            0x03 => Self::IllegalDataValue,
            0x04 => Self::ServerDeviceFailure,
            0x05 => Self::Acknowledge,
            0x06 => Self::ServerDeviceBusy,
            0x08 => Self::MemoryParityError,
            0x0A => Self::GatewayPathUnavailable,
            0x0B => Self::GatewayTargetFailedToRespond,
            other => Self::Other(other),
        }
    }

    /// The code as it goes on the wire.
    pub fn value(self) -> u8 {
        match self {
            Self::IllegalFunction => 0x01,
            Self::IllegalDataAddress => 0x02,
            Self::IllegalDataValue => 0x03,
            Self::ServerDeviceFailure => 0x04,
            Self::Acknowledge => 0x05,
            Self::ServerDeviceBusy => 0x06,
            Self::MemoryParityError => 0x08,
            Self::GatewayPathUnavailable => 0x0A,
            Self::GatewayTargetFailedToRespond => 0x0B,
            Self::Other(code) => code,
        }
    }
}

impl std::fmt::Display for ExceptionCode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let name = match self {
            Self::IllegalFunction => "illegal function",
            Self::IllegalDataAddress => "illegal data address",
            Self::IllegalDataValue => "illegal data value",
            Self::ServerDeviceFailure => "server device failure",
            Self::Acknowledge => "acknowledge",
            Self::ServerDeviceBusy => "server device busy",
            Self::MemoryParityError => "memory parity error",
            Self::GatewayPathUnavailable => "gateway path unavailable",
            Self::GatewayTargetFailedToRespond => "gateway target failed to respond",
            Self::Other(_) => "non-standard exception",
        };
        write!(f, "exception {:02X} ({name})", self.value())
    }
}

/// A request PDU, one variant per [`FunctionCode`]. Addresses are the PDU's 0-based
/// addresses (register 40001 of a vendor's table is `start: 0` of
/// [`Request::ReadHoldingRegisters`]); quantities count coils or registers, not bytes.
/// [`crate::codec::encode_request`] refuses quantities outside the specification's limits.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Request {
    /// FC01: `quantity` coils from `start`.
    ReadCoils {
        /// Address of the first coil.
        start: u16,
        /// Coils to read, 1–2000.
        quantity: u16,
    },
    /// FC02: `quantity` discrete inputs from `start`.
    ReadDiscreteInputs {
        /// Address of the first discrete input.
        start: u16,
        /// Inputs to read, 1–2000.
        quantity: u16,
    },
    /// FC03: `quantity` holding registers from `start`.
    ReadHoldingRegisters {
        /// Address of the first register.
        start: u16,
        /// Registers to read, 1–125.
        quantity: u16,
    },
    /// FC04: `quantity` input registers from `start`.
    ReadInputRegisters {
        /// Address of the first register.
        start: u16,
        /// Registers to read, 1–125.
        quantity: u16,
    },
    /// FC05: the coil at `address` set on (`true`, sent as 0xFF00) or off (0x0000).
    WriteSingleCoil {
        /// Address of the coil.
        address: u16,
        /// On or off.
        value: bool,
    },
    /// FC06: `value` written to the holding register at `address`.
    WriteSingleRegister {
        /// Address of the register.
        address: u16,
        /// The word written.
        value: u16,
    },
    /// FC0F: `values` written to the coils from `start` on, one coil each (1–1968).
    WriteMultipleCoils {
        /// Address of the first coil.
        start: u16,
        /// On or off for each coil, first coil first.
        values: Vec<bool>,
    },
    /// FC10: `values` written to the holding registers from `start` on (1–123 words).
    WriteMultipleRegisters {
        /// Address of the first register.
        start: u16,
        /// The words written, first register first.
        values: Vec<u16>,
    },
    /// FC43 / MEI type 14: the device's identification objects, a stream of a category from
    /// `object_id` on, or the one object `object_id`. Changes nothing on the device.
    ReadDeviceIdentification {
        /// What is asked for: basic, regular or extended stream, or one object.
        code: ReadDeviceIdCode,
        /// The first object of the stream (0 to start), or the one object asked for.
        object_id: u8,
    },
}

impl Request {
    /// The function code this request is sent with.
    pub fn function(&self) -> FunctionCode {
        match self {
            Self::ReadCoils { .. } => FunctionCode::ReadCoils,
            Self::ReadDiscreteInputs { .. } => FunctionCode::ReadDiscreteInputs,
            Self::ReadHoldingRegisters { .. } => FunctionCode::ReadHoldingRegisters,
            Self::ReadInputRegisters { .. } => FunctionCode::ReadInputRegisters,
            Self::WriteSingleCoil { .. } => FunctionCode::WriteSingleCoil,
            Self::WriteSingleRegister { .. } => FunctionCode::WriteSingleRegister,
            Self::WriteMultipleCoils { .. } => FunctionCode::WriteMultipleCoils,
            Self::WriteMultipleRegisters { .. } => FunctionCode::WriteMultipleRegisters,
            Self::ReadDeviceIdentification { .. } => FunctionCode::EncapsulatedInterface,
        }
    }

    /// True for the four write functions: the requests that change something on the device
    /// (every other one only asks).
    pub fn is_write(&self) -> bool {
        matches!(
            self,
            Self::WriteSingleCoil { .. }
                | Self::WriteSingleRegister { .. }
                | Self::WriteMultipleCoils { .. }
                | Self::WriteMultipleRegisters { .. }
        )
    }

    /// True for the four read functions (those reading a span of a table).
    pub fn is_read(&self) -> bool {
        self.read_span().is_some()
    }

    /// `(start, quantity)` of a read request; `None` for writes.
    pub fn read_span(&self) -> Option<(u16, u16)> {
        match *self {
            Self::ReadCoils { start, quantity }
            | Self::ReadDiscreteInputs { start, quantity }
            | Self::ReadHoldingRegisters { start, quantity }
            | Self::ReadInputRegisters { start, quantity } => Some((start, quantity)),
            _ => None,
        }
    }

    /// Where `part` lies inside this read: the offset of its first item, when `part` reads the
    /// same table and every item it asks for is one this read asks for too.
    pub fn offset_of(&self, part: &Request) -> Option<u16> {
        let (first, len) = self.read_span()?;
        let (start, quantity) = part.read_span()?;
        let same_table = std::mem::discriminant(self) == std::mem::discriminant(part);
        let inside = start >= first
            && u32::from(start) + u32::from(quantity) <= u32::from(first) + u32::from(len);
        (same_table && inside).then(|| start - first)
    }

    /// True when this read asks for every item `part` asks for, in the same table.
    pub fn covers(&self, part: &Request) -> bool {
        self.offset_of(part).is_some()
    }

    /// The read of the same table for `quantity` items from `offset` inside this read
    /// (`None` for writes or when the start would pass the last address).
    pub fn sub_read(&self, offset: u16, quantity: u16) -> Option<Request> {
        let (first, _) = self.read_span()?;
        let start = first.checked_add(offset)?;
        Some(match self {
            Self::ReadCoils { .. } => Self::ReadCoils { start, quantity },
            Self::ReadDiscreteInputs { .. } => Self::ReadDiscreteInputs { start, quantity },
            Self::ReadHoldingRegisters { .. } => Self::ReadHoldingRegisters { start, quantity },
            _ => Self::ReadInputRegisters { start, quantity },
        })
    }

    /// The answer this read would get from a device whose items are all zero (`None` for
    /// writes): the image a block's parts are assembled in.
    pub fn empty_answer(&self) -> Option<Response> {
        let (_, quantity) = self.read_span()?;
        let quantity = usize::from(quantity);
        Some(match self {
            Self::ReadCoils { .. } => Response::Coils(vec![false; quantity]),
            Self::ReadDiscreteInputs { .. } => Response::DiscreteInputs(vec![false; quantity]),
            Self::ReadHoldingRegisters { .. } => Response::HoldingRegisters(vec![0; quantity]),
            _ => Response::InputRegisters(vec![0; quantity]),
        })
    }

    /// Length in bytes of this request's frame, address and CRC included.
    pub fn frame_len(&self) -> usize {
        match self {
            Self::WriteMultipleCoils { values, .. } => 9 + values.len().div_ceil(8),
            Self::WriteMultipleRegisters { values, .. } => 9 + 2 * values.len(),
            // Address, function, MEI type, code, object id, CRC.
            Self::ReadDeviceIdentification { .. } => 7,
            _ => 8,
        }
    }

    /// Data bytes of the normal answer to a read (`None` for writes).
    pub(crate) fn answer_data_len(&self) -> Option<usize> {
        let (_, quantity) = self.read_span()?;
        let quantity = usize::from(quantity);
        Some(match self {
            Self::ReadCoils { .. } | Self::ReadDiscreteInputs { .. } => quantity.div_ceil(8),
            _ => 2 * quantity,
        })
    }

    /// Length in bytes of the normal answer frame to this request, address and CRC included;
    /// for Read Device Identification, whose answer's length is in its bytes, the longest
    /// frame there is.
    pub fn answer_len(&self) -> usize {
        match self.answer_data_len() {
            // Address, function, byte count, data, CRC.
            Some(data) => 5 + data,
            None if matches!(self, Self::ReadDeviceIdentification { .. }) => MAX_FRAME_LEN,
            // Writes echo address and value, or start and quantity: address, function, 4, CRC.
            None => 8,
        }
    }
}

/// A normal (non-exception) answer PDU. Bit answers hold exactly the requested quantity of
/// bits (the padding bits of the last byte are dropped).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Response {
    /// FC01's answer: the coils read, first address first (`true`: on).
    Coils(Vec<bool>),
    /// FC02's answer: the discrete inputs read, first address first.
    DiscreteInputs(Vec<bool>),
    /// FC03's answer: the holding registers read, first address first.
    HoldingRegisters(Vec<u16>),
    /// FC04's answer: the input registers read, first address first.
    InputRegisters(Vec<u16>),
    /// FC05's answer: the device's echo of the coil written.
    WriteSingleCoil {
        /// Address of the coil.
        address: u16,
        /// The state it was set to.
        value: bool,
    },
    /// FC06's answer: the device's echo of the register written.
    WriteSingleRegister {
        /// Address of the register.
        address: u16,
        /// The word written.
        value: u16,
    },
    /// FC0F's answer: which coils were written.
    WriteMultipleCoils {
        /// Address of the first coil written.
        start: u16,
        /// Coils written.
        quantity: u16,
    },
    /// FC10's answer: which registers were written.
    WriteMultipleRegisters {
        /// Address of the first register written.
        start: u16,
        /// Registers written.
        quantity: u16,
    },
    /// FC43 / MEI type 14's answer: identification objects.
    DeviceIdentification(DeviceIdentification),
}

impl Response {
    /// The register words of a register read answer; `None` for any other answer.
    pub fn registers(&self) -> Option<&[u16]> {
        match self {
            Self::HoldingRegisters(words) | Self::InputRegisters(words) => Some(words),
            _ => None,
        }
    }

    /// The bits of a coil or discrete-input read answer; `None` for any other answer.
    pub fn bits(&self) -> Option<&[bool]> {
        match self {
            Self::Coils(bits) | Self::DiscreteInputs(bits) => Some(bits),
            _ => None,
        }
    }

    /// The items of this read answer from `offset` on, `quantity` of them, as the answer to a
    /// read of just those items; `None` for a write's answer or a span past this answer's end.
    pub fn part(&self, offset: u16, quantity: u16) -> Option<Response> {
        let from = usize::from(offset);
        let to = from.checked_add(usize::from(quantity))?;
        Some(match self {
            Self::Coils(bits) => Self::Coils(bits.get(from..to)?.to_vec()),
            Self::DiscreteInputs(bits) => Self::DiscreteInputs(bits.get(from..to)?.to_vec()),
            Self::HoldingRegisters(words) => Self::HoldingRegisters(words.get(from..to)?.to_vec()),
            Self::InputRegisters(words) => Self::InputRegisters(words.get(from..to)?.to_vec()),
            _ => return None,
        })
    }

    /// Copies the items of `part` (an answer to a part of this read) into this answer from
    /// `offset` on; anything beyond this answer's end, or of another kind, is ignored.
    pub fn place(&mut self, offset: u16, part: &Response) {
        let offset = usize::from(offset);
        match self {
            Self::Coils(bits) | Self::DiscreteInputs(bits) => {
                if let Some(part) = part.bits() {
                    for (slot, bit) in bits.iter_mut().skip(offset).zip(part) {
                        *slot = *bit;
                    }
                }
            }
            Self::HoldingRegisters(words) | Self::InputRegisters(words) => {
                if let Some(part) = part.registers() {
                    for (slot, word) in words.iter_mut().skip(offset).zip(part) {
                        *slot = *word;
                    }
                }
            }
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_part_of_an_answer_is_the_answer_to_a_read_of_that_part() {
        let words = Response::HoldingRegisters(vec![10, 11, 12, 13]);
        assert_eq!(
            words.part(1, 2),
            Some(Response::HoldingRegisters(vec![11, 12]))
        );
        assert_eq!(words.part(0, 4), Some(words.clone()));
        assert_eq!(words.part(3, 2), None);
        assert_eq!(words.part(u16::MAX, u16::MAX), None);
        let bits = Response::Coils(vec![true, false, true]);
        assert_eq!(bits.part(2, 1), Some(Response::Coils(vec![true])));
        let echo = Response::WriteSingleRegister {
            address: 1,
            value: 2,
        };
        assert_eq!(echo.part(0, 1), None);
    }

    #[test]
    fn a_read_covers_the_reads_of_its_own_table_inside_its_span() {
        let block = Request::ReadHoldingRegisters {
            start: 0x70,
            quantity: 8,
        };
        let inside = Request::ReadHoldingRegisters {
            start: 0x74,
            quantity: 4,
        };
        assert!(block.covers(&inside));
        assert_eq!(block.offset_of(&inside), Some(4));
        assert!(block.covers(&block));
        let past_the_end = Request::ReadHoldingRegisters {
            start: 0x74,
            quantity: 5,
        };
        assert!(!block.covers(&past_the_end));
        let before = Request::ReadHoldingRegisters {
            start: 0x6F,
            quantity: 2,
        };
        assert!(!block.covers(&before));
        let other_table = Request::ReadInputRegisters {
            start: 0x70,
            quantity: 1,
        };
        assert!(!block.covers(&other_table));
        let write = Request::WriteSingleRegister {
            address: 0x70,
            value: 1,
        };
        assert!(!block.covers(&write));
        assert!(!write.covers(&write));
        // No overflow at the top of the address space.
        let top = Request::ReadCoils {
            start: u16::MAX,
            quantity: 1,
        };
        assert!(top.covers(&top));
        assert_eq!(top.sub_read(1, 1), None);
    }

    #[test]
    fn a_sub_read_keeps_the_table_and_moves_the_start() {
        let block = Request::ReadDiscreteInputs {
            start: 10,
            quantity: 20,
        };
        assert_eq!(
            block.sub_read(5, 3),
            Some(Request::ReadDiscreteInputs {
                start: 15,
                quantity: 3
            })
        );
        let write = Request::WriteSingleCoil {
            address: 1,
            value: true,
        };
        assert_eq!(write.sub_read(0, 1), None);
    }

    #[test]
    fn frame_lengths_match_the_golden_frames() {
        // 81 01 00 00 00 16 A2 04 → 81 01 03 b0 b1 b2 CRC (8 bytes).
        let coils = Request::ReadCoils {
            start: 0,
            quantity: 22,
        };
        assert_eq!(coils.frame_len(), 8);
        assert_eq!(coils.answer_len(), 8);
        assert_eq!(coils.answer_data_len(), Some(3));
        // 01 03 10 00 00 06 → 01 03 0C + 12 bytes + CRC (17 bytes).
        let words = Request::ReadHoldingRegisters {
            start: 0x1000,
            quantity: 6,
        };
        assert_eq!(words.answer_len(), 17);
        // The golden FC10 write of four words is 17 bytes long; its answer an 8-byte echo.
        let write = Request::WriteMultipleRegisters {
            start: 0x1000,
            values: vec![0x0300, 5, 2, 10],
        };
        assert_eq!(write.frame_len(), 17);
        assert_eq!(write.answer_len(), 8);
        assert_eq!(write.answer_data_len(), None);
        // 81 0F 00 00 00 0C 02 b0 b1 CRC: 11 bytes.
        let coils_write = Request::WriteMultipleCoils {
            start: 0,
            values: vec![false; 12],
        };
        assert_eq!(coils_write.frame_len(), 11);
        assert_eq!(coils_write.answer_len(), 8);
    }

    #[test]
    fn the_empty_answer_has_the_shape_of_the_read() {
        let coils = Request::ReadCoils {
            start: 3,
            quantity: 4,
        };
        assert_eq!(coils.empty_answer(), Some(Response::Coils(vec![false; 4])));
        let inputs = Request::ReadInputRegisters {
            start: 0,
            quantity: 2,
        };
        assert_eq!(
            inputs.empty_answer(),
            Some(Response::InputRegisters(vec![0, 0]))
        );
        let write = Request::WriteSingleRegister {
            address: 0,
            value: 0,
        };
        assert_eq!(write.empty_answer(), None);
    }

    #[test]
    fn parts_are_placed_with_zeros_in_unread_places() {
        let block = Request::ReadHoldingRegisters {
            start: 0x70,
            quantity: 8,
        };
        assert_eq!(
            block.sub_read(4, 2),
            Some(Request::ReadHoldingRegisters {
                start: 0x74,
                quantity: 2
            })
        );
        let mut answer = block.empty_answer().unwrap();
        answer.place(4, &Response::HoldingRegisters(vec![0x64, 0x12]));
        answer.place(7, &Response::HoldingRegisters(vec![9, 9, 9]));
        // A part of another kind is ignored.
        answer.place(0, &Response::Coils(vec![true]));
        assert_eq!(
            answer,
            Response::HoldingRegisters(vec![0, 0, 0, 0, 0x64, 0x12, 0, 9])
        );
        let mut bits = Response::Coils(vec![false; 4]);
        bits.place(2, &Response::Coils(vec![true, true]));
        assert_eq!(bits, Response::Coils(vec![false, false, true, true]));
    }
}
