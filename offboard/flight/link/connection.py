"""The pymavlink connection: URL, heartbeat and flavour, commands with acknowledgement, message intervals,
vehicle-time to local-time mapping, and a tlog of every packet in and out.

URLs (pymavlink's forms; ``scheme://`` spellings are accepted too):

- ``udpin:HOST:PORT``  listen on HOST:PORT and answer whoever talks (PX4 SITL offboard: ``udpin:0.0.0.0:14540``);
- ``udpout:HOST:PORT`` send to HOST:PORT (the autopilot listens there);
- ``tcp:HOST:PORT``    connect to a TCP server (ArduPilot SITL ``tcp:127.0.0.1:5760``);
- ``serial:/dev/ttyUSB0:921600`` or ``/dev/ttyUSB0`` with ``baud`` (companion computer on a telemetry port).

Identity: we send as system ``source_system`` (default 255) component 191 (MAV_COMP_ID_ONBOARD_COMPUTER) and a
1 Hz HEARTBEAT of type MAV_TYPE_ONBOARD_CONTROLLER (18), autopilot MAV_AUTOPILOT_INVALID (8).

Flavour: from the autopilot's HEARTBEAT (component 1): ``autopilot`` 12 -> ``"px4"``, 3 -> ``"ardupilot"``;
anything else is refused with a one-line error.

tlog (QGroundControl format): each record is the 8-byte big-endian microseconds since the Unix epoch (low two
bits cleared, as pymavlink does) followed by the raw packet, for every packet received (after the CRC check)
and every packet sent; each record is one ``write`` on an unbuffered file, so the log is complete up to the
last packet even if the process is killed.

Receive side (UDP): the connection reads the datagrams itself (``recvfrom``, then pymavlink's parser with its CRC
and signature checks) so that it knows who sent each one. Until the autopilot's HEARTBEAT is identified it
answers whoever talks (pymavlink's ``udpin``); from then on it talks to that one address only, and datagrams
from any other address are dropped unparsed and counted (``LinkStats.foreign_datagrams``): pymavlink alone
answers every address that ever sent a datagram, so 2 000 datagrams from other ports multiplied every setpoint
by 2 000 sends. One :meth:`MavConnection.poll` handles at most ``READ_BUDGET`` messages; the rest wait in
:attr:`MavConnection.backlog` for the next call (one 60 kB datagram of valid frames stalled the loop 86 ms).

Time: :class:`VehicleClock` keeps ``offset = local - vehicle`` (s). With TIMESYNC answers it takes the offset of
the exchange with the smallest round trip; without them it takes the smallest ``receive time - sample time``
over the telemetry (the least-delayed packet bounds the offset), allowed to creep up by ``drift`` s/s so that a
clock drift is followed.

Why over 500 lines: :class:`MavConnection` is one object, the link's one receive / send path (sockets or serial,
framing, signing, the foreign-sender filter, counters, heartbeat, parameters) over one shared state. The pieces
that stand alone are in ``offboard.flight.link.vehicle_clock`` (the clock) and ``offboard.flight.link.tlog_writer``.
"""

from __future__ import annotations

import contextlib
import os
import socket
import struct
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil

from estimators.errors import UserError
from estimators.mavlink_signing import install_checked_signing, next_timestamp, save_timestamp
from offboard.flight.link.tlog_writer import TlogWriter
from offboard.flight.link.vehicle_clock import VehicleClock

MAV_COMP_ID_ONBOARD_COMPUTER = 191
MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8
FLAVOURS = {12: "px4", 3: "ardupilot"}

MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_RESULT_ACCEPTED = 0

#: messages handled per :meth:`MavConnection.poll` (a 250 Hz tick normally brings 4-6; pymavlink parses one in
#: about 40 us, so the budget bounds a poll to a few milliseconds whatever arrives)
READ_BUDGET = 64


