"""``slung fly --connect serial:DEVICE:BAUD``, the companion computer's usual link to the autopilot's TELEM port.

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

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from offboard.demo_cli import EmulatorThread, configure, free_udp_port
from offboard.fly_cli import fly


class PtyRelay(threading.Thread):
    """pty master <-> UDP socket bound on 127.0.0.1:``port`` (where the emulator sends)."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.device = os.ttyname(self.slave)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.emu_addr: tuple[str, int] | None = None
        self.parser = mavutil.mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.to_serial = self.to_udp = 0
        self.stop = False

    def run(self) -> None:
        while not self.stop:
            r, _, _ = select.select([self.sock, self.master], [], [], 0.05)
            if self.sock in r:
                data, self.emu_addr = self.sock.recvfrom(65535)
                os.write(self.master, data)
                self.to_serial += 1
            if self.master in r:
                try:
                    chunk = os.read(self.master, 4096)
                except OSError:
                    return
                for msg in self.parser.parse_buffer(chunk) or []:
                    if self.emu_addr is not None and msg.get_type() != "BAD_DATA":
                        self.sock.sendto(bytes(msg.get_msgbuf()), self.emu_addr)
                        self.to_udp += 1

    def close(self) -> None:
        self.stop = True
        self.join(2.0)
        self.sock.close()
        os.close(self.master)
        os.close(self.slave)


def test_fly_over_a_serial_line(tmp_path: Path) -> None:
    port = free_udp_port()
    relay = PtyRelay(port)
    relay.start()
    emu = EmulatorThread("px4", port, lockstep=True, period=0.004, vehicle=None, attitude_model="rigid",
                         noise=0.0, loss=0.0, tlog=None).start()
    p = argparse.ArgumentParser()
    configure(p)
    args = p.parse_args(["--scenario", "hover", "--duration", "2", "--no-figures", "--out", str(tmp_path / "f")])
    args.connect, args.trajectory = f"serial:{relay.device}:921600", None
    try:
        m, folder = fly(args, lockstep=True, truth_probe=emu.truth, quiet=True,
                        on_reference_start=emu.set_reference_start)
    finally:
        summary = emu.stop()
        relay.close()
    assert m["flight"]["ended_by"] == "completed", m["flight"]
    assert m["max"]["e_z"] < 0.05 and m["loop"]["ticks"] >= 2 * 250 * 0.99
    assert m["link"]["bad_data"] == 0
    assert summary["counters"]["setpoints_accepted"] >= m["loop"]["ticks"]
    assert summary["mode"] == "AUTO.LOITER" and summary["armed"]
    assert relay.to_serial > 1000 and relay.to_udp > 500
    assert (folder / "flight.tlog").stat().st_size > 10_000
