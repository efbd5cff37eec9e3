//! Modbus TCP framing (MBAP header: transaction id, protocol id 0, length, unit id) and its
//! mapping to and from the RTU frames of [`crate::codec`]: an ADU is the RTU frame with the
//! address moved into the header as the unit id and the CRC dropped (TCP checks integrity).
//!
//! Pure byte work, no I/O. Both sides use it: the master encodes requests and matches answers
//! by transaction id (an answer carrying another id is [`Matched::Stale`], never taken for the
//! current request); the simulators turn a received ADU into the RTU frame their devices
//! already understand and wrap the RTU answer back.

use crate::codec::{self, Answer, DecodeError, EncodeError};
use crate::crc::append_crc;
use crate::frame::{Request, SlaveId};

/// Bytes of the MBAP header.
pub const HEADER_LEN: usize = 7;
/// The only protocol id Modbus defines.
pub(crate) const PROTOCOL_ID: u16 = 0;
/// Longest PDU (function code and data) Modbus allows.
pub(crate) const MAX_PDU_LEN: usize = 253;

/// The MBAP header. `length` counts the unit id and the PDU that follow it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// Set by the master for each request, repeated by the server in its answer.
    pub transaction: u16,
    pub(crate) protocol: u16,
    pub(crate) length: u16,
    /// The unit id: the RTU address of the device behind a gateway.
    pub unit: u8,
}

/// Why bytes are not a usable Modbus TCP ADU.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MbapError {
    /// The header's protocol id, which it carries, is not 0: not Modbus.
    #[error("protocol id {0}, expected 0")]
    Protocol(u16),
    /// The length field cannot describe a PDU (below 2 or above 254): the stream is out of
    /// step and must be reconnected.
    #[error("MBAP length {0} outside 2..=254")]
    Length(u16),
    /// Fewer bytes than the header, or than the length it announces.
    #[error("truncated ADU: {got} of {needed} bytes")]
    Truncated {
        /// Bytes the ADU should have.
        needed: usize,
        /// Bytes there are.
        got: usize,
    },
    /// The answer carries another unit id than the request.
    #[error("answer from unit {found}, expected {expected}")]
    WrongUnit {
        /// The unit the request went to.
        expected: SlaveId,
        /// The unit the answer carries.
        found: SlaveId,
    },
    /// The PDU is not the answer to the request (see [`DecodeError`]).
    #[error("answer PDU: {0}")]
    Pdu(DecodeError),
}

impl Header {
    pub(crate) fn encode(&self) -> [u8; HEADER_LEN] {
        let [t0, t1] = self.transaction.to_be_bytes();
        let [p0, p1] = self.protocol.to_be_bytes();
        let [l0, l1] = self.length.to_be_bytes();
        [t0, t1, p0, p1, l0, l1, self.unit]
    }

    /// Decodes and checks the header at the start of `bytes` (protocol 0, a length a PDU can
    /// have).
    pub fn decode(bytes: &[u8]) -> Result<Header, MbapError> {
        let Some(head) = bytes.get(..HEADER_LEN) else {
            return Err(MbapError::Truncated {
                needed: HEADER_LEN,
                got: bytes.len(),
            });
        };
        let header = Header {
            transaction: u16::from_be_bytes([head[0], head[1]]),
            protocol: u16::from_be_bytes([head[2], head[3]]),
            length: u16::from_be_bytes([head[4], head[5]]),
            unit: head[6],
        };
        if header.protocol != PROTOCOL_ID {
            return Err(MbapError::Protocol(header.protocol));
        }
        if !(2..=(MAX_PDU_LEN as u16 + 1)).contains(&header.length) {
            return Err(MbapError::Length(header.length));
        }
        Ok(header)
    }

    /// Length of the whole ADU this header starts.
    pub fn adu_len(&self) -> usize {
        HEADER_LEN - 1 + usize::from(self.length)
    }
}

/// The total length of the ADU starting with `head`, once its header is in (`Ok(None)`: need
/// more bytes).
pub fn adu_len(head: &[u8]) -> Result<Option<usize>, MbapError> {
    if head.len() < HEADER_LEN {
        return Ok(None);
    }
    Header::decode(head).map(|header| Some(header.adu_len()))
}

/// The length of the RTU frame an ADU of `adu_len` bytes carries: the unit id as its address,
/// the PDU, a CRC.
pub fn rtu_frame_len(adu_len: usize) -> usize {
    adu_len.saturating_sub(HEADER_LEN) + 1 + 2
}

