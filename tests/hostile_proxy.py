"""A hostile UDP link between a MAVLink client and an autopilot, independent of slung's code: it knows nothing
of MAVLink beyond "datagrams", and runs as its own process (``python tests/hostile_proxy.py ...``) so that its
timing does not share the flight loop's interpreter.

    client (slung fly, udpin:127.0.0.1:CLIENT) <-> proxy 127.0.0.1:LISTEN <-> autopilot (udpout to LISTEN)

The autopilot sends to LISTEN (its address is learnt from its first datagram); everything it sends is forwarded to
CLIENT and everything CLIENT sends back is forwarded to the autopilot, each datagram on its own:

- ``--delay S``: one-way delay added in each direction, s;
- ``--jitter S``: plus a uniform 0..S extra delay per datagram (order kept per direction unless ``--reorder``);
- ``--loss P``: each datagram dropped with probability P;
- ``--duplicate P``: each datagram sent twice with probability P (the copy 0..1 ms later);
- ``--foreign P``: with probability P a copy of an autopilot datagram also reaches CLIENT from another, fresh
  source port (a second sender on the link).

Lockstep (``--lockstep-step S``, the emulator's lockstep period): the emulator advances one period per setpoint
and ends each period with a SYSTEM_TIME marker, so a delay in wall time means nothing to the vehicle. In this mode
the delays are counted in vehicle periods instead: the vehicle's datagrams are held for ``round(delay / S)`` (plus
a uniform ``0..round(jitter / S)``, order kept) markers, the markers themselves pass at once (the client's clock);
the client's datagrams go through a delay line of ``round(delay / S)`` setpoints (each setpoint sent releases the
one sent that many setpoints earlier, with what was sent between them). The only MAVLink the proxy reads is the
frame header's message id (SYSTEM_TIME 2; setpoints 82, 84, 139). When the vehicle free-runs (no marker for
``--free-run-after`` s, default 1 s: the emulator's own lockstep grace in the tests) or the client sends no setpoint
for as long, the held datagrams go after the delay in wall time. The threshold must not be shorter than the
emulator's grace: a loaded machine stalls a process for a few hundred ms now and then, and a proxy that falls back
to wall time while the emulator is still in lockstep reorders the vehicle's datagrams against its markers (seen on
CI: a 115 ms gap in vehicle time, so the flight ended on telemetry_stale).

Counters are printed as one JSON line on SIGTERM / SIGINT (and written to ``--summary FILE``)."""

from __future__ import annotations

import argparse
import heapq
import json
import random
import select
import signal
import socket
import sys
import time
from typing import Any


