"""The emulator's MAVLink link: UDP sockets, fault injection (loss, latency, jitter), framing with counters, tlog.

Connection strings (a subset of pymavlink's, parsed here because the emulator needs the raw datagrams):

- ``udpout:HOST:PORT`` (default ``udpout:127.0.0.1:14540``, like PX4 SITL's offboard link): bind an ephemeral
  local port, send to HOST:PORT, and also answer every address that sends us a valid MAVLink packet;
- ``udpin:HOST:PORT`` / ``udp:HOST:PORT``: bind HOST:PORT and answer every address that talks to us.

Only 127.0.0.1 / localhost / 0.0.0.0 style addresses make sense for tests, but any address works.

Framing (per datagram; a datagram never continues into the next): bytes before a start marker (0xFD v2,
0xFE v1) count as garbage; a frame whose declared length runs past the end of the datagram is *truncated*;
a complete frame goes to pymavlink's ``decode`` which checks the CRC, the signature and unpacks the payload.
Each outcome has its own counter (:class:`RxCounters`).

Faults are applied in *simulation* time so that lockstep runs stay deterministic: an outgoing packet created at
sim time t leaves at ``t + latency + U(0, jitter)`` (order kept) unless dropped with probability ``loss_out``;
an incoming packet is dropped with probability ``loss_in`` or delayed the same way before it is handled.

tlog (QGroundControl / MAVProxy format): for every packet sent by the autopilot (before link faults) and every
received packet that passed the CRC check, ``uint64 big-endian microseconds since the Unix epoch`` (wall clock,
low two bits cleared as pymavlink does) followed by the raw packet; each record is written with one ``write`` on
an unbuffered file, so the log is complete up to the last packet even if the process is killed.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import os
import socket
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimators.errors import UserError

DEFAULT_URL = "udpout:127.0.0.1:14540"
MAX_PEERS = 8


@dataclass
class RxCounters:
    """What the link saw coming in (all counts since start)."""

    datagrams: int = 0  # UDP datagrams received (before fault injection)
    dropped_in: int = 0  # datagrams dropped by the injected incoming loss
    packets_ok: int = 0  # frames that decoded and passed signing (handed to the autopilot)
    garbage_bytes: int = 0  # bytes outside any frame
    garbage_datagrams: int = 0  # datagrams without a single frame start
    truncated: int = 0  # frames cut short by the end of the datagram
    bad_crc: int = 0  # frames with a wrong checksum
    unknown_msgid: int = 0  # frames with a message id the dialect does not know
    malformed: int = 0  # frames that failed to unpack, or setpoints with invalid values (NaN, bad quaternion)
    unsigned_rejected: int = 0  # unsigned frames refused because signing is on
    bad_signature: int = 0  # signed frames whose signature / timestamp did not verify
    foreign_target: int = 0  # valid messages addressed to another system (ignored)

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dict (for the JSON summary)."""
        return dataclasses.asdict(self)


@dataclass
class LinkFaults:
    """Injected link faults; times in seconds (simulation time), probabilities 0..1."""

    loss_in: float = 0.0
    loss_out: float = 0.0
    latency: float = 0.0
    jitter: float = 0.0
    seed: int = 0

    def validate(self) -> None:
        """Raise UserError on out-of-range values."""
        for name in ("loss_in", "loss_out"):
            v = getattr(self, name)
            if not (0.0 <= v <= 1.0):
                raise UserError(f"--{name.replace('_', '-')} must be a probability in [0, 1], got {v!r}")
        for name in ("latency", "jitter"):
            v = getattr(self, name)
            if not (v >= 0.0 and v < 10.0):
                raise UserError(f"--{name} must be in [0, 10) s, got {v!r}")

    @property
    def active(self) -> bool:
        """True if any fault is configured."""
        return self.loss_in > 0 or self.loss_out > 0 or self.latency > 0 or self.jitter > 0


