"""Pipelines Modbus TCP requests built by pymodbus (an implementation not written in this
project): every round sends all OPS at once on one connection, without waiting for an answer,
then reads the answers with pymodbus's framer and prints them as one JSON list per round:
{"registers": [...]}, {"bits": [...]}, {"written": true} or {"exception": CODE}.

Usage: modbus_pipeline_client.py HOST PORT ROUNDS PAUSE_MS OPS, OPS a JSON list of
["read", UNIT, START, COUNT], ["write", UNIT, ADDRESS, VALUE],
["write_registers", UNIT, START, [VALUES]] or ["write_coils", UNIT, START, [BITS]].
Exit status 1 when the connection fails or an answer does not come within 15 s.
"""

import json
import socket
import sys
import time

from pymodbus.framer import FramerSocket
from pymodbus.pdu import DecodePDU
from pymodbus.pdu.bit_message import WriteMultipleCoilsRequest
from pymodbus.pdu.register_message import (
    ReadHoldingRegistersRequest,
    WriteMultipleRegistersRequest,
    WriteSingleRegisterRequest,
)


def request(op, transaction):
    kind, unit, start, arg = op
    common = {"dev_id": unit, "transaction_id": transaction, "address": start}
    if kind == "read":
        return ReadHoldingRegistersRequest(count=arg, **common)
    if kind == "write":
        return WriteSingleRegisterRequest(registers=[arg], **common)
    if kind == "write_registers":
        return WriteMultipleRegistersRequest(registers=arg, **common)
    if kind == "write_coils":
        return WriteMultipleCoilsRequest(bits=[bool(bit) for bit in arg], **common)
    raise ValueError(f"unknown op {kind}")


def described(pdu):
    if pdu.isError():
        return {"exception": pdu.exception_code}
    if getattr(pdu, "function_code", 0) == 3:
        return {"registers": list(pdu.registers)}
    return {"written": True}


def round_trip(sock, framer, ops, first_transaction):
    pending = []
    frames = b""
    for index, op in enumerate(ops):
        transaction = (first_transaction + index) % 0x10000
        frames += framer.buildFrame(request(op, transaction))
        pending.append((op[1], transaction))
    sock.sendall(frames)
    answers, data = [], b""
    deadline = time.monotonic() + 15
    while len(answers) < len(pending):
        unit, transaction = pending[len(answers)]
        used, pdu = framer.handleFrame(data, unit, transaction)
        if pdu is not None:
            data = data[used:]
            answers.append(described(pdu))
            continue
        data = data[used:]
        sock.settimeout(max(0.1, deadline - time.monotonic()))
        chunk = sock.recv(4096)
        if not chunk:
            raise ConnectionError("closed by the server")
        data += chunk
    return answers


def main() -> int:
    host, port = sys.argv[1], int(sys.argv[2])
    rounds, pause = int(sys.argv[3]), int(sys.argv[4]) / 1000
    ops = json.loads(sys.argv[5])
    framer = FramerSocket(DecodePDU(False))
    try:
        with socket.create_connection((host, port), timeout=15) as sock:
            for number in range(rounds):
                answers = round_trip(sock, framer, ops, number * len(ops))
                print(json.dumps(answers), flush=True)
                time.sleep(pause)
    except (OSError, ConnectionError) as error:
        print(f"{type(error).__name__}: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
