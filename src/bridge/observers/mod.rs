//! What watches the bridge from outside its loop: [`statistics`] (the statistics documents and
//! the Prometheus text, pure: snapshots in, JSON or text out), [`figures`] (where those
//! snapshots are read) and [`plant_view`] (the last
//! message of every topic the bridge published, and each new one, for the console).

pub mod figures;
pub mod plant_view;
pub mod statistics;
