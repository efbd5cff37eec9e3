//! The gateway configuration: serde structs, `config` layering (file < `RTU2MQTT__*`
//! environment), and complete validation that names the place of every problem.
