//! The simulated Wuzhou valve controller with PID, written from `docs/devices.md` §2 and the
//! vendor's register table.
//!
//! Kept on purpose: addresses 1–253 with broadcast 0x00 answered and 0xFF acted on silently;
//! Char registers (low byte); Float values as two packed-BCD registers (integer, hundredths);
//! a sparse map where a read covering an unmapped register is refused with exception 02 (or, in
//! lenient mode, reads zeros there); FC06 one standard register at a time; a write to the baud
//! register switches at once and is not answered; a write to register 0 changes the address and
//! is answered from the new one; the opening moves toward the commanded value at a motor's speed
//! with the status register's motor, limit and direction bits following it.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use super::device::{Addressing, Reply, SimDevice};
use rtu2mqtt_modbus::frame::{ExceptionCode, Request, Response, SlaveId};
use rtu2mqtt_profile::bcd;

pub const REG_ADDRESS: u16 = 0x00;
pub const REG_BAUD: u16 = 0x0A;
pub const REG_MODE: u16 = 0x19;
pub const REG_OPENING: u16 = 0x74;
pub const REG_STATUS: u16 = 0x90;
pub const REG_MEASURED_1: u16 = 0xA2;
pub const REG_MEASURED_2: u16 = 0xA4;
pub const REG_SETPOINT: u16 = 0xB2;

/// Status register (0x90) bits.
pub const CLOSED_SWITCH_FAILED: u16 = 1 << 0;
pub const OPEN_SWITCH_FAILED: u16 = 1 << 1;
pub const MOTOR_OPENING: u16 = 1 << 2;
pub const MOTOR_CLOSING: u16 = 2 << 2;
/// 0 when fully open (inverted).
pub const NOT_FULLY_OPEN: u16 = 1 << 4;
/// 0 when fully closed (inverted).
pub const NOT_FULLY_CLOSED: u16 = 1 << 5;
pub const DIRECTION_CLOSE: u16 = 1 << 6;
pub const JAMMED: u16 = 1 << 7;

const MAX_READ: u16 = 120;

/// How a register may be written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    ReadOnly,
    /// One byte in the low byte of the register, up to this value.
    Char(u16),
    /// Integer half of a BCD Float (4 digits).
    BcdInteger,
    /// Fraction half of a BCD Float (2 digits, hundredths).
    BcdFraction,
}

/// The register map: which registers exist, and how each may be written.
fn kind_of(register: u16) -> Option<Kind> {
    Some(match register {
        0x00 => Kind::Char(253),
        0x01..=0x09 | 0x90..=0x93 | 0xA2..=0xA5 => Kind::ReadOnly,
        0x0A => Kind::Char(8),
        0x19 => Kind::Char(1),
        0x74 => Kind::Char(100),
        0xB2 | 0xBC | 0xBE | 0xC0 | 0xC2 | 0xC4 | 0xC6 | 0xD4 | 0xD6 | 0xD8 | 0xDA | 0xDC => {
            Kind::BcdInteger
        }
        0xB3 | 0xBD | 0xBF | 0xC1 | 0xC3 | 0xC5 | 0xC7 | 0xD5 | 0xD7 | 0xD9 | 0xDB | 0xDD => {
            Kind::BcdFraction
        }
        0xD0..=0xD3 => Kind::Char(0xFF),
        0xE0..=0xE8 => Kind::Char(99),
        _ => return None,
    })
}

/// Encodes `hundredths` (e.g. 12.34 → 1234) as the (integer, fraction) BCD register pair.
pub fn bcd_pair(hundredths: u32) -> [u16; 2] {
    [
        u16::try_from(hundredths / 100)
            .ok()
            .and_then(|integer| bcd::encode(integer, 4))
            .unwrap_or(0x9999),
        // Below 100: always two digits.
        bcd::encode((hundredths % 100) as u16, 2).unwrap_or(0),
    ]
}

