//! The repository's shape and its documents:
//!
//! - `layers`: the layers point one way.
//! - `module_maps`: every `lib.rs`, `main.rs` and `mod.rs` is a map naming exactly the modules
//!   it declares, and nothing else.
//! - `readme`: the README, docs/ and ARCHITECTURE.md stay true to the code.
//! - `source_scan`: Rust source read as text, which `layers` and `module_maps` share.

mod layers;
mod module_maps;
mod readme;
mod source_scan;
