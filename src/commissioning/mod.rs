//! The commissioning tools: commands that talk to devices directly, without a running gateway,
//! to find them and to write their profiles. Reads only; none of them builds a write request.
//!
//! - [`target`]: where a command talks (`--port` or `--url`) and how it opens the link,
//!   refusing a port a running gateway holds.
//! - [`read`]: `rtu2mqtt read`, one raw read decoded every way a profile could.
//! - [`scan`]: `rtu2mqtt scan`, which device answers at which address, baud rate and parity,
//!   what each says it is, and the configuration to copy.
//! - [`sunspec`]: `rtu2mqtt sunspec`, a SunSpec device's model chain walked and written as a
//!   profile.

pub mod read;
pub mod scan;
pub mod sunspec;
pub mod target;
