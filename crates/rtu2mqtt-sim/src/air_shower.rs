//! The simulated Lixian multi-mode air shower, written from `docs/devices.md` §3.
//!
//! Kept on purpose: the fixed address 0x81 and silence to every other address (broadcast
//! included) and to bad CRCs; coils 0–23 readable with FC01; FC0F writing coils 0–15 of which
//! 12–15 are reserved and ignored; strong wind with breeze refused with exception 03 and nothing
//! applied; the emergency stop as a toggle (writing coil 0 = 1 flips it, 0 leaves it) that opens
//! both doors while active; voice coils as buttons that fall back to 0 shortly after a press;
//! door-closed sensors (16/17) following the doors.

use std::time::{Duration, Instant};

use super::device::{Addressing, Reply, SimDevice};
use rtu2mqtt_modbus::frame::{ExceptionCode, Request, Response, SlaveId};

/// The device's fixed address.
pub const ADDRESS: SlaveId = 0x81;

pub const EMERGENCY_STOP: usize = 0;
pub const FRONT_DOOR_LOCK: usize = 1;
pub const REAR_DOOR_LOCK: usize = 2;
pub const STRONG_WIND: usize = 3;
pub const BREEZE: usize = 4;
pub const FRONT_DOOR_OPEN: usize = 5;
pub const REAR_DOOR_OPEN: usize = 6;
pub const TUNNEL_EXTENSION: usize = 7;
pub const LIGHT: usize = 8;
pub const BUZZER: usize = 9;
pub const VOICE_START: usize = 10;
pub const VOICE_DOOR: usize = 11;
pub const FRONT_DOOR_CLOSED: usize = 16;
pub const REAR_DOOR_CLOSED: usize = 17;
pub const PHOTO_SENSOR_1: usize = 18;
pub const PHOTO_SENSOR_2: usize = 19;
pub const HEPA_FILTER_EXPIRED: usize = 20;
pub const PREFILTER_EXPIRED: usize = 21;
pub const FRONT_DOOR_BUTTON: usize = 22;
pub const REAR_DOOR_BUTTON: usize = 23;

/// Readable coils.
pub const COIL_COUNT: usize = 24;
/// Coils an FC0F may cover (0–15; 12–15 reserved).
const WRITABLE_SPAN: usize = 16;
/// Coils that take effect when written.
const EFFECTIVE_WRITES: usize = 12;
/// How long a voice coil reads 1 after a press.
pub const VOICE_HOLD: Duration = Duration::from_millis(300);

/// The simulated air shower.
#[derive(Debug, Clone)]
pub struct AirShower {
    /// Plain states of coils 1–9 and the input coils 18–23 (set by tests); 0, 10, 11, 16, 17
    /// are derived.
    coils: [bool; COIL_COUNT],
    emergency_stop: bool,
    voice_pressed_at: [Option<Instant>; 2],
    /// Every e-stop toggle with its new state, in order.
    toggles: Vec<bool>,
    voice_presses: [u32; 2],
}

impl Default for AirShower {
    fn default() -> Self {
        Self::new()
    }
}

impl AirShower {
    /// All outputs off, doors closed, no e-stop.
    pub fn new() -> Self {
        Self {
            coils: [false; COIL_COUNT],
            emergency_stop: false,
            voice_pressed_at: [None; 2],
            toggles: Vec::new(),
            voice_presses: [0; 2],
        }
    }

    pub fn emergency_stop(&self) -> bool {
        self.emergency_stop
    }

    /// Sets the e-stop state directly (as the panel's button would); not counted as a toggle.
    pub fn set_emergency_stop(&mut self, active: bool) {
        self.emergency_stop = active;
    }

    /// Every e-stop toggle caused by a write, as the state it switched to.
    pub fn toggles(&self) -> &[bool] {
        &self.toggles
    }

    /// How many times the "start" and "door" voice prompts were pressed.
    pub fn voice_presses(&self) -> [u32; 2] {
        self.voice_presses
    }

    /// Sets a plain coil (outputs 1–9 or inputs 18–23); derived coils are ignored (false).
    pub fn set_coil(&mut self, coil: usize, on: bool) -> bool {
        let plain = (1..=9).contains(&coil) || (18..COIL_COUNT).contains(&coil);
        if plain {
            self.coils[coil] = on;
        }
        plain
    }