def normalize_url(url: str, baud: int | None = None) -> tuple[str, int]:
    """pymavlink device string and baud rate from a user URL; UserError for what pymavlink cannot open."""
    u = url.strip()
    for scheme in ("udpin", "udpout", "udp", "tcp", "tcpin", "serial"):
        if u.startswith(scheme + "://"):
            u = scheme + ":" + u[len(scheme) + 3 :]
    b = 57600 if baud is None else int(baud)
    if b <= 0:  # pyserial would take a negative rate and fail later, or open the port at an undefined one
        raise UserError(f"bad baud rate {baud}: must be a positive whole number (e.g. 57600 or 921600)")
    if u.startswith("serial:"):
        rest = u[len("serial:") :]
        dev, _, maybe_baud = rest.rpartition(":")
        if dev and maybe_baud.isdigit():
            if int(maybe_baud) <= 0:
                raise UserError(f"bad baud rate in {url!r}: must be a positive whole number (e.g. 921600)")
            return dev, int(maybe_baud)
        return rest, b
    if u.startswith(("udpin:", "udpout:", "udp:", "tcp:", "tcpin:")):
        parts = u.split(":")
        if len(parts) != 3 or not parts[2].isdigit() or not (0 < int(parts[2]) < 65536):
            raise UserError(f"bad connection URL {url!r}: expected e.g. udpin:0.0.0.0:14540 or tcp:127.0.0.1:5760")
        return u, b
    if u.startswith("/dev/") or u.upper().startswith("COM"):
        return u, b
    raise UserError(
        f"bad connection URL {url!r}: expected udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT or "
        "serial:/dev/ttyXXX:BAUD"
    )


#: MAV_PARAM_TYPE of the integer types (UINT8 .. INT32) -> struct format
_INT_PARAM_FORMATS = {1: "<B", 2: "<b", 3: "<H", 4: "<h", 5: "<I", 6: "<i"}


def param_value(raw: float, param_type: int, vehicle: VehicleInfo | None) -> float:
    """A PARAM_VALUE's value as a number: PX4 sends integer parameters bytewise (the integer's bytes in the float
    field, MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE), ArduPilot as the integer converted to a float."""
    fmt = _INT_PARAM_FORMATS.get(int(param_type))
    if fmt is None or vehicle is None or vehicle.flavour != "px4":
        return float(raw)
    packed = struct.pack("<f", raw)
    size = struct.calcsize(fmt)
    return float(struct.unpack(fmt, packed[:size])[0])


@dataclass(frozen=True)
class SigningConfig:
    """MAVLink 2 signing of the link (``estimators/mavlink_signing.py``): the 32-byte key, our link id (0..255),
    and the file where the session's last timestamp is persisted (None: not persisted)."""

    key: bytes
    link_id: int = 1
    state_path: Path | None = None

    def __post_init__(self) -> None:
        if len(self.key) != 32:
            raise UserError(f"signing key: expected 32 bytes, got {len(self.key)}")
        if not 0 <= self.link_id <= 255:
            raise UserError(f"signing link id must be within 0..255, got {self.link_id}")


@dataclass
class VehicleInfo:
    """The autopilot we talk to: ids, flavour (``px4`` / ``ardupilot``), MAV_TYPE, last heartbeat."""

    system: int
    component: int
    flavour: str
    mav_type: int
    base_mode: int = 0
    custom_mode: int = 0
    system_status: int = 0
    last_heartbeat: float = 0.0  # local monotonic time

    @property
    def armed(self) -> bool:
        """SAFETY_ARMED flag of the last heartbeat."""
        return bool(self.base_mode & 128)


@dataclass
class Received:
    """A received message with its local monotonic receive time (s) and, over UDP, the sender's address."""

    msg: Any
    t_local: float
    addr: tuple[str, int] | None = None


@dataclass
class LinkStats:
    """Counters of the link (since open)."""

    received: int = 0
    sent: int = 0
    bad_data: int = 0
    foreign: int = 0
    foreign_acks: int = 0
    foreign_datagrams: int = 0  # UDP datagrams from another address than the autopilot's, dropped unparsed
    #: other systems seen on the autopilot's link (any message, heartbeats included): system id -> messages
    foreign_systems: dict[int, int] = field(default_factory=dict)
    deferred_polls: int = 0  # polls that left messages for the next one (READ_BUDGET reached)
    #: frames refused by the signing check for carrying no signature (pymavlink counts only the bad signatures)
    refused_unsigned: int = 0
    by_type: dict[str, int] = field(default_factory=dict)


