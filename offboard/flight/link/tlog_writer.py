"""The flight's tlog (QGroundControl's format: an 8-byte big-endian microsecond timestamp before each raw MAVLink
packet), written as packets go in and out and flushed as written (``offboard.flight.link.connection``)."""

from __future__ import annotations

import contextlib
import logging
import os
import struct
import time

from estimators.errors import UserError

log = logging.getLogger(__name__)


class TlogWriter:
    """QGC-format tlog: ``>Q`` microseconds since the epoch + raw packet per record, unbuffered.

    A write that fails (disk full, a removed USB stick, an I/O error) stops the logging, not the flight: the
    writer closes the file, keeps the reason in :attr:`failure` (the loop reports it as a warning) and ignores
    every later record. The log is then complete up to the last record written."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        try:
            self._fh = open(path, "wb", buffering=0)  # noqa: SIM115 - closed by close()
        except OSError as exc:
            raise UserError(f"cannot open the tlog {path}: {exc.strerror or exc}") from None
        self.path = str(path)
        self.records = 0
        #: why logging stopped (one line), None while it works
        self.failure: str | None = None

    def write(self, packet: bytes, wall_time: float | None = None) -> None:
        """Append one packet stamped with ``wall_time`` (s since the epoch; now if None)."""
        if self.failure is not None:
            return
        us = int((time.time() if wall_time is None else wall_time) * 1e6) & ~3
        try:
            self._fh.write(struct.pack(">Q", us) + packet)
        except (OSError, ValueError) as exc:  # ValueError: the file was closed under us
            self.failure = (
                f"tlog {self.path}: writing stopped after {self.records} records: "
                f"{getattr(exc, 'strerror', None) or exc}"
            )
            with contextlib.suppress(OSError):
                self._fh.close()
            log.warning("output stopped: %s (the flight goes on)", self.failure)  # once: later records are ignored
            return
        self.records += 1

    def close(self) -> None:
        """Close the file (idempotent)."""
        if not self._fh.closed:
            self._fh.close()


__all__ = ["TlogWriter"]
