//! What a device says it is, asked with reads only, and the profile that fits it.
//!
//! [`Identifier`] is the sequence of requests, without I/O: the caller sends each request it
//! names to the device and hands back what came ([`Heard`]), until it names none. It asks for
//! the device's Read Device Identification (FC43/14, the basic objects, following "more
//! follows" a bounded number of times), then for the SunSpec marker ("SunS" at 40000, 0 and
//! 50000 in turn) and, where it is found, the ids of the chain's first models. A device
//! without FC43 answers exception 01 (02 or 03 from some): that is no identification, not an
//! error. The result, an [`Identity`], is matched against profiles' `[device] identification`
//! ([`Identity::fit`]).

use rtu2mqtt_modbus::device_id::{object, DeviceIdObject, ReadDeviceIdCode};
use rtu2mqtt_modbus::{ExceptionCode, Request, Response};

use super::sunspec::{BASES, END_ID, MARKER};
use super::Profile;

/// What came back for one request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Heard {
    /// The device's normal answer.
    Answer(Response),
    /// The device's exception answer.
    Exception(ExceptionCode),
    /// No answer from the device: a timeout, a garbled answer, a gateway answering in its
    /// place.
    Nothing,
}

/// What a device answered to Read Device Identification.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DeviceId {
    /// Its objects (the basic ones, and whatever else the device put in the stream).
    Objects(Vec<DeviceIdObject>),
    /// An exception: the device does not implement the function (01), or not this part of it.
    Refused(ExceptionCode),
    /// No answer (some devices stay silent on a function they do not know), or an answer that
    /// is not one.
    NoAnswer,
}

impl DeviceId {
    /// How the device answered, in a word: `ok`, the exception, or `no answer`.
    pub fn status(&self) -> String {
        match self {
            Self::Objects(_) => "ok".to_string(),
            Self::Refused(code) => code.to_string(),
            Self::NoAnswer => "no answer".to_string(),
        }
    }

    fn text(&self, id: u8) -> Option<String> {
        match self {
            Self::Objects(objects) => objects
                .iter()
                .find(|o| o.id == id)
                .map(DeviceIdObject::to_text)
                .filter(|text| !text.is_empty()),
            _ => None,
        }
    }

    /// The VendorName (object 0x00).
    pub fn vendor(&self) -> Option<String> {
        self.text(object::VENDOR_NAME)
    }

    /// The ProductCode (object 0x01).
    pub fn product_code(&self) -> Option<String> {
        self.text(object::PRODUCT_CODE)
    }

    /// The MajorMinorRevision (object 0x02).
    pub fn revision(&self) -> Option<String> {
        self.text(object::MAJOR_MINOR_REVISION)
    }
}

/// A SunSpec map found on the device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SunSpecMap {
    /// Where "SunS" is.
    pub base: u16,
    /// The ids of the chain's first models, in order (at most [`SUNSPEC_MODELS_READ`]).
    pub models: Vec<u16>,
}

impl std::fmt::Display for SunSpecMap {
    /// `40000: models 1, 103`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let models: Vec<String> = self.models.iter().map(u16::to_string).collect();
        match models.as_slice() {
            [] => write!(f, "{}", self.base),
            [one] => write!(f, "{}: model {one}", self.base),
            _ => write!(f, "{}: models {}", self.base, models.join(", ")),
        }
    }
}

/// What a device says it is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Identity {
    /// Its Read Device Identification.
    pub device_id: DeviceId,
    /// Its SunSpec map, if it has one.
    pub sunspec: Option<SunSpecMap>,
}

/// The profile that fits an [`Identity`].
#[derive(Debug, Clone, Copy)]
pub enum Fit<'p> {
    /// This profile's `identification` matches what the device reports.
    Profile(&'p Profile),
    /// A SunSpec map no profile's `identification` matches: `rtu2mqtt sunspec` writes one
    /// from the device's chain.
    SunSpecChain {
        /// Where "SunS" is.
        base: u16,
    },
    /// Nothing fits.
    Unknown,
}

impl Identity {
    /// The first of `candidates` whose `identification` matches what the device reports (its
    /// Read Device Identification, then its SunSpec map).
    pub fn fit<'p>(&self, candidates: &'p [Profile]) -> Fit<'p> {
        let identified = |profile: &&Profile| profile.identification().is_some();
        if let (Some(vendor), Some(code)) = (self.device_id.vendor(), self.device_id.product_code())
        {
            if let Some(profile) = candidates.iter().filter(identified).find(|profile| {
                profile
                    .identification()
                    .is_some_and(|id| id.matches_device_id(&vendor, &code))
            }) {
                return Fit::Profile(profile);
            }
        }
        if let Some(map) = &self.sunspec {
            return candidates
                .iter()
                .find(|profile| {
                    profile
                        .identification()
                        .is_some_and(|id| id.matches_sunspec(map.base, &map.models))
                })
                .map_or(Fit::SunSpecChain { base: map.base }, Fit::Profile);
        }
        Fit::Unknown
    }
}

