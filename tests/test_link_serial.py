"""``slung fly --connect serial:DEVICE:BAUD``, the companion computer's usual link to the autopilot's TELEM port, and
``--connect tcp:HOST:PORT`` (ArduPilot SITL's serial 0).

A pseudo-terminal stands in for the UART: the loop opens its slave side through pymavlink / pyserial exactly as it
would open /dev/ttyUSB0, and a relay carries the bytes between the master side and the bundled emulator's UDP link
on 127.0.0.1 (one MAVLink packet per datagram towards the emulator, as its UDP link expects). The byte stream on the
serial side is the real thing: no framing but MAVLink's own, partial reads, packets split across reads."""

from __future__ import annotations

import argparse
import os
import select
import socket
import threading
import tty
from pathlib import Path
from typing import Any

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from offboard.flight.fly_cli import fly
from offboard.harness.demo_cli import EmulatorThread, configure, free_udp_port


class Relay(threading.Thread):
    """The autopilot's end of a byte-stream link <-> the emulator's UDP link (a socket bound on 127.0.0.1:``port``,
    where the emulator sends): datagrams from the emulator are written to the stream as they are; the stream is
    parsed and each MAVLink packet sent to the emulator as one datagram."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.emu_addr: tuple[str, int] | None = None
        self.parser = mavutil.mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.to_stream = self.to_udp = 0
        self.stop = False

    def relay(self, fd: int, write: Any, read: Any) -> None:
        """Relay until stopped or the stream closes; ``fd`` is select()able, ``write(bytes)``, ``read() -> bytes``."""
        while not self.stop:
            r, _, _ = select.select([self.sock, fd], [], [], 0.05)
            if self.sock in r:
                data, self.emu_addr = self.sock.recvfrom(65535)
                write(data)
                self.to_stream += 1
            if fd in r:
                chunk = read()
                if not chunk:
                    return
                for msg in self.parser.parse_buffer(chunk) or []:
                    if self.emu_addr is not None and msg.get_type() != "BAD_DATA":
                        self.sock.sendto(bytes(msg.get_msgbuf()), self.emu_addr)
                        self.to_udp += 1

    def close(self) -> None:
        self.stop = True
        self.join(2.0)
        self.sock.close()


class PtyRelay(Relay):
    """A pseudo-terminal: the loop opens its slave side (``device``) as it would open a UART."""

    def __init__(self, port: int) -> None:
        super().__init__(port)
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.device = os.ttyname(self.slave)

    def run(self) -> None:
        self.relay(self.master, lambda b: os.write(self.master, b), lambda: os.read(self.master, 4096))

    def close(self) -> None:
        super().close()
        os.close(self.master)
        os.close(self.slave)


class TcpRelay(Relay):
    """A TCP server on 127.0.0.1 (the autopilot's side of ``tcp:HOST:PORT``, as ArduPilot SITL's serial 0)."""

    def __init__(self, port: int) -> None:
        super().__init__(port)
        self.server = socket.create_server(("127.0.0.1", 0))
        self.server.settimeout(20.0)
        self.device = f"127.0.0.1:{self.server.getsockname()[1]}"

    def run(self) -> None:
        conn, _ = self.server.accept()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # small packets leave at once, as on SITL
        with conn:
            self.relay(conn.fileno(), conn.sendall, lambda: conn.recv(4096))

    def close(self) -> None:
        super().close()
        self.server.close()


@pytest.mark.parametrize(("kind", "url"), [("serial", "serial:{}:921600"), ("tcp", "tcp:{}")])
def test_fly_over_a_serial_line_and_tcp(tmp_path: Path, kind: str, url: str) -> None:
    port = free_udp_port()
    relay = PtyRelay(port) if kind == "serial" else TcpRelay(port)
    relay.start()
    emu = EmulatorThread("px4", port, lockstep=True, period=0.004).start()
    p = argparse.ArgumentParser()
    configure(p)
    args = p.parse_args(["--scenario", "hover", "--duration", "2", "--no-figures", "--out", str(tmp_path / "f")])
    args.connect, args.trajectory = url.format(relay.device), None
    try:
        m, folder = fly(
            args, lockstep=True, truth_probe=emu.truth, quiet=True, on_reference_start=emu.set_reference_start
        )
    finally:
        summary = emu.stop()
        relay.close()
    assert m["flight"]["ended_by"] == "completed", m["flight"]
    assert m["max"]["e_z"] < 0.05 and m["loop"]["ticks"] >= 2 * 250 * 0.99
    assert m["link"]["bad_data"] == 0
    assert summary["counters"]["setpoints_accepted"] >= m["loop"]["ticks"]
    assert summary["mode"] == "AUTO.LOITER" and summary["armed"]
    assert relay.to_stream > 1000 and relay.to_udp > 500
    assert (folder / "flight.tlog").stat().st_size > 10_000
