#!/usr/bin/env bash
# Home Assistant's own modbus integration against the gateway's Modbus TCP server in front of a
# line (`[lines.serve]`, access = "profile"): Home Assistant reads the dust collector's gear and
# temperature, writes gear 8 (which must reach the line and come back on MQTT) and gear 11
# (out of the profile's range: refused with exception 03, no frame on the line).
#
# Everything runs on loopback ports picked free: a simulated seed line A on a pseudo-terminal
# (`rtu2mqtt simulate`), mosquitto, the gateway and Home Assistant Core from a virtual
# environment. Run by hand, never in CI (the Home Assistant install is large):
#
#   tests/interop/home_assistant_modbus/run.sh
#
# Environment:
#   HA_VENV       virtual environment with Home Assistant (made and filled if missing;
#                 default target/home-assistant/venv in the repository)
#   HA_PYTHON     Python that makes it (default python3.11: the newest Python that the
#                 pinned Home Assistant supports)
#   HA_VERSION    Home Assistant Core release (default 2024.3.3, the last one for Python 3.11)
#   RTU2MQTT_BIN  gateway binary (default: `cargo build`, then target/debug/rtu2mqtt)
#   KEEP_RUNNING  1: leave everything running after the checks until Ctrl-C
# Exit status 0 only when every check passed; the logs stay in the printed work directory.

set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
repo=$(cd "$here/../../.." && pwd)
HA_VERSION=${HA_VERSION:-2024.3.3}
HA_VENV=${HA_VENV:-$repo/target/home-assistant/venv}
HA_PYTHON=${HA_PYTHON:-python3.11}
work=$(mktemp -d -t rtu2mqtt-ha-modbus.XXXXXX)
pids=()
failures=0

say() { printf '\n== %s\n' "$*"; }
pass() { printf 'PASS: %s\n' "$*"; }
fail() { printf 'FAIL: %s\n' "$*"; failures=$((failures + 1)); }

stop_all() {
    local pid
    for pid in "${pids[@]}"; do
        kill "$pid" 2>/dev/null || true
    done
    for pid in "${pids[@]}"; do
        wait "$pid" 2>/dev/null || true
    done
}
trap stop_all EXIT
trap 'echo "run.sh stopped at line $LINENO; logs in $work"' ERR

# Waits up to $1 seconds for the command in the remaining arguments to succeed.
wait_for() {
    local seconds=$1
    shift
    local deadline=$((SECONDS + seconds))
    until "$@"; do
        if ((SECONDS >= deadline)); then
            return 1
        fi
        sleep 0.5
    done
}

