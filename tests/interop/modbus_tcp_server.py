"""A Modbus TCP server built with pymodbus (an implementation not written in this project)
serving one dust collector's register table at unit 1, for the gateway's modbus-tcp:// lines.

Usage: modbus_tcp_server.py HOST PORT. Prints `listening` once the port is bound, then serves
until killed. Holding registers 0x1000..0x1005 hold, in order: status (power on = 0x0200),
gear 7, pulse interval 12, pulse duration 3, fan speed 1450, temperature 31. Read Device
Identification (FC43/14) is answered by pymodbus itself with IDENTITY.
"""

import asyncio
import socket
import sys
import time

from pymodbus import ModbusDeviceIdentification
from pymodbus.datastore import (
    ModbusDeviceContext,
    ModbusSequentialDataBlock,
    ModbusServerContext,
)
from pymodbus.server import ModbusTcpServer

TABLE_START = 0x1000
TABLE = [0x0200, 7, 12, 3, 1450, 31]
IDENTITY = {
    "VendorName": "pymodbus interop",
    "ProductCode": "PM-DUST-1",
    "MajorMinorRevision": "3.16",
}


def wait_until_bound(host: str, port: int) -> None:
    """Returns once the server accepts connections."""
    for _ in range(400):
        try:
            with socket.create_connection((host, port), timeout=0.1):
                return
        except OSError:
            time.sleep(0.05)
    raise SystemExit(f"server did not bind {host}:{port}")


async def main() -> None:
    host, port = sys.argv[1], int(sys.argv[2])
    # pymodbus stores a block one address above the protocol address it serves.
    registers = ModbusSequentialDataBlock(TABLE_START + 1, TABLE)
    device = ModbusDeviceContext(hr=registers)
    context = ModbusServerContext(devices={1: device}, single=False)
    identity = ModbusDeviceIdentification(info_name=IDENTITY)
    server = ModbusTcpServer(context, identity=identity, address=(host, port))
    serving = asyncio.create_task(server.serve_forever())
    await asyncio.get_running_loop().run_in_executor(None, wait_until_bound, host, port)
    print("listening", flush=True)
    await serving


if __name__ == "__main__":
    asyncio.run(main())
