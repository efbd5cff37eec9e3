//! The console's shared state: its settings, the plant as configured now (following reloads)
//! and the channels into the bridge, read by every request.

use std::sync::Arc;

use tokio::sync::{mpsc, watch};

use super::{auth, gateway_info, live, model};
use crate::bridge::observers::plant_view::PlantView;
use crate::bridge::{BridgeFigures, BridgeHealth, LocalMessage};
use crate::bus::LineHandle;
use crate::config::{Config, WebSettings};
use crate::topics::Topics;
use rtu2mqtt_modbus::live_frames::LiveFrames;

/// What the console reads and where it sends, shared by every request.
#[derive(Debug)]
pub struct Console {
    pub settings: WebSettings,
    pub topics: Topics,
    /// The plant as configured now, following reloads.
    pub layout: watch::Receiver<Arc<Layout>>,
    pub view: PlantView,
    pub figures: BridgeFigures,
    pub health: BridgeHealth,
    /// The console's commands and refreshes, into the bridge.
    pub messages: mpsc::Sender<LocalMessage>,
    pub frames: LiveFrames,
    pub sessions: auth::Sessions,
    /// Places for the pages' event streams ([`live::MAX_STREAMS`]).
    pub streams: Arc<tokio::sync::Semaphore>,
    /// One commissioning run at a time: a second waits rather than doubling the bus share.
    pub commissioning: tokio::sync::Mutex<()>,
    pub started: std::time::Instant,
}

/// The plant as configured: what the page draws, the configuration it shows and the running
/// lines the commissioning reads go through. A reload makes a new one.
#[derive(Debug)]
pub struct Layout {
    pub model: model::PlantModel,
    /// The configuration in effect as JSON text, secrets masked (kept as text: a tree of a
    /// thousand lines' values would cost more than the page ever reads).
    pub effective_config: String,
    pub lines: Vec<LineHandle>,
}

impl Layout {
    /// The layout of `config` running on `lines`.
    pub fn of(config: &Config, lines: Vec<LineHandle>) -> Arc<Layout> {
        let read_only = config.web.as_ref().map_or(true, |web| web.token.is_none());
        Arc::new(Layout {
            model: model::PlantModel::of(config, read_only),
            effective_config: gateway_info::effective_config(config).to_string(),
            lines,
        })
    }
}

/// Everything the console is built from.
#[derive(Debug)]
pub struct ConsoleParts {
    pub view: PlantView,
    pub figures: BridgeFigures,
    pub health: BridgeHealth,
    /// The plant as configured, and after each reload.
    pub layout: watch::Receiver<Arc<Layout>>,
    pub messages: mpsc::Sender<LocalMessage>,
    pub frames: LiveFrames,
}

impl Console {
    /// The console of `config` (whose `[web]` is `settings`); its layout follows `parts`.
    pub fn new(config: &Config, settings: WebSettings, parts: ConsoleParts) -> Arc<Console> {
        Arc::new(Console {
            topics: config.mqtt.topics(),
            settings,
            layout: parts.layout,
            view: parts.view,
            figures: parts.figures,
            health: parts.health,
            messages: parts.messages,
            frames: parts.frames,
            sessions: auth::Sessions::default(),
            streams: Arc::new(tokio::sync::Semaphore::new(live::MAX_STREAMS)),
            commissioning: tokio::sync::Mutex::new(()),
            started: std::time::Instant::now(),
        })
    }

    /// The plant as configured now.
    pub fn layout(&self) -> Arc<Layout> {
        Arc::clone(&self.layout.borrow())
    }

    /// The running line named `name`.
    pub fn line(&self, name: &str) -> Option<LineHandle> {
        let layout = self.layout.borrow();
        layout.lines.iter().find(|line| line.name == name).cloned()
    }
}
