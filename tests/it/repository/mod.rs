//! The repository's shape and its documents:
//!
//! - `layers`: the layers point one way.
//! - `readme`: the README, docs/ and ARCHITECTURE.md stay true to the code.

mod layers;
mod readme;
