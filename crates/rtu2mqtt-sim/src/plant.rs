//! The seed plant on virtual lines, as `docs/devices.md` lays it out: line A (9600 8N1) with the
//! dust collector at 1 and the air shower at 0x81, line B (9600 8E1) with the valve at 1. For
//! the demo, the end-to-end tests and the benchmark.

use std::sync::{Arc, Mutex};

use super::air_shower::AirShower;
use super::device::share;
use super::dust_collector::DustCollector;
use super::server::ServeOptions;
use super::valve::Valve;
use super::virtual_line::VirtualLine;
use rtu2mqtt_modbus::timing::Parity;

/// The three seed devices on two served ptys, with typed handles on each device.
#[derive(Debug)]
pub struct SeedPlant {
    pub line_a: VirtualLine,
    pub line_b: VirtualLine,
    pub dust_collector: Arc<Mutex<DustCollector>>,
    pub air_shower: Arc<Mutex<AirShower>>,
    pub valve: Arc<Mutex<Valve>>,
}

impl SeedPlant {
    /// Serves the plant (paced at 9600 baud when `pace`). Needs a tokio runtime.
    pub fn spawn(pace: bool) -> std::io::Result<Self> {
        let (dust_collector, dust_shared) = share(DustCollector::new(1));
        let (air_shower, shower_shared) = share(AirShower::new());
        let (valve, valve_shared) = share(Valve::new(1));
        let line_a = VirtualLine::spawn(
            ServeOptions::new(9600, Parity::None).paced(pace),
            vec![dust_shared, shower_shared],
        )?;
        let line_b = VirtualLine::spawn(
            ServeOptions::new(9600, Parity::Even).paced(pace),
            vec![valve_shared],
        )?;
        Ok(Self {
            line_a,
            line_b,
            dust_collector,
            air_shower,
            valve,
        })
    }
}