/// Requests following "more follows", at most: a device that keeps saying so is not followed
/// further.
pub const MAX_DEVICE_ID_REQUESTS: usize = 4;
/// Identification objects kept, at most (the basic category has three).
pub const MAX_OBJECTS: usize = 16;
/// Bytes of an object's value kept, at most.
pub const MAX_OBJECT_LEN: usize = 64;
/// Model ids of a SunSpec chain read, at most.
pub const SUNSPEC_MODELS_READ: usize = 4;

/// Where the sequence stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Step {
    /// Read Device Identification from this object on (the `n`th request).
    DeviceId {
        from: u8,
        requests: usize,
    },
    /// The SunSpec marker at `BASES[index]`.
    Marker {
        index: usize,
    },
    /// The id and length of the model at `at` of the chain based at `base`.
    Model {
        base: u16,
        at: u16,
    },
    Done,
}

/// The sequence of reads that identifies one device; see the module documentation.
#[derive(Debug, Clone)]
pub struct Identifier {
    step: Step,
    device_id: DeviceId,
    sunspec: Option<SunSpecMap>,
}

impl Default for Identifier {
    fn default() -> Self {
        Self::new()
    }
}

impl Identifier {
    /// The sequence's start.
    pub fn new() -> Self {
        Self {
            step: Step::DeviceId {
                from: 0,
                requests: 1,
            },
            device_id: DeviceId::NoAnswer,
            sunspec: None,
        }
    }

    /// The next request to send, `None` once the device is identified.
    pub fn next_request(&self) -> Option<Request> {
        Some(match self.step {
            Step::DeviceId { from, .. } => Request::ReadDeviceIdentification {
                code: ReadDeviceIdCode::Basic,
                object_id: from,
            },
            Step::Marker { index } => Request::ReadHoldingRegisters {
                start: *BASES.get(index)?,
                quantity: 2,
            },
            Step::Model { at, .. } => Request::ReadHoldingRegisters {
                start: at,
                quantity: 2,
            },
            Step::Done => return None,
        })
    }

    /// Takes what came for the request [`Identifier::next_request`] named.
    pub fn hear(&mut self, heard: Heard) {
        self.step = match self.step {
            Step::DeviceId { from, requests } => self.hear_device_id(from, requests, heard),
            Step::Marker { index } => match heard {
                Heard::Answer(Response::HoldingRegisters(words)) if words == MARKER => {
                    let base = BASES[index];
                    self.sunspec = Some(SunSpecMap {
                        base,
                        models: Vec::new(),
                    });
                    Self::model_at(base, base.checked_add(2))
                }
                _ if index + 1 < BASES.len() => Step::Marker { index: index + 1 },
                _ => Step::Done,
            },
            Step::Model { base, at } => match (heard, self.sunspec.as_mut()) {
                (Heard::Answer(Response::HoldingRegisters(words)), Some(map))
                    if words.len() == 2 && words[0] != END_ID =>
                {
                    map.models.push(words[0]);
                    if map.models.len() >= SUNSPEC_MODELS_READ {
                        Step::Done
                    } else {
                        let next = at
                            .checked_add(2)
                            .and_then(|body| body.checked_add(words[1]));
                        Self::model_at(base, next)
                    }
                }
                _ => Step::Done,
            },
            Step::Done => Step::Done,
        };
    }

    fn model_at(base: u16, at: Option<u16>) -> Step {
        at.map_or(Step::Done, |at| Step::Model { base, at })
    }

    fn hear_device_id(&mut self, from: u8, requests: usize, heard: Heard) -> Step {
        let after = Step::Marker { index: 0 };
        match heard {
            Heard::Answer(Response::DeviceIdentification(answer)) => {
                if !matches!(self.device_id, DeviceId::Objects(_)) {
                    self.device_id = DeviceId::Objects(Vec::new());
                }
                let DeviceId::Objects(kept) = &mut self.device_id else {
                    return after;
                };
                for mut object in answer.objects {
                    if kept.len() >= MAX_OBJECTS {
                        break;
                    }
                    if kept.iter().any(|k| k.id == object.id) {
                        continue;
                    }
                    object.value.truncate(MAX_OBJECT_LEN);
                    kept.push(object);
                }
                // Followed only forwards, so that a device repeating itself ends the stream.
                let advances = answer.next_object_id > from;
                if answer.more_follows && advances && requests < MAX_DEVICE_ID_REQUESTS {
                    Step::DeviceId {
                        from: answer.next_object_id,
                        requests: requests + 1,
                    }
                } else {
                    after
                }
            }
            Heard::Exception(code) if requests == 1 => {
                self.device_id = DeviceId::Refused(code);
                after
            }
            // An answer of another kind is no identification; what came before it stays.
            _ => after,
        }
    }

