//! Read Device Identification (FC43/14) against an implementation not written here: pymodbus
//! builds the RTU frames (the basic request, the answer with the specification's example
//! objects, a stream too long for one answer), this codec decodes each of pymodbus's answers
//! to the objects pymodbus was given and encodes the same bytes from them.

use rtu2mqtt_modbus::codec::{decode_answer, encode_answer, encode_request, hex, Answer};
use rtu2mqtt_modbus::{DeviceIdObject, DeviceIdentification, ReadDeviceIdCode, Request, Response};

/// Prints, one a line in hex, the frames pymodbus builds: the request, the example's answer,
/// and the first answer of a stream of three 100-byte objects.
const PYMODBUS_FRAMES: &str = r#"
from pymodbus.framer import FramerRTU
from pymodbus.pdu import DecodePDU
from pymodbus.pdu.mei_message import ReadDeviceInformationRequest, ReadDeviceInformationResponse

def frame(pdu, server):
    return FramerRTU(DecodePDU(server)).buildFrame(pdu).hex()

print(frame(ReadDeviceInformationRequest(read_code=1, object_id=0, dev_id=1), False))
example = {0: b"Company identification", 1: b"Product code XX", 2: b"V2.11"}
print(frame(ReadDeviceInformationResponse(read_code=1, information=example, dev_id=1), True))
long = {0: b"a" * 100, 1: b"b" * 100, 2: b"c" * 100}
print(frame(ReadDeviceInformationResponse(read_code=1, information=long, dev_id=1), True))
"#;

fn bytes(text: &str) -> Vec<u8> {
    (0..text.len())
        .step_by(2)
        .map(|at| u8::from_str_radix(&text[at..at + 2], 16).expect("hex from pymodbus"))
        .collect()
}

/// pymodbus answers at conformity level 0x83 (it has every category).
fn answer(more: Option<u8>, objects: Vec<DeviceIdObject>) -> Response {
    Response::DeviceIdentification(DeviceIdentification {
        code: ReadDeviceIdCode::Basic,
        conformity_level: 0x83,
        more_follows: more.is_some(),
        next_object_id: more.unwrap_or(0),
        objects,
    })
}

#[test]
fn pymodbus_builds_the_frames_this_codec_reads_and_writes() {
    let output = crate::support::pymodbus::run_snippet(PYMODBUS_FRAMES);
    let text = String::from_utf8_lossy(&output).into_owned();
    let frames: Vec<Vec<u8>> = text.lines().map(bytes).collect();
    assert_eq!(frames.len(), 3, "{text}");

    let request = Request::ReadDeviceIdentification {
        code: ReadDeviceIdCode::Basic,
        object_id: 0,
    };
    assert_eq!(hex(&encode_request(1, &request).unwrap()), hex(&frames[0]));

    let example = answer(
        None,
        vec![
            DeviceIdObject::text(0, "Company identification"),
            DeviceIdObject::text(1, "Product code XX"),
            DeviceIdObject::text(2, "V2.11"),
        ],
    );
    assert_eq!(
        decode_answer(1, &request, &frames[1]),
        Ok(Answer::Normal(example.clone()))
    );
    assert_eq!(hex(&encode_answer(1, &example)), hex(&frames[1]));

    // The third object does not fit: more follows, from object 2.
    let first = answer(
        Some(2),
        vec![
            DeviceIdObject {
                id: 0,
                value: vec![b'a'; 100],
            },
            DeviceIdObject {
                id: 1,
                value: vec![b'b'; 100],
            },
        ],
    );
    assert_eq!(
        decode_answer(1, &request, &frames[2]),
        Ok(Answer::Normal(first.clone()))
    );
    assert_eq!(hex(&encode_answer(1, &first)), hex(&frames[2]));
}
