//! The files the gateway ships in, checked against the code and each other:
//!
//! - `docker_files`: the container files.
//! - `package_files`: the Debian package's files.
//! - `systemd_unit`: `systemd/rtu2mqtt.service`.

mod docker_files;
mod package_files;
mod systemd_unit;
