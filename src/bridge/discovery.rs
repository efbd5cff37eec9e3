//! Home Assistant device-based discovery (discovery helper).
