//! Writes the committed seed corpora (`fuzz/corpus/<target>/`) from the project's own data and
//! code: the golden frames of the seed devices (requests encoded by the master's codec for
//! every block of the seed profiles, answers by the simulators' encoder), the library's
//! profiles, the configuration file and the documentation's examples, segments written by the
//! journal, Sparkplug payloads written by the edge node's encoder. Run after a change of an
//! input layout: `cargo run --manifest-path fuzz/Cargo.toml --example seeds`.

use std::fs;
use std::path::{Path, PathBuf};
use std::time::Duration;

use rtu2mqtt::config::HistoryConfig;
use rtu2mqtt::history::{Journal, Record};
use rtu2mqtt::sparkplug::core::protobuf::{Metric, MetricValue, Payload};
use rtu2mqtt::sparkplug::core::session_interface::REBIRTH;
use rtu2mqtt_fuzz::{plant, push_part, push_request, seed_profiles};
use rtu2mqtt_modbus::codec::{self, encode_answer, encode_exception};
use rtu2mqtt_modbus::crc::append_crc;
use rtu2mqtt_modbus::tcp::mbap;
use rtu2mqtt_modbus::{ExceptionCode, Request, Response, SlaveId};
use rtu2mqtt_profile::{DeviceState, Profile};

fn repository() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The seeds of one target, written as `<name>` files in its corpus directory.
struct Corpus {
    dir: PathBuf,
}

impl Corpus {
    fn new(target: &str) -> Self {
        let dir = repository().join("fuzz/corpus").join(target);
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).expect("the corpus directory");
        Corpus { dir }
    }

    fn add(&self, name: &str, bytes: &[u8]) {
        fs::write(self.dir.join(name), bytes).expect("a seed written");
    }
}

/// A device's answer to `request` with a recognisable value in every place.
fn answer_to(request: &Request) -> Option<Response> {
    Some(match request.empty_answer()? {
        Response::HoldingRegisters(words) => {
            Response::HoldingRegisters((1..=words.len() as u16).collect())
        }
        Response::InputRegisters(words) => {
            Response::InputRegisters((1..=words.len() as u16).map(|w| w * 10).collect())
        }
        Response::Coils(bits) => Response::Coils((0..bits.len()).map(|i| i % 3 == 0).collect()),
        Response::DiscreteInputs(bits) => {
            Response::DiscreteInputs((0..bits.len()).map(|i| i % 2 == 0).collect())
        }
        other => other,
    })
}

/// The requests a master sends to device `slave` of `profile`, and the device's answer frame
/// to each: every block read, and the writes of the profile's example commands.
fn exchanges(profile: &Profile, slave: SlaveId) -> Vec<(Request, Vec<u8>)> {
    let reads: Vec<(Request, Response)> = profile
        .read_blocks()
        .iter()
        .filter_map(|block| Some((block.request.clone(), answer_to(&block.request)?)))
        .collect();
    let mut exchanges: Vec<(Request, Vec<u8>)> = reads
        .iter()
        .map(|(request, answer)| (request.clone(), encode_answer(slave, answer)))
        .collect();
    for (field, text) in profile.example_commands() {
        let Ok(plan) = profile.plan_command(field, &text, &DeviceState::new()) else {
            continue;
        };
        let before: Vec<Response> = plan
            .reads_before()
            .iter()
            .filter_map(|read| Some(reads.iter().find(|(r, _)| r == read)?.1.clone()))
            .collect();
        for write in plan.writes(&before).unwrap_or_default() {
            let frame = codec::encode_request(slave, &write).expect("a planned write");
            exchanges.push((write, echo(&frame)));
        }
    }
    exchanges
}

/// A device's answer to the write request `frame`: a single write's answer is the request
/// itself, a multiple write's its address, function, start and quantity.
fn echo(frame: &[u8]) -> Vec<u8> {
    match frame[1] {
        0x05 | 0x06 => frame.to_vec(),
        _ => {
            let mut answer = frame[..6].to_vec();
            append_crc(&mut answer);
            answer
        }
    }
}

