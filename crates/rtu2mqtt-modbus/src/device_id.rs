//! FC43 / MEI type 14, Read Device Identification (Modbus Application Protocol Specification
//! V1.1b3, §6.21): its request and answer with the specification's names, the byte work of
//! their PDUs, and how long an answer is, which only its own bytes tell (the number of objects,
//! then each object's length).
//!
//! The answer PDU: function 0x2B, MEI type 0x0E, the read device ID code of the request, the
//! conformity level, "more follows" (0x00 or 0xFF), the next object id, the number of objects,
//! then each object as id, length and value. A stream (codes 01–03) that does not fit one
//! answer says "more follows" and the id to ask for next.

use crate::decode_error::DecodeError;

/// The MEI type of Read Device Identification, the byte after function code 0x2B.
pub const MEI_READ_DEVICE_ID: u8 = 0x0E;

/// Longest PDU (function code and data) Modbus allows.
const MAX_PDU_LEN: usize = 253;

/// Bytes of an answer PDU before its objects: function, MEI type, read device ID code,
/// conformity level, more follows, next object id, number of objects.
const ANSWER_HEADER_LEN: usize = 7;

/// "More follows" as the wire carries it.
const MORE_FOLLOWS: u8 = 0xFF;
const NO_MORE: u8 = 0x00;

/// What a Read Device Identification request asks for: a stream of objects (basic, regular
/// or extended ones, from an object id on) or one object alone.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ReadDeviceIdCode {
    /// 01: the basic objects (0x00 VendorName, 0x01 ProductCode, 0x02 MajorMinorRevision),
    /// which every device that implements the function has.
    Basic,
    /// 02: the regular objects (0x03–0x7F), optional.
    Regular,
    /// 03: the extended, private objects (0x80–0xFF), optional.
    Extended,
    /// 04: the one object the request names.
    Individual,
}

impl ReadDeviceIdCode {
    /// The code of `byte`; `None` outside 01–04.
    pub fn from_u8(byte: u8) -> Option<Self> {
        Some(match byte {
            0x01 => Self::Basic,
            0x02 => Self::Regular,
            0x03 => Self::Extended,
            0x04 => Self::Individual,
            _ => return None,
        })
    }

    /// The code as it goes on the wire.
    pub fn value(self) -> u8 {
        match self {
            Self::Basic => 0x01,
            Self::Regular => 0x02,
            Self::Extended => 0x03,
            Self::Individual => 0x04,
        }
    }
}

/// The object ids of the basic category.
pub mod object {
    /// 0x00: the vendor's name.
    pub const VENDOR_NAME: u8 = 0x00;
    /// 0x01: the product code.
    pub const PRODUCT_CODE: u8 = 0x01;
    /// 0x02: the major and minor revision.
    pub const MAJOR_MINOR_REVISION: u8 = 0x02;
}

/// One identification object as the device sent it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceIdObject {
    /// The object id (0x00 VendorName, 0x01 ProductCode, …).
    pub id: u8,
    /// Its value's bytes (an ASCII string for the basic and regular objects).
    pub value: Vec<u8>,
}

impl DeviceIdObject {
    /// An object holding `text`.
    pub fn text(id: u8, text: &str) -> Self {
        Self {
            id,
            value: text.as_bytes().to_vec(),
        }
    }

    /// The value as text: bytes that are not printable ASCII become `?`, and the padding
    /// some devices add (NUL bytes, spaces) is dropped.
    pub fn to_text(&self) -> String {
        let printable: String = self
            .value
            .iter()
            .map(|&byte| {
                if byte == b' ' || byte.is_ascii_graphic() {
                    char::from(byte)
                } else if byte == 0 {
                    ' '
                } else {
                    '?'
                }
            })
            .collect();
        printable.trim().to_string()
    }
}