class HostileProxy:
    """The proxy's state; :meth:`run` until :attr:`stop` is set."""

    def __init__(self, listen: int, client: int, delay: float, jitter: float, loss: float, duplicate: float,
                 foreign: float, reorder: bool, seed: int, step: float = 0.0,
                 free_run_after: float = 1.0) -> None:  # fmt: skip
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        self.sock.bind(("127.0.0.1", listen))
        self.sock.setblocking(False)
        self.client = ("127.0.0.1", client)
        self.autopilot: tuple[str, int] | None = None
        self.delay, self.jitter, self.loss, self.dup, self.foreign = delay, jitter, loss, duplicate, foreign
        self.reorder = reorder
        self.rng = random.Random(seed)
        self.queue: list[tuple[float, int, bytes, tuple[str, int], bool]] = []
        self.last_release = {"up": 0.0, "down": 0.0}
        self.seq = 0
        self.stop = False
        self.counts = {"to_client": 0, "to_autopilot": 0, "dropped": 0, "duplicated": 0, "foreign": 0, "markers": 0}
        # lockstep mode (module docstring)
        self.step = step
        self.free_run_after = free_run_after
        self.n_delay = round(delay / step) if step > 0 else 0
        self.n_jitter = round(jitter / step) if step > 0 else 0
        self.markers = 0
        self.last_marker_wall = -1.0
        self.last_setpoint_wall = -1.0
        self.down_held: list[tuple[int, int, bytes]] = []  # (release marker count, seq, datagram)
        self.last_down_release = 0
        self.up_line: list[tuple[bool, bytes]] = []  # (is setpoint, datagram), oldest first

    def _schedule(self, data: bytes, dest: tuple[str, int], direction: str, foreign: bool = False) -> None:
        now = time.monotonic()
        release = now + self.delay + (self.rng.random() * self.jitter if self.jitter > 0 else 0.0)
        if not self.reorder:
            release = max(release, self.last_release[direction])
            self.last_release[direction] = release
        heapq.heappush(self.queue, (release, self.seq, data, dest, foreign))
        self.seq += 1

    def _lockstep_down(self, data: bytes) -> None:
        now = time.monotonic()
        if _msgid(data) == 2:  # SYSTEM_TIME: the end of a vehicle period
            self.markers += 1
            self.counts["markers"] += 1
            self.last_marker_wall = now
            held = self.down_held
            while held and held[0][0] <= self.markers:
                self._send(heapq.heappop(held)[2], self.client)
            self._send(data, self.client)
            return
        if now - self.last_marker_wall > self.free_run_after:  # free-running vehicle: wall-time delay
            self._schedule(data, self.client, "down")
            return
        release = self.markers + self.n_delay + (self.rng.randint(0, self.n_jitter) if self.n_jitter else 0)
        release = max(release, self.last_down_release)
        self.last_down_release = release
        heapq.heappush(self.down_held, (release, self.seq, data))
        self.seq += 1

    def _lockstep_up(self, data: bytes) -> None:
        assert self.autopilot is not None
        is_sp = _msgid(data) in (82, 84, 139)
        if is_sp:
            self.last_setpoint_wall = time.monotonic()
        self.up_line.append((is_sp, data))
        line = self.up_line
        while sum(1 for sp, _ in line if sp) > self.n_delay:
            while line:
                sp, d = line.pop(0)
                self._send(d, self.autopilot)
                if sp:
                    break

    def _send(self, data: bytes, dest: tuple[str, int]) -> None:
        try:
            self.sock.sendto(data, dest)
            self.counts["to_client" if dest == self.client else "to_autopilot"] += 1
        except OSError:
            self.counts["dropped"] += 1

    def _lockstep_flush(self) -> None:
        """Free-run fallbacks (module docstring)."""
        now = time.monotonic()
        if self.up_line and now - self.last_setpoint_wall > self.free_run_after and self.autopilot is not None:
            for _, d in self.up_line:
                self._schedule(d, self.autopilot, "up")
            self.up_line.clear()
        if self.down_held and now - self.last_marker_wall > self.free_run_after:
            for _, _, d in sorted(self.down_held):
                self._schedule(d, self.client, "down")
            self.down_held.clear()

    def _incoming(self, data: bytes, addr: tuple[str, int]) -> None:
        if addr == self.client:
            dest, direction = self.autopilot, "up"
        else:
            self.autopilot = self.autopilot or addr
            if addr != self.autopilot:
                return
            dest, direction = self.client, "down"
        if dest is None:
            return
        if self.loss > 0 and self.rng.random() < self.loss:
            self.counts["dropped"] += 1
            return
        if self.step > 0:
            (self._lockstep_down if direction == "down" else self._lockstep_up)(data)
            return
        self._schedule(data, dest, direction)
        if self.dup > 0 and self.rng.random() < self.dup:
            self.counts["duplicated"] += 1
            self._schedule(data, dest, direction)
        if direction == "down" and self.foreign > 0 and self.rng.random() < self.foreign:
            self._schedule(data, dest, direction, foreign=True)

    def _release_due(self) -> None:
        now = time.monotonic()
        q = self.queue
        while q and q[0][0] <= now:
            _, _, data, dest, foreign = heapq.heappop(q)
            try:
                if foreign:
                    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                        s.sendto(data, dest)
                    self.counts["foreign"] += 1
                else:
                    self.sock.sendto(data, dest)
                    self.counts["to_client" if dest == self.client else "to_autopilot"] += 1
            except OSError:
                self.counts["dropped"] += 1

    def run(self) -> None:
        while not self.stop:
            timeout = 0.05
            if self.queue:
                timeout = max(0.0, min(timeout, self.queue[0][0] - time.monotonic()))
            r, _, _ = select.select([self.sock], [], [], timeout)
            if r:
                for _ in range(256):
                    try:
                        data, addr = self.sock.recvfrom(65535)
                    except (BlockingIOError, InterruptedError):
                        break
                    except OSError:
                        break
                    self._incoming(data, addr)
            self._release_due()
            if self.step > 0:
                self._lockstep_flush()


def _msgid(data: bytes) -> int:
    """The message id of a datagram's first MAVLink frame (-1 if it is not one)."""
    if len(data) >= 10 and data[0] == 0xFD:
        return data[7] | (data[8] << 8) | (data[9] << 16)
    if len(data) >= 6 and data[0] == 0xFE:
        return data[5]
    return -1


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--listen", type=int, required=True)
    p.add_argument("--client", type=int, required=True)
    p.add_argument("--delay", type=float, default=0.0)
    p.add_argument("--jitter", type=float, default=0.0)
    p.add_argument("--loss", type=float, default=0.0)
    p.add_argument("--duplicate", type=float, default=0.0)
    p.add_argument("--foreign", type=float, default=0.0)
    p.add_argument("--reorder", action="store_true")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--lockstep-step", type=float, default=0.0, metavar="S")
    p.add_argument("--free-run-after", type=float, default=1.0, metavar="S")
    p.add_argument("--summary")
    a = p.parse_args(argv)
    proxy = HostileProxy(
        a.listen,
        a.client,
        a.delay,
        a.jitter,
        a.loss,
        a.duplicate,
        a.foreign,
        a.reorder,
        a.seed,
        a.lockstep_step,
        a.free_run_after,
    )

    def _stop(signum: int, frame: Any) -> None:
        proxy.stop = True

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    print("ready", flush=True)
    proxy.run()
    line = json.dumps(proxy.counts)
    if a.summary:
        with open(a.summary, "w", encoding="utf-8") as f:
            f.write(line + "\n")
    print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
