//! `Profile::decode_block_changes` against decoding in full, on every built-in profile: for any
//! earlier answer whose fields all decoded and any later one, a field left out decodes from the
//! later answer to what it decoded to from the earlier one, and every field it returns decodes
//! as in full.

use proptest::prelude::*;
use rtu2mqtt_modbus::Response;
use rtu2mqtt_profile::{registry, FieldReading, Profile};

/// A small deterministic generator: the test's cases come from proptest's seed.
struct Mix(u64);

impl Mix {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// A word that is mostly small (a usable scale factor, valid BCD, a printable
    /// character pair) and sometimes a special one (all ones, a "not implemented" mark) or
    /// anything at all.
    fn word(&mut self) -> u16 {
        match self.next() % 16 {
            0 => 0xFFFF,
            1 => 0x8000,
            2 => (self.next() >> 16) as u16,
            3..=5 => 0u16.wrapping_sub((self.next() % 4) as u16),
            6..=8 => 0x4142,
            _ => (self.next() % 10) as u16,
        }
    }
}

/// A random answer of the kind and length `block` of `profile` is read with.
fn answer_to(profile: &Profile, block: usize, mix: &mut Mix) -> Option<Response> {
    let empty = profile.read_blocks()[block].request.empty_answer()?;
    Some(match empty {
        Response::HoldingRegisters(words) => {
            Response::HoldingRegisters(words.iter().map(|_| mix.word()).collect())
        }
        Response::InputRegisters(words) => {
            Response::InputRegisters(words.iter().map(|_| mix.word()).collect())
        }
        Response::Coils(bits) => {
            Response::Coils(bits.iter().map(|_| mix.next() % 2 == 0).collect())
        }
        Response::DiscreteInputs(bits) => {
            Response::DiscreteInputs(bits.iter().map(|_| mix.next() % 2 == 0).collect())
        }
        other => other,
    })
}

/// `answer` with a few places changed.
fn moved(answer: &Response, mix: &mut Mix) -> Response {
    let mut next = answer.clone();
    let changes = 1 + mix.next() % 3;
    for _ in 0..changes {
        match &mut next {
            Response::HoldingRegisters(words) | Response::InputRegisters(words)
                if !words.is_empty() =>
            {
                let at = (mix.next() % words.len() as u64) as usize;
                words[at] = mix.word();
            }
            Response::Coils(bits) | Response::DiscreteInputs(bits) if !bits.is_empty() => {
                let at = (mix.next() % bits.len() as u64) as usize;
                bits[at] = !bits[at];
            }
            _ => {}
        }
    }
    next
}

fn find<'a>(readings: &'a [FieldReading], field: &str) -> Option<&'a FieldReading> {
    readings.iter().find(|reading| reading.field == field)
}

/// Checks `profile` on a few answer pairs; returns how many were compared.
fn check(profile: &Profile, name: &str, mix: &mut Mix) -> usize {
    let mut compared = 0;
    let blocks = profile.read_blocks().len();
    let others: Vec<Option<Response>> = (0..blocks)
        .map(|block| answer_to(profile, block, mix))
        .collect();
    let latest = |block: usize| others.get(block).and_then(Option::as_ref);
    for block in 0..blocks {
        let Some(before) = answer_to(profile, block, mix) else {
            continue;
        };
        let full_before = profile.decode_block_with(block, &before, latest);
        if full_before.iter().any(|reading| reading.value.is_err()) {
            // Only an answer whose fields all decoded is compared against.
            continue;
        }
        compared += 1;
        let after = moved(&before, mix);
        let full_after = profile.decode_block_with(block, &after, latest);
        let changes = profile.decode_block_changes(block, &after, Some(&before), latest);
        for reading in &changes {
            assert_eq!(
                find(&full_after, &reading.field),
                Some(reading),
                "{name}, block {block}: a returned field decodes as in full"
            );
        }
        for reading in &full_after {
            if find(&changes, &reading.field).is_none() {
                assert_eq!(
                    find(&full_before, &reading.field),
                    Some(reading),
                    "{name}, block {block}: `{}` was left out but its value moved",
                    reading.field
                );
            }
        }
        let unchanged = profile.decode_block_changes(block, &before, Some(&before), latest);
        assert!(
            unchanged.is_empty(),
            "{name}, block {block}: an equal answer decodes nothing"
        );
        let without = profile.decode_block_changes(block, &after, None, latest);
        assert_eq!(
            without, full_after,
            "{name}, block {block}: no earlier answer, every field"
        );
    }
    compared
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn a_field_left_out_decodes_to_what_it_did(seed in 1u64..) {
        let mut mix = Mix(seed);
        for name in registry::built_in_names() {
            let profile = registry::built_in(name).expect("a built-in profile loads");
            check(&profile, name, &mut mix);
        }
    }
}

#[test]
fn every_block_of_every_built_in_profile_is_compared() {
    let mut mix = Mix(0x5eed);
    for name in registry::built_in_names() {
        let profile = registry::built_in(name).expect("a built-in profile loads");
        let compared: usize = (0..256).map(|_| check(&profile, name, &mut mix)).sum();
        let blocks = profile.read_blocks().len();
        assert!(
            compared >= blocks * 16,
            "{name}: only {compared} answer pairs of {blocks} blocks × 256 decoded in full"
        );
    }
}

#[test]
fn an_answer_of_another_kind_or_length_decodes_every_field() {
    let profile = registry::built_in("eastron-sdm120").expect("built in");
    let mut mix = Mix(7);
    let answer = answer_to(&profile, 0, &mut mix).expect("a read block");
    let Response::InputRegisters(words) = &answer else {
        panic!("the SDM120 is read with FC04");
    };
    let full = profile.decode_block(0, &answer);
    let other_kind = Response::HoldingRegisters(words.clone());
    assert_eq!(
        profile.decode_block_changes(0, &answer, Some(&other_kind), |_| None),
        full
    );
    let shorter = Response::InputRegisters(words[..words.len() - 2].to_vec());
    assert_eq!(
        profile.decode_block_changes(0, &answer, Some(&shorter), |_| None),
        full
    );
}
