//! Frames written as text the way the tests and the documents show them: bytes in upper-case
//! hex separated by single spaces (`01 03 10 00 00 07 00 C8`), and the write frames among those a
//! line heard.

/// `frame` as spaced upper-case hex.
pub fn encode(frame: &[u8]) -> String {
    frame
        .iter()
        .map(|byte| format!("{byte:02X}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// The bytes of spaced hex text written in a test; panics on anything else (a typo in the test).
pub fn decode(text: &str) -> Vec<u8> {
    text.split_whitespace()
        .map(|byte| {
            u8::from_str_radix(byte, 16)
                .unwrap_or_else(|_| panic!("{byte:?} in {text:?} is no hex byte"))
        })
        .collect()
}

/// The write frames (any function other than the reads 01–04) among `frames` sent to
/// `address`, as spaced hex.
pub fn writes(frames: &[Vec<u8>], address: u8) -> Vec<String> {
    frames
        .iter()
        .filter(|f| f.len() > 2 && f[0] == address && !(1..=4).contains(&f[1]))
        .map(|f| encode(f))
        .collect()
}