/// A normal answer to Read Device Identification.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceIdentification {
    /// The read device ID code of the request it answers.
    pub code: ReadDeviceIdCode,
    /// The device's conformity level (0x01–0x03 stream access for basic, regular, extended;
    /// 0x81–0x83 individual access too).
    pub conformity_level: u8,
    /// The stream goes on: ask again from [`DeviceIdentification::next_object_id`].
    pub more_follows: bool,
    /// The object to ask for next while `more_follows`; 0 otherwise.
    pub next_object_id: u8,
    /// The objects of this answer, in the device's order.
    pub objects: Vec<DeviceIdObject>,
}

impl DeviceIdentification {
    /// The answer a device holding `objects` (ordered by id) gives to a stream request for
    /// `code` from `first_id` on: the objects of the request's category from `first_id` on,
    /// as many as fit one PDU, and "more follows" with the id of the first one left out when
    /// not all of them fit; from the category's first object when none is at `first_id` or
    /// after it (the specification's restart). An `Individual` request gets the object
    /// `first_id` alone. `None` when there is nothing to answer with (the device answers
    /// exception 02). Objects longer than a PDU can carry are cut to fit.
    pub fn answer_from(
        objects: &[DeviceIdObject],
        code: ReadDeviceIdCode,
        conformity_level: u8,
        first_id: u8,
    ) -> Option<Self> {
        let in_category = |id: u8| match code {
            ReadDeviceIdCode::Basic => id <= object::MAJOR_MINOR_REVISION,
            ReadDeviceIdCode::Regular => id <= 0x7F,
            ReadDeviceIdCode::Extended | ReadDeviceIdCode::Individual => true,
        };
        let room = MAX_PDU_LEN - ANSWER_HEADER_LEN;
        let fit = |object: &DeviceIdObject| {
            let mut value = object.value.clone();
            value.truncate((room - 2).min(usize::from(u8::MAX)));
            DeviceIdObject {
                id: object.id,
                value,
            }
        };
        let mut answer = Self {
            code,
            conformity_level,
            more_follows: false,
            next_object_id: 0,
            objects: Vec::new(),
        };
        if code == ReadDeviceIdCode::Individual {
            let wanted = objects.iter().find(|o| o.id == first_id)?;
            answer.objects.push(fit(wanted));
            return Some(answer);
        }
        let mut used = 0;
        for candidate in objects
            .iter()
            .filter(|o| o.id >= first_id && in_category(o.id))
        {
            let candidate = fit(candidate);
            let size = 2 + candidate.value.len();
            if used + size > room {
                answer.more_follows = true;
                answer.next_object_id = candidate.id;
                break;
            }
            used += size;
            answer.objects.push(candidate);
        }
        if answer.objects.is_empty() && first_id != 0 {
            return Self::answer_from(objects, code, conformity_level, 0);
        }
        (!answer.objects.is_empty()).then_some(answer)
    }

    /// The text of object `id`, if this answer holds it.
    pub fn text_of(&self, id: u8) -> Option<String> {
        self.objects
            .iter()
            .find(|o| o.id == id)
            .map(DeviceIdObject::to_text)
    }
}

/// The request PDU after its function code: MEI type, read device ID code, object id.
pub(crate) fn request_data(code: ReadDeviceIdCode, object_id: u8) -> [u8; 3] {
    [MEI_READ_DEVICE_ID, code.value(), object_id]
}

/// Server side: the read device ID code and object id of a request whose PDU after the
/// function code is `data` (MEI type, code, object id).
pub(crate) fn parse_request_data(data: &[u8]) -> Result<(ReadDeviceIdCode, u8), DecodeError> {
    match *data {
        [MEI_READ_DEVICE_ID, code, object_id] => ReadDeviceIdCode::from_u8(code)
            .map(|code| (code, object_id))
            .ok_or(DecodeError::Malformed("read device ID code outside 01–04")),
        [_, _, _] => Err(DecodeError::Malformed("MEI type other than 0x0E")),
        _ => Err(DecodeError::Malformed(
            "device identification request length",
        )),
    }
}

