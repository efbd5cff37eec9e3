//! The bridge's decisions, without I/O: every handler takes one event (the MQTT link up or
//! down, an incoming message, a line event, a tick, a send the driver could not make, a
//! reload) with the time passed in, and returns the [`Action`]s to carry out (publish,
//! subscribe, hand a command to a line, report). Nothing here touches the network, a channel
//! or the clock, and its one random choice (the delay before re-announcing discovery) comes
//! from the generator it is given, so equal inputs give equal actions; the driver
//! (`bridge::driver`) owns the I/O and only executes what it is told.
//!
//! The [`Core`] routes each event to its two halves: the [`CommandDesk`] (commands from
//! arrival to result) and the [`Publisher`] (the state cache and what is published from it,
//! results kept while MQTT is down, the defence of our topics); an incoming message by the
//! kind of its topic, classified once. It keeps what is neither's: the connection counters,
//! the statistics document's cadence and Home Assistant's re-announcement. Commands from
//! outside the plain topics (a Sparkplug DCMD, [`Core::on_external_command`]) go through the
//! same desk, with their results on `…/result` too, and their end reported back
//! ([`Action::Report`]).
//!
//! Its parts: [`machine`] (the [`Core`] itself), [`settings`] (what it is built from),
//! [`incoming`] (what it is given: a message, an external command), [`action`] and
//! [`bridge_device`] (what it gives, and the devices it is given); [`command_desk`] and
//! [`command_book`] (the commands), [`payload`] (what a `…/set` carries and a result says),
//! [`publisher`] with [`state`] and [`json_view`] (the published state), [`discovery`] with
//! [`entity_naming`], [`ha_templates`] and [`action_entities`] (Home Assistant),
//! [`topic_guard`] (our retained topics defended).
//!
//! [`CommandDesk`]: command_desk::CommandDesk
//! [`Publisher`]: publisher::Publisher

pub(crate) mod action;
pub mod action_entities;
pub(crate) mod bridge_device;
pub(crate) mod command_book;
pub(crate) mod command_desk;
pub mod discovery;
mod entity_naming;
mod ha_templates;
pub(crate) mod incoming;
pub mod json_view;
pub(crate) mod machine;
pub mod payload;
pub(crate) mod publisher;
pub(crate) mod settings;
pub mod state;
#[cfg(test)]
mod tests;
pub(crate) mod topic_guard;

pub use self::action::{Action, CommandReport, HistoryEntry, Publish};
pub use self::bridge_device::BridgeDevice;
pub use self::incoming::{ExternalCommand, Incoming};
pub use self::machine::Core;
pub use self::settings::CoreSettings;
