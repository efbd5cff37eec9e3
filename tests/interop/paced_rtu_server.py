"""pymodbus's own Modbus RTU server (an implementation not written in this project) on a
pseudo-terminal, behind a pacer that gives it a wire: every byte crosses at the line's
character rate, as through a UART, and the pacer notes when each frame crossed.

Usage: paced_rtu_server.py BAUD JOURNAL [REGISTERS]

Serves unit 1 with REGISTERS holding registers from address 0 (default 6, all 0; FC03, FC06,
FC16 and the rest of pymodbus's server). Prints the path of the gateway's end of the line, then
serves until stdin closes or the process is killed.

The pacer stands between two pseudo-terminals: the gateway's and pymodbus's. A request's bytes
reach pymodbus one character time apart, its last byte one frame time after the first; the
answer pymodbus writes at once reaches the gateway byte by byte, each byte one character time
after the one before (its last one frame time after the first left). Timer slack is set to
nothing on the pacer's threads, so the kernel wakes them on time.

The journal (one JSON object per line, times in CLOCK_MONOTONIC nanoseconds) has a `request`
line for every frame from the gateway, `at` being when the pacer saw its first byte (where the
device sees the line come alive), and an `answer` line for every answer, naming the request it
follows, with `due` (when its last byte was on the wire: its first byte's start plus the
answer's frame time), `handed_over` (just before the write that gave the gateway its last byte)
and `written` (when that write returned). A frame's bytes are those that follow each other
within one and a half character times of the wire.
"""

import ctypes
import json
import os
import select
import sys
import threading
import time
import tty

from pymodbus import FramerType
from pymodbus.datastore import (
    ModbusDeviceContext,
    ModbusSequentialDataBlock,
    ModbusServerContext,
)
from pymodbus.server import StartSerialServer

PR_SET_TIMERSLACK = 29
UNIT = 1


def no_timer_slack() -> None:
    """The calling thread's sleeps end when asked, not up to 50 us later."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_TIMERSLACK, 1, 0, 0, 0)
    except OSError:
        pass


def spaced_hex(frame: bytes) -> str:
    """A frame as the project's tests write it: upper-case hex bytes, one space apart."""
    return frame.hex(" ").upper()


def sleep_until(deadline_ns: int) -> None:
    remaining = deadline_ns - time.monotonic_ns()
    if remaining > 0:
        time.sleep(remaining / 1e9)


class Journal:
    """The journal file, written by both directions' threads."""

    def __init__(self, path: str) -> None:
        self.file = open(path, "w", buffering=1, encoding="ascii")
        self.lock = threading.Lock()
        self.requests = 0

    def request(self, at: int, frame: bytes) -> None:
        with self.lock:
            self.requests += 1
            self.write({"request": self.requests, "at": at, "frame": spaced_hex(frame)})

    def answer(self, frame: bytes, due: int, handed_over: int, written: int) -> None:
        with self.lock:
            self.write(
                {
                    "answer": self.requests,
                    "frame": spaced_hex(frame),
                    "due": due,
                    "handed_over": handed_over,
                    "written": written,
                }
            )

    def write(self, record: dict) -> None:
        self.file.write(json.dumps(record, separators=(",", ":")) + "\n")


def raw_pty() -> tuple[int, int, str]:
    """A pseudo-terminal in raw mode: its master, its slave (kept open so that the master
    never reads end-of-file while the other side reopens it) and the slave's path."""
    master, slave = os.openpty()
    tty.setraw(slave)
    tty.setraw(master)
    return master, slave, os.ttyname(slave)


def frames(source: int, char_ns: int):
    """Yields (first byte seen at, bytes) for each frame read from `source`: bytes that follow
    each other within 1.5 character times of their wire time."""
    while True:
        select.select([source], [], [])
        chunk = os.read(source, 512)
        seen = time.monotonic_ns()
        frame = bytearray(chunk)
        # The wire time of what has come so far, from the first byte.
        while True:
            quiet = (seen + len(frame) * char_ns + char_ns * 3 // 2 - time.monotonic_ns()) / 1e9
            ready, _, _ = select.select([source], [], [], max(quiet, 0))
            if not ready:
                break
            frame.extend(os.read(source, 512))
        yield seen, bytes(frame)


def requests_to_device(gateway: int, device: int, char_ns: int, journal: Journal) -> None:
    """The gateway's requests, each byte passed on to pymodbus when it has crossed the wire."""
    no_timer_slack()
    for seen, frame in frames(gateway, char_ns):
        journal.request(seen, frame)
        for index, byte in enumerate(frame):
            sleep_until(seen + (index + 1) * char_ns)
            os.write(device, bytes([byte]))


def answers_to_gateway(device: int, gateway: int, char_ns: int, journal: Journal) -> None:
    """pymodbus's answers released to the gateway byte by byte at the wire's rate."""
    no_timer_slack()
    while True:
        select.select([device], [], [])
        answer = os.read(device, 512)
        start = time.monotonic_ns()
        handed_over = written = start
        for index, byte in enumerate(answer):
            sleep_until(start + (index + 1) * char_ns)
            handed_over = time.monotonic_ns()
            os.write(gateway, bytes([byte]))
            written = time.monotonic_ns()
        journal.answer(answer, start + len(answer) * char_ns, handed_over, written)


def main() -> None:
    baud = int(sys.argv[1])
    journal = Journal(sys.argv[2])
    count = int(sys.argv[3]) if len(sys.argv) > 3 else 6
    # 8N1: ten bits a character.
    char_ns = 10 * 1_000_000_000 // baud

    gateway_master, _gateway_slave, gateway_path = raw_pty()
    device_master, _device_slave, device_path = raw_pty()
    for target, args in (
        (requests_to_device, (gateway_master, device_master, char_ns, journal)),
        (answers_to_gateway, (device_master, gateway_master, char_ns, journal)),
    ):
        threading.Thread(target=target, args=args, daemon=True).start()
    # Ends the process when its parent closes stdin.
    threading.Thread(
        target=lambda: (sys.stdin.read(), os._exit(0)), daemon=True
    ).start()

    # pymodbus stores a block one address above the protocol address it serves.
    registers = ModbusSequentialDataBlock(1, [0] * count)
    context = ModbusServerContext(
        devices={UNIT: ModbusDeviceContext(hr=registers)}, single=False
    )
    print(gateway_path, flush=True)
    StartSerialServer(
        context,
        framer=FramerType.RTU,
        port=device_path,
        baudrate=baud,
        bytesize=8,
        parity="N",
        stopbits=1,
    )


if __name__ == "__main__":
    main()