    /// Every readable coil as the device reports it at `now`.
    pub fn coils_at(&self, now: Instant) -> [bool; COIL_COUNT] {
        let mut coils = self.coils;
        coils[EMERGENCY_STOP] = self.emergency_stop;
        for (i, coil) in [VOICE_START, VOICE_DOOR].into_iter().enumerate() {
            coils[coil] = self.voice_pressed_at[i]
                .is_some_and(|at| now.saturating_duration_since(at) < VOICE_HOLD);
        }
        // An active e-stop opens both automatic doors.
        let front_open = self.emergency_stop || self.coils[FRONT_DOOR_OPEN];
        let rear_open = self.emergency_stop || self.coils[REAR_DOOR_OPEN];
        coils[FRONT_DOOR_CLOSED] = !front_open;
        coils[REAR_DOOR_CLOSED] = !rear_open;
        coils
    }

    /// The current coils (read at the present instant).
    pub fn coils(&self) -> [bool; COIL_COUNT] {
        self.coils_at(Instant::now())
    }

    fn read(&self, start: u16, quantity: u16, now: Instant) -> Reply {
        let (start, quantity) = (usize::from(start), usize::from(quantity));
        if quantity == 0 || start + quantity > COIL_COUNT {
            return Reply::Exception(ExceptionCode::IllegalDataAddress);
        }
        Reply::Normal(Response::Coils(
            self.coils_at(now)[start..start + quantity].to_vec(),
        ))
    }

    fn write(&mut self, start: u16, values: &[bool], now: Instant) -> Reply {
        let first = usize::from(start);
        if values.is_empty() || first + values.len() > WRITABLE_SPAN {
            return Reply::Exception(ExceptionCode::IllegalDataAddress);
        }
        let written = |coil: usize| -> Option<bool> {
            coil.checked_sub(first).and_then(|i| values.get(i)).copied()
        };
        let strong = written(STRONG_WIND).unwrap_or(self.coils[STRONG_WIND]);
        let breeze = written(BREEZE).unwrap_or(self.coils[BREEZE]);
        if strong && breeze {
            return Reply::Exception(ExceptionCode::IllegalDataValue);
        }
        for coil in first..(first + values.len()).min(EFFECTIVE_WRITES) {
            let on = values[coil - first];
            match coil {
                EMERGENCY_STOP => {
                    if on {
                        self.emergency_stop = !self.emergency_stop;
                        self.toggles.push(self.emergency_stop);
                    }
                }
                VOICE_START | VOICE_DOOR => {
                    if on {
                        let i = coil - VOICE_START;
                        self.voice_pressed_at[i] = Some(now);
                        self.voice_presses[i] += 1;
                    }
                }
                _ => self.coils[coil] = on,
            }
        }
        Reply::Normal(Response::WriteMultipleCoils {
            start,
            quantity: values.len() as u16,
        })
    }
}

impl SimDevice for AirShower {
    fn address(&self) -> SlaveId {
        ADDRESS
    }

    fn addressing(&self, address: SlaveId) -> Addressing {
        if address == ADDRESS {
            Addressing::Answer
        } else {
            Addressing::NotMine
        }
    }

    fn handle(&mut self, request: &Request, now: Instant) -> Reply {
        match request {
            Request::ReadCoils { start, quantity } => self.read(*start, *quantity, now),
            Request::WriteMultipleCoils { start, values } => self.write(*start, values, now),
            _ => Reply::Exception(ExceptionCode::IllegalFunction),
        }
    }

    fn kind(&self) -> &'static str {
        "air-shower"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_bytes(shower: &mut AirShower, b0: u8, b1: u8, now: Instant) -> Reply {
        let values = (0..12)
            .map(|i| [b0, b1][i / 8] & (1 << (i % 8)) != 0)
            .collect();
        shower.handle(&Request::WriteMultipleCoils { start: 0, values }, now)
    }

