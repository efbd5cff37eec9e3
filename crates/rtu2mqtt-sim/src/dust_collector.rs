//! The simulated Ruiwan dust collector (protocol V1.3), written from `docs/devices.md` §1.
//!
//! Quirks kept on purpose:
//! - reads: FC03 from 0x1000, word i = table row i, at most 6 words (an FC03 at 0x1002 returns
//!   PV, not the gear);
//! - single writes: FC06 at the table address 0x1000 + 2·i (gear at 0x1002, PV 0x1004, SV 0x1006);
//! - multiple writes: FC10 from 0x1000 over consecutive words, at most 4 (status, gear, PV, SV);
//! - the status word carries internal bits (0x0040 | 0x2000 here) that must never change: a
//!   write that would change one is recorded as a violation and the bits are kept;
//! - standby: while off every valid write is acknowledged, but only power-on takes effect; a
//!   write that powers on applies the rest of its values too;
//! - optional power-up handshake: no answers at all for a while after power-up.

use std::time::{Duration, Instant};

use super::device::{Reply, SimDevice};
use rtu2mqtt_modbus::frame::{ExceptionCode, Request, Response, SlaveId};

/// First register of the device's table.
pub const BASE: u16 = 0x1000;
/// Status word bits.
pub const POWER: u16 = 0x0200;
pub const PULSE_CLEANING: u16 = 0x0100;
pub const TEMPERATURE_ALARM: u16 = 0x0001;
pub const FILTER_ALARM: u16 = 0x0002;
pub const FAN_ALARM: u16 = 0x0004;
/// The bits a master may change.
const WRITABLE_BITS: u16 = POWER | PULSE_CLEANING;
/// The alarm bits: read-only, owned by the device.
const ALARM_BITS: u16 = TEMPERATURE_ALARM | FILTER_ALARM | FAN_ALARM;
/// Internal bits this simulated unit keeps set, so a gateway that writes zeros over them shows.
pub const DEFAULT_INTERNAL_BITS: u16 = 0x0040 | 0x2000;

const MAX_READ: u16 = 6;
const MAX_WRITE: u16 = 4;
const AMBIENT_C: f64 = 24.0;

/// The simulated dust collector.
#[derive(Debug, Clone)]
pub struct DustCollector {
    address: SlaveId,
    /// Bits of the status word other than power, pulse cleaning and alarms.
    internal_bits: u16,
    power: bool,
    pulse_cleaning: bool,
    alarms: u16,
    gear: u16,
    pulse_interval: u16,
    pulse_duration: u16,
    /// Fan speed (rpm) and temperature (°C), simulated as smooth curves.
    fan_rpm: f64,
    temperature_c: f64,
    last_advance: Option<Instant>,
    powered_up_at: Instant,
    /// No answers during this long after power-up (the 2 s handshake), if set.
    handshake: Option<Duration>,
    violations: Vec<String>,
    /// Writes acknowledged while in standby and not applied.
    ignored_in_standby: u32,
}

impl DustCollector {
    /// A unit at `address`, switched off, gear 3, PV 10 min, SV 5 s, answering at once.
    pub fn new(address: SlaveId) -> Self {
        Self {
            address,
            internal_bits: DEFAULT_INTERNAL_BITS,
            power: false,
            pulse_cleaning: false,
            alarms: 0,
            gear: 3,
            pulse_interval: 10,
            pulse_duration: 5,
            fan_rpm: 0.0,
            temperature_c: AMBIENT_C,
            last_advance: None,
            powered_up_at: Instant::now(),
            handshake: None,
            violations: Vec::new(),
            ignored_in_standby: 0,
        }
    }

    /// Models the power-up handshake: no answers during `silence` after `powered_up_at`.
    pub fn with_power_up_handshake(mut self, powered_up_at: Instant, silence: Duration) -> Self {
        self.powered_up_at = powered_up_at;
        self.handshake = Some(silence);
        self
    }

    pub fn power(&self) -> bool {
        self.power
    }

    pub fn set_power(&mut self, on: bool) {
        self.power = on;
    }

    pub fn pulse_cleaning(&self) -> bool {
        self.pulse_cleaning
    }

    pub fn gear(&self) -> u16 {
        self.gear
    }

    pub fn pulse_interval(&self) -> u16 {
        self.pulse_interval
    }

    pub fn pulse_duration(&self) -> u16 {
        self.pulse_duration
    }

