"""Runs Modbus TCP requests against a server with pymodbus (an implementation not written in
this project) and prints one JSON object per request: {"registers": [...]}, {"bits": [...]},
{"written": true} or {"exception": CODE}.

Usage: modbus_share_client.py HOST PORT OPS, OPS a JSON list of
["read", UNIT, START, COUNT], ["coils", UNIT, START, COUNT], ["write", UNIT, ADDRESS, VALUE],
["write_registers", UNIT, START, [VALUES]] or ["write_coils", UNIT, START, [BITS]].
Exit status 1 when the connection fails or a request gets no answer at all.
"""

import json
import sys

from pymodbus.client import ModbusTcpClient


def run(client, op):
    kind, unit, start, arg = op
    if kind == "read":
        result = client.read_holding_registers(start, count=arg, device_id=unit)
    elif kind == "coils":
        result = client.read_coils(start, count=arg, device_id=unit)
    elif kind == "write_registers":
        result = client.write_registers(start, arg, device_id=unit)
    elif kind == "write_coils":
        result = client.write_coils(start, [bool(bit) for bit in arg], device_id=unit)
    else:
        result = client.write_register(start, arg, device_id=unit)
    if result.isError():
        code = getattr(result, "exception_code", None)
        if code is None:
            raise RuntimeError(f"{op}: {result}")
        return {"exception": code}
    if kind == "read":
        return {"registers": list(result.registers)}
    if kind == "coils":
        return {"bits": [int(bit) for bit in result.bits[:arg]]}
    return {"written": True}


def main() -> int:
    host, port, ops = sys.argv[1], int(sys.argv[2]), json.loads(sys.argv[3])
    client = ModbusTcpClient(host, port=port, timeout=5, retries=0)
    if not client.connect():
        print(f"cannot connect to {host}:{port}", file=sys.stderr)
        return 1
    try:
        for op in ops:
            print(json.dumps(run(client, op)), flush=True)
    except Exception as error:  # a request without an answer: the test reads the message
        print(f"{type(error).__name__}: {error}", file=sys.stderr)
        return 1
    finally:
        client.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