/// The ADU carrying the RTU frame `rtu` (address, PDU, CRC; the CRC is not checked here) with
/// `transaction`: the address becomes the unit id, the CRC is dropped.
pub fn rtu_to_adu(transaction: u16, rtu: &[u8]) -> Result<Vec<u8>, MbapError> {
    if rtu.len() < 4 {
        return Err(MbapError::Truncated {
            needed: 4,
            got: rtu.len(),
        });
    }
    let unit_and_pdu = &rtu[..rtu.len() - 2];
    let header = Header {
        transaction,
        protocol: PROTOCOL_ID,
        length: unit_and_pdu.len() as u16,
        unit: unit_and_pdu[0],
    };
    let mut adu = Vec::with_capacity(HEADER_LEN + unit_and_pdu.len() - 1);
    adu.extend_from_slice(&header.encode());
    adu.extend_from_slice(&unit_and_pdu[1..]);
    Ok(adu)
}

/// The header of `adu` and the ADU's length, which `adu` holds at least.
fn whole_adu(adu: &[u8]) -> Result<(Header, usize), MbapError> {
    let header = Header::decode(adu)?;
    let needed = header.adu_len();
    if adu.len() < needed {
        return Err(MbapError::Truncated {
            needed,
            got: adu.len(),
        });
    }
    Ok((header, needed))
}

/// The header of the complete ADU `adu` and the RTU frame it carries (unit id as the address,
/// CRC computed).
pub fn adu_to_rtu(adu: &[u8]) -> Result<(Header, Vec<u8>), MbapError> {
    let (header, needed) = whole_adu(adu)?;
    let mut rtu = Vec::with_capacity(usize::from(header.length) + 2);
    rtu.push(header.unit);
    rtu.extend_from_slice(&adu[HEADER_LEN..needed]);
    append_crc(&mut rtu);
    Ok((header, rtu))
}

/// Master side: the ADU of `request` to `unit` with `transaction`.
pub fn encode_request(
    transaction: u16,
    unit: SlaveId,
    request: &Request,
) -> Result<Vec<u8>, EncodeError> {
    let rtu = codec::encode_request(unit, request)?;
    // An encoded request is always at least address, function, two words and the CRC.
    Ok(rtu_to_adu(transaction, &rtu).unwrap_or_default())
}

/// What a complete answer ADU is to the transaction waiting for it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Matched {
    /// The answer to this transaction (normal or exception).
    Current(Answer),
    /// An answer to an earlier transaction (it timed out): to be discarded and counted.
    Stale {
        /// The id the answer carries.
        transaction: u16,
    },
}

