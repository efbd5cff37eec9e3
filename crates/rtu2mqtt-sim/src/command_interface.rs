//! A command interface as meters and drives have one (Schneider's registers 5250 and 5376): a
//! frame of holding registers written with one FC16, the command number first and its
//! parameter words after it, carried out at once, its result code left in a result register
//! for the master to read. A table says which commands exist, how many parameter words each
//! takes and which values each word accepts; the codes are Schneider's. A
//! [`GenericDevice`](super::GenericDevice) gets one with
//! [`GenericDevice::with_command_interface`](super::GenericDevice::with_command_interface).

use std::ops::RangeInclusive;

/// The command was carried out.
pub const SUCCESS: u16 = 0;
/// No command of the table has this number.
pub const INVALID_COMMAND: u16 = 3000;
/// A parameter word is outside what the command accepts.
pub const INVALID_PARAMETER: u16 = 3001;
/// The frame holds another number of parameter words than the command takes.
pub const INVALID_PARAMETER_COUNT: u16 = 3002;

/// One command of the table: its number and the values each parameter word accepts.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Command {
    number: u16,
    params: Vec<RangeInclusive<u16>>,
}

/// A command interface: where its frame and its result register are, and its commands.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CommandInterface {
    frame: u16,
    result: u16,
    commands: Vec<Command>,
    /// The commands carried out, with their parameter words, oldest first.
    executed: Vec<(u16, Vec<u16>)>,
}

impl CommandInterface {
    /// An interface whose frame starts at register `frame` (the command number) and whose
    /// result code is left at register `result`; no command yet.
    pub fn new(frame: u16, result: u16) -> Self {
        Self {
            frame,
            result,
            commands: Vec::new(),
            executed: Vec::new(),
        }
    }

    /// The same interface with one more command: `number`, taking one parameter word per
    /// entry of `params`, each inside its range.
    pub fn command(mut self, number: u16, params: Vec<RangeInclusive<u16>>) -> Self {
        self.commands.push(Command { number, params });
        self
    }

    /// Where the frame starts.
    pub fn frame(&self) -> u16 {
        self.frame
    }

    /// Where the result code is left.
    pub fn result(&self) -> u16 {
        self.result
    }

    /// The commands carried out so far, with their parameter words, oldest first.
    pub fn executed(&self) -> &[(u16, Vec<u16>)] {
        &self.executed
    }

    /// Takes a write of `values` from register `start`: the result code when the write is a
    /// command frame (it starts at the frame's first register), None for any other write.
    pub fn take(&mut self, start: u16, values: &[u16]) -> Option<u16> {
        if start != self.frame {
            return None;
        }
        let (&number, params) = values.split_first()?;
        let Some(command) = self.commands.iter().find(|c| c.number == number) else {
            return Some(INVALID_COMMAND);
        };
        if params.len() != command.params.len() {
            return Some(INVALID_PARAMETER_COUNT);
        }
        let accepted = params
            .iter()
            .zip(&command.params)
            .all(|(word, range)| range.contains(word));
        if !accepted {
            return Some(INVALID_PARAMETER);
        }
        self.executed.push((number, params.to_vec()));
        Some(SUCCESS)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_is_judged_by_the_table() {
        let mut interface = CommandInterface::new(5249, 5375).command(2060, vec![0..=0, 1..=4]);
        assert_eq!(interface.take(5249, &[2060, 0, 2]), Some(SUCCESS));
        assert_eq!(interface.take(5249, &[2060, 0, 5]), Some(INVALID_PARAMETER));
        assert_eq!(
            interface.take(5249, &[2060, 0]),
            Some(INVALID_PARAMETER_COUNT)
        );
        assert_eq!(interface.take(5249, &[2061, 0, 2]), Some(INVALID_COMMAND));
        assert_eq!(interface.take(5250, &[2060, 0, 2]), None);
        assert_eq!(interface.take(5249, &[]), None);
        assert_eq!(interface.executed(), [(2060, vec![0, 2])]);
    }
}