def parse_url(url: str) -> tuple[str, str, int]:
    """``udpout:HOST:PORT`` / ``udpin:HOST:PORT`` / ``udp:HOST:PORT`` -> (kind, host, port); UserError otherwise."""
    parts = url.split(":")
    if len(parts) != 3 or parts[0] not in ("udpout", "udpin", "udp"):
        raise UserError(f"unsupported --mavlink {url!r}: expected udpout:HOST:PORT or udpin:HOST:PORT")
    kind = "udpin" if parts[0] == "udp" else parts[0]
    try:
        port = int(parts[2])
    except ValueError:
        raise UserError(f"bad port in --mavlink {url!r}") from None
    if not (0 <= port <= 65535) or (kind == "udpout" and port == 0):
        raise UserError(f"bad port in --mavlink {url!r}")
    return kind, parts[1] or "0.0.0.0", port


class TlogWriter:
    """Appends ``[uint64 BE usec][packet]`` records, one unbuffered write each."""

    def __init__(self, path: str) -> None:
        try:
            self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        except OSError as exc:
            raise UserError(f"cannot open tlog {path}: {exc.strerror}") from None
        self.records = 0

    def write(self, packet: bytes) -> None:
        """Log one raw packet with the current wall-clock time."""
        usec = int(time.time() * 1e6) & ~3
        os.write(self._fd, struct.pack(">Q", usec) + bytes(packet))
        self.records += 1

    def close(self) -> None:
        """Close the file."""
        with contextlib.suppress(OSError):
            os.close(self._fd)


class UdpEndpoint:
    """One UDP socket and the set of peers it sends to."""

    def __init__(self, url: str) -> None:
        kind, host, port = parse_url(url)
        self.url = url
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 * 1024 * 1024)
        self.peers: list[tuple[str, int]] = []
        try:
            if kind == "udpout":
                self.sock.bind(("127.0.0.1" if host in ("127.0.0.1", "localhost") else "", 0))
                self.peers.append((socket.gethostbyname(host), port))
            else:
                self.sock.bind((host, port))
        except OSError as exc:
            raise UserError(f"cannot open {url}: {exc.strerror}") from None
        self.sock.setblocking(False)
        self.send_errors = 0

    @property
    def local_port(self) -> int:
        """The bound local UDP port."""
        return self.sock.getsockname()[1]

    def add_peer(self, addr: tuple[str, int]) -> None:
        """Remember an address that sent us a valid packet (answer whoever talks to us)."""
        if addr not in self.peers:
            if len(self.peers) >= MAX_PEERS:
                self.peers.pop(1 if len(self.peers) > 1 else 0)
            self.peers.append(addr)

    def sendto_all(self, data: bytes) -> None:
        """Send one datagram to every peer; transient socket errors are counted, never raised."""
        for p in self.peers:
            try:
                self.sock.sendto(data, p)
            except OSError:
                self.send_errors += 1

    def close(self) -> None:
        """Close the socket."""
        self.sock.close()