/// Decodes a (integer, fraction) BCD register pair into hundredths.
pub fn from_bcd_pair(pair: [u16; 2]) -> Option<u32> {
    let integer = bcd::decode(pair[0], bcd::WORD_DIGITS).ok()?;
    let fraction = bcd::decode(pair[1], bcd::WORD_DIGITS).ok()?;
    Some(u32::from(integer) * 100 + u32::from(fraction))
}

/// The simulated valve controller.
#[derive(Debug, Clone)]
pub struct Valve {
    address: SlaveId,
    /// Stored registers (everything but opening, status and measured values, which are live).
    registers: BTreeMap<u16, u16>,
    /// Real position in percent, moving toward `target`.
    position: f64,
    target: u16,
    /// Percent per second.
    speed: f64,
    direction_close: bool,
    jammed: bool,
    switch_failures: u16,
    /// Measured values drift when true; tests freeze them to poke raw words.
    drift: bool,
    lenient: bool,
    started: Instant,
    last_advance: Option<Instant>,
    baud_switches: Vec<u16>,
}

impl Valve {
    /// A valve at `address` (1–253), 30 % open and still, strict about unmapped reads.
    pub fn new(address: SlaveId) -> Self {
        let mut registers = BTreeMap::new();
        registers.insert(REG_ADDRESS, u16::from(address));
        // Serial number: seven Char bytes.
        for (i, byte) in [0x20u16, 0x23, 0x11, 0x22, 0x00, 0x4A, 0x5B]
            .iter()
            .enumerate()
        {
            registers.insert(0x01 + i as u16, *byte);
        }
        registers.insert(0x08, 0x13); // software version
        registers.insert(0x09, 0x02); // hardware version
        registers.insert(REG_BAUD, 6); // 9600
        registers.insert(REG_MODE, 0); // manual
        for register in 0x91..=0x93 {
            registers.insert(register, 0);
        }
        let floats: [(u16, u32); 12] = [
            (REG_SETPOINT, 12_000),
            (0xBC, 50_000),
            (0xBE, 50_000),
            (0xC0, 40_000),
            (0xC2, 40_000),
            (0xC4, 2_000),
            (0xC6, 2_000),
            (0xD4, 150),
            (0xD6, 150),
            (0xD8, 50),
            (0xDA, 50),
            (0xDC, 100),
        ];
        for (register, hundredths) in floats {
            let [integer, fraction] = bcd_pair(hundredths);
            registers.insert(register, integer);
            registers.insert(register + 1, fraction);
        }
        for register in 0xD0..=0xD3 {
            registers.insert(register, 0xFF); // alarm openings disabled
        }
        // Sample period 0 h 0 min 5 s, integral 0 h 1 min 0 s, derivative 0 h 0 min 2 s.
        for (register, value) in [0xE0u16, 0xE1, 0xE2, 0xE3, 0xE4, 0xE5, 0xE6, 0xE7, 0xE8]
            .into_iter()
            .zip([0u16, 0, 5, 0, 1, 0, 0, 0, 2])
        {
            registers.insert(register, value);
        }
        let mut valve = Self {
            address,
            registers,
            position: 30.0,
            target: 30,
            speed: 5.0,
            direction_close: false,
            jammed: false,
            switch_failures: 0,
            drift: true,
            lenient: false,
            started: Instant::now(),
            last_advance: None,
            baud_switches: Vec::new(),
        };
        valve.update_measurements(valve.started);
        valve
    }

    /// Lenient: reads over unmapped registers give zeros there instead of exception 02.
    pub fn set_lenient(&mut self, lenient: bool) {
        self.lenient = lenient;
    }

    /// Motor speed in percent per second.
    pub fn set_speed(&mut self, percent_per_second: f64) {
        self.settle_motion();
        self.speed = percent_per_second.max(0.0);
    }

    /// Jammed: the motor does not move and status bit 7 is set.
    pub fn set_jammed(&mut self, jammed: bool) {
        self.settle_motion();
        self.jammed = jammed;
    }