/// (address, request, answer frame) for every exchange of every seed profile, with an
/// exception answer to each profile's first block.
fn golden_frames() -> Vec<(String, SlaveId, Request, Vec<u8>)> {
    let mut frames = Vec::new();
    for (index, (name, profile)) in seed_profiles().iter().enumerate() {
        let slave = profile.default_address().unwrap_or(index as u8 + 1);
        for (number, (request, frame)) in exchanges(profile, slave).into_iter().enumerate() {
            frames.push((format!("{name}-{number}"), slave, request, frame));
        }
        if let Some(block) = profile.read_blocks().first() {
            let function = block.request.function().value();
            let frame = encode_exception(slave, function, ExceptionCode::IllegalDataAddress);
            frames.push((
                format!("{name}-exception"),
                slave,
                block.request.clone(),
                frame,
            ));
        }
    }
    frames
}

/// `rtu_answer`: options (9600 baud, no echo), a 300 ms timeout, the answer in one chunk 10 ms
/// after the request; a second seed has it in two chunks with a 5 ms pause, another device's
/// frame and noise in front.
fn rtu_answer() {
    let corpus = Corpus::new("rtu_answer");
    for (name, slave, request, frame) in golden_frames() {
        let mut seed = Vec::new();
        push_request(&mut seed, slave, &request);
        seed.extend_from_slice(&[0, 140]);
        seed.push(40);
        push_part(&mut seed, &frame);
        corpus.add(&format!("{name}-whole"), &seed);

        let mut seed = Vec::new();
        push_request(&mut seed, slave, &request);
        seed.extend_from_slice(&[0, 140]);
        let foreign = encode_answer(slave.wrapping_add(1), &Response::HoldingRegisters(vec![7]));
        seed.push(8);
        push_part(&mut seed, &foreign);
        seed.push(0);
        push_part(&mut seed, &[0x00, 0xFF]);
        let (head, rest) = frame.split_at(frame.len() / 2);
        seed.push(0);
        push_part(&mut seed, head);
        seed.push(20);
        push_part(&mut seed, rest);
        corpus.add(&format!("{name}-paused"), &seed);
    }
}

/// `tcp_answer`: the request, transaction 0x0102, the answer as an ADU; and the answer as an
/// RTU frame on a raw stream.
fn tcp_answer() {
    let corpus = Corpus::new("tcp_answer");
    for (name, slave, request, frame) in golden_frames() {
        let mut seed = Vec::new();
        push_request(&mut seed, slave, &request);
        seed.extend_from_slice(&0x0102u16.to_be_bytes());
        let mut rtu = seed.clone();
        seed.extend(mbap::rtu_to_adu(0x0102, &frame).expect("an answer frame"));
        corpus.add(&format!("{name}-adu"), &seed);
        rtu.extend_from_slice(&frame);
        corpus.add(&format!("{name}-rtu"), &rtu);
    }
}

/// `served_request`: every request of the seed plant in both framings under each access.
fn served_request() {
    let corpus = Corpus::new("served_request");
    let addresses = [1u8, 2, 0x81];
    for (access, word) in [(0u8, "profile"), (2, "read-only"), (4, "raw")] {
        let mut adus = vec![access];
        let mut rtus = vec![access | 1];
        for ((name, profile), address) in seed_profiles().iter().zip(addresses) {
            let mut one_adu = vec![access];
            let mut one_rtu = vec![access | 1];
            for (transaction, (request, _)) in exchanges(profile, address).into_iter().enumerate() {
                let adu =
                    mbap::encode_request(transaction as u16, address, &request).expect("a request");
                let rtu = codec::encode_request(address, &request).expect("a request");
                one_adu.extend_from_slice(&adu);
                one_rtu.extend_from_slice(&rtu);
            }
            adus.extend_from_slice(&one_adu[1..]);
            rtus.extend_from_slice(&one_rtu[1..]);
            corpus.add(&format!("{name}-{word}-adu"), &one_adu);
            corpus.add(&format!("{name}-{word}-rtu"), &one_rtu);
        }
        corpus.add(&format!("plant-{word}-adu"), &adus);
        corpus.add(&format!("plant-{word}-rtu"), &rtus);
    }
}

