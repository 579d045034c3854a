"""The run folder's time series (``timeseries_live.slts``, ``timeseries.slts``): a compact columnar file that can be
appended to while it is written and read back up to its last complete block after a crash.

Why this format (docs/usage.md, "Run folders"): a flight's tick log is ~120 float64 columns at 250 Hz. As CSV at
full precision it took 2.2x its binary size (30 MB for the 50 s demo); a table format with a footer (Parquet)
cannot be read until it is closed, so a flight killed mid-way would lose it all. Here the file is a header and a
sequence of self-contained blocks, each a few hundred rows compressed on their own; the flight appends one every
half second (:class:`TableStreamer`), so a SIGKILL loses at most the rows of the last half second, and a reader
keeps every block whose length and CRC are whole. No dependency beyond numpy and the standard library (a
companion computer installs nothing more); ``slung export --csv RUN`` writes CSV for other tools.

Layout (little-endian)::

    b"SLTS1\\n", uint32 n, n bytes of UTF-8 JSON {"columns": [...], "dtype": "<f8", "meta": {...}}
    block*:  b"SLB1", uint32 rows, uint32 payload bytes, uint32 CRC-32 of the payload, payload
    end:     b"SLB1", uint32 0, uint32 0, uint32 0  (written by a clean close: the file is complete)

A payload is zlib of the block's values, column after column, each column's 8-byte values byte-shuffled (the
first bytes of every value, then the second bytes, ...): the exponent and high mantissa bytes of a signal change
slowly and compress, the noisy low bytes cannot. Every value is stored as the float64 the run computed (nothing
rounded: ``slung replay`` compares its estimates and setpoints with the live run's to the bit).
"""

from __future__ import annotations

import json
import logging
import struct
import threading
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from estimators.errors import UserError
from offboard.outputs import user_file_mode, write_atomic

log = logging.getLogger(__name__)

#: file suffix of the format; the CSV it replaces keeps reading (:func:`read_table`)
SUFFIX = ".slts"
#: the live loop's tick log and the run's time series (``SimLog`` columns) in a run folder
LIVE_LOG_NAME = "timeseries_live" + SUFFIX
RUN_LOG_NAME = "timeseries" + SUFFIX
MAGIC = b"SLTS1\n"
BLOCK_MAGIC = b"SLB1"
_BLOCK_HEAD = struct.Struct("<4sIII")
#: rows per block of a file written whole (larger blocks compress about 10 % better than the streamed ones)
WHOLE_BLOCK_ROWS = 4096
#: how often a streamed table appends what the flight added (s): a SIGKILL loses at most this much
STREAM_PERIOD_S = 0.5
#: most rows in one streamed block (a quarter second of a 250 Hz loop; blocks of 64 to 4096 rows of a demo differ
#: by 8 % in size): what a flight adds between two appends
#: depends on the machine's speed (a lockstep flight runs faster than real time), so it is split into blocks of
#: this size and a full disk loses at most one block, not everything since the last append
STREAM_BLOCK_ROWS = 64
_ZLIB_LEVEL = 6


@dataclass(frozen=True)
class Table:
    """A time series read back: ``columns`` (names), ``data`` (rows x columns, float64), ``complete`` (False: the
    file ends without its end mark, e.g. the flight was killed; ``data`` holds every whole block), ``meta``."""

    columns: tuple[str, ...]
    data: np.ndarray
    complete: bool = True
    meta: dict[str, Any] = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        """One column by name (KeyError if absent)."""
        return self.data[:, self.index[name]]

    def __len__(self) -> int:
        return int(self.data.shape[0])

    @property
    def index(self) -> dict[str, int]:
        """Column name -> index."""
        return {n: i for i, n in enumerate(self.columns)}


def _header(columns: Sequence[str], meta: dict[str, Any] | None) -> bytes:
    body = json.dumps({"columns": list(columns), "dtype": "<f8", "meta": meta or {}}).encode("utf-8")
    return MAGIC + struct.pack("<I", len(body)) + body


def encode_block(rows: np.ndarray) -> bytes:
    """One block of ``rows`` (n x columns, converted to float64), head and payload."""
    a = np.ascontiguousarray(np.asarray(rows, dtype="<f8").T)  # column after column
    shuffled = a.view(np.uint8).reshape(a.shape[0], a.shape[1], 8).transpose(0, 2, 1).tobytes()
    payload = zlib.compress(shuffled, _ZLIB_LEVEL)
    return _BLOCK_HEAD.pack(BLOCK_MAGIC, rows.shape[0], len(payload), zlib.crc32(payload)) + payload


_END = _BLOCK_HEAD.pack(BLOCK_MAGIC, 0, 0, 0)


def write_table(path: str | Path, columns: Sequence[str], data: np.ndarray, meta: dict[str, Any] | None = None) -> Path:
    """Write a whole table atomically (complete, with its end mark); returns the path."""
    data = np.asarray(data, dtype=float).reshape(-1, len(columns))

    def write(p: Path) -> None:
        with open(p, "wb") as fh:
            fh.write(_header(columns, meta))
            for i in range(0, len(data), WHOLE_BLOCK_ROWS):
                fh.write(encode_block(data[i : i + WHOLE_BLOCK_ROWS]))
            fh.write(_END)

    return write_atomic(path, write)


