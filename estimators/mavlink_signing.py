"""MAVLink 2 message signing shared by the flight side and the emulator: the key, the check order, timestamps.

Check before you store. pymavlink's ``MAVLink.check_signature`` (2.4.x) records the packet's timestamp for its
stream (link id, system, component) BEFORE it verifies the signature. One forged packet on the genuine stream
with a timestamp near 2^48 (any bytes for the signature) is refused, but leaves that stream's timestamp at 2^48,
so every later correctly signed packet of the stream is refused as a replay: a one-packet denial of service
(write-up: ``docs/deploy.md``, "MAVLink signing"). :func:`install_checked_signing` puts the signature check in
front of pymavlink's own: a packet whose signature does not verify is refused without touching any timestamp;
one that verifies then goes through pymavlink's replay and new-stream rules unchanged.

Timestamps: units of 10 us since 2015-01-01 00:00 UTC (the MAVLink 2 signing specification). A sender's
timestamp must never go backwards for a link id, so :func:`next_timestamp` starts a new session above both the
clock and the last timestamp persisted by the previous one (a companion computer without a real-time clock
boots at 1970).
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path
from typing import Any

from estimators.errors import UserError

SIGNING_EPOCH_UNIX_S = 1420070400  # 2015-01-01 00:00 UTC
TIMESTAMP_UNITS_PER_S = 100_000  # 10 us


def parse_key(text: str) -> bytes:
    """A 32-byte key from ``64 hex digits`` or ``@FILE`` (a file holding the 64 hex digits, or the 32 raw bytes);
    UserError (one line) otherwise. The key is never echoed."""
    raw = text.strip()
    if raw.startswith("@"):
        path = Path(raw[1:])
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise UserError(f"cannot read the signing key file {path}: {exc.strerror or exc}") from None
        if len(data) == 32:
            return data
        try:
            raw = data.decode("ascii").strip()
        except UnicodeDecodeError:
            raise UserError(f"signing key file {path}: expected 64 hex digits or 32 raw bytes") from None
    try:
        key = bytes.fromhex(raw)
    except ValueError:
        raise UserError("signing key: expected 64 hex digits (32 bytes) or @FILE") from None
    if len(key) != 32:
        raise UserError(f"signing key: expected 32 bytes (64 hex digits), got {len(key)} bytes")
    return key


def signature_ok(key: bytes, msgbuf: bytes | bytearray) -> bool:
    """Whether a signed MAVLink 2 frame's 6-byte signature is the key's (SHA-256 over key + frame up to it)."""
    h = hashlib.sha256()
    h.update(key)
    h.update(msgbuf[:-6])
    return h.digest()[:6] == bytes(msgbuf[-6:])


def install_checked_signing(mav: Any) -> None:
    """Make ``mav`` (a pymavlink ``MAVLink`` object with signing set up) verify a frame's signature before
    pymavlink's timestamp bookkeeping sees it (module docstring). Idempotent."""
    if getattr(mav, "_slung_checked_signing", False):
        return
    original = mav.check_signature

    def check_signature(msgbuf: bytearray, src_system: int, src_component: int) -> bool:
        key = mav.signing.secret_key
        if key is not None and not signature_ok(key, msgbuf):
            return False  # pymavlink counts it (signing.badsig_count) and refuses the frame
        return bool(original(msgbuf, src_system, src_component))

    mav.check_signature = check_signature
    mav._slung_checked_signing = True


def clock_timestamp(unix_s: float | None = None) -> int:
    """The signing timestamp of a wall-clock time (now if None), 10 us units since 2015-01-01."""
    t = time.time() if unix_s is None else unix_s
    return int(max(t - SIGNING_EPOCH_UNIX_S, 0.0) * TIMESTAMP_UNITS_PER_S)


def load_timestamp(path: Path) -> int:
    """The last timestamp a previous session persisted in ``path`` (0 if none or unreadable)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        return int(data["timestamp"])
    except (OSError, ValueError, KeyError, TypeError):
        return 0


def next_timestamp(path: Path | None) -> int:
    """The first timestamp of a new session: above the clock and above the last persisted one."""
    last = load_timestamp(path) if path is not None else 0
    return max(clock_timestamp(), last + 1)


def save_timestamp(path: Path, timestamp: int, link_id: int) -> str | None:
    """Persist the session's last timestamp (atomic replace); a one-line warning if it cannot be written."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(json.dumps({"timestamp": int(timestamp), "link_id": int(link_id)}) + "\n", encoding="utf-8")
        tmp.replace(path)
    except OSError as exc:
        return f"could not persist the signing timestamp to {path}: {exc.strerror or exc}"
    return None


__all__ = [
    "clock_timestamp",
    "install_checked_signing",
    "load_timestamp",
    "next_timestamp",
    "parse_key",
    "save_timestamp",
    "signature_ok",
]
