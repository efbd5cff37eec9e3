# rtu2mqtt container image: the static edge build (scripts/edge-build: one executable with the C
# library linked in, no dynamic loader) on an empty base. The image holds the binary, the
# example configuration, a CA bundle for mqtts:// brokers, a passwd/group pair naming its user,
# and the directories the daemon writes; no shell, no package manager. It runs as uid 10001 in
# group dialout (gid 20 on Debian, the owner group of serial devices), configured from
# /etc/rtu2mqtt, its state (history journal, Sparkplug bdSeq) in the volume /var/lib/rtu2mqtt.
#
#   docker build -t rtu2mqtt .
#   docker run -d --name rtu2mqtt --read-only --cap-drop ALL --security-opt no-new-privileges \
#     --tmpfs /run/rtu2mqtt:uid=10001,gid=20,mode=0770,size=64k \
#     -v rtu2mqtt-state:/var/lib/rtu2mqtt \
#     --device /dev/serial/by-id/usb-FTDI_FT232R_USB_UART_A1B2C3-if00-port0:/dev/ttyRS485A \
#     -v /etc/rtu2mqtt:/etc/rtu2mqtt:ro rtu2mqtt
#   docker run --rm -v /etc/rtu2mqtt:/etc/rtu2mqtt:ro rtu2mqtt check
#
# Podman: `podman build --format docker` (its OCI default drops the HEALTHCHECK) and
# `--tmpfs /run/rtu2mqtt:mode=0770,size=64k,U` (it refuses uid=/gid=); docs/operations.md.
# scripts/container-check builds this image and runs it so, end to end.

# ---- build -------------------------------------------------------------------------------
FROM rust:1-bookworm AS builder
WORKDIR /src

# Dependencies first, in their own layer: a change to the sources does not rebuild them.
# Placeholder sources stand in for every target of the manifest; the crate's own artefacts are
# removed afterwards so the real sources are always compiled. Built as scripts/edge-build
# builds (static, for this machine's target, the daemon's package alone: the simulators, the
# demo and its embedded broker are other crates of the workspace), so that its build reuses
# this layer.
COPY Cargo.toml Cargo.lock ./
COPY crates/rtu2mqtt-assets/Cargo.toml crates/rtu2mqtt-assets/
COPY crates/rtu2mqtt-modbus/Cargo.toml crates/rtu2mqtt-modbus/
COPY crates/rtu2mqtt-profile/Cargo.toml crates/rtu2mqtt-profile/
COPY crates/rtu2mqtt-sim/Cargo.toml crates/rtu2mqtt-sim/
COPY testkit/Cargo.toml testkit/
COPY demo/Cargo.toml demo/
COPY docker/placeholder-sources.sh docker/
RUN sh docker/placeholder-sources.sh \
 && target=$(rustc -vV | sed -n 's/^host: //p') \
 && RUSTFLAGS="-C target-feature=+crt-static" \
    cargo build --release --locked -p rtu2mqtt --target "$target" \
 && rm -rf src benches tests crates/*/src demo/src testkit/src "target/$target/release/rtu2mqtt"* \
           "target/$target/release/deps/rtu2mqtt-"* "target/$target/release/deps/librtu2mqtt-"* \
           "target/$target/release/deps/librtu2mqtt_modbus-"* \
           "target/$target/release/deps/librtu2mqtt_profile-"* \
           "target/$target/release/.fingerprint/rtu2mqtt-"*

COPY . .
# The image's whole file system, assembled here: the empty base has no tools to do it.
# The CA bundle is Debian's Mozilla set (ca-certificates, in the build image; not what the
# build machine may have added to its own store): the daemon verifies
# mqtts:// brokers without ca_file against it (SSL_CERT_FILE below; mount another over it, or
# set SSL_CERT_FILE, to trust other CAs). The state and status directories belong to the
# daemon's user; a named volume mounted on /var/lib/rtu2mqtt starts as a copy of it.
RUN scripts/edge-build >/dev/null \
 && install -D -m 0755 target/edge/rtu2mqtt /rootfs/usr/local/bin/rtu2mqtt \
 && install -D -m 0644 config/rtu2mqtt.toml /rootfs/etc/rtu2mqtt/config.toml \
 && mkdir -p /rootfs/etc/ssl/certs \
 && cat /usr/share/ca-certificates/mozilla/*.crt > /rootfs/etc/ssl/certs/ca-certificates.crt \
 && printf 'root:x:0:0:root:/:/nonexistent\nrtu2mqtt:x:10001:20::/nonexistent:/nonexistent\n' \
      > /rootfs/etc/passwd \
 && printf 'root:x:0:\ndialout:x:20:\n' > /rootfs/etc/group \
 && install -d -m 0770 -o 10001 -g 20 /rootfs/run/rtu2mqtt /rootfs/var/lib/rtu2mqtt

# ---- runtime -----------------------------------------------------------------------------
FROM scratch
COPY --from=builder /rootfs/ /

USER 10001:20
ENV PATH=/usr/local/bin \
    SSL_CERT_FILE=/etc/ssl/certs/ca-certificates.crt \
    STATE_DIRECTORY=/var/lib/rtu2mqtt
# The history journal ([history] path = "/var/lib/rtu2mqtt/history") and the Sparkplug bdSeq
# (kept in the [history] path, else in STATE_DIRECTORY) live here: mount a named volume (or a
# host directory owned by uid 10001) so that they survive the container.
VOLUME /var/lib/rtu2mqtt
# /run/rtu2mqtt holds the status file the daemon refreshes every few seconds; with
# --read-only, mount a tmpfs there (see above), or the health check reports "cannot read".

# Healthy = the status file is at most 30 s old, every line task and the MQTT loop turn, and
# the broker is connected (or was lost less than 30 s ago). A stuck daemon also ends itself
# (exit 70) after its stall limit, since Docker does not restart unhealthy containers.
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
  CMD ["/usr/local/bin/rtu2mqtt", "health", "--status-file", "/run/rtu2mqtt/health", "--max-age", "30s"]

# SIGTERM: publish offline, finish the transaction on the bus, disconnect, exit 0.
STOPSIGNAL SIGTERM
ENTRYPOINT ["/usr/local/bin/rtu2mqtt"]
CMD ["run", "--config", "/etc/rtu2mqtt/config.toml"]