    /// What the device said, once [`Identifier::next_request`] names no more requests (or
    /// whatever it said so far).
    pub fn identity(&self) -> Identity {
        Identity {
            device_id: self.device_id.clone(),
            sunspec: self.sunspec.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rtu2mqtt_modbus::DeviceIdentification;

    /// Runs the sequence against `device`, returning the identity and the requests sent.
    fn run(mut device: impl FnMut(&Request) -> Heard) -> (Identity, Vec<Request>) {
        let mut identifier = Identifier::new();
        let mut sent = Vec::new();
        while let Some(request) = identifier.next_request() {
            assert!(sent.len() < 20, "the sequence does not end: {sent:?}");
            identifier.hear(device(&request));
            sent.push(request);
        }
        (identifier.identity(), sent)
    }

    fn answer(objects: Vec<DeviceIdObject>, more: Option<u8>) -> Heard {
        Heard::Answer(Response::DeviceIdentification(DeviceIdentification {
            code: ReadDeviceIdCode::Basic,
            conformity_level: 0x01,
            more_follows: more.is_some(),
            next_object_id: more.unwrap_or(0),
            objects,
        }))
    }

    fn basic_from(from: u8) -> Request {
        Request::ReadDeviceIdentification {
            code: ReadDeviceIdCode::Basic,
            object_id: from,
        }
    }

    fn holding(start: u16) -> Request {
        Request::ReadHoldingRegisters { start, quantity: 2 }
    }

    #[test]
    fn a_device_without_fc43_or_sunspec_costs_four_reads() {
        let (identity, sent) = run(|request| match request {
            Request::ReadDeviceIdentification { .. } => {
                Heard::Exception(ExceptionCode::IllegalFunction)
            }
            _ => Heard::Exception(ExceptionCode::IllegalDataAddress),
        });
        assert_eq!(
            sent,
            [basic_from(0), holding(40000), holding(0), holding(50000)]
        );
        assert_eq!(
            identity.device_id,
            DeviceId::Refused(ExceptionCode::IllegalFunction)
        );
        assert_eq!(identity.sunspec, None);
        assert_eq!(
            identity.device_id.status(),
            "exception 01 (illegal function)"
        );
        assert!(matches!(identity.fit(&[]), Fit::Unknown));
    }

    #[test]
    fn more_follows_is_followed_from_the_next_object() {
        let (identity, sent) = run(|request| match request {
            Request::ReadDeviceIdentification { object_id: 0, .. } => answer(
                vec![
                    DeviceIdObject::text(0, "Schneider Electric"),
                    DeviceIdObject::text(1, "A9MEM3155"),
                ],
                Some(2),
            ),
            Request::ReadDeviceIdentification { object_id: 2, .. } => {
                answer(vec![DeviceIdObject::text(2, "V2.1")], None)
            }
            _ => Heard::Nothing,
        });
        assert_eq!(sent[..2], [basic_from(0), basic_from(2)]);
        assert_eq!(
            identity.device_id.vendor().as_deref(),
            Some("Schneider Electric")
        );
        assert_eq!(
            identity.device_id.product_code().as_deref(),
            Some("A9MEM3155")
        );
        assert_eq!(identity.device_id.revision().as_deref(), Some("V2.1"));
    }

    #[test]
    fn a_device_that_never_stops_saying_more_follows_is_left_after_a_bound() {
        let (identity, sent) = run(|request| match request {
            Request::ReadDeviceIdentification { object_id, .. } => answer(
                vec![DeviceIdObject {
                    id: *object_id,
                    value: vec![b'x'; 200],
                }],
                Some(object_id.wrapping_add(1)),
            ),
            _ => Heard::Nothing,
        });
        let asked = sent
            .iter()
            .filter(|r| matches!(r, Request::ReadDeviceIdentification { .. }))
            .count();
        assert_eq!(asked, MAX_DEVICE_ID_REQUESTS);
        let DeviceId::Objects(objects) = identity.device_id else {
            panic!("no objects");
        };
        assert_eq!(objects.len(), MAX_DEVICE_ID_REQUESTS);
        assert!(objects.iter().all(|o| o.value.len() == MAX_OBJECT_LEN));
        // One that points back at an object already read is not followed either.
        let (_, sent) = run(|request| match request {
            Request::ReadDeviceIdentification { .. } => {
                answer(vec![DeviceIdObject::text(0, "A")], Some(0))
            }
            _ => Heard::Nothing,
        });
        assert_eq!(sent[..2], [basic_from(0), holding(40000)]);
    }

    #[test]
    fn a_sunspec_chain_is_read_to_its_first_models() {
        // "SunS" at 40000, model 1 (length 66) at 40002, model 103 (50) at 40070, the end.
        let (identity, sent) = run(|request| match request {
            Request::ReadHoldingRegisters { start, .. } => match start {
                40000 => Heard::Answer(Response::HoldingRegisters(MARKER.to_vec())),
                40002 => Heard::Answer(Response::HoldingRegisters(vec![1, 66])),
                40070 => Heard::Answer(Response::HoldingRegisters(vec![103, 50])),
                40122 => Heard::Answer(Response::HoldingRegisters(vec![END_ID, 0])),
                _ => Heard::Exception(ExceptionCode::IllegalDataAddress),
            },
            _ => Heard::Nothing,
        });
        assert_eq!(
            sent,
            [
                basic_from(0),
                holding(40000),
                holding(40002),
                holding(40070),
                holding(40122)
            ]
        );
        assert_eq!(identity.device_id, DeviceId::NoAnswer);
        assert_eq!(
            identity.sunspec,
            Some(SunSpecMap {
                base: 40000,
                models: vec![1, 103]
            })
        );
        assert_eq!(
            identity
                .sunspec
                .as_ref()
                .map(ToString::to_string)
                .as_deref(),
            Some("40000: models 1, 103")
        );
        assert_eq!(identity.device_id.status(), "no answer");
        let inverter = crate::registry::built_in("sunspec-inverter").unwrap();
        let candidates = [inverter];
        assert!(
            matches!(identity.fit(&candidates), Fit::Profile(p) if p.name() == "sunspec-inverter")
        );
        // Elsewhere, or with other models, it is a chain for `rtu2mqtt sunspec`.
        let single_phase = Identity {
            device_id: DeviceId::NoAnswer,
            sunspec: Some(SunSpecMap {
                base: 40000,
                models: vec![1, 101],
            }),
        };
        assert!(matches!(
            single_phase.fit(&candidates),
            Fit::SunSpecChain { base: 40000 }
        ));
    }

    #[test]
    fn a_marker_at_the_top_of_the_address_space_ends_the_walk() {
        let mut identifier = Identifier::new();
        identifier.hear(Heard::Nothing);
        identifier.sunspec = Some(SunSpecMap {
            base: 0xFFFE,
            models: Vec::new(),
        });
        identifier.step = Identifier::model_at(0xFFFE, 0xFFFEu16.checked_add(2));
        assert_eq!(identifier.next_request(), None);
    }

    #[test]
    fn the_profile_whose_identification_matches_is_named() {
        let text = |id: &str| {
            format!(
                "[device]\nname = \"m\"\nmanufacturer = \"m\"\nmodel = \"x\"\nidentification = {id}\n\
                 [line]\n[[blocks]]\nname = \"b\"\nfunction = 3\nstart = 0\ncount = 2\n\
                 [[fields]]\nname = \"f\"\nblock = \"b\"\noffset = 0\ncodec = {{ type = \"u16\" }}\n"
            )
        };
        let meter = Profile::from_toml(
            &text("{ vendor = \"Schneider Electric\", product_code = \"A9MEM31*5\" }"),
            "test",
        )
        .unwrap();
        let identity = Identity {
            device_id: DeviceId::Objects(vec![
                DeviceIdObject::text(0, "Schneider Electric"),
                DeviceIdObject::text(1, "A9MEM3165"),
            ]),
            sunspec: None,
        };
        let candidates = [meter];
        assert!(matches!(identity.fit(&candidates), Fit::Profile(p) if p.name() == "m"));
        let other = Identity {
            device_id: DeviceId::Objects(vec![
                DeviceIdObject::text(0, "Schneider Electric"),
                DeviceIdObject::text(1, "METSEPM3255"),
            ]),
            sunspec: None,
        };
        assert!(matches!(other.fit(&candidates), Fit::Unknown));
        // A half-given key is the profile's problem, with its place.
        let problems = Profile::from_toml(&text("{ vendor = \"ACME\" }"), "test").unwrap_err();
        assert!(
            problems.0[0].place.ends_with("device.identification"),
            "{problems}"
        );
    }
}
