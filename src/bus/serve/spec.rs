//! A line served to other Modbus masters, as configured (`[lines.serve]`: its URL, framing,
//! access and places), and a client's request on its way to the line task.

use std::time::Duration;

use tokio::sync::oneshot;

use rtu2mqtt_modbus::Reply;
use rtu2mqtt_modbus::{Request, SlaveId};

/// Connections a server takes when `max_clients` is not set.
pub const DEFAULT_MAX_CLIENTS: usize = 8;

/// How clients frame their requests on the server's socket.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ServeFraming {
    /// `modbus-tcp://`: MBAP header, unit id = device address.
    ModbusTcp,
    /// `tcp://`: RTU frames with their CRC, as a serial device server carries them.
    RawRtu,
}

/// What clients may do through the server.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Reads inside the devices' declared blocks, writes to writable profile fields.
    Profile,
    /// Reads as under `Profile`; every write refused.
    ReadOnly,
    /// Everything passes to the line, for commissioning.
    Raw,
}

impl Access {
    /// The word of the configuration file.
    pub fn word(self) -> &'static str {
        match self {
            Access::Profile => "profile",
            Access::ReadOnly => "read-only",
            Access::Raw => "raw",
        }
    }

    /// Parses the configuration's word.
    pub fn from_word(word: &str) -> Option<Self> {
        [Access::Profile, Access::ReadOnly, Access::Raw]
            .into_iter()
            .find(|access| access.word() == word)
    }
}

/// A line's server, checked (`[lines.serve]`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServeSpec {
    /// `host:port` to listen on.
    pub listen: String,
    pub framing: ServeFraming,
    pub access: Access,
    /// Reads of a block polled younger than this are answered from the poll; zero: never.
    pub cache: Duration,
    pub max_clients: usize,
}

impl ServeSpec {
    /// The listen address as the configuration writes it.
    pub fn url(&self) -> String {
        let scheme = match self.framing {
            ServeFraming::ModbusTcp => "modbus-tcp",
            ServeFraming::RawRtu => "tcp",
        };
        format!("{scheme}://{}", self.listen)
    }
}

/// A client's request, allowed by the policy, on its way to the line task.
#[derive(Debug)]
pub struct ClientRequest {
    /// Who asked (the peer address), for the logs.
    pub client: String,
    pub unit: SlaveId,
    pub request: Request,
    /// One attempt, no retry: a commissioning probe, where silence is an answer too.
    pub probe: bool,
    /// Answered with the device's reply, or an exception the gateway gives in its place.
    pub reply: oneshot::Sender<Reply>,
}