/// `mqtt_command`: every device online, then each example command of its profile, its end
/// and a tick; a second seed sends them while the device is offline.
fn mqtt_command() {
    let corpus = Corpus::new("mqtt_command");
    let config = plant::config();
    let devices: Vec<_> = config.lines.iter().flat_map(|line| &line.devices).collect();
    for (index, device) in devices.iter().enumerate() {
        let profile = &device.profile;
        let mut online = Vec::new();
        for other in 0..devices.len() {
            online.extend_from_slice(&[4, other as u8, 0]);
        }
        let mut offline = Vec::new();
        for (field, text) in profile.example_commands() {
            let Some(position) = profile.fields().iter().position(|f| f.name == field) else {
                continue;
            };
            let mut step = vec![0, index as u8, position as u8];
            push_part(&mut step, text.as_bytes());
            online.extend_from_slice(&step);
            offline.extend_from_slice(&step);
            let mut finished = vec![5, 0, 0];
            push_part(&mut finished, b"applied");
            online.extend_from_slice(&finished);
            online.extend_from_slice(&[6, 0, 0, 0, 100]);
        }
        corpus.add(&format!("{}-online", device.name), &online);
        offline.extend_from_slice(&[6, 0, 0, 0xFF, 0xFF]);
        corpus.add(&format!("{}-offline", device.name), &offline);
    }
}

/// `sparkplug_command`: a rebirth NCMD, and for each device a DCMD of each writable metric
/// with the value it was born with, named and by alias.
fn sparkplug_command() {
    let corpus = Corpus::new("sparkplug_command");
    let rebirth = Payload {
        timestamp: Some(plant::SPARKPLUG_NOW),
        metrics: vec![Metric {
            name: Some(REBIRTH.to_string()),
            datatype: Some(11),
            value: Some(MetricValue::Boolean(true)),
            ..Default::default()
        }],
        ..Default::default()
    };
    let mut seed = vec![0];
    seed.extend(rebirth.encode_to_bytes());
    corpus.add("ncmd-rebirth", &seed);
    let mut session = plant::born_session();
    let births = session.rebirth(plant::SPARKPLUG_NOW);
    let config = plant::config();
    let devices: Vec<_> = config.lines.iter().flat_map(|line| &line.devices).collect();
    for action in births {
        let rtu2mqtt::sparkplug::core::session_interface::Action::Publish {
            topic, payload, ..
        } = action
        else {
            continue;
        };
        let Some((_, device)) = topic.split_once("/DBIRTH/gw/") else {
            continue;
        };
        let Some(index) = devices.iter().position(|d| d.name == device) else {
            continue;
        };
        let profile = &devices[index].profile;
        let birth = Payload::decode_bytes(&payload).expect("our own DBIRTH");
        let writable: Vec<&Metric> = birth
            .metrics
            .iter()
            .filter(|m| {
                m.name
                    .as_deref()
                    .and_then(|name| profile.field(name))
                    .is_some_and(|field| field.writable)
            })
            .collect();
        for (named, by) in [(true, "named"), (false, "alias")] {
            let metrics = writable
                .iter()
                .filter(|m| m.value.is_some())
                .map(|m| Metric {
                    name: if named { m.name.clone() } else { None },
                    alias: if named { None } else { m.alias },
                    datatype: m.datatype,
                    value: m.value.clone(),
                    ..Default::default()
                })
                .collect();
            let dcmd = Payload {
                timestamp: Some(plant::SPARKPLUG_NOW),
                metrics,
                ..Default::default()
            };
            let mut seed = vec![index as u8 + 1];
            seed.extend(dcmd.encode_to_bytes());
            corpus.add(&format!("dcmd-{device}-{by}"), &seed);
        }
    }
}

/// `profile_toml`: the library's profile files.
fn profile_toml() {
    let corpus = Corpus::new("profile_toml");
    let dir = repository().join("config/profiles");
    let mut entries: Vec<_> = fs::read_dir(&dir)
        .expect("config/profiles")
        .filter_map(Result::ok)
        .collect();
    entries.sort_by_key(|entry| entry.file_name());
    for entry in entries {
        let name = entry.file_name().to_string_lossy().into_owned();
        corpus.add(&name, &fs::read(entry.path()).expect("a profile file"));
    }
}

