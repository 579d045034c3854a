"""Robust reader for MAVLink telemetry logs (``.tlog``: QGroundControl, MAVProxy, pymavlink, ``slung``).

Format: a sequence of records ``[uint64 big-endian timestamp, us since the Unix epoch][one MAVLink packet]``.
The timestamp is the LOGGER's receive time (its two low bits are pymavlink's link index), not the vehicle's:
dynamics must use the messages' own ``time_boot_ms`` / ``time_usec``. Packets are MAVLink 1 (STX 0xFE,
8 bytes of framing) or MAVLink 2 (STX 0xFD, 12 bytes of framing, +13 when signed).

Robustness (never fatal, everything counted in :class:`TlogStats`):

- every packet of a known message id is validated by pymavlink's own parser, CRC_EXTRA included; a packet
  whose framing is intact but whose CRC fails is counted in ``bad_crc`` and skipped;
- a packet of an id the dialect (``ardupilotmega``, a superset of ``common``) does not know cannot be
  CRC-checked: it is accepted (counted in ``unknown_ids``, not yielded) only when the next record starts right
  after it (or the file ends there);
- anything else is garbage: the reader resynchronizes on the next position holding a plausible timestamp
  (within :data:`RESYNC_WINDOW_US` of the last good one), an STX byte and a packet that passes the CRC check;
  the skipped bytes are counted in ``garbage_bytes`` and each such run in ``resyncs``;
- a final packet cut short by the end of the file is counted in ``truncated`` and ignored.

Use::

    reader = TlogReader.from_path("flight.tlog")
    for logger_time_s, msg in reader:      # msg: a pymavlink message (msg._timestamp = logger_time_s)
        ...
    print(reader.stats)
"""

from __future__ import annotations

import os
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as dialect

from estimators.errors import UserError

STX_V1 = 0xFE
STX_V2 = 0xFD
#: a resynchronization candidate's timestamp must lie within this distance of the last good one (us)
RESYNC_WINDOW_US = 24 * 3600 * 1_000_000
#: without a previous good timestamp, candidates must lie between 2000-01-01 and 2100-01-01 (us since epoch)
EPOCH_MIN_US = 946_684_800 * 1_000_000
EPOCH_MAX_US = 4_102_444_800 * 1_000_000
_SIGNED = 0x01
_U16 = struct.Struct("<H")
_CRC = getattr(dialect, "mcrf4xx", None)  # fastcrc's CRC-16/MCRF4XX, which pymavlink's x25crc uses when installed


class _MsgSpec:
    """What :meth:`TlogReader._decode` needs of one message class, computed once per message id: per constructor
    argument (pymavlink's ``orders``) the index of its first unpacked value, its length and its kind (0 a number,
    1 an array -> list, 2 a string -> NUL-stripped bytes), exactly as ``MAVLink.decode`` builds them."""

    __slots__ = ("cls", "extra", "plain", "size", "slots", "unpack")

    def __init__(self, cls: Any) -> None:
        self.cls = cls
        self.extra = bytes((cls.crc_extra,))
        self.unpack = cls.unpacker.unpack
        self.size = cls.unpacker.size
        lengths = cls.lengths
        sample = cls.unpacker.unpack(bytes(self.size))  # the unpacked types depend on the format only
        slots = []
        for order in cls.orders:
            tip, n = sum(lengths[:order]), lengths[order]
            kind = 2 if isinstance(sample[tip], bytes) else 0 if n == 1 else 1
            slots.append((tip, n, kind))
        self.slots = tuple(slots)
        #: no arrays and no strings: the arguments are the unpacked values reordered
        self.plain = tuple(tip for tip, _, kind in slots) if all(k == 0 for _, _, k in slots) else None


_SPECS: dict[int, _MsgSpec] = {}