free_port() {
    python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

# --- Home Assistant ----------------------------------------------------------------------------
if [[ ! -x $HA_VENV/bin/hass ]]; then
    say "installing Home Assistant $HA_VERSION into $HA_VENV (takes minutes)"
    "$HA_PYTHON" -m venv "$HA_VENV"
    "$HA_VENV/bin/pip" install --quiet --upgrade pip wheel
    # acme (through hass-nabucasa) of that release needs josepy 1.x; pip would take 2.x.
    "$HA_VENV/bin/pip" install --quiet "homeassistant==$HA_VERSION" "josepy<2"
fi
py=$HA_VENV/bin/python
# The pymodbus release that Home Assistant's modbus integration pins, from its manifest.
modbus_requirements=$("$py" -c '
import json, pathlib, homeassistant
manifest = pathlib.Path(homeassistant.__file__).parent / "components/modbus/manifest.json"
print(" ".join(json.loads(manifest.read_text())["requirements"]))')
"$HA_VENV/bin/pip" install --quiet $modbus_requirements
ha_version=$("$py" -c 'from homeassistant.const import __version__; print(__version__)')
pymodbus_version=$("$py" -c 'import pymodbus; print(pymodbus.__version__)')
say "Home Assistant $ha_version, pymodbus $pymodbus_version ($modbus_requirements), work directory $work"

# --- the gateway -------------------------------------------------------------------------------
if [[ -z ${RTU2MQTT_BIN:-} ]]; then
    (cd "$repo" && cargo build --quiet --bin rtu2mqtt)
    RTU2MQTT_BIN=$repo/target/debug/rtu2mqtt
fi

mqtt_port=$(free_port)
serve_port=$(free_port)
ha_port=$(free_port)

say "line A on a pseudo-terminal pair, simulated dust collector (1) and air shower (0x81)"
socat pty,raw,echo=0,link="$work/line-a-gateway" pty,raw,echo=0,link="$work/line-a-devices" \
    2>"$work/socat.log" &
pids+=($!)
wait_for 10 test -e "$work/line-a-devices" || { echo "socat made no pty pair"; exit 1; }
"$RTU2MQTT_BIN" simulate --seed-line a --port "$work/line-a-devices" --baud 9600 \
    >"$work/simulator.log" 2>&1 &
pids+=($!)

say "mosquitto on 127.0.0.1:$mqtt_port"
printf 'listener %s 127.0.0.1\nallow_anonymous true\npersistence false\n' "$mqtt_port" \
    >"$work/mosquitto.conf"
mosquitto -c "$work/mosquitto.conf" >"$work/mosquitto.log" 2>&1 &
pids+=($!)
mqtt_up() { mosquitto_pub -p "$mqtt_port" -t probe -n 2>/dev/null; }
wait_for 10 mqtt_up || { echo "mosquitto did not start"; exit 1; }
mosquitto_sub -p "$mqtt_port" -v -t 'plant/dust_collector/#' >"$work/mqtt.log" 2>&1 &
pids+=($!)

say "gateway, serving line A on modbus-tcp://127.0.0.1:$serve_port"
cat >"$work/gateway.toml" <<EOF
[mqtt]
url = "mqtt://127.0.0.1:$mqtt_port"
client_id = "rtu2mqtt-ha-interop"
prefix = "plant"

[[lines]]
name = "line-a"
port = "$work/line-a-gateway"
baud = 9600
parity = "none"

[lines.serve]
listen = "modbus-tcp://127.0.0.1:$serve_port"
access = "profile"

[[lines.devices]]
name = "dust_collector"
profile = "ruiwan-dust-collector"
address = 1

[[lines.devices]]
name = "air_shower"
profile = "lixian-air-shower"
address = 0x81
EOF
RUST_LOG=${RUST_LOG:-info} "$RTU2MQTT_BIN" run --config "$work/gateway.toml" >"$work/gateway.log" 2>&1 &
pids+=($!)

# The retained value of `topic` on the broker (empty if none within 2 s).
retained() {
    mosquitto_sub -p "$mqtt_port" -t "$1" -C 1 -W 2 2>/dev/null || true
}
gear_is() { [[ $(retained plant/dust_collector/gear) == "$1" ]]; }
gear_published() { [[ -n $(retained plant/dust_collector/gear) ]]; }
powered_on() { [[ $(retained plant/dust_collector/power) == ON ]]; }

wait_for 30 gear_published ||
    { echo "the gateway published no gear"; cat "$work/gateway.log"; exit 1; }
# The collector starts in standby, where it acknowledges a gear but does not apply it.
mosquitto_pub -p "$mqtt_port" -t plant/dust_collector/power/set -m ON
wait_for 15 powered_on || { echo "the dust collector did not power on"; exit 1; }
pass "gateway polls line A; dust collector powered on over MQTT"

# --- Home Assistant's configuration, user and token ---------------------------------------------
config=$work/home-assistant
mkdir -p "$config"
sed -e "s/@HA_PORT@/$ha_port/" -e "s/@SERVE_PORT@/$serve_port/" \
    "$here/configuration.yaml.in" >"$config/configuration.yaml"
"$HA_VENV/bin/hass" --script auth -c "$config" add interop interop-password >/dev/null

say "Home Assistant on 127.0.0.1:$ha_port (the first start installs the frontend's packages)"
"$HA_VENV/bin/hass" -c "$config" >"$work/home-assistant.out" 2>&1 &
pids+=($!)
ha=http://127.0.0.1:$ha_port
ha_up() { [[ $(curl -s -o /dev/null -w '%{http_code}' "$ha/api/") == 401 ]]; }
wait_for 600 ha_up || { echo "Home Assistant did not start"; tail -50 "$work/home-assistant.out"; exit 1; }

# An access token through the login flow of the `homeassistant` auth provider.
client_id=$ha/
json() { "$py" -c "import json, sys; print(json.load(sys.stdin)$1)"; }
flow_id=$(curl -sf -X POST "$ha/auth/login_flow" -H 'Content-Type: application/json' \
    -d "{\"client_id\": \"$client_id\", \"handler\": [\"homeassistant\", null], \"redirect_uri\": \"$client_id?auth_callback=1\"}" |
    json '["flow_id"]')
code=$(curl -sf -X POST "$ha/auth/login_flow/$flow_id" -H 'Content-Type: application/json' \
    -d "{\"client_id\": \"$client_id\", \"username\": \"interop\", \"password\": \"interop-password\"}" |
    json '["result"]')
token=$(curl -sf -X POST "$ha/auth/token" -d grant_type=authorization_code -d "code=$code" \
    --data-urlencode "client_id=$client_id" | json '["access_token"]')

api() { curl -sf -H "Authorization: Bearer $token" -H 'Content-Type: application/json' "$@"; }
ha_state() { api "$ha/api/states/$1" | json '["state"]'; }
sensor_is() { [[ $(ha_state "$1") == "$2" ]]; }
sensor_has_value() { [[ $(ha_state "$1") =~ ^[0-9]+$ ]]; }
write_gear() {
    api -X POST "$ha/api/services/modbus/write_register" \
        -d "{\"hub\": \"line_a\", \"slave\": 1, \"address\": 4098, \"value\": $1}" >/dev/null
}
# Single-register writes (function 06) to the dust collector seen by the simulated line.
line_writes() { grep -cE 'request="?01 06' "$work/simulator.log" || true; }

# --- (a) reads -----------------------------------------------------------------------------------
say "(a) Home Assistant reads the gear and the temperature through the line server"
for sensor in sensor.dust_collector_gear sensor.dust_collector_temperature; do
    wait_for 60 sensor_has_value "$sensor" || fail "$sensor never got a value"
done
ha_gear=$(ha_state sensor.dust_collector_gear)
mqtt_gear=$(retained plant/dust_collector/gear)
echo "gear: Home Assistant $ha_gear, MQTT $mqtt_gear"
if [[ $ha_gear == "$mqtt_gear" ]]; then pass "gear read by Home Assistant = device's"; else
    fail "gear read by Home Assistant ($ha_gear) differs from MQTT ($mqtt_gear)"; fi
# The temperature moves while the fan runs: the two views are compared until they agree.
temperatures_agree() {
    ha_temperature=$(ha_state sensor.dust_collector_temperature)
    mqtt_temperature=$(retained plant/dust_collector/temperature)
    [[ $ha_temperature == "$mqtt_temperature" ]]
}
if wait_for 10 temperatures_agree; then
    pass "temperature read by Home Assistant = device's ($ha_temperature)"
else
    fail "temperature: Home Assistant $ha_temperature, MQTT $mqtt_temperature"
fi
# cache = "0s": every read of Home Assistant's is a frame of its own on the line.
own_reads=$(grep -cE 'request="?01 03 10 01 00 01' "$work/simulator.log" || true)
if ((own_reads > 0)); then
    pass "$own_reads of Home Assistant's gear reads (01 03 10 01 00 01) went over the line"
else
    fail "none of Home Assistant's gear reads reached the line"
fi

# --- (b) an accepted write -----------------------------------------------------------------------
say "(b) Home Assistant writes gear 8 (modbus.write_register, slave 1, address 4098)"
target=8
if [[ $mqtt_gear == 8 ]]; then target=7; fi
writes_before=$(line_writes)
write_gear "$target"
if wait_for 15 gear_is "$target"; then pass "MQTT shows the new gear $target"; else
    fail "MQTT gear is $(retained plant/dust_collector/gear), not $target"; fi
if wait_for 15 sensor_is sensor.dust_collector_gear "$target"; then
    pass "Home Assistant reads back gear $target"
else
    fail "Home Assistant's gear is $(ha_state sensor.dust_collector_gear), not $target"
fi
sleep 1
if (($(line_writes) == writes_before + 1)); then
    pass "one write frame on the line: $(grep -E 'request="?01 06' "$work/simulator.log" | tail -1)"
else
    fail "$(($(line_writes) - writes_before)) write frames on the line, not 1"
fi
result=$(grep '^plant/dust_collector/gear/result' "$work/mqtt.log" | tail -1 || true)
echo "plant/dust_collector/gear/result: $result"
if [[ $result == *'"applied"'* ]]; then pass "outcome applied on …/gear/result"; else
    fail "outcome on …/gear/result is not applied"; fi

# --- (c) a refused write -------------------------------------------------------------------------
say "(c) Home Assistant writes gear 11 (the profile's range is 1–10)"
writes_before=$(line_writes)
write_gear 11
exception_logged() { grep -q 'address: 4098 -> Exception Response(134, 6, IllegalValue)' "$config/home-assistant.log"; }
if wait_for 10 exception_logged; then
    pass "Home Assistant logs: $(grep -o 'Pymodbus: line_a: Error: device: 1 address: 4098 -> Exception.*' "$config/home-assistant.log" | tail -1)"
else
    fail "Home Assistant logged no exception 03 for gear 11"
fi
sleep 3
if (($(line_writes) == writes_before)); then pass "no write frame reached the line"; else
    fail "$(($(line_writes) - writes_before)) write frames reached the line"; fi
if gear_is "$target"; then pass "MQTT gear stays $target"; else fail "MQTT gear changed"; fi

say "gateway log on the line server"
grep -i 'serv\|client' "$work/gateway.log" | tail -20 || true
say "MQTT seen (plant/dust_collector/gear…)"
grep '^plant/dust_collector/gear' "$work/mqtt.log" || true

if [[ ${KEEP_RUNNING:-0} == 1 ]]; then
    say "running on: Home Assistant $ha, MQTT 127.0.0.1:$mqtt_port, line server 127.0.0.1:$serve_port; Ctrl-C stops"
    wait "${pids[0]}" || true
fi

say "logs in $work"
if ((failures > 0)); then
    echo "$failures check(s) failed"
    exit 1
fi
echo "every check passed"
