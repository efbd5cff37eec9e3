//! What a simulated device on a pty can know of the master's serial settings, to make a
//! baud-rate mismatch visible where the kernel does not enforce one.
//!
//! On Linux a pty pair shares one set of terminal settings: the baud rate the master sets on
//! its end (the slave, `/dev/pts/N`) is what `tcgetattr` shows on the served end too. Parity is
//! not observable: the pty driver clears PARENB on every `tcsetattr`, so a parity mismatch
//! cannot be simulated this way and only the baud rate is checked.

use std::os::fd::{AsRawFd, BorrowedFd};

use super::server::ServeOptions;

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

/// The master's baud rate when it differs from the line's (only with
/// [`ServeOptions::enforce_baud`] on a virtual line).
pub fn baud_mismatch(options: &ServeOptions) -> Option<u32> {
    if !options.enforce_baud {
        return None;
    }
    let fd = options.settings_fd?;
    // SAFETY: the fd belongs to the stream the serving task owns for as long as it runs, and
    // this is only called from that task.
    let fd = unsafe { BorrowedFd::borrow_raw(fd) };
    baud_of(fd).filter(|&peer| peer != options.timing.baud)
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
    fn garbled_answer_fails_its_crc() {
        let mut answer = rtu2mqtt_modbus::codec::encode_exception(
            1,
            0x03,
            rtu2mqtt_modbus::frame::ExceptionCode::IllegalDataAddress,
        );
        garble(&mut answer);
        assert!(!crate::sim::wire::crc_ok(&answer));
    }
}
