# rtu2mqtt container image: the Rust binary (built against bookworm's glibc) on
# debian:bookworm-slim, run as an unprivileged user in group dialout (gid 20), configured from
# /etc/rtu2mqtt.
#
#   docker build -t rtu2mqtt .
#   docker run -d --name rtu2mqtt --read-only --cap-drop ALL --security-opt no-new-privileges \
#     --tmpfs /run/rtu2mqtt:uid=10001,gid=20,mode=0770,size=64k \
#     --device /dev/serial/by-id/usb-FTDI_FT232R_USB_UART_A1B2C3-if00-port0:/dev/ttyRS485A \
#     -v /etc/rtu2mqtt:/etc/rtu2mqtt:ro rtu2mqtt
#   docker run --rm -v /etc/rtu2mqtt:/etc/rtu2mqtt:ro rtu2mqtt check

# ---- build -------------------------------------------------------------------------------
FROM rust:1-bookworm AS builder
WORKDIR /src

# Dependencies first, in their own layer: a change to the sources does not rebuild them.
# Placeholder sources stand in for every target of the manifest; the crate's own artefacts are
# removed afterwards so the real sources are always compiled. The daemon is built without the
# feature `demo` (no simulators, demo, embedded broker or `simulate`). (scripts/edge-build
# makes a static binary that maps no shared C library; its wire timing's tail is longer:
# docs/performance.md. This image ships the dynamic build.)
COPY Cargo.toml Cargo.lock ./
COPY crates/rtu2mqtt-modbus/Cargo.toml crates/rtu2mqtt-modbus/
COPY docker/placeholder-sources.sh docker/
RUN sh docker/placeholder-sources.sh \
 && cargo build --release --locked --no-default-features \
 && rm -rf src benches tests crates/rtu2mqtt-modbus/src target/release/rtu2mqtt* \
           target/release/deps/rtu2mqtt-* target/release/deps/librtu2mqtt-* \
           target/release/deps/librtu2mqtt_modbus-* target/release/.fingerprint/rtu2mqtt-*

COPY . .
RUN cargo build --release --locked --no-default-features --bin rtu2mqtt \
 && install -m 0755 target/release/rtu2mqtt /usr/local/bin/rtu2mqtt

# ---- runtime -----------------------------------------------------------------------------
FROM debian:bookworm-slim

# CA certificates for mqtts:// brokers; nothing else.
RUN apt-get update \
 && apt-get install -y --no-install-recommends ca-certificates \
 && rm -rf /var/lib/apt/lists/*

# Unprivileged user whose primary group is dialout (gid 20 on Debian), the owner group of
# serial devices, so that ports passed with --device open without any capability.
RUN useradd --system --uid 10001 --gid dialout --no-create-home --home-dir /nonexistent \
      --shell /usr/sbin/nologin rtu2mqtt \
 && install -d -m 0755 /etc/rtu2mqtt \
 && install -d -m 0770 -o rtu2mqtt -g dialout /run/rtu2mqtt

COPY --from=builder /usr/local/bin/rtu2mqtt /usr/local/bin/rtu2mqtt
# The example plant; mount your own configuration over /etc/rtu2mqtt.
COPY config/rtu2mqtt.toml /etc/rtu2mqtt/config.toml

USER rtu2mqtt:dialout
# /run/rtu2mqtt holds the status file the daemon refreshes every few seconds; with
# --read-only, mount a tmpfs there (see above), or the health check reports "cannot read".

# Healthy = the status file is at most 30 s old, every line task and the MQTT loop turn, and
# the broker is connected (or was lost less than 30 s ago). A stuck daemon also ends itself
# (exit 70) after its stall limit, since Docker does not restart unhealthy containers.
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
  CMD ["rtu2mqtt", "health", "--status-file", "/run/rtu2mqtt/health", "--max-age", "30s"]

# SIGTERM: publish offline, finish the transaction on the bus, disconnect, exit 0.
STOPSIGNAL SIGTERM
ENTRYPOINT ["rtu2mqtt"]
CMD ["run", "--config", "/etc/rtu2mqtt/config.toml"]
