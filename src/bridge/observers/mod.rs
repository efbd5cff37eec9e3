//! What watches the bridge from outside its loop: [`statistics`] (the statistics documents and
//! the Prometheus text, pure: snapshots in, JSON or text out) and [`prometheus`] (the HTTP
//! endpoint that serves the text).

pub mod prometheus;
pub mod statistics;
