//! What a simulated device on a pty can know of the master's serial settings, to make a
//! baud-rate mismatch visible where the kernel does not enforce one.
//!
//! On Linux a pty pair shares one set of terminal settings: the baud rate the master sets on
//! its end (the slave, `/dev/pts/N`) is what `tcgetattr` shows on the served end too. Parity is
//! not observable: the pty driver clears PARENB on every `tcsetattr`, so a parity mismatch
//! cannot be simulated this way and only the baud rate is checked.

use std::os::fd::{AsFd, AsRawFd, BorrowedFd, OwnedFd};

/// The baud rate `fd`'s terminal settings carry (None: not a terminal). Read with TCGETS2:
/// serial libraries set the rate as a number (BOTHER), which the classic `cfgetospeed` cannot
/// name.
pub fn baud_of(fd: BorrowedFd<'_>) -> Option<u32> {
    let mut settings = std::mem::MaybeUninit::<libc::termios2>::uninit();
    // SAFETY: TCGETS2 fills a termios2 when it returns 0; it is read only then.
    let settings = unsafe {
        if libc::ioctl(fd.as_raw_fd(), libc::TCGETS2, settings.as_mut_ptr()) != 0 {
            return None;
        }
        settings.assume_init()
    };
    Some(settings.c_ospeed)
}

/// Watches the baud rate the master set on a pty, through a descriptor of the pty's own.
#[derive(Debug)]
pub struct BaudWatch {
    pty: OwnedFd,
    line_baud: u32,
}

impl BaudWatch {
    /// Watches `pty` (either end: both show the one set of settings) for a rate other than
    /// `line_baud`.
    pub fn new(pty: OwnedFd, line_baud: u32) -> Self {
        Self { pty, line_baud }
    }

    /// The master's baud rate when it differs from the line's.
    pub fn mismatch(&self) -> Option<u32> {
        baud_of(self.pty.as_fd()).filter(|&peer| peer != self.line_baud)
    }
}

/// Turns an answer into what a UART at another baud rate makes of it: other bytes (the CRC no
/// longer holds).
pub fn garble(bytes: &mut [u8]) {
    for byte in bytes.iter_mut() {
        *byte = byte.rotate_left(3) ^ 0xA5;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rate_set_on_the_slave_is_seen_and_compared() {
        use mio_serial::SerialPort as _;
        use std::os::unix::fs::OpenOptionsExt as _;

        let (_master, mut slave) = mio_serial::SerialStream::pair().expect("a pty pair");
        let path = slave.name().expect("the slave's path");
        let watched = std::fs::OpenOptions::new()
            .read(true)
            .custom_flags(libc::O_NOCTTY)
            .open(path)
            .expect("the slave opened again");
        let watch = BaudWatch::new(watched.into(), 9600);
        slave.set_baud_rate(9600).expect("9600 set");
        assert_eq!(watch.mismatch(), None);
        slave.set_baud_rate(19_200).expect("19200 set");
        assert_eq!(watch.mismatch(), Some(19_200));
    }

    #[test]
    fn garbled_answer_fails_its_crc() {
        let mut answer = rtu2mqtt_modbus::codec::encode_exception(
            1,
            0x03,
            rtu2mqtt_modbus::frame::ExceptionCode::IllegalDataAddress,
        );
        garble(&mut answer);
        assert!(!crate::wire::crc_ok(&answer));
    }
}