/// Master side: matches the complete answer `adu` against the request `request` sent to `unit`
/// as `transaction`, and decodes it when it is the current one.
pub fn decode_answer(
    transaction: u16,
    unit: SlaveId,
    request: &Request,
    adu: &[u8],
) -> Result<Matched, MbapError> {
    let (header, needed) = whole_adu(adu)?;
    if adu.len() > needed {
        return Err(MbapError::Pdu(DecodeError::Malformed(
            "bytes after the ADU's length",
        )));
    }
    if header.transaction != transaction {
        return Ok(Matched::Stale {
            transaction: header.transaction,
        });
    }
    if header.unit != unit {
        return Err(MbapError::WrongUnit {
            expected: unit,
            found: header.unit,
        });
    }
    // The unit id ends the header: with the PDU after it, it is the frame without its CRC.
    codec::decode_unit_answer(unit, request, &adu[HEADER_LEN - 1..needed])
        .map(Matched::Current)
        .map_err(MbapError::Pdu)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{ExceptionCode, Response};
    use proptest::prelude::*;

    const READ_DUST: Request = Request::ReadHoldingRegisters {
        start: 0x1000,
        quantity: 6,
    };

    #[test]
    fn request_golden_frame() {
        // RTU 01 03 10 00 00 06 C1 08 as Modbus TCP, transaction 0x0102.
        let adu = encode_request(0x0102, 1, &READ_DUST).unwrap();
        assert_eq!(
            adu,
            [0x01, 0x02, 0x00, 0x00, 0x00, 0x06, 0x01, 0x03, 0x10, 0x00, 0x00, 0x06]
        );
        let (header, rtu) = adu_to_rtu(&adu).unwrap();
        assert_eq!(header.transaction, 0x0102);
        assert_eq!(header.unit, 1);
        assert_eq!(rtu, [0x01, 0x03, 0x10, 0x00, 0x00, 0x06, 0xC1, 0x08]);
    }

    #[test]
    fn answer_matched_by_transaction() {
        let words = vec![0x0003, 0x0005, 0x0002, 0x000A, 0x05DC, 0x0019];
        let rtu = codec::encode_answer(1, &Response::HoldingRegisters(words.clone()));
        let adu = rtu_to_adu(7, &rtu).unwrap();
        assert_eq!(
            &adu[..9],
            &[0x00, 0x07, 0x00, 0x00, 0x00, 15, 0x01, 0x03, 12]
        );
        assert_eq!(
            decode_answer(7, 1, &READ_DUST, &adu).unwrap(),
            Matched::Current(Answer::Normal(Response::HoldingRegisters(words)))
        );
        assert_eq!(
            decode_answer(8, 1, &READ_DUST, &adu).unwrap(),
            Matched::Stale { transaction: 7 }
        );
        assert_eq!(
            decode_answer(7, 2, &READ_DUST, &adu),
            Err(MbapError::WrongUnit {
                expected: 2,
                found: 1
            })
        );
    }

    #[test]
    fn exception_answer() {
        let adu = [0x00, 0x01, 0x00, 0x00, 0x00, 0x03, 0x01, 0x83, 0x02];
        assert_eq!(
            decode_answer(1, 1, &READ_DUST, &adu).unwrap(),
            Matched::Current(Answer::Exception(ExceptionCode::IllegalDataAddress))
        );
    }

    #[test]
    fn bad_headers_refused() {
        assert_eq!(
            Header::decode(&[0, 1, 0, 1, 0, 6, 1]),
            Err(MbapError::Protocol(1))
        );
        assert_eq!(
            Header::decode(&[0, 1, 0, 0, 0, 1, 1]),
            Err(MbapError::Length(1))
        );
        assert_eq!(
            Header::decode(&[0, 1, 0, 0, 1, 0, 1]),
            Err(MbapError::Length(256))
        );
        assert_eq!(adu_len(&[0, 1, 0, 0, 0]), Ok(None));
        assert_eq!(adu_len(&[0, 1, 0, 0, 0, 6, 1]), Ok(Some(12)));
        assert!(matches!(
            adu_to_rtu(&[0, 1, 0, 0, 0, 6, 1, 3]),
            Err(MbapError::Truncated { needed: 12, got: 8 })
        ));
    }

    proptest! {
        #[test]
        fn rtu_and_adu_round_trip(
            transaction in any::<u16>(),
            unit in any::<u8>(),
            pdu in proptest::collection::vec(any::<u8>(), 1..=MAX_PDU_LEN),
        ) {
            let mut rtu = vec![unit];
            rtu.extend_from_slice(&pdu);
            append_crc(&mut rtu);
            let adu = rtu_to_adu(transaction, &rtu).unwrap();
            prop_assert_eq!(adu.len(), HEADER_LEN + pdu.len());
            prop_assert_eq!(adu_len(&adu), Ok(Some(adu.len())));
            let (header, back) = adu_to_rtu(&adu).unwrap();
            prop_assert_eq!(header.transaction, transaction);
            prop_assert_eq!(rtu_frame_len(adu.len()), rtu.len());
            prop_assert_eq!(back, rtu);
        }

        /// An answer inside an ADU decodes as the same answer on a serial line with its CRC
        /// does; only the lengths in a truncation or length error count no CRC.
        #[test]
        fn an_adu_decodes_as_its_rtu_frame(
            unit in 1u8..=3,
            function in prop_oneof![Just(3u8), Just(0x83), Just(4), Just(6)],
            count in prop_oneof![Just(12u8), any::<u8>()],
            data in proptest::collection::vec(any::<u8>(), 0..=16),
        ) {
            let mut rtu = vec![unit, function, count];
            rtu.extend_from_slice(&data);
            append_crc(&mut rtu);
            let adu = rtu_to_adu(9, &rtu).unwrap();
            let by_adu = decode_answer(9, 1, &READ_DUST, &adu);
            let by_rtu = codec::decode_answer(1, &READ_DUST, &rtu);
            match (by_adu, by_rtu) {
                (Ok(Matched::Current(adu)), Ok(rtu)) => prop_assert_eq!(adu, rtu),
                (Err(MbapError::WrongUnit { found, .. }), Err(DecodeError::WrongAddress { .. })) => {
                    prop_assert_eq!(found, unit)
                }
                (
                    Err(MbapError::Pdu(DecodeError::Truncated { needed, got })),
                    Err(DecodeError::Truncated { needed: rtu_needed, got: rtu_got }),
                ) => prop_assert_eq!((needed + 2, got + 2), (rtu_needed, rtu_got)),
                (Err(MbapError::Pdu(adu)), Err(rtu)) => prop_assert_eq!(adu, rtu),
                (adu, rtu) => prop_assert!(false, "ADU {adu:?}, RTU {rtu:?}"),
            }
        }

        #[test]
        fn any_bytes_decode_without_panicking(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
            let _ = adu_len(&bytes);
            let _ = adu_to_rtu(&bytes);
            let _ = decode_answer(1, 1, &READ_DUST, &bytes);
        }
    }
}
