//! Sparkplug B:
//!
//! - `sparkplug_node`: the edge node driver on a real mosquitto.
//! - `sparkplug_e2e`: the gateway as an edge node, decoded by `pysparkplug`.
//! - `sparkplug_decode`: the node's messages for every profile, as `pysparkplug` decodes them.
//! - `sparkplug_readme`: docs/sparkplug.md stays true to the code.

mod sparkplug_decode;
mod sparkplug_e2e;
pub(crate) mod sparkplug_node;
mod sparkplug_readme;
