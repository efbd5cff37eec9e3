//! The compiler from the file format ([`super::format`]) to the validated model
//! ([`super::model`]).
//!
//! Everything a profile file can get wrong is caught here, at load, with the file and the key:
//! unknown keys and codecs (serde), duplicate names, blocks over the device's read limits, fields
//! outside their block or overlapping another field, write rules on read-only blocks or outside
//! the device's write limits, bad ranges and enumerations. What leaves this module is known to be
//! consistent, so decoding and command planning never have to re-check the profile.
//!
//! [`phases`] holds the entry point and the order of the phases; each other part builds one
//! thing:
//! [`problems`] (every problem with its place), [`blocks`] (the line's limits, the read blocks
//! and their cadence), [`writes`] (write frames and a field's write), [`codecs`] (a codec
//! section as a [`FieldCodec`](super::codec::FieldCodec)), [`fields`] (the fields, what they
//! refer to across each other, and the forbidden combinations) and [`actions`] (the command
//! interfaces).

mod actions;
mod blocks;
mod codecs;
mod fields;
mod phases;
mod problems;
mod writes;

pub(super) use blocks::polled_at_least_as_often;
pub(crate) use phases::compile;
pub use problems::{ProfileError, ProfileErrors};
