//! rtu2mqtt-profile: device knowledge as data, and the names the MQTT topics reserve. A
//! [`Profile`] is loaded from TOML (`config/profiles/*.toml`, or one of the built-in copies),
//! validated completely at load, and then answers every question the rest of the gateway has
//! about a device: which blocks to poll, how raw words become field values, which fields exist
//! and how they are exposed, and how a command on a field becomes the frames of one bus slot.
//! Everything here is pure (no I/O, no clock, no tokio) except [`registry`], which reads
//! profile files.
//!
//! # What the crate offers
//!
//! At the root: [`Profile`] and what its questions answer with: the fields ([`FieldInfo`],
//! [`FieldKind`], [`HaHints`], [`Identity`]), the blocks ([`ReadBlock`], [`PollClass`],
//! [`Limits`]), decoded values ([`FieldReading`], [`Value`], [`FieldError`], [`DeviceState`]),
//! commands ([`CommandPlan`], [`Verification`], [`Rejection`], [`Behaviour`]), actions
//! ([`ActionInfo`], [`ActionParam`], [`ActionResult`]), when a value is
//! published ([`PublishRule`]), a profile's problems ([`ProfileErrors`], [`ProfileError`]) and
//! the raw images a simulated device keeps ([`BlockImage`], [`RawPatch`]). The public modules:
//!
//! - [`registry`]: the built-in profiles, loading a profile by name or path, the listing of
//!   `rtu2mqtt profiles`.
//! - [`topic_levels`]: the words the MQTT topics use as levels of their own, which no device,
//!   field or action may be named, and the longest name a topic level may have (the daemon's
//!   `topics` builds and classifies the topics with them).
//! - [`publish`]: the `publish` table as written ([`publish::RawPublish`], which the
//!   daemon's configuration also reads) and its exact amounts.
//! - [`sunspec`]: the SunSpec model table and the profile written from a device's model chain.
//! - [`bcd`]: packed BCD words, shared with the commissioning read and the simulators.
//! - [`register_numbers`]: how a profile numbers its registers (bus, one-based, Modicon) and
//!   the bus address each number stands for.
//! - [`identification`]: a profile's `[device] identification` (what the device reports when
//!   asked what it is) and how it is matched; [`identify`]: the reads that ask a device what
//!   it is (Read Device Identification, the SunSpec marker) and the profile that fits.
//! - [`enumeration`]: the `enum` codec (sparse codes over whole registers) and its
//!   [`enumeration::UnknownCode`] rule.
//!
//! # Inside
//!
//! A module only uses those before it in this order: `bcd`, `topic_levels`, `number` (the
//! number grammar of payloads and commands), `value`, `registers` (word and byte order), `register_numbers`,
//! `numeric` (the number codecs), `text` (text encodings), `enumeration`, `rejection`,
//! `publish`, `field`, `codec` (every field codec and command parsing), `action` (command
//! interfaces and their payloads), `identification`, `model`, `format` (the file's serde
//! types), `compile` (file to model, with every problem), then `command` (a command on fields as
//! one bus slot's plan, with `command_planning` the profile's side of it), `plan` (any command's plan, an action's included) and `raw` (simulated
//! block images patched through the write frames); `profile` ([`Profile`] and its answers) is
//! what the rest of the crate sees, `sunspec` stands apart, and `identify` (after `sunspec` and
//! [`Profile`]) uses them. This file is the map: it declares the modules and re-exports the
//! surface.

// Kept true on every build, as in the daemon: `pub` is the crate's surface, every public type
// prints with `{:?}`, every public item says what it is, the 2018 idioms.
#![warn(
    unreachable_pub,
    missing_debug_implementations,
    missing_docs,
    rust_2018_idioms
)]

mod action;
pub mod bcd;
mod codec;
mod command;
mod command_planning;
mod compile;
pub mod enumeration;
mod field;
mod format;
pub mod identification;
pub mod identify;
mod model;
mod number;
mod numeric;
mod plan;
mod profile;
pub mod publish;
mod raw;
pub mod register_numbers;
mod registers;
pub mod registry;
mod rejection;
pub mod sunspec;
mod text;
pub mod topic_levels;
mod value;

pub use action::{ActionInfo, ActionParam, ActionResult};
pub use codec::{BlockImage, FieldError, RawPatch};
pub use command::Verification;
pub use compile::{ProfileError, ProfileErrors};
pub use field::{FieldInfo, FieldKind, HaHints, Identity};
pub use model::{Behaviour, Limits, PollClass, ReadBlock};
pub use plan::CommandPlan;
pub use profile::{DeviceState, FieldReading, Profile};
pub use publish::PublishRule;
pub use rejection::Rejection;
pub use value::{Value, UNAVAILABLE};
