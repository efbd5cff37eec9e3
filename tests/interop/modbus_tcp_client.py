"""Reads the seed devices' blocks from a Modbus TCP server with pymodbus (an implementation not
written in this project) and prints one line per read: `unit=U fc=FF [values]`.

Usage: modbus_tcp_client.py HOST PORT. Exit status 1 on any error or exception answer.
"""

import sys

from pymodbus.client import ModbusTcpClient

# (unit id, function, start, count): the dust collector's table, the air shower's coils, the
# valve's mode and opening registers (the valve at unit 2 here).
READS = [
    (1, 3, 0x1000, 6),
    (0x81, 1, 0x0000, 22),
    (2, 3, 0x0019, 1),
    (2, 3, 0x0074, 1),
]


def main() -> int:
    host, port = sys.argv[1], int(sys.argv[2])
    client = ModbusTcpClient(host, port=port, timeout=3, retries=0)
    if not client.connect():
        print(f"cannot connect to {host}:{port}", file=sys.stderr)
        return 1
    try:
        for unit, function, start, count in READS:
            if function == 3:
                result = client.read_holding_registers(start, count=count, device_id=unit)
            else:
                result = client.read_coils(start, count=count, device_id=unit)
            if result.isError():
                print(f"unit={unit} fc={function:02}: {result}", file=sys.stderr)
                return 1
            values = result.registers if function == 3 else [int(b) for b in result.bits[:count]]
            print(f"unit={unit} fc={function:02} {values}")
    finally:
        client.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