    /// Sets the alarm bits (low byte bits 0–2, see the constants); other bits are ignored.
    pub fn set_alarms(&mut self, alarms: u16) {
        self.alarms = alarms & ALARM_BITS;
    }

    /// Replaces the internal status bits (outside power, pulse cleaning and alarms).
    pub fn set_internal_bits(&mut self, bits: u16) {
        self.internal_bits = bits & !(WRITABLE_BITS | ALARM_BITS);
    }

    /// Writes acknowledged in standby without effect.
    pub fn ignored_in_standby(&self) -> u32 {
        self.ignored_in_standby
    }

    /// The status word as the device reports it.
    pub fn status_word(&self) -> u16 {
        let mut word = self.internal_bits | self.alarms;
        if self.power {
            word |= POWER;
        }
        if self.pulse_cleaning {
            word |= PULSE_CLEANING;
        }
        word
    }

    /// The six words of the read table (word i = row i).
    pub fn table(&self) -> [u16; 6] {
        [
            self.status_word(),
            self.gear,
            self.pulse_interval,
            self.pulse_duration,
            self.fan_rpm.round().clamp(0.0, 65_535.0) as u16,
            self.temperature_c.round().clamp(0.0, 65_535.0) as u16,
        ]
    }

    /// Moves fan speed and temperature toward where the running state takes them.
    pub fn advance(&mut self, now: Instant) {
        let elapsed = match self.last_advance {
            Some(last) => now.saturating_duration_since(last).as_secs_f64(),
            None => 0.0,
        };
        self.last_advance = Some(now);
        let since_power_up = now
            .saturating_duration_since(self.powered_up_at)
            .as_secs_f64();
        // A gentle wobble so the values keep moving while the unit runs.
        let wobble = (since_power_up / 7.0).sin();
        let (fan_target, temperature_target) = if self.power {
            (
                600.0 + 140.0 * f64::from(self.gear) + 15.0 * wobble,
                38.0 + 1.5 * f64::from(self.gear) + 2.0 * wobble,
            )
        } else {
            (0.0, AMBIENT_C)
        };
        // First-order approach: a fan spins up in a few seconds, temperature takes a minute.
        let fan_step = 1.0 - (-elapsed / 3.0).exp();
        let temperature_step = 1.0 - (-elapsed / 60.0).exp();
        self.fan_rpm += (fan_target - self.fan_rpm) * fan_step;
        self.temperature_c += (temperature_target - self.temperature_c) * temperature_step;
    }

    /// Checks one write of table row `row`; Err is the exception to answer.
    fn check_row(row: usize, value: u16) -> Result<(), ExceptionCode> {
        let ok = match row {
            0 => true,
            1 => (1..=10).contains(&value),
            2 | 3 => value <= 99,
            _ => return Err(ExceptionCode::IllegalDataAddress),
        };
        if ok {
            Ok(())
        } else {
            Err(ExceptionCode::IllegalDataValue)
        }
    }

    /// Applies validated writes of `(row, value)`, following the standby rule.
    fn apply(&mut self, writes: &[(usize, u16)]) {
        let powers_on = writes
            .iter()
            .any(|&(row, value)| row == 0 && value & POWER != 0);
        for &(_, value) in writes.iter().filter(|(row, _)| *row == 0) {
            self.check_internal_bits(value);
        }
        if !self.power && !powers_on {
            self.ignored_in_standby += 1;
            return;
        }
        for &(row, value) in writes {
            match row {
                0 => self.write_status(value),
                1 => self.gear = value,
                2 => self.pulse_interval = value,
                3 => self.pulse_duration = value,
                _ => {}
            }
        }
    }

    /// Records a status write that would change an internal bit (they are kept as they are).
    fn check_internal_bits(&mut self, value: u16) {
        let internal_mask = !(WRITABLE_BITS | ALARM_BITS);
        if value & internal_mask != self.internal_bits {
            self.violations.push(format!(
                "status write {value:#06x} changes internal bits: {:#06x} → {:#06x}",
                self.internal_bits,
                value & internal_mask
            ));
        }
    }

    fn write_status(&mut self, value: u16) {
        self.power = value & POWER != 0;
        self.pulse_cleaning = value & PULSE_CLEANING != 0;
    }