    #[test]
    fn reads_22_coils_with_doors_closed() {
        let mut shower = AirShower::new();
        shower.set_coil(LIGHT, true);
        let reply = shower.handle(
            &Request::ReadCoils {
                start: 0,
                quantity: 22,
            },
            Instant::now(),
        );
        let Reply::Normal(Response::Coils(bits)) = reply else {
            panic!("{reply:?}")
        };
        assert_eq!(bits.len(), 22);
        let on: Vec<usize> = (0..22).filter(|i| bits[*i]).collect();
        assert_eq!(on, vec![LIGHT, FRONT_DOOR_CLOSED, REAR_DOOR_CLOSED]);
    }

    #[test]
    fn estop_is_a_toggle_and_opens_doors() {
        let mut shower = AirShower::new();
        let now = Instant::now();
        let ok = Reply::Normal(Response::WriteMultipleCoils {
            start: 0,
            quantity: 12,
        });
        assert_eq!(write_bytes(&mut shower, 0x01, 0x00, now), ok);
        assert!(shower.emergency_stop());
        let coils = shower.coils_at(now);
        assert!(!coils[FRONT_DOOR_CLOSED] && !coils[REAR_DOOR_CLOSED]);
        // Writing 0 leaves it.
        write_bytes(&mut shower, 0x00, 0x01, now);
        assert!(shower.emergency_stop());
        assert!(shower.coils_at(now)[LIGHT]);
        // Writing 1 again clears it.
        write_bytes(&mut shower, 0x01, 0x01, now);
        assert!(!shower.emergency_stop());
        assert_eq!(shower.toggles(), &[true, false]);
        assert!(shower.coils_at(now)[FRONT_DOOR_CLOSED]);
    }

    #[test]
    fn strong_wind_with_breeze_is_refused_and_nothing_applies() {
        let mut shower = AirShower::new();
        let now = Instant::now();
        assert_eq!(
            write_bytes(&mut shower, 0x18 | 0x02, 0x01, now),
            Reply::Exception(ExceptionCode::IllegalDataValue)
        );
        let coils = shower.coils_at(now);
        assert!(!coils[FRONT_DOOR_LOCK] && !coils[LIGHT] && !coils[STRONG_WIND]);
        // Breeze while strong is on, written alone, is refused too.
        write_bytes(&mut shower, 0x08, 0x00, now);
        let values = vec![true];
        assert_eq!(
            shower.handle(
                &Request::WriteMultipleCoils {
                    start: BREEZE as u16,
                    values
                },
                now
            ),
            Reply::Exception(ExceptionCode::IllegalDataValue)
        );
    }

    #[test]
    fn voice_coils_fall_back() {
        let mut shower = AirShower::new();
        let now = Instant::now();
        write_bytes(&mut shower, 0x00, 0x04, now);
        assert!(shower.coils_at(now)[VOICE_START]);
        assert!(!shower.coils_at(now + VOICE_HOLD)[VOICE_START]);
        assert_eq!(shower.voice_presses(), [1, 0]);
    }

    #[test]
    fn out_of_range_and_bad_function() {
        let mut shower = AirShower::new();
        let now = Instant::now();
        assert_eq!(
            shower.handle(
                &Request::ReadCoils {
                    start: 0,
                    quantity: 25
                },
                now
            ),
            Reply::Exception(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            shower.handle(
                &Request::WriteMultipleCoils {
                    start: 10,
                    values: vec![false; 7]
                },
                now
            ),
            Reply::Exception(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            shower.handle(
                &Request::ReadHoldingRegisters {
                    start: 0,
                    quantity: 1
                },
                now
            ),
            Reply::Exception(ExceptionCode::IllegalFunction)
        );
        assert_eq!(shower.addressing(0), Addressing::NotMine);
        assert_eq!(shower.addressing(1), Addressing::NotMine);
    }

    #[test]
    fn reserved_coils_are_ignored() {
        let mut shower = AirShower::new();
        let now = Instant::now();
        let mut values = vec![false; 16];
        values[13] = true;
        values[1] = true;
        assert!(matches!(
            shower.handle(&Request::WriteMultipleCoils { start: 0, values }, now),
            Reply::Normal(_)
        ));
        let coils = shower.coils_at(now);
        assert!(coils[FRONT_DOOR_LOCK]);
        assert!(!coils[13]);
    }
}