    /// Limit switch failure bits (status bits 0–1).
    pub fn set_switch_failures(&mut self, closed_failed: bool, open_failed: bool) {
        self.switch_failures = u16::from(closed_failed) * CLOSED_SWITCH_FAILED
            + u16::from(open_failed) * OPEN_SWITCH_FAILED;
    }

    /// Stops the measured values from drifting (so [`Valve::set_register`] pokes stay).
    pub fn set_drift(&mut self, drift: bool) {
        self.drift = drift;
    }

    /// The opening in whole percent, as register 0x74 reads now.
    pub fn opening(&self) -> u16 {
        self.opening_at(Instant::now())
    }

    /// Whole percent, cut toward where the valve comes from: the register shows the commanded
    /// value only once the motor has got there.
    fn opening_at(&self, now: Instant) -> u16 {
        let position = self.position_at(now);
        let shown = if f64::from(self.target) >= position {
            (position + 1e-9).floor()
        } else {
            (position - 1e-9).ceil()
        };
        shown.clamp(0.0, 100.0) as u16
    }

    /// Commits the motion so far before a change of how the motor moves.
    fn settle_motion(&mut self) {
        let now = Instant::now();
        self.advance(self.last_advance.map_or(now, |last| last.max(now)));
    }

    /// Where the motor has taken the valve by `now` (the state moves on only when advanced).
    fn position_at(&self, now: Instant) -> f64 {
        let Some(last) = self.last_advance else {
            return self.position;
        };
        if self.jammed {
            return self.position;
        }
        let step = self.speed * now.saturating_duration_since(last).as_secs_f64();
        let target = f64::from(self.target);
        if (target - self.position).abs() <= step {
            target
        } else if target > self.position {
            self.position + step
        } else {
            self.position - step
        }
    }

    /// The commanded opening.
    pub fn target(&self) -> u16 {
        self.target
    }

    /// Puts the valve at `percent` at once (motor stopped there).
    pub fn set_opening(&mut self, percent: u16) {
        let percent = percent.min(100);
        self.target = percent;
        self.position = f64::from(percent);
    }

    pub fn mode_auto(&self) -> bool {
        self.registers.get(&REG_MODE).copied().unwrap_or(0) & 1 == 1
    }

    /// Baud codes written so far (each switched the device at once, without an answer).
    pub fn baud_switches(&self) -> &[u16] {
        &self.baud_switches
    }

    /// A register's raw value now (live registers included).
    pub fn register(&self, register: u16) -> Option<u16> {
        self.register_at(register, Instant::now())
    }

    fn register_at(&self, register: u16, now: Instant) -> Option<u16> {
        match register {
            REG_OPENING => Some(self.opening_at(now)),
            REG_STATUS => Some(self.status_at(now)),
            _ => self.registers.get(&register).copied(),
        }
    }

    /// Pokes a raw value into a mapped register (e.g. an invalid BCD nibble); refused (false)
    /// for unmapped and live registers.
    pub fn set_register(&mut self, register: u16, value: u16) -> bool {
        if kind_of(register).is_none() || matches!(register, REG_OPENING | REG_STATUS) {
            return false;
        }
        self.registers.insert(register, value);
        true
    }

    /// The status register (0x90) now.
    pub fn status(&self) -> u16 {
        self.status_at(Instant::now())
    }

    fn status_at(&self, now: Instant) -> u16 {
        let position = self.position_at(now);
        let mut status = self.switch_failures;
        let moving = !self.jammed && (position - f64::from(self.target)).abs() > 1e-9;
        if moving {
            status |= if f64::from(self.target) > position {
                MOTOR_OPENING
            } else {
                MOTOR_CLOSING
            };
        }
        if position < 100.0 - 1e-9 {
            status |= NOT_FULLY_OPEN;
        }
        if position > 1e-9 {
            status |= NOT_FULLY_CLOSED;
        }
        if self.direction_close {
            status |= DIRECTION_CLOSE;
        }
        if self.jammed {
            status |= JAMMED;
        }
        status
    }

    /// Moves the motor and lets the measured values drift.
    pub fn advance(&mut self, now: Instant) {
        self.position = self.position_at(now);
        self.last_advance = Some(now);
        if self.mode_auto() {
            self.regulate();
        }
        self.update_measurements(now);
    }

