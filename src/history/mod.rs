//! What the gateway measured, kept while the broker is away: the history stream's documents
//! ([`document`]: `{"ts":…,"values":{…}}`, pure), their on-disk format ([`record`], pure) and
//! the journal of segment files in the `[history]` directory ([`journal`], file I/O only, with
//! [`segment_file`] the names and safe reading of the directory's files).
//! It knows neither MQTT nor the bridge: the bridge decides what goes in and when it comes out.

pub mod document;
pub mod journal;
pub mod record;
mod segment_file;

pub use journal::{Journal, JournalStats};
pub use record::Record;