    fn read(&self, start: u16, quantity: u16) -> Reply {
        if quantity == 0 || quantity > MAX_READ {
            return Reply::Exception(ExceptionCode::IllegalDataValue);
        }
        let Some(first) = start.checked_sub(BASE).map(usize::from) else {
            return Reply::Exception(ExceptionCode::IllegalDataAddress);
        };
        let end = first + usize::from(quantity);
        if end > usize::from(MAX_READ) {
            return Reply::Exception(ExceptionCode::IllegalDataAddress);
        }
        Reply::Normal(Response::HoldingRegisters(
            self.table()[first..end].to_vec(),
        ))
    }

    fn write_single(&mut self, address: u16, value: u16) -> Reply {
        let offset = address.wrapping_sub(BASE);
        if address < BASE || offset % 2 != 0 || offset / 2 > 3 {
            // Odd addresses, fan speed / temperature (read-only) and anything off the table.
            return Reply::Exception(ExceptionCode::IllegalDataAddress);
        }
        let row = usize::from(offset / 2);
        if let Err(code) = Self::check_row(row, value) {
            return Reply::Exception(code);
        }
        self.apply(&[(row, value)]);
        Reply::Normal(Response::WriteSingleRegister { address, value })
    }

    fn write_multiple(&mut self, start: u16, values: &[u16]) -> Reply {
        let quantity = values.len();
        if quantity == 0 || quantity > usize::from(MAX_WRITE) {
            return Reply::Exception(ExceptionCode::IllegalDataValue);
        }
        let Some(first) = start.checked_sub(BASE).map(usize::from) else {
            return Reply::Exception(ExceptionCode::IllegalDataAddress);
        };
        if first + quantity > usize::from(MAX_WRITE) {
            return Reply::Exception(ExceptionCode::IllegalDataAddress);
        }
        let writes: Vec<(usize, u16)> = values
            .iter()
            .enumerate()
            .map(|(i, &value)| (first + i, value))
            .collect();
        if let Some(code) = writes
            .iter()
            .find_map(|&(row, value)| Self::check_row(row, value).err())
        {
            return Reply::Exception(code);
        }
        self.apply(&writes);
        Reply::Normal(Response::WriteMultipleRegisters {
            start,
            quantity: quantity as u16,
        })
    }
}

impl SimDevice for DustCollector {
    fn address(&self) -> SlaveId {
        self.address
    }

    fn handle(&mut self, request: &Request, now: Instant) -> Reply {
        if let Some(silence) = self.handshake {
            if now.saturating_duration_since(self.powered_up_at) < silence {
                return Reply::Silent;
            }
        }
        self.advance(now);
        match request {
            Request::ReadHoldingRegisters { start, quantity } => self.read(*start, *quantity),
            Request::WriteSingleRegister { address, value } => self.write_single(*address, *value),
            Request::WriteMultipleRegisters { start, values } => {
                self.write_multiple(*start, values)
            }
            _ => Reply::Exception(ExceptionCode::IllegalFunction),
        }
    }

    fn handle_unknown_function(&mut self, _function: u8, now: Instant) -> Reply {
        if let Some(silence) = self.handshake {
            if now.saturating_duration_since(self.powered_up_at) < silence {
                return Reply::Silent;
            }
        }
        Reply::Exception(ExceptionCode::IllegalFunction)
    }

    fn violations(&self) -> Vec<String> {
        self.violations.clone()
    }

    fn kind(&self) -> &'static str {
        "dust-collector"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::{assert_refuses_coils, read, words, write};

    /// An FC10 write of `values` from the table's first register.
    fn write_registers(dust: &mut DustCollector, values: Vec<u16>, now: Instant) -> Reply {
        dust.handle(
            &Request::WriteMultipleRegisters {
                start: BASE,
                values,
            },
            now,
        )
    }

    fn read_all(dust: &mut DustCollector, now: Instant) -> Vec<u16> {
        words(read(dust, BASE, 6, now))
    }

    #[test]
    fn read_all_gives_six_rows_with_internal_bits() {
        let mut dust = DustCollector::new(1);
        let words = read_all(&mut dust, Instant::now());
        assert_eq!(words.len(), 6);
        assert_eq!(words[0], 0x2040);
        assert_eq!(&words[1..4], &[3, 10, 5]);
        assert_eq!(words[4], 0, "fan stands still while off");
    }

    #[test]
    fn read_at_0x1002_returns_pv_not_gear() {
        let mut dust = DustCollector::new(1);
        let reply = read(&mut dust, 0x1002, 1, Instant::now());
        assert_eq!(reply, Reply::Normal(Response::HoldingRegisters(vec![10])));
    }