    /// Auto mode (PID): a plain proportional law stands in for the PID. Opening the valve
    /// lowers the measured differential pressure, so a pressure above the setpoint opens it.
    fn regulate(&mut self) {
        let pair = |register: u16| {
            from_bcd_pair([
                self.registers.get(&register).copied().unwrap_or(0),
                self.registers.get(&(register + 1)).copied().unwrap_or(0),
            ])
        };
        let (Some(measured), Some(setpoint)) = (pair(REG_MEASURED_1), pair(REG_SETPOINT)) else {
            return;
        };
        // Hundredths of a unit → percent of opening, 1 % per 1.00 of error.
        let error = (f64::from(measured) - f64::from(setpoint)) / 100.0;
        let wanted = self.position + error;
        let target = wanted.round().clamp(0.0, 100.0) as u16;
        if target != self.target {
            self.direction_close = f64::from(target) < self.position;
            self.target = target;
        }
    }

    fn update_measurements(&mut self, now: Instant) {
        if !self.drift {
            return;
        }
        let t = now.saturating_duration_since(self.started).as_secs_f64();
        // Differential pressure falls as the valve opens, with a slow wobble on top.
        let measured_1 = 180.0 - 0.9 * self.position + 3.0 * (t / 11.0).sin();
        let measured_2 = 95.0 + 2.0 * (t / 17.0).cos();
        for (register, value) in [(REG_MEASURED_1, measured_1), (REG_MEASURED_2, measured_2)] {
            let hundredths = (value.max(0.0) * 100.0).round() as u32;
            let [integer, fraction] = bcd_pair(hundredths);
            self.registers.insert(register, integer);
            self.registers.insert(register + 1, fraction);
        }
    }

    fn read(&self, start: u16, quantity: u16, now: Instant) -> Reply {
        if quantity == 0 || quantity > MAX_READ {
            return Reply::Exception(ExceptionCode::IllegalDataValue);
        }
        let Some(end) = start.checked_add(quantity - 1) else {
            return Reply::Exception(ExceptionCode::IllegalDataAddress);
        };
        let mut words = Vec::with_capacity(usize::from(quantity));
        for register in start..=end {
            match self.register_at(register, now) {
                Some(value) if kind_of(register).is_some() => words.push(value),
                _ if self.lenient => words.push(0),
                _ => return Reply::Exception(ExceptionCode::IllegalDataAddress),
            }
        }
        Reply::Normal(Response::HoldingRegisters(words))
    }

    fn write(&mut self, register: u16, value: u16) -> Reply {
        let answer = Reply::Normal(Response::WriteSingleRegister {
            address: register,
            value,
        });
        let valid = match kind_of(register) {
            None | Some(Kind::ReadOnly) => {
                return Reply::Exception(ExceptionCode::IllegalDataAddress)
            }
            Some(Kind::Char(max)) => value <= max,
            Some(Kind::BcdInteger) => bcd::decode(value, bcd::WORD_DIGITS).is_ok(),
            Some(Kind::BcdFraction) => bcd::decode(value, 2).is_ok(),
        };
        let valid = valid
            && match register {
                REG_ADDRESS => value >= 1,
                REG_BAUD => value >= 1,
                _ => true,
            };
        if !valid {
            return Reply::Exception(ExceptionCode::IllegalDataValue);
        }
        match register {
            REG_ADDRESS => {
                self.address = value as u8;
                self.registers.insert(REG_ADDRESS, value);
                answer
            }
            REG_BAUD => {
                // The device switches at once: the answer would go out at the new rate, which
                // the master does not listen at, so it is not sent at all.
                self.registers.insert(REG_BAUD, value);
                self.baud_switches.push(value);
                Reply::Silent
            }
            REG_OPENING => {
                if value != self.target {
                    self.direction_close = f64::from(value) < self.position;
                }
                self.target = value;
                answer
            }
            _ => {
                self.registers.insert(register, value);
                answer
            }
        }
    }
}

