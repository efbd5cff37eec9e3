//! The one question the demo asks the terminal: its size (the TIOCGWINSZ ioctl on stdout).

/// Columns and rows of the terminal on stdout (100 × 40 when unknown).
pub(super) fn terminal_size() -> (usize, usize) {
    nix::ioctl_read_bad!(window_size, libc::TIOCGWINSZ, libc::winsize);
    let mut size = libc::winsize {
        ws_row: 0,
        ws_col: 0,
        ws_xpixel: 0,
        ws_ypixel: 0,
    };
    // SAFETY: TIOCGWINSZ writes one `winsize` into the struct we own; a failure leaves it zero.
    let result = unsafe { window_size(libc::STDOUT_FILENO, &mut size) };
    match result {
        Ok(_) if size.ws_col >= 40 && size.ws_row >= 10 => {
            (usize::from(size.ws_col), usize::from(size.ws_row))
        }
        _ => (100, 40),
    }
}