/// The length of the answer PDU that starts with `pdu` (at its function code), as far as its
/// bytes tell: exact once the number of objects and every object's length have arrived, and
/// otherwise the least it can be, which is then always more than `pdu.len()`. An error when
/// the bytes cannot be such an answer: another MEI type, or objects that run past the longest
/// PDU.
pub(crate) fn answer_pdu_len(pdu: &[u8]) -> Result<usize, DecodeError> {
    if pdu.get(1).is_some_and(|&mei| mei != MEI_READ_DEVICE_ID) {
        return Err(DecodeError::Malformed("MEI type other than 0x0E"));
    }
    let Some(&count) = pdu.get(ANSWER_HEADER_LEN - 1) else {
        return Ok(ANSWER_HEADER_LEN);
    };
    let mut end = ANSWER_HEADER_LEN;
    for index in 0..usize::from(count) {
        let Some(&length) = pdu.get(end + 1) else {
            // Each object still to come has at least its id and length.
            return Ok(end + 2 * (usize::from(count) - index));
        };
        end += 2 + usize::from(length);
        if end > MAX_PDU_LEN {
            return Err(DecodeError::Malformed(
                "device identification objects run past the longest PDU",
            ));
        }
    }
    Ok(end)
}

/// Decodes a complete answer PDU (its length checked by [`answer_pdu_len`]) to a request for
/// `code`.
pub(crate) fn decode_answer_pdu(
    code: ReadDeviceIdCode,
    pdu: &[u8],
) -> Result<DeviceIdentification, DecodeError> {
    if answer_pdu_len(pdu)? != pdu.len() {
        return Err(DecodeError::Malformed(
            "device identification length does not match its objects",
        ));
    }
    // Complete: the header is there.
    let header = &pdu[..ANSWER_HEADER_LEN];
    if header[2] != code.value() {
        return Err(DecodeError::Malformed(
            "answer's read device ID code is not the request's",
        ));
    }
    let more_follows = match header[4] {
        MORE_FOLLOWS => true,
        NO_MORE => false,
        _ => return Err(DecodeError::Malformed("more follows neither 00 nor FF")),
    };
    let mut objects = Vec::with_capacity(usize::from(header[6]));
    let mut at = ANSWER_HEADER_LEN;
    while at < pdu.len() {
        let id = pdu[at];
        let length = usize::from(pdu[at + 1]);
        objects.push(DeviceIdObject {
            id,
            value: pdu[at + 2..at + 2 + length].to_vec(),
        });
        at += 2 + length;
    }
    Ok(DeviceIdentification {
        code,
        conformity_level: header[3],
        more_follows,
        next_object_id: header[5],
        objects,
    })
}