class TableStreamer:
    """Appends the rows a running flight adds to ``rows`` (a list the loop appends tuples to; only read here, as
    a prefix that grows) to ``path`` every :data:`STREAM_PERIOD_S`, from a background thread, each append flushed
    to the kernel: a process killed with SIGKILL leaves every block written before it. The file is created at the
    first block (a flight refused before its first tick leaves none). A write failure (full disk) stops the
    stream and is kept in ``failure`` (one line); the flight goes on, as with the tlog."""

    def __init__(self, path: str | Path, columns: Sequence[str], rows: list[Any], meta: dict[str, Any] | None = None):
        self.path = Path(path)
        self.columns = tuple(columns)
        self.rows = rows
        self.meta = meta
        self.written = 0
        self.failure: str | None = None
        self._fh: BinaryIO | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="slung-timeseries", daemon=True)

    def start(self) -> TableStreamer:
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.wait(STREAM_PERIOD_S):
            self._append()

    def _append(self) -> None:
        n = len(self.rows)
        while self.written < n and self.failure is None:
            end = min(n, self.written + STREAM_BLOCK_ROWS)
            block = np.array(self.rows[self.written : end], dtype=float).reshape(-1, len(self.columns))
            try:
                if self._fh is None:
                    self._fh = open(self.path, "wb")  # noqa: SIM115 (held open for the flight)
                    self.path.chmod(user_file_mode())
                    self._fh.write(_header(self.columns, self.meta))
                self._fh.write(encode_block(block))
                self._fh.flush()
            except OSError as exc:
                self.failure = f"{self.path.name}: stopped writing ({exc.strerror or exc})"
                log.warning("output stopped: %s (the flight goes on)", self.failure)  # once: the stream stops here
                return
            self.written = end

    def close(self) -> None:
        """Stop the thread, append the rows left and the end mark, close the file."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        self._append()
        if self._fh is not None:
            try:
                if self.failure is None:
                    self._fh.write(_END)
                self._fh.close()
            except OSError as exc:
                self.failure = self.failure or f"{self.path.name}: stopped writing ({exc.strerror or exc})"
            self._fh = None


def read_table(path: str | Path) -> Table:
    """The table in ``path``: this format (every whole block of a truncated file) or, for a run folder written
    before it, the CSV it replaced (header of names, one row per line). UserError (one line) when the file is
    missing or not a table."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise UserError(f"cannot read {p}: {exc.strerror or exc}") from None
    if not raw.startswith(MAGIC):
        return _read_csv(p, raw)
    if len(raw) < len(MAGIC) + 4:
        raise UserError(f"{p}: truncated before its column names")
    (n,) = struct.unpack_from("<I", raw, len(MAGIC))
    start = len(MAGIC) + 4
    try:
        head = json.loads(raw[start : start + n].decode("utf-8"))
        columns = tuple(head["columns"])
    except (ValueError, KeyError, TypeError):
        raise UserError(f"{p}: unreadable header (not a slung time series?)") from None
    pos, blocks, complete = start + n, [], False
    while pos + _BLOCK_HEAD.size <= len(raw):
        magic, rows, size, crc = _BLOCK_HEAD.unpack_from(raw, pos)
        if magic != BLOCK_MAGIC:
            break
        if rows == 0 and size == 0:
            complete = True
            break
        payload = raw[pos + _BLOCK_HEAD.size : pos + _BLOCK_HEAD.size + size]
        if len(payload) < size or zlib.crc32(payload) != crc:
            break  # the block being written when the writer stopped
        try:
            flat = np.frombuffer(zlib.decompress(payload), dtype=np.uint8)
            values = flat.reshape(len(columns), 8, rows).transpose(0, 2, 1).copy().view("<f8")
        except (zlib.error, ValueError):
            break  # a block that does not decode as its head says: keep what came before it
        blocks.append(values.reshape(len(columns), rows).T)
        pos += _BLOCK_HEAD.size + size
    data = np.concatenate(blocks) if blocks else np.empty((0, len(columns)))
    return Table(columns, np.ascontiguousarray(data, dtype=float), complete, dict(head.get("meta") or {}))


def _read_csv(p: Path, raw: bytes) -> Table:
    """A time series written as CSV by slung before 2026-12-07 (``timeseries*.csv``)."""
    try:
        text = raw.decode("utf-8")
        header, _, body = text.partition("\n")
        columns = tuple(header.strip().split(","))
        if not header.strip() or not all(c.isprintable() for c in header.strip()):
            raise ValueError("no header of column names")
        lines = [ln for ln in body.split("\n") if ln.strip()]
        data = np.array([[float(v) for v in ln.split(",")] for ln in lines], dtype=float)
    except (UnicodeDecodeError, ValueError):
        raise UserError(f"{p}: neither a slung time series ({SUFFIX}) nor CSV") from None
    data = data.reshape(-1, len(columns))
    return Table(columns, data, complete=True)


def table_path(folder: str | Path, stem: str) -> Path | None:
    """``<folder>/<stem>.slts``, or the ``<stem>.csv`` a run folder written before this format holds; None when
    neither exists."""
    for suffix in (SUFFIX, ".csv"):
        p = Path(folder) / f"{stem}{suffix}"
        if p.is_file():
            return p
    return None


def write_csv(table: Table, path: str | Path) -> Path:
    """``table`` as CSV (header of names, full precision: ``%.17g``), atomically."""
    import io

    buf = io.StringIO()
    np.savetxt(buf, table.data, delimiter=",", header=",".join(table.columns), comments="", fmt="%.17g")
    return write_atomic(path, lambda p: p.write_text(buf.getvalue(), encoding="utf-8"))


__all__ = [
    "LIVE_LOG_NAME",
    "RUN_LOG_NAME",
    "STREAM_PERIOD_S",
    "SUFFIX",
    "Table",
    "TableStreamer",
    "encode_block",
    "read_table",
    "table_path",
    "write_csv",
    "write_table",
]