class MavConnection:
    """One MAVLink link to one autopilot, single-threaded: call :meth:`poll` often (it never blocks)."""

    def __init__(
        self,
        url: str,
        *,
        baud: int | None = None,
        tlog_path: str | os.PathLike[str] | None = None,
        source_system: int = 255,
        source_component: int = MAV_COMP_ID_ONBOARD_COMPUTER,
        signing: SigningConfig | None = None,
    ) -> None:
        device, b = normalize_url(url, baud)
        try:
            self.conn = mavutil.mavlink_connection(
                device,
                baud=b,
                source_system=source_system,
                source_component=source_component,
                autoreconnect=False,
                robust_parsing=True,
            )
        except Exception as exc:  # pymavlink raises assorted OSError / SerialException types
            raise UserError(f"cannot open {url!r}: {exc}") from None
        self.mav = self.conn.mav
        self.signing = signing
        #: one-line problems of the signing set-up (e.g. the timestamp could not be persisted), for the report
        self.signing_warnings: list[str] = []
        if signing is not None:
            self.conn.setup_signing(
                signing.key,
                sign_outgoing=True,
                allow_unsigned_callback=None,
                initial_timestamp=next_timestamp(signing.state_path),
                link_id=signing.link_id,
            )
            install_checked_signing(self.mav)
        #: the UDP socket when the link is UDP (read here, see the module docstring), else None
        self._udp = self.conn if isinstance(self.conn, mavutil.mavudp) else None
        if self._udp is not None:  # room for a burst (a stalled tick, a flood) instead of silent kernel drops
            with contextlib.suppress(OSError):
                self._udp.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        #: the autopilot's address once its heartbeat is identified (UDP only)
        self.peer: tuple[str, int] | None = None
        #: parsed messages not yet handled (more than READ_BUDGET arrived at once)
        self._backlog: list[tuple[Any, tuple[str, int] | None]] = []
        self._parser_pending = False
        self._parser_addr: tuple[str, int] | None = None
        self.url = url
        self.tlog = TlogWriter(tlog_path) if tlog_path is not None else None
        self.clock = VehicleClock()
        self.stats = LinkStats()
        self.vehicle: VehicleInfo | None = None
        self.acks: dict[int, tuple[int, float]] = {}  # command -> (result, local time)
        self.params: dict[str, float] = {}
        self.statustexts: list[str] = []
        self._timesync_pending: dict[int, float] = {}
        self._last_hb_sent = -1e9
        self._closed = False
        #: called with every batch of received messages, whoever polls (the loop must see all telemetry even
        #: while a management command waits for its acknowledgement)
        self.listener: Any = None

    # ---------------------------------------------------------------------------------------- sending ---
    def send(self, msg: Any, log: bool = True) -> bytes:
        """Pack ``msg`` with our ids and sequence, write it and log it; returns the bytes written.

        ``log=False``: the caller logs the packet itself with :meth:`log_sent` once the time-critical part is over
        (the control loop: the setpoint leaves first, and a slow log write, an SD card that stalls, never delays it).
        """
        buf = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        self.conn.write(buf)
        self.stats.sent += 1
        if log and self.tlog is not None:
            self.tlog.write(buf)
        return buf

    def log_sent(self, buf: bytes, wall_time: float) -> None:
        """Log a packet :meth:`send` wrote with ``log=False``, stamped with ``wall_time`` (s since the epoch: when
        it was written)."""
        if self.tlog is not None:
            self.tlog.write(buf, wall_time)

    def heartbeat(self, now: float, period: float = 1.0) -> None:
        """Send our HEARTBEAT if ``period`` s have passed since the last one (``now``: local monotonic s)."""
        if now - self._last_hb_sent >= period:
            self._last_hb_sent = now
            self.send(self.mav.heartbeat_encode(MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0, 4))

    def command_long(self, command: int, *params: float) -> None:
        """Send COMMAND_LONG to the autopilot (no wait; see :meth:`command`)."""
        v = self._require_vehicle()
        p = list(params) + [0.0] * (7 - len(params))
        self.acks.pop(command, None)
        self.send(self.mav.command_long_encode(v.system, v.component, command, 0, *p[:7]))

    def command(
        self, command: int, *params: float, timeout: float = 0.5, retries: int = 5, idle: Any = None
    ) -> int | None:
        """COMMAND_LONG with acknowledgement: the MAV_RESULT, or None after ``retries`` timeouts.

        idle: called (with no argument) while waiting, e.g. to keep a setpoint stream alive.
        """
        for _ in range(max(1, retries)):
            self.command_long(command, *params)
            t_end = time.monotonic() + timeout
            while time.monotonic() < t_end:
                self.poll()
                if command in self.acks:
                    return self.acks[command][0]
                if idle is not None:
                    idle()
                time.sleep(0.002)
        return None

    def set_message_interval(self, message_id: int, rate_hz: float, idle: Any = None) -> int | None:
        """MAV_CMD_SET_MESSAGE_INTERVAL: ``rate_hz`` > 0 sets the rate, 0 restores the default, < 0 disables."""
        interval = -1.0 if rate_hz < 0 else 0.0 if rate_hz == 0 else 1e6 / rate_hz
        return self.command(MAV_CMD_SET_MESSAGE_INTERVAL, float(message_id), interval, idle=idle)

    def request_timesync(self, now: float) -> None:
        """Send a TIMESYNC request stamped with our local time ``now`` (s)."""
        ns = int(now * 1e9)
        self._timesync_pending[ns] = now
        if len(self._timesync_pending) > 16:
            self._timesync_pending.pop(next(iter(self._timesync_pending)))
        self.send(self.mav.timesync_encode(0, ns))

    def param_set(self, name: str, value: float, param_type: int = 9) -> None:
        """PARAM_SET (no wait; the PARAM_VALUE answer lands in :attr:`params`)."""
        v = self._require_vehicle()
        self.send(self.mav.param_set_encode(v.system, v.component, name.encode("ascii"), float(value), param_type))

    def param_request(self, name: str) -> None:
        """PARAM_REQUEST_READ by name (the answer lands in :attr:`params`)."""
        v = self._require_vehicle()
        self.send(self.mav.param_request_read_encode(v.system, v.component, name.encode("ascii"), -1))

    def param_get(self, name: str, timeout: float = 0.3, retries: int = 3) -> float | None:
        """Read a parameter (blocking up to ``timeout`` x ``retries``); None if the autopilot did not answer."""
        self.params.pop(name, None)
        for _ in range(retries):
            self.param_request(name)
            t_end = time.monotonic() + timeout
            while time.monotonic() < t_end:
                self.poll()
                if name in self.params:
                    return self.params[name]
                time.sleep(0.002)
        return None

    # -------------------------------------------------------------------------------------- receiving ---
    def poll(self) -> list[Received]:
        """Every message waiting on the link (never blocks), after bookkeeping (heartbeat, acks, timesync,
        parameters, tlog). Messages from systems other than the autopilot's are returned too (the decoder
        filters them)."""
        out: list[Received] = []
        conn = self.conn
        udp = self._udp is not None
        if udp:
            self._fill_backlog()
        budget = READ_BUDGET
        while budget > 0:
            addr = None
            if udp:
                if not self._backlog:
                    break
                msg, addr = self._backlog.pop(0)
            else:
                try:
                    msg = conn.recv_msg()
                except Exception:  # a malformed packet: pymavlink raises from the parser in some versions
                    self.stats.bad_data += 1
                    continue
                if msg is None:
                    break
            budget -= 1
            now = time.monotonic()
            kind = msg.get_type()
            if kind == "BAD_DATA":
                self.stats.bad_data += 1
                data = getattr(msg, "data", b"")
                if getattr(msg, "reason", "") == "Invalid signature" and len(data) > 2 and not data[2] & 0x01:
                    self.stats.refused_unsigned += 1
                continue
            self.stats.received += 1
            self.stats.by_type[kind] = self.stats.by_type.get(kind, 0) + 1
            if self.tlog is not None:
                self.tlog.write(msg.get_msgbuf())
            self._bookkeep(msg, kind, now)
            out.append(Received(msg, now, addr))
        if budget == 0 and self.backlog:
            self.stats.deferred_polls += 1
        if out and self.listener is not None:
            self.listener(out)
        return out

    @property
    def backlog(self) -> bool:
        """True when messages already received wait for the next :meth:`poll` (do not block before it)."""
        return bool(self._backlog) or self._parser_pending

    def _fill_backlog(self) -> None:
        """UDP: parse up to READ_BUDGET messages into the backlog: first what the parser still holds, then the
        waiting datagrams from the autopilot's address (any address before it is known); other senders'
        datagrams are counted and dropped unparsed. The parser is fed one frame at a time (``parse_char(b"")``),
        so a datagram of thousands of frames costs one budget per poll, not one long stall."""
        udp = self._udp
        assert udp is not None
        port, backlog = udp.port, self._backlog
        parse = self.mav.parse_char
        while True:
            if self._parser_pending:  # frames of an earlier datagram still in the parser's buffer
                while len(backlog) < READ_BUDGET:
                    try:
                        m = parse(b"")
                    except Exception:  # a malformed packet: pymavlink raises from the parser in some versions
                        self.stats.bad_data += 1
                        continue
                    if m is None:
                        self._parser_pending = False
                        break
                    backlog.append((m, self._parser_addr))
                if self._parser_pending:
                    return
            if len(backlog) >= READ_BUDGET:
                return
            try:
                data, addr = port.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # ECONNREFUSED after an ICMP port-unreachable, and the like: nothing to read now
                return
            peer = self.peer
            if peer is not None and addr != peer:
                self.stats.foreign_datagrams += 1
                continue
            if peer is None and udp.udp_server:  # answer whoever talks, until the autopilot is known
                udp.clients.add(addr)
                udp.clients_last_alive[addr] = time.time()
            self._parser_addr = addr
            try:
                m = parse(data)
            except Exception:
                self.stats.bad_data += 1
                m = None
            if m is not None:
                backlog.append((m, addr))
            self._parser_pending = True  # more frames of this datagram may follow

    def lock_peer(self, addr: tuple[str, int] | None) -> None:
        """UDP: talk to ``addr`` (the autopilot's) only from now on (see the module docstring)."""
        if self._udp is None or addr is None:
            return
        self.peer = addr
        if self._udp.udp_server:
            self._udp.clients = {addr}
            self._udp.clients_last_alive = {addr: time.time()}
        self._backlog = [(m, a) for m, a in self._backlog if a == addr]

    def _bookkeep(self, msg: Any, kind: str, now: float) -> None:
        v = self.vehicle
        src = msg.get_srcSystem()
        # (system 0 is no sender: pymavlink's UNKNOWN_<id> for messages outside its dialect carry it; PX4 sends
        # several such)
        if v is not None and src not in (v.system, 0):
            self.stats.foreign_systems[src] = self.stats.foreign_systems.get(src, 0) + 1
        if kind == "HEARTBEAT":
            comp = msg.get_srcComponent()
            if v is not None and src == v.system and comp == v.component:
                v.base_mode, v.custom_mode = msg.base_mode, msg.custom_mode
                v.system_status, v.last_heartbeat = msg.system_status, now
            return
        if v is not None and src != v.system:
            self.stats.foreign += 1
            return
        if kind == "COMMAND_ACK":
            # an acknowledgement addressed to another sender answers ITS command, not ours (MAVLink 2 extension
            # fields; 0 / 0 when the autopilot leaves them unset)
            ts, tc = getattr(msg, "target_system", 0) or 0, getattr(msg, "target_component", 0) or 0
            if (ts, tc) == (0, 0) or (ts, tc) == (self.mav.srcSystem, self.mav.srcComponent):
                self.acks[msg.command] = (msg.result, now)
            else:
                self.stats.foreign_acks += 1
        elif kind == "TIMESYNC":
            if msg.tc1 != 0 and msg.ts1 in self._timesync_pending:
                sent = self._timesync_pending.pop(msg.ts1)
                self.clock.observe_timesync(msg.tc1 * 1e-9, sent, now)
            elif msg.tc1 == 0:  # the autopilot asks us: answer with our time
                self.send(self.mav.timesync_encode(int(now * 1e9), msg.ts1))
        elif kind == "PARAM_VALUE":
            name = msg.param_id.decode("ascii", "replace") if isinstance(msg.param_id, bytes) else msg.param_id
            self.params[name.rstrip("\x00")] = param_value(msg.param_value, msg.param_type, v)
        elif kind == "STATUSTEXT":
            text = msg.text.decode("ascii", "replace") if isinstance(msg.text, bytes) else str(msg.text)
            self.statustexts.append(text.rstrip("\x00"))

    def wait_heartbeat(self, timeout: float = 10.0, idle: Any = None) -> VehicleInfo:
        """Wait for the autopilot's HEARTBEAT (component 1 preferred) and identify its flavour.

        UserError on timeout or for an autopilot that is neither PX4 nor ArduPilot.
        """
        t_end = time.monotonic() + timeout
        other: str | None = None
        while time.monotonic() < t_end:
            self.heartbeat(time.monotonic())
            for r in self.poll():
                m = r.msg
                if m.get_type() != "HEARTBEAT" or m.autopilot == MAV_AUTOPILOT_INVALID:
                    continue
                flavour = FLAVOURS.get(m.autopilot)
                if flavour is None:
                    other = f"autopilot type {m.autopilot}"
                    continue
                self.vehicle = VehicleInfo(
                    m.get_srcSystem(),
                    m.get_srcComponent(),
                    flavour,
                    m.type,
                    m.base_mode,
                    m.custom_mode,
                    m.system_status,
                    r.t_local,
                )
                # answers must reach the right peer, and only it
                self.conn.target_system = self.vehicle.system
                self.conn.target_component = self.vehicle.component
                self.lock_peer(r.addr)
                return self.vehicle
            if idle is not None:
                idle()
            time.sleep(0.005)
        if other is not None:
            raise UserError(f"{self.url}: the autopilot is neither PX4 (12) nor ArduPilot (3): {other}")
        sg = self.mav.signing if self.signing is not None else None
        unsigned = self.stats.refused_unsigned
        if sg is not None and unsigned > 0:  # something talks, but unsigned: our refusal, not silence
            raise UserError(
                f"no signed autopilot heartbeat on {self.url} within {timeout:g} s: {unsigned} unsigned "
                "packets refused (the autopilot does not sign: give it the key, docs/deploy.md 4a, or fly without "
                "--signing-key)"
            )
        if sg is not None and sg.badsig_count > 0:
            raise UserError(
                f"no signed autopilot heartbeat on {self.url} within {timeout:g} s: {sg.badsig_count} packets refused "
                "for a bad signature (the autopilot signs with another key, or its timestamps are behind ours)"
            )
        raise UserError(f"no autopilot heartbeat on {self.url} within {timeout:g} s")

    def _require_vehicle(self) -> VehicleInfo:
        if self.vehicle is None:
            raise RuntimeError("no autopilot yet: call wait_heartbeat() first")
        return self.vehicle

    def close(self) -> None:
        """Close the socket / port and the tlog (idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            self.conn.close()
        finally:
            if self.tlog is not None:
                self.tlog.close()
            sg = self.signing
            if sg is not None and sg.state_path is not None:
                warning = save_timestamp(sg.state_path, self.mav.signing.timestamp, sg.link_id)
                if warning is not None:
                    self.signing_warnings.append(warning)


__all__ = [
    "FLAVOURS",
    "LinkStats",
    "MavConnection",
    "Received",
    "SigningConfig",
    "TlogWriter",
    "VehicleClock",
    "VehicleInfo",
    "normalize_url",
]