class Link:
    """All endpoints + fault injection + tlog + framing. The autopilot calls :meth:`write` for each packet."""

    def __init__(self, urls: list[str], faults: LinkFaults, tlog: str | None = None) -> None:
        faults.validate()
        self.faults = faults
        self.endpoints = [UdpEndpoint(u) for u in (urls or [DEFAULT_URL])]
        self.rng = np.random.default_rng(faults.seed)
        self.tlog = TlogWriter(tlog) if tlog else None
        self.rx = RxCounters()
        self.tx_packets = 0
        self.tx_dropped = 0
        self.now = 0.0  # simulation time, s, set by the clock before each write / poll
        self._out: collections.deque[tuple[float, bytes]] = collections.deque()
        self._in: collections.deque[tuple[float, bytes, UdpEndpoint, tuple[str, int]]] = collections.deque()
        self._faulty = faults.active
        self._last_out = 0.0
        self._last_in = 0.0

    # ---------------------------------------------------------------- sending
    def write(self, buf: bytes) -> None:
        """Called by pymavlink's ``MAVLink.send`` for each packed packet."""
        self.tx_packets += 1
        if self.tlog is not None:
            self.tlog.write(buf)
        if not self._faulty:
            for ep in self.endpoints:
                ep.sendto_all(buf)
            return
        f = self.faults
        if f.loss_out > 0.0 and self.rng.random() < f.loss_out:
            self.tx_dropped += 1
            return
        release = self.now + f.latency + (self.rng.random() * f.jitter if f.jitter > 0.0 else 0.0)
        release = max(release, self._last_out)
        self._last_out = release
        if release <= self.now + 1e-9 and not self._out:  # no delay due: send now (a lockstep client may be
            for ep in self.endpoints:  # waiting for this reply before it sends the next setpoint)
                ep.sendto_all(buf)
            return
        self._out.append((release, bytes(buf)))

    def flush_due(self) -> None:
        """Send the delayed outgoing packets whose release time has come (fault injection only)."""
        out = self._out
        while out and out[0][0] <= self.now + 1e-9:
            _, buf = out.popleft()
            for ep in self.endpoints:
                ep.sendto_all(buf)

    # ---------------------------------------------------------------- receiving
    def fileno_list(self) -> list[socket.socket]:
        """Sockets to wait on."""
        return [ep.sock for ep in self.endpoints]

    def poll(
        self, on_datagram: Callable[[bytes], object] | None = None
    ) -> list[tuple[bytes, UdpEndpoint, tuple[str, int]]]:
        """Read every waiting datagram (non-blocking); returns those that survive the incoming faults now (the
        delayed ones come out of :meth:`due_incoming`). ``on_datagram``: called with each datagram as it is read,
        before the faults (the lockstep emulator counts the setpoints sent, whatever the link then does to them)."""
        got: list[tuple[bytes, UdpEndpoint, tuple[str, int]]] = []
        f = self.faults
        for ep in self.endpoints:
            for _ in range(4096):
                try:
                    data, addr = ep.sock.recvfrom(65535)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    break
                self.rx.datagrams += 1
                if on_datagram is not None:
                    on_datagram(data)
                if not self._faulty:
                    got.append((data, ep, addr))
                    continue
                if f.loss_in > 0.0 and self.rng.random() < f.loss_in:
                    self.rx.dropped_in += 1
                    continue
                if f.latency > 0.0 or f.jitter > 0.0:
                    rel = self.now + f.latency + (self.rng.random() * f.jitter if f.jitter > 0.0 else 0.0)
                    rel = max(rel, self._last_in)
                    self._last_in = rel
                    self._in.append((rel, data, ep, addr))
                else:
                    got.append((data, ep, addr))
        return got

    def due_incoming(self) -> list[tuple[bytes, UdpEndpoint, tuple[str, int]]]:
        """Delayed incoming datagrams whose delivery time has come."""
        out = []
        q = self._in
        while q and q[0][0] <= self.now + 1e-9:
            _, data, ep, addr = q.popleft()
            out.append((data, ep, addr))
        return out

    def frames(self, data: bytes) -> list[bytes]:
        """Split one datagram into complete frames; counts garbage and truncation."""
        rx = self.rx
        n = len(data)
        i = 0
        frames: list[bytes] = []
        found_start = False
        while i < n:
            j = i
            while j < n and data[j] != 0xFD and data[j] != 0xFE:
                j += 1
            rx.garbage_bytes += j - i
            if j >= n:
                break
            found_start = True
            if data[j] == 0xFD:
                if n - j < 10:
                    rx.truncated += 1
                    break
                total = 12 + data[j + 1] + (13 if data[j + 2] & 0x01 else 0)
            else:
                if n - j < 6:
                    rx.truncated += 1
                    break
                total = 8 + data[j + 1]
            if j + total > n:
                rx.truncated += 1
                break
            frames.append(data[j : j + total])
            i = j + total
        if not found_start:
            rx.garbage_datagrams += 1
        return frames

    def log_received(self, frame: bytes) -> None:
        """tlog a received packet that passed the CRC check."""
        if self.tlog is not None:
            self.tlog.write(frame)

    def close(self) -> None:
        """Close sockets and the tlog."""
        for ep in self.endpoints:
            ep.close()
        if self.tlog is not None:
            self.tlog.close()

    def summary(self) -> dict[str, Any]:
        """Counters for the final report."""
        return {
            "rx": self.rx.as_dict(),
            "tx_packets": self.tx_packets,
            "tx_dropped": self.tx_dropped,
            "tx_send_errors": sum(ep.send_errors for ep in self.endpoints),
            "tlog_records": self.tlog.records if self.tlog else 0,
            "local_ports": [ep.local_port for ep in self.endpoints],
        }
