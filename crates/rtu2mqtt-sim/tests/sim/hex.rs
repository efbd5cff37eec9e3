//! Frames written in a test as the documents print them: bytes in hex separated by spaces.

/// The bytes of spaced hex text (`01 03 10 00`); a typo in a test panics.
pub fn decode(text: &str) -> Vec<u8> {
    text.split_whitespace()
        .map(|byte| u8::from_str_radix(byte, 16).expect("a hex byte"))
        .collect()
}
