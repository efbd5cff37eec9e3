//! One configured line with its devices, as the bus takes it from the configuration: what it
//! talks through ([`Transport`]), its timing and retry settings, and the server of other
//! masters it may carry.

use std::time::Duration;

use rtu2mqtt_modbus::link::TcpEndpoint;
use rtu2mqtt_modbus::serial::transport::SerialSettings;
use rtu2mqtt_modbus::tcp::masters::TcpOptions;

use super::device_spec::DeviceSpec;
use super::serve;

/// What a line talks through.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Transport {
    /// The serial port at [`LineSpec::serial`]'s path.
    Serial,
    /// A serial device server (`tcp://`: raw RTU, timed by [`LineSpec::serial`]'s baud and
    /// format) or a Modbus TCP gateway (`modbus-tcp://`).
    Tcp {
        endpoint: TcpEndpoint,
        options: TcpOptions,
        /// Added to the default response timeout for the network's round trip.
        network_allowance: Duration,
    },
}

impl Transport {
    /// How `check` and the logs name it.
    pub fn describe(&self, serial: &SerialSettings) -> String {
        match self {
            Transport::Serial => format!("serial port {}", serial.path),
            Transport::Tcp { endpoint, .. } => endpoint.describe(),
        }
    }
}

/// One configured line with its devices.
#[derive(Debug, Clone)]
pub struct LineSpec {
    pub name: String,
    /// The serial port and its character format. On a TCP line `path` holds the url (for logs)
    /// and baud and format time the server's serial side.
    pub serial: SerialSettings,
    pub transport: Transport,
    /// None: derived from baud and the longest expected answer plus a device margin.
    pub response_timeout: Option<Duration>,
    /// Retries after a failed transaction (timeout, CRC, truncated answer).
    pub retries: u32,
    /// Consecutive failed polls after which a device is reported offline.
    pub offline_after: u32,
    /// The adapter echoes what it sends.
    pub echo: bool,
    /// Silence after a broadcast write.
    pub broadcast_turnaround: Duration,
    /// Longest pause inside an answer (None: the master's default).
    pub byte_timeout: Option<Duration>,
    /// Where every frame of the line is recorded (`gateway.frame_log`, the console's view).
    pub recorders: FrameRecorders,
    /// The browser console may send its commissioning reads through the line's scheduler.
    pub console: bool,
    pub devices: Vec<DeviceSpec>,
    /// The line served to other Modbus masters (`[lines.serve]`; none: not served).
    pub serve: Option<serve::ServeSpec>,
}

/// Where a line's frames are recorded: the frame log's file and the live view, either or both.
#[derive(Debug, Clone, Default)]
pub struct FrameRecorders {
    /// `gateway.frame_log`.
    pub log: Option<rtu2mqtt_modbus::frame_log::FrameLog>,
    /// The console's live frame view.
    pub live: Option<rtu2mqtt_modbus::live_frames::LiveFrames>,
}

impl FrameRecorders {
    /// The writer for line `line`'s link; None when nothing records.
    pub fn writer(&self, line: &str) -> Option<Box<dyn rtu2mqtt_modbus::FrameSink>> {
        let mut tee = rtu2mqtt_modbus::live_frames::Tee::default();
        if let Some(log) = &self.log {
            tee.push(Box::new(log.writer(line)));
        }
        if let Some(live) = &self.live {
            tee.push(Box::new(live.writer(line)));
        }
        tee.into_writer()
    }
}