/// Server side: the answer PDU after its function code. Objects beyond what one PDU carries
/// are left out (build answers with [`DeviceIdentification::answer_from`], which never makes
/// one that long).
pub(crate) fn answer_data(answer: &DeviceIdentification) -> Vec<u8> {
    let mut data = vec![
        MEI_READ_DEVICE_ID,
        answer.code.value(),
        answer.conformity_level,
        if answer.more_follows {
            MORE_FOLLOWS
        } else {
            NO_MORE
        },
        answer.next_object_id,
        0,
    ];
    let mut count = 0u8;
    for object in &answer.objects {
        let length = object.value.len().min(usize::from(u8::MAX));
        if 1 + data.len() + 2 + length > MAX_PDU_LEN || count == u8::MAX {
            break;
        }
        data.push(object.id);
        data.push(length as u8);
        data.extend_from_slice(&object.value[..length]);
        count += 1;
    }
    data[ANSWER_HEADER_LEN - 2] = count;
    data
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::{self, Answer};
    use crate::frame::{ExceptionCode, Request, Response};

    /// The specification's example (§6.21): the basic stream from object 0, and the answer
    /// "Company identification", "Product code XX", "V2.11" at conformity level 01. The
    /// example prints 0D as the product code's length; its value is 15 bytes long, the length
    /// used here (and by other implementations). The CRCs are the ones pymodbus puts on the
    /// same frames.
    #[rustfmt::skip]
    const SPEC_ANSWER: &[u8] = &[
        0x01,                   // address
        0x2B, 0x0E,             // function, MEI type
        0x01,                   // read device ID code: basic
        0x01,                   // conformity level
        0x00, 0x00,             // more follows: no; next object id
        0x03,                   // number of objects
        0x00, 0x16,             // VendorName, 22 bytes
        b'C', b'o', b'm', b'p', b'a', b'n', b'y', b' ', b'i', b'd', b'e', b'n', b't', b'i',
        b'f', b'i', b'c', b'a', b't', b'i', b'o', b'n',
        0x01, 0x0F,             // ProductCode, 15 bytes
        b'P', b'r', b'o', b'd', b'u', b'c', b't', b' ', b'c', b'o', b'd', b'e', b' ', b'X',
        b'X',
        0x02, 0x05,             // MajorMinorRevision, 5 bytes
        b'V', b'2', b'.', b'1', b'1',
        0xFC, 0x21,             // CRC
    ];

    fn spec_answer() -> DeviceIdentification {
        DeviceIdentification {
            code: ReadDeviceIdCode::Basic,
            conformity_level: 0x01,
            more_follows: false,
            next_object_id: 0,
            objects: vec![
                DeviceIdObject::text(object::VENDOR_NAME, "Company identification"),
                DeviceIdObject::text(object::PRODUCT_CODE, "Product code XX"),
                DeviceIdObject::text(object::MAJOR_MINOR_REVISION, "V2.11"),
            ],
        }
    }

    const BASIC_FROM_0: Request = Request::ReadDeviceIdentification {
        code: ReadDeviceIdCode::Basic,
        object_id: 0,
    };

    #[test]
    fn the_specifications_example_byte_for_byte() {
        let request = codec::encode_request(1, &BASIC_FROM_0).unwrap();
        assert_eq!(request, [0x01, 0x2B, 0x0E, 0x01, 0x00, 0x70, 0x77]);
        assert_eq!(BASIC_FROM_0.frame_len(), request.len());
        assert_eq!(codec::request_frame_len(&request[..2]), Ok(Some(7)));
        assert_eq!(codec::decode_request(&request), Ok((1, BASIC_FROM_0)));

        let answer = Response::DeviceIdentification(spec_answer());
        assert_eq!(codec::encode_answer(1, &answer), SPEC_ANSWER);
        assert_eq!(
            codec::decode_answer(1, &BASIC_FROM_0, SPEC_ANSWER),
            Ok(Answer::Normal(answer))
        );
        // Cut short, it is truncated with the length its bytes announce (all of it once the
        // last object's length is in); one byte more is not the answer.
        assert!(matches!(
            codec::decode_answer(1, &BASIC_FROM_0, &SPEC_ANSWER[..52]),
            Err(DecodeError::Truncated { needed, got: 52 }) if needed == SPEC_ANSWER.len()
        ));
        assert!(matches!(
            codec::decode_answer(1, &BASIC_FROM_0, &SPEC_ANSWER[..40]),
            Err(DecodeError::Truncated { needed, got: 40 }) if needed > 40
        ));
        let mut longer = SPEC_ANSWER.to_vec();
        longer.push(0);
        assert!(codec::decode_answer(1, &BASIC_FROM_0, &longer).is_err());
    }

    #[test]
    fn the_framer_finds_the_answers_end_from_its_bytes() {
        use crate::answer_framing::{AnswerFramer, Framed, Framing};
        let sent = codec::encode_request(1, &BASIC_FROM_0).unwrap();
        let framer = AnswerFramer::on_serial_line(1, &BASIC_FROM_0, &sent, false);
        for end in 3..SPEC_ANSWER.len() {
            match framer.frame(&SPEC_ANSWER[..end]) {
                Framing::NeedMore { needed } => {
                    assert!(
                        needed > end && needed <= SPEC_ANSWER.len(),
                        "{end}: {needed}"
                    )
                }
                // The answer starts as the request does: it may still be the request's echo.
                Framing::EchoCandidate => assert!(sent.starts_with(&SPEC_ANSWER[..end])),
                other => panic!("{end} bytes: {other:?}"),
            }
        }
        let mut followed = SPEC_ANSWER.to_vec();
        followed.extend_from_slice(&[0x01, 0x03]);
        assert_eq!(
            framer.frame(&followed),
            Framing::Complete(SPEC_ANSWER.len())
        );
        // On a stream, after garbage.
        let mut stream = vec![0x00, 0xFF];
        stream.extend_from_slice(&followed);
        let mut framer = AnswerFramer::new(1, &BASIC_FROM_0);
        assert_eq!(
            framer.poll(&mut stream),
            Framed::Answer {
                answer: Answer::Normal(Response::DeviceIdentification(spec_answer())),
                frame: SPEC_ANSWER.to_vec(),
                skipped: 2,
            }
        );
        assert_eq!(stream, [0x01, 0x03]);
        // A device without the function answers exception 01 in five bytes.
        let refused = codec::encode_exception(1, 0x2B, ExceptionCode::IllegalFunction);
        assert_eq!(refused, [0x01, 0xAB, 0x01, 0x9E, 0xF0]);
        let framer = AnswerFramer::on_serial_line(1, &BASIC_FROM_0, &sent, false);
        assert_eq!(framer.frame(&refused), Framing::Complete(5));
        assert_eq!(
            codec::decode_answer(1, &BASIC_FROM_0, &refused),
            Ok(Answer::Exception(ExceptionCode::IllegalFunction))
        );
    }

    #[test]
    fn a_modbus_tcp_answer_decodes_as_its_rtu_frame() {
        use crate::tcp::mbap::{self, Matched};
        let adu = mbap::rtu_to_adu(9, SPEC_ANSWER).unwrap();
        assert_eq!(&adu[..7], [0x00, 0x09, 0x00, 0x00, 0x00, 0x38, 0x01]);
        assert_eq!(
            mbap::decode_answer(9, 1, &BASIC_FROM_0, &adu),
            Ok(Matched::Current(Answer::Normal(
                Response::DeviceIdentification(spec_answer())
            )))
        );
        assert_eq!(
            mbap::encode_request(9, 1, &BASIC_FROM_0).unwrap(),
            [0x00, 0x09, 0x00, 0x00, 0x00, 0x05, 0x01, 0x2B, 0x0E, 0x01, 0x00]
        );
    }

    fn objects() -> Vec<DeviceIdObject> {
        vec![
            DeviceIdObject::text(0, "Schneider Electric"),
            DeviceIdObject::text(1, "A9MEM3155"),
            DeviceIdObject::text(2, "V1.2.3"),
            DeviceIdObject::text(4, "iEM3000"),
        ]
    }

    #[test]
    fn the_length_grows_with_the_bytes_until_it_is_known() {
        let answer =
            DeviceIdentification::answer_from(&objects(), ReadDeviceIdCode::Basic, 0x81, 0)
                .unwrap();
        let mut pdu = vec![0x2B];
        pdu.extend_from_slice(&answer_data(&answer));
        let whole = pdu.len();
        assert_eq!(whole, 7 + (2 + 18) + (2 + 9) + (2 + 6));
        for end in 0..whole {
            let needed = answer_pdu_len(&pdu[..end]).unwrap();
            assert!(needed > end, "{end} bytes: {needed}");
            assert!(needed <= whole, "{end} bytes: {needed}");
        }
        assert_eq!(answer_pdu_len(&pdu), Ok(whole));
        assert_eq!(decode_answer_pdu(ReadDeviceIdCode::Basic, &pdu), Ok(answer));
    }

    #[test]
    fn a_basic_stream_holds_the_basic_objects_only() {
        let answer =
            DeviceIdentification::answer_from(&objects(), ReadDeviceIdCode::Basic, 0x81, 0)
                .unwrap();
        assert_eq!(answer.objects.len(), 3);
        assert!(!answer.more_follows);
        assert_eq!(
            answer.text_of(object::VENDOR_NAME).as_deref(),
            Some("Schneider Electric")
        );
        let regular =
            DeviceIdentification::answer_from(&objects(), ReadDeviceIdCode::Regular, 0x82, 3)
                .unwrap();
        assert_eq!(regular.objects, [DeviceIdObject::text(4, "iEM3000")]);
        let one =
            DeviceIdentification::answer_from(&objects(), ReadDeviceIdCode::Individual, 0x81, 1)
                .unwrap();
        assert_eq!(one.objects, [DeviceIdObject::text(1, "A9MEM3155")]);
        // No object at 9 or after: the stream restarts at the category's first object.
        let restarted =
            DeviceIdentification::answer_from(&objects(), ReadDeviceIdCode::Basic, 0x81, 9)
                .unwrap();
        assert_eq!(restarted.objects.first().map(|o| o.id), Some(0));
        assert_eq!(
            DeviceIdentification::answer_from(&objects(), ReadDeviceIdCode::Individual, 0x81, 9),
            None
        );
        assert_eq!(
            DeviceIdentification::answer_from(&[], ReadDeviceIdCode::Basic, 0x81, 0),
            None
        );
    }

    #[test]
    fn a_stream_longer_than_a_pdu_says_more_follows_and_where() {
        let long: Vec<DeviceIdObject> = (0u8..3)
            .map(|id| DeviceIdObject {
                id,
                value: vec![b'x'; 100],
            })
            .collect();
        let first =
            DeviceIdentification::answer_from(&long, ReadDeviceIdCode::Basic, 0x01, 0).unwrap();
        assert_eq!(first.objects.len(), 2);
        assert!(first.more_follows);
        assert_eq!(first.next_object_id, 2);
        let rest =
            DeviceIdentification::answer_from(&long, ReadDeviceIdCode::Basic, 0x01, 2).unwrap();
        assert_eq!(rest.objects.len(), 1);
        assert!(!rest.more_follows);
        // An object longer than a PDU is cut to fit one.
        let huge = [DeviceIdObject {
            id: 0,
            value: vec![b'y'; 300],
        }];
        let cut =
            DeviceIdentification::answer_from(&huge, ReadDeviceIdCode::Basic, 0x01, 0).unwrap();
        let mut pdu = vec![0x2B];
        pdu.extend_from_slice(&answer_data(&cut));
        assert!(pdu.len() <= MAX_PDU_LEN);
        assert_eq!(answer_pdu_len(&pdu), Ok(pdu.len()));
    }

    #[test]
    fn bytes_that_cannot_be_an_answer_are_refused() {
        assert!(answer_pdu_len(&[0x2B, 0x0D]).is_err());
        // Two objects of 200 bytes cannot fit one PDU.
        let mut runaway = vec![0x2B, 0x0E, 0x01, 0x01, 0x00, 0x00, 0x02, 0x00, 200];
        runaway.extend_from_slice(&[b'a'; 200]);
        runaway.extend_from_slice(&[0x01, 200]);
        assert!(answer_pdu_len(&runaway).is_err());
        // More follows must be 00 or FF.
        let odd = [0x2B, 0x0E, 0x01, 0x01, 0x07, 0x00, 0x00];
        assert!(decode_answer_pdu(ReadDeviceIdCode::Basic, &odd).is_err());
        // The answer to another code.
        let other = [0x2B, 0x0E, 0x02, 0x01, 0x00, 0x00, 0x00];
        assert!(decode_answer_pdu(ReadDeviceIdCode::Basic, &other).is_err());
        assert!(parse_request_data(&[0x0E, 0x05, 0x00]).is_err());
        assert!(parse_request_data(&[0x0D, 0x01, 0x00]).is_err());
        assert_eq!(
            parse_request_data(&[0x0E, 0x04, 0x02]),
            Ok((ReadDeviceIdCode::Individual, 2))
        );
    }

    #[test]
    fn text_drops_padding_and_shows_what_is_not_ascii() {
        let padded = DeviceIdObject {
            id: 0,
            value: b"ACME\0\0  ".to_vec(),
        };
        assert_eq!(padded.to_text(), "ACME");
        let binary = DeviceIdObject {
            id: 0x80,
            value: vec![0x41, 0xFF, 0x42],
        };
        assert_eq!(binary.to_text(), "A?B");
    }
}
