//! The one question the demo asks the terminal: its size on stdout.

/// Columns and rows of the terminal on stdout (100 × 40 when unknown or too small to draw on).
pub(super) fn terminal_size() -> (usize, usize) {
    use terminal_size::{terminal_size_of, Height, Width};
    match terminal_size_of(std::io::stdout()) {
        Some((Width(columns), Height(rows))) if columns >= 40 && rows >= 10 => {
            (usize::from(columns), usize::from(rows))
        }
        _ => (100, 40),
    }
}