/// `config_toml`: the seed plant's configuration, the same with every option that is only
/// commented out in it written in, and the documentation's configuration examples (a section
/// the configuration file has not got added to it, whole configurations as they are).
fn config_toml() {
    let corpus = Corpus::new("config_toml");
    let base = fs::read_to_string(repository().join("config/rtu2mqtt.toml"))
        .expect("config/rtu2mqtt.toml");
    corpus.add("rtu2mqtt.toml", base.as_bytes());
    let uncommented: String = base
        .lines()
        .map(|line| {
            let option = line.strip_prefix("# ").filter(|rest| {
                rest.starts_with('[')
                    || rest.split_once(" = ").is_some_and(|(key, _)| {
                        key.chars().all(|c| c.is_ascii_lowercase() || c == '_')
                    })
            });
            format!("{}\n", option.unwrap_or(line))
        })
        .collect();
    corpus.add("rtu2mqtt-every-option.toml", uncommented.as_bytes());
    let docs = repository().join("docs");
    let mut pages: Vec<_> = fs::read_dir(&docs)
        .expect("docs")
        .filter_map(Result::ok)
        .map(|entry| entry.path())
        .filter(|path| path.extension().is_some_and(|e| e == "md"))
        .collect();
    pages.sort();
    for page in pages {
        let text = fs::read_to_string(&page).expect("a page");
        let stem = page
            .file_stem()
            .expect("a name")
            .to_string_lossy()
            .into_owned();
        for (number, block) in text.split("```toml\n").skip(1).enumerate() {
            let Some((example, _)) = block.split_once("```") else {
                continue;
            };
            let tables: Vec<&str> = example
                .lines()
                .filter(|line| line.starts_with('['))
                .collect();
            // Profiles and other programs' configurations are no configuration of ours.
            let ours = tables.iter().all(|table| {
                [
                    "[mqtt",
                    "[gateway",
                    "[health",
                    "[[lines",
                    "[lines",
                    "[sparkplug",
                    "[history",
                    "[web",
                ]
                .iter()
                .any(|section| table.starts_with(section))
            });
            // A table the file has already cannot come twice; an array of tables can.
            let in_base = |table: &&str| {
                !table.starts_with("[[") && base.lines().any(|line| line.trim() == *table)
            };
            let seed = if !ours || tables.is_empty() {
                continue;
            } else if example.contains("[mqtt]") {
                example.to_string()
            } else if !tables.iter().any(in_base) {
                format!("{base}\n{example}")
            } else {
                continue;
            };
            corpus.add(&format!("{stem}-{number}.toml"), seed.as_bytes());
        }
    }
}

/// `journal_segment`: segments written by the journal: a few records; one cut short in its
/// last record (a crash while appending).
fn journal_segment() {
    let corpus = Corpus::new("journal_segment");
    let dir = tempfile::tempdir().expect("a temporary directory");
    let config = HistoryConfig {
        path: dir.path().to_path_buf(),
        max_size: 1 << 20,
        max_age: Duration::from_secs(1 << 30),
    };
    let mut journal = Journal::open(&config);
    let documents = [
        (
            "dust_collector",
            r#"{"ts":1700000000000,"values":{"gear":8,"running":true}}"#,
        ),
        (
            "valve",
            r#"{"ts":1700000000500,"values":{"position":42.5}}"#,
        ),
        (
            "air_shower",
            r#"{"ts":1700000001000,"values":{"door":"closed"}}"#,
        ),
    ];
    for (at, (device, document)) in documents.iter().enumerate() {
        let record = Record {
            at_ms: 1_700_000_000_000 + at as u64 * 500,
            device: device.to_string(),
            document: document.to_string(),
        };
        journal.append(&record, 1_700_000_000_000);
    }
    journal.sync();
    let mut segments: Vec<_> = fs::read_dir(dir.path())
        .expect("the journal's directory")
        .filter_map(Result::ok)
        .map(|entry| entry.path())
        .collect();
    segments.sort();
    let segment = fs::read(segments.first().expect("a segment")).expect("a segment's bytes");
    corpus.add("three-records", &segment);
    corpus.add("torn-tail", &segment[..segment.len() - 7]);
}

fn main() {
    rtu_answer();
    tcp_answer();
    served_request();
    mqtt_command();
    sparkplug_command();
    profile_toml();
    config_toml();
    journal_segment();
}