    #[test]
    fn read_limits_give_exceptions() {
        let mut dust = DustCollector::new(1);
        let now = Instant::now();
        // (start, quantity, exception)
        let refused = [
            (BASE, 7, ExceptionCode::IllegalDataValue),
            (BASE, 0, ExceptionCode::IllegalDataValue),
            (0x1004, 3, ExceptionCode::IllegalDataAddress),
            (0x0FFF, 1, ExceptionCode::IllegalDataAddress),
        ];
        for (start, quantity, code) in refused {
            assert_eq!(
                read(&mut dust, start, quantity, now),
                Reply::Exception(code),
                "read of {quantity} from {start:#06X}"
            );
        }
        assert_refuses_coils(&mut dust, now);
    }

    #[test]
    fn standby_acknowledges_but_ignores_gear_write() {
        let mut dust = DustCollector::new(1);
        let now = Instant::now();
        let reply = write(&mut dust, 0x1002, 8, now);
        assert_eq!(
            reply,
            Reply::Normal(Response::WriteSingleRegister {
                address: 0x1002,
                value: 8
            })
        );
        assert_eq!(dust.gear(), 3);
        assert_eq!(dust.ignored_in_standby(), 1);
        dust.set_power(true);
        write(&mut dust, 0x1002, 8, now);
        assert_eq!(dust.gear(), 8);
    }

    #[test]
    fn power_on_fc10_applies_everything() {
        let mut dust = DustCollector::new(1);
        let now = Instant::now();
        let values = vec![0x2340, 5, 2, 10];
        let reply = write_registers(&mut dust, values, now);
        assert_eq!(
            reply,
            Reply::Normal(Response::WriteMultipleRegisters {
                start: BASE,
                quantity: 4
            })
        );
        assert!(dust.power() && dust.pulse_cleaning());
        assert_eq!(
            (dust.gear(), dust.pulse_interval(), dust.pulse_duration()),
            (5, 2, 10)
        );
        assert!(dust.violations().is_empty());
    }

    #[test]
    fn writing_zeros_over_internal_bits_is_a_violation() {
        let mut dust = DustCollector::new(1);
        let now = Instant::now();
        // The golden FC10 frame's status word 0x0300 clears 0x2040: kept, but recorded.
        let values = vec![0x0300, 5, 2, 10];
        write_registers(&mut dust, values, now);
        assert!(dust.power());
        assert_eq!(dust.status_word(), 0x2340);
        assert_eq!(dust.violations().len(), 1);
    }

    #[test]
    fn invalid_values_are_refused_and_nothing_applies() {
        let mut dust = DustCollector::new(1);
        dust.set_power(true);
        let now = Instant::now();
        // (address, value, exception)
        let refused = [
            (0x1002, 11, ExceptionCode::IllegalDataValue),
            (0x1001, 1, ExceptionCode::IllegalDataAddress),
            (0x1008, 1, ExceptionCode::IllegalDataAddress),
        ];
        for (address, value, code) in refused {
            assert_eq!(
                write(&mut dust, address, value, now),
                Reply::Exception(code),
                "write of {value} to {address:#06X}"
            );
        }
        let values = vec![0x2240, 4, 100];
        assert_eq!(
            write_registers(&mut dust, values, now),
            Reply::Exception(ExceptionCode::IllegalDataValue)
        );
        assert_eq!(dust.gear(), 3);
        let values = vec![1, 2, 3, 4, 5];
        assert_eq!(
            write_registers(&mut dust, values, now),
            Reply::Exception(ExceptionCode::IllegalDataValue)
        );
    }

    #[test]
    fn fan_and_temperature_move_when_on() {
        let start = Instant::now();
        let mut dust = DustCollector::new(1);
        dust.set_power(true);
        dust.advance(start);
        let first = dust.table();
        dust.advance(start + Duration::from_secs(5));
        let later = dust.table();
        assert!(
            later[4] > first[4] + 500,
            "fan spins up: {first:?} → {later:?}"
        );
        assert!(later[5] > first[5]);
    }

    #[test]
    fn handshake_keeps_it_silent_after_power_up() {
        let start = Instant::now();
        let mut dust = DustCollector::new(1).with_power_up_handshake(start, Duration::from_secs(2));
        let read = Request::ReadHoldingRegisters {
            start: BASE,
            quantity: 6,
        };
        assert_eq!(
            dust.handle(&read, start + Duration::from_millis(1500)),
            Reply::Silent
        );
        assert!(matches!(
            dust.handle(&read, start + Duration::from_millis(2100)),
            Reply::Normal(_)
        ));
    }
}
