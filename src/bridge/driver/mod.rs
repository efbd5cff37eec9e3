//! The bridge's driver: the one task ([`task`]) that owns the
//! [`Core`](crate::bridge::core::Core), the outbox and the channels. It
//! feeds every event to the core (link events from rumqttc's event loop, which runs in its own
//! task ([`connection`]); line events, values and command ends alike; a tick) and executes the
//! actions it returns. Sends to lines are non-blocking `try_*`, so line events are always
//! consumed (polling never stops because MQTT is down). What goes to MQTT waits in the
//! [`outbox::Outbox`] and is handed to the [`writer`] task, which awaits room in the client's
//! short request queue: nothing is dropped because the client is busy, and when the outbox grows past
//! [`OVERLOAD_HIGH`] the core sheds incoming commands (each still gets its outcome) until it is
//! back under [`OVERLOAD_LOW`]. With `[history]`, [`history_stream`] carries the history stream:
//! published while the broker is there, journaled while it is away, replayed after. [`tls`] is
//! the `mqtts://` client configuration. [`oversized`] keeps an incoming packet larger than the
//! gateway reads from ending connection after connection. [`inputs`] waits for what comes
//! besides the broker's messages and the lines' events: the console's messages and a Sparkplug
//! node's commands.

pub mod connection;
pub(crate) mod history_stream;
mod inputs;
pub(crate) mod outbox;
pub mod oversized;
mod task;
pub(crate) mod tls;
mod writer;

pub use self::inputs::LocalMessage;
pub use crate::bridge::observers::figures::BridgeFigures;
pub use task::{Bridge, BridgeHealth, Reconfiguration, OVERLOAD_HIGH, OVERLOAD_LOW, TICK};