impl SimDevice for Valve {
    fn address(&self) -> SlaveId {
        self.address
    }

    fn addressing(&self, address: SlaveId) -> Addressing {
        match address {
            0x00 => Addressing::Answer,
            0xFF => Addressing::ActSilently,
            own if own == self.address => Addressing::Answer,
            _ => Addressing::NotMine,
        }
    }

    fn handle(&mut self, request: &Request, now: Instant) -> Reply {
        self.advance(now);
        match request {
            Request::ReadHoldingRegisters { start, quantity } => self.read(*start, *quantity, now),
            Request::WriteSingleRegister { address, value } => self.write(*address, *value),
            _ => Reply::Exception(ExceptionCode::IllegalFunction),
        }
    }

    fn kind(&self) -> &'static str {
        "valve"
    }
}

/// How long the motor needs from `from` to `to` percent at `speed` percent per second.
pub fn travel_time(from: u16, to: u16, speed: f64) -> Duration {
    Duration::from_secs_f64(f64::from(from.abs_diff(to)) / speed.max(1e-6))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::{assert_refuses_coils, read, words, write};

    #[test]
    fn identity_registers_read_as_chars() {
        let mut valve = Valve::new(1);
        let now = Instant::now();
        let identity = words(read(&mut valve, 0x00, 0x0B, now));
        assert_eq!(identity[0], 1);
        assert_eq!(&identity[1..8], &[0x20, 0x23, 0x11, 0x22, 0x00, 0x4A, 0x5B]);
        assert_eq!(identity[10], 6);
        assert!(identity.iter().all(|w| *w <= 0xFF));
    }

    #[test]
    fn floats_are_bcd_pairs() {
        let mut valve = Valve::new(1);
        let now = Instant::now();
        assert_eq!(
            words(read(&mut valve, REG_SETPOINT, 2, now)),
            vec![0x0120, 0x0000]
        );
        let measured = words(read(&mut valve, REG_MEASURED_1, 4, now));
        for pair in measured.chunks(2) {
            assert!(from_bcd_pair([pair[0], pair[1]]).is_some(), "{measured:x?}");
        }
        valve.set_drift(false);
        assert!(valve.set_register(REG_MEASURED_1, 0x012A));
        assert_eq!(
            words(read(&mut valve, REG_MEASURED_1, 1, now)),
            vec![0x012A]
        );
    }

    #[test]
    fn unmapped_reads_strict_or_lenient() {
        let mut valve = Valve::new(1);
        let now = Instant::now();
        assert_eq!(
            read(&mut valve, 0x74, 0x20, now),
            Reply::Exception(ExceptionCode::IllegalDataAddress)
        );
        valve.set_lenient(true);
        let block = words(read(&mut valve, 0x74, 0x20, now));
        assert_eq!(block.len(), 0x20);
        assert_eq!(block[0], 30);
        assert_eq!(block[1], 0);
        assert_eq!(
            read(&mut valve, 0x00, 121, now),
            Reply::Exception(ExceptionCode::IllegalDataValue)
        );
    }

    #[test]
    fn opening_moves_at_motor_speed_with_status_bits() {
        let start = Instant::now();
        let mut valve = Valve::new(1);
        valve.advance(start);
        let reply = write(&mut valve, REG_OPENING, 80, start);
        assert_eq!(
            reply,
            Reply::Normal(Response::WriteSingleRegister {
                address: REG_OPENING,
                value: 80
            })
        );
        valve.advance(start + Duration::from_secs(2));
        assert_eq!(valve.opening(), 40);
        let status = valve.status();
        assert_eq!(status & 0x0C, MOTOR_OPENING);
        assert_eq!(
            status & (NOT_FULLY_OPEN | NOT_FULLY_CLOSED),
            NOT_FULLY_OPEN | NOT_FULLY_CLOSED
        );
        assert_eq!(status & DIRECTION_CLOSE, 0);
        valve.advance(start + Duration::from_secs(20));
        assert_eq!(valve.opening(), 80);
        assert_eq!(valve.status() & 0x0C, 0, "motor stopped");
        write(
            &mut valve,
            REG_OPENING,
            100,
            start + Duration::from_secs(20),
        );
        valve.advance(start + Duration::from_secs(40));
        assert_eq!(valve.status() & NOT_FULLY_OPEN, 0, "fully open reads 0");
        write(&mut valve, REG_OPENING, 0, start + Duration::from_secs(40));
        valve.advance(start + Duration::from_secs(41));
        assert_eq!(valve.status() & 0x0C, MOTOR_CLOSING);
        assert_ne!(valve.status() & DIRECTION_CLOSE, 0);
        valve.advance(start + Duration::from_secs(80));
        assert_eq!(valve.status() & NOT_FULLY_CLOSED, 0, "fully closed reads 0");
    }

    #[test]
    fn auto_mode_drives_the_pressure_to_the_setpoint() {
        let start = Instant::now();
        let mut valve = Valve::new(1);
        valve.set_speed(20.0);
        valve.advance(start);
        write(&mut valve, REG_MODE, 1, start);
        for second in 1..=120 {
            valve.advance(start + Duration::from_secs(second));
        }
        let measured = from_bcd_pair([
            valve.register(REG_MEASURED_1).unwrap(),
            valve.register(REG_MEASURED_1 + 1).unwrap(),
        ])
        .unwrap();
        // Setpoint 120.00; the wobble is ±3.00.
        assert!((11_400..=12_600).contains(&measured), "measured {measured}");
        assert!(
            valve.opening() > 30,
            "opened from 30 %: {}",
            valve.opening()
        );
    }

    #[test]
    fn jammed_valve_does_not_move() {
        let start = Instant::now();
        let mut valve = Valve::new(1);
        valve.advance(start);
        valve.set_jammed(true);
        write(&mut valve, REG_OPENING, 90, start);
        valve.advance(start + Duration::from_secs(30));
        assert_eq!(valve.opening(), 30);
        assert_ne!(valve.status() & JAMMED, 0);
    }

    #[test]
    fn write_rules() {
        let mut valve = Valve::new(1);
        let now = Instant::now();
        // (register, value, exception)
        let refused = [
            (REG_OPENING, 101, ExceptionCode::IllegalDataValue),
            (0x08, 1, ExceptionCode::IllegalDataAddress),
            (0x50, 1, ExceptionCode::IllegalDataAddress),
            (REG_SETPOINT, 0x00A0, ExceptionCode::IllegalDataValue),
            (REG_SETPOINT + 1, 0x0100, ExceptionCode::IllegalDataValue),
        ];
        for (address, value, code) in refused {
            assert_eq!(
                write(&mut valve, address, value, now),
                Reply::Exception(code),
                "write of {value:#06X} to register {address:#04X}"
            );
        }
        assert!(matches!(
            write(&mut valve, REG_SETPOINT, 0x0150, now),
            Reply::Normal(_)
        ));
        assert_eq!(valve.register(REG_SETPOINT), Some(0x0150));
        assert!(matches!(
            write(&mut valve, REG_MODE, 1, now),
            Reply::Normal(_)
        ));
        assert!(valve.mode_auto());
        assert_eq!(write(&mut valve, REG_BAUD, 7, now), Reply::Silent);
        assert_eq!(valve.baud_switches(), &[7]);
        assert_refuses_coils(&mut valve, now);
    }

    #[test]
    fn addressing_and_address_change() {
        let mut valve = Valve::new(1);
        assert_eq!(valve.addressing(0x00), Addressing::Answer);
        assert_eq!(valve.addressing(0xFF), Addressing::ActSilently);
        assert_eq!(valve.addressing(0x02), Addressing::NotMine);
        write(&mut valve, REG_ADDRESS, 7, Instant::now());
        assert_eq!(valve.address(), 7);
        assert_eq!(valve.addressing(0x07), Addressing::Answer);
        assert_eq!(valve.addressing(0x01), Addressing::NotMine);
    }
}