@dataclass
class TlogStats:
    """What the reader met. packets: packets yielded (known ids, valid CRC); bad_crc: framed packets whose CRC
    failed; garbage_bytes: bytes skipped while resynchronizing; resyncs: runs of garbage; truncated: 1 when the
    file ends inside a packet; unknown_ids: message id -> count of intact packets the dialect does not know;
    mavlink1 / mavlink2 / signed: yielded packets by protocol; bytes_total: file size."""

    packets: int = 0
    bad_crc: int = 0
    garbage_bytes: int = 0
    resyncs: int = 0
    truncated: int = 0
    unknown_ids: dict[int, int] = field(default_factory=dict)
    mavlink1: int = 0
    mavlink2: int = 0
    signed: int = 0
    bytes_total: int = 0

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready copy (unknown ids as decimal strings)."""
        return {
            "packets": self.packets,
            "bad_crc": self.bad_crc,
            "garbage_bytes": self.garbage_bytes,
            "resyncs": self.resyncs,
            "truncated": self.truncated,
            "unknown_ids": {str(k): v for k, v in sorted(self.unknown_ids.items())},
            "unknown_packets": sum(self.unknown_ids.values()),
            "mavlink1": self.mavlink1,
            "mavlink2": self.mavlink2,
            "signed": self.signed,
            "bytes_total": self.bytes_total,
        }


def _packet_length(buf: bytes, i: int) -> int:
    """Length in bytes of the packet whose STX is at ``buf[i]``, or 0 if the header is not a MAVLink header
    (or -1 when the header itself is cut by the end of ``buf``)."""
    n = len(buf)
    stx = buf[i]
    if stx == STX_V1:
        if i + 2 > n:
            return -1
        return 8 + buf[i + 1]
    if stx == STX_V2:
        if i + 3 > n:
            return -1
        flags = buf[i + 2]
        if flags & ~_SIGNED:
            return 0
        return 12 + buf[i + 1] + (13 if flags & _SIGNED else 0)
    return 0


class TlogReader:
    """Iterate ``(logger_time_s, message)`` over a tlog held in memory; see the module docstring.

    data: the whole file; progress: optional callback receiving the fraction of bytes read (0..1), called
    about every 64 kB.
    """

    def __init__(self, data: bytes, progress: Callable[[float], None] | None = None) -> None:
        self.data = bytes(data)
        self.stats = TlogStats(bytes_total=len(self.data))
        self.progress = progress
        self._mav = dialect.MAVLink(None)
        self._mav.robust_parsing = True

    @classmethod
    def from_path(cls, path: str | os.PathLike[str], progress: Callable[[float], None] | None = None) -> TlogReader:
        """Read the file at ``path``; UserError (one line) when it cannot be read."""
        p = Path(path)
        try:
            data = p.read_bytes()
        except IsADirectoryError:
            raise UserError(f"{p} is a folder, not a .tlog file") from None
        except OSError as exc:
            raise UserError(f"cannot read {p}: {exc.strerror or exc}") from None
        return cls(data, progress)

    # ------------------------------------------------------------------------------------------------------
    def _decode(self, i: int, length: int) -> Any:
        """:meth:`_try_decode` with pymavlink's ``MAVLink.decode`` done here for the common case (an unsigned
        packet of a known id, with fastcrc installed): the same checks (CRC with CRC_EXTRA; the framing length is
        the header's by construction of :func:`_packet_length`), the same payload handling (zero-padded to the
        message size) and the same message object, attribute by attribute, at about 60 % of the cost. Everything
        else goes through pymavlink itself."""
        d = self.data
        if d[i] == STX_V2:
            if d[i + 2] or _CRC is None:  # signed or unknown incompat flags: pymavlink's path
                return self._try_decode(i, length)
            msg_id = d[i + 7] | (d[i + 8] << 8) | (d[i + 9] << 16)
            head = 10
        else:
            msg_id = d[i + 5]
            head = 6
            if _CRC is None:
                return self._try_decode(i, length)
        spec = _SPECS.get(msg_id)
        if spec is None:
            cls = dialect.mavlink_map.get(msg_id)
            if cls is None:
                return "unknown"
            spec = _SPECS[msg_id] = _MsgSpec(cls)
        if dialect.MAVLINK_IGNORE_CRC:
            return self._try_decode(i, length)
        end = i + length - 2
        crc = _U16.unpack_from(d, end)[0]
        if _CRC(spec.extra, _CRC(d[i + 1 : end], 0xFFFF)) != crc:
            return None
        payload = d[i + head : end]
        size = spec.size
        if len(payload) < size:
            payload += bytes(size - len(payload))
        elif len(payload) > size:
            payload = payload[:size]
        t = spec.unpack(payload)
        if spec.plain is not None:
            args = [t[o] for o in spec.plain]
        else:
            args = [
                t[tip] if kind == 0 else list(t[tip : tip + n]) if kind == 1 else t[tip].rstrip(b"\x00")
                for tip, n, kind in spec.slots
            ]
        try:
            m = spec.cls(*args)
        except Exception:
            return self._try_decode(i, length)
        msgbuf = bytearray(d[i : i + length])
        m._signed = False
        m._msgbuf = msgbuf
        m._payload = msgbuf[6:-2]
        m._crc = crc
        if head == 10:
            m._header = dialect.MAVLink_header(msg_id, 0, d[i + 3], d[i + 1], d[i + 4], d[i + 5], d[i + 6])
        else:
            m._header = dialect.MAVLink_header(msg_id, 0, 0, d[i + 1], d[i + 2], d[i + 3], d[i + 4])
        return m

    def _try_decode(self, i: int, length: int) -> Any:
        """The decoded message at ``data[i : i + length]``: a pymavlink message, the string "unknown" for an
        id the dialect does not know, or None when the packet fails pymavlink's checks (CRC, length)."""
        try:
            msg = self._mav.decode(bytearray(self.data[i : i + length]))
        except Exception:  # pymavlink raises MAVError and, on some malformed payloads, struct.error
            return None
        if isinstance(msg, dialect.MAVLink_unknown) or msg.get_type() == "BAD_DATA":
            return "unknown"
        return msg

    def _header_plausible(self, j: int, last_ts: int | None) -> bool:
        """Whether a record could start at ``data[j]``: plausible timestamp and an STX after it."""
        d = self.data
        if j + 9 > len(d):
            return False
        if d[j + 8] != STX_V1 and d[j + 8] != STX_V2:
            return False
        ts = int.from_bytes(d[j : j + 8], "big")
        if last_ts is None:
            return EPOCH_MIN_US <= ts <= EPOCH_MAX_US
        return abs(ts - last_ts) <= RESYNC_WINDOW_US

    def _resync(self, start: int, last_ts: int | None) -> int:
        """Position of the next record (plausible timestamp + STX + packet passing the CRC) at or after
        ``start``, or ``len(data)`` when there is none."""
        d = self.data
        n = len(d)
        pos = start
        while True:
            a = d.find(b"\xfe", pos + 8)
            b = d.find(b"\xfd", pos + 8)
            cands = [c for c in (a, b) if c >= 0]
            if not cands:
                return n
            k = min(cands)
            j = k - 8
            pos = j + 1
            if not self._header_plausible(j, last_ts):
                continue
            length = _packet_length(d, k)
            if length <= 0 or k + length > n:
                continue
            msg = self._try_decode(k, length)
            if msg is None or msg == "unknown":
                continue
            return j

    def __iter__(self) -> Iterator[tuple[float, Any]]:
        d = self.data
        n = len(d)
        st = self.stats
        last_ts: int | None = None
        i = 0
        next_progress = 1 << 16
        in_sync = True
        while i < n:
            if self.progress is not None and i >= next_progress:
                self.progress(i / n)
                next_progress = i + (1 << 16)
            if n - i < 9:
                # fewer bytes than a timestamp + STX: a record cut short (in sync) or trailing garbage
                if in_sync:
                    st.truncated += 1
                else:
                    st.garbage_bytes += n - i
                    st.resyncs += 1
                return
            k = i + 8
            ts = int.from_bytes(d[i:k], "big")
            length = _packet_length(d, k)
            ts_ok = last_ts is None or abs(ts - last_ts) <= RESYNC_WINDOW_US
            if length != 0 and ts_ok:
                if length < 0 or k + length > n:
                    if in_sync:  # the last packet, cut by the end of the file
                        st.truncated += 1
                        return
                else:
                    msg = self._decode(k, length)
                    end = k + length
                    if msg is not None and type(msg) is not str:  # not "unknown"
                        last_ts = ts
                        st.packets += 1
                        if d[k] == STX_V1:
                            st.mavlink1 += 1
                        else:
                            st.mavlink2 += 1
                            if d[k + 2] & _SIGNED:
                                st.signed += 1
                        t = ts * 1e-6
                        msg._timestamp = t
                        msg._link = ts & 0x3
                        i = end
                        in_sync = True
                        yield t, msg
                        continue
                    # intact framing is only believed when the next record starts right after the packet
                    if end == n or self._header_plausible(end, last_ts if last_ts is not None else ts):
                        if msg is None:
                            st.bad_crc += 1
                        else:
                            mid = d[k + 5] if d[k] == STX_V1 else d[k + 7] | (d[k + 8] << 8) | (d[k + 9] << 16)
                            st.unknown_ids[mid] = st.unknown_ids.get(mid, 0) + 1
                        last_ts = ts if last_ts is None else last_ts
                        i = end
                        in_sync = True
                        continue
            # garbage: find the next good record
            j = self._resync(i, last_ts)
            st.garbage_bytes += j - i
            st.resyncs += 1
            in_sync = False
            i = j
        if self.progress is not None:
            self.progress(1.0)


def read_messages(path: str | os.PathLike[str]) -> tuple[list[tuple[float, Any]], TlogStats]:
    """All ``(logger_time_s, message)`` of the tlog at ``path`` and the reader's counters."""
    reader = TlogReader.from_path(path)
    out = list(reader)
    return out, reader.stats


def encode_record(time_us: int, packet: bytes) -> bytes:
    """One tlog record: the 8-byte big-endian timestamp ``time_us`` (us since the epoch) then ``packet``."""
    return int(time_us).to_bytes(8, "big") + bytes(packet)


__all__ = ["RESYNC_WINDOW_US", "TlogReader", "TlogStats", "encode_record", "read_messages"]
