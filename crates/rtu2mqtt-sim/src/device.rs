//! What a simulated device is: a pure request → [`Reply`] function with its clock passed in
//! ([`SimDevice`]), how it takes a frame's address ([`Addressing`]), and the shared handle a
//! line serves while a test or the demo inspects the same device ([`SharedDevice`], [`share`],
//! [`lock`]).

use std::sync::{Arc, Mutex};
use std::time::Instant;

use rtu2mqtt_modbus::frame::{ExceptionCode, Request, Response, SlaveId};

/// What a device does with a request addressed to it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Reply {
    Normal(Response),
    Exception(ExceptionCode),
    /// The device acted (or not) but sends nothing back.
    Silent,
}

/// Whether a device takes a frame sent to `address`, and whether it answers it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Addressing {
    /// Not for this device.
    NotMine,
    /// Act on it and answer (with the device's own address).
    Answer,
    /// Act on it without answering (broadcast).
    ActSilently,
}

/// A device to put on a simulated line.
pub trait SimDevice: Send {
    /// The device's address (the one its answers carry).
    fn address(&self) -> SlaveId;

    /// How the device treats a frame sent to `address`. The default is standard Modbus:
    /// its own address answered, broadcast 0 acted on silently.
    fn addressing(&self, address: SlaveId) -> Addressing {
        if address == self.address() {
            Addressing::Answer
        } else if address == 0 {
            Addressing::ActSilently
        } else {
            Addressing::NotMine
        }
    }

    /// Handles one decoded request at time `now`.
    fn handle(&mut self, request: &Request, now: Instant) -> Reply;

    /// Handles a CRC-valid request with a function code outside the decoded set.
    fn handle_unknown_function(&mut self, _function: u8, _now: Instant) -> Reply {
        Reply::Exception(ExceptionCode::IllegalFunction)
    }

    /// Protocol violations seen so far (writes that changed what must not be changed).
    fn violations(&self) -> Vec<String> {
        Vec::new()
    }

    /// A short name for logs.
    fn kind(&self) -> &'static str;
}

/// A device shared between the line serving it and the test or demo inspecting it.
pub type SharedDevice = Arc<Mutex<dyn SimDevice>>;

/// Wraps a device for a line, keeping a typed handle: `let (dust, shared) = share(d)`.
pub fn share<D: SimDevice + 'static>(device: D) -> (Arc<Mutex<D>>, SharedDevice) {
    let typed = Arc::new(Mutex::new(device));
    let shared: SharedDevice = typed.clone();
    (typed, shared)
}

/// Locks a shared device even if a panicking holder poisoned the lock: the simulated state is
/// plain data and stays usable.
pub fn lock<D: ?Sized>(device: &Mutex<D>) -> std::sync::MutexGuard<'_, D> {
    device
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}
