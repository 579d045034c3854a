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

    b"SLTS2\\n", uint32 n, n bytes of UTF-8 JSON {"columns": [...], "storage": [...], "meta": {...}}
    block*:  b"SLB1", uint32 rows, uint32 payload bytes, uint32 CRC-32 of the payload, payload
    end:     b"SLB1", uint32 0, uint32 0, uint32 0  (written by a clean close: the file is complete)

A payload is zlib of one code byte per column (how the block stores it: its width in bytes, 8, 4 or 2 for
IEEE float64 / float32 / float16, plus :data:`DELTA` when the column's bit patterns are stored as differences from
the previous row's) followed by the columns, one after the other, each column's values byte-shuffled (the first
bytes of every value, then the second bytes, ...): the exponent and high mantissa bytes of a signal change slowly
and compress, the noisy low bytes cannot.

**What is stored at what precision** is the writer's ``storage``, one entry per column (:data:`STORAGE_KINDS`;
the header lists them, :attr:`Table.storage` gives them back): ``"f8"`` keeps the float64 the run computed, bit
for bit; ``"f4"`` / ``"f2"`` keep it rounded to float32 / float16 (a block whose finite value would overflow the
narrower type keeps that column one size wider: no finite value is ever stored as inf); a ``" delta"`` suffix
codes the column as differences of its bit patterns (exact; it halves smooth signals such as times and
references, and does not help noisy ones). Why not all float64: the low mantissa bytes of a noisy float64 are
incompressible (the 50 s demo's tick log: 609 bytes a row in float64 whatever the compressor; about 200 as stored
by :func:`offboard.logs.live_storage.live_storage`).

Files of this format's first version (slung up to main 6595949, 7 Dec 2026) start with ``b"SLTS1\\n"``: the same
blocks without code bytes, every column float64 (:func:`read_table` reads both, and the CSV of the folders before
those).
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
MAGIC = b"SLTS2\n"
#: the first version (up to main 6595949): every column float64, no code bytes in a block; still read
MAGIC_V1 = b"SLTS1\n"
#: code bit of a column stored as the differences of its bit patterns from the previous row's
DELTA = 0x80
#: storage of a column: its type (``"f8"`` float64, ``"f4"`` float32, ``"f2"`` float16), optionally ``" delta"``
STORAGE_KINDS = ("f8", "f4", "f2", "f8 delta", "f4 delta", "f2 delta")
_FLOAT = {8: np.dtype("<f8"), 4: np.dtype("<f4"), 2: np.dtype("<f2")}
_UINT = {8: np.dtype("<u8"), 4: np.dtype("<u4"), 2: np.dtype("<u2")}
BLOCK_MAGIC = b"SLB1"
_BLOCK_HEAD = struct.Struct("<4sIII")
#: rows per block of a file written whole (blocks of 16384 rows made the 10-minute demo's tick log 4 % smaller than
#: blocks of 4096, and 17 % smaller than the streamed ones of 64; 16 MB of float64 to code at a time)
WHOLE_BLOCK_ROWS = 16384
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
    file ends without its end mark, e.g. the flight was killed; ``data`` holds every whole block), ``meta``,
    ``storage`` (per column, :data:`STORAGE_KINDS`: the precision it was kept at; all ``"f8"`` for the older
    formats)."""

    columns: tuple[str, ...]
    data: np.ndarray
    complete: bool = True
    meta: dict[str, Any] = field(default_factory=dict)
    storage: tuple[str, ...] = ()

    def __getitem__(self, name: str) -> np.ndarray:
        """One column by name (KeyError if absent)."""
        return self.data[:, self.index[name]]

    def __len__(self) -> int:
        return int(self.data.shape[0])

    @property
    def index(self) -> dict[str, int]:
        """Column name -> index."""
        return {n: i for i, n in enumerate(self.columns)}

    def stored_as(self, name: str) -> np.dtype:
        """The float type column ``name`` was kept at (float64 when the file does not say)."""
        kinds = self.storage or ("f8",) * len(self.columns)
        return _FLOAT[int(kinds[self.index[name]][1])]


def _parse_storage(columns: Sequence[str], storage: Sequence[str] | None) -> list[tuple[int, bool]]:
    """(width in bytes, delta) per column; ``None``: every column float64, as computed."""
    if storage is None:
        return [(8, False)] * len(columns)
    if len(storage) != len(columns) or any(k not in STORAGE_KINDS for k in storage):
        raise ValueError(f"storage must give one of {STORAGE_KINDS} per column")
    return [(int(k[1]), k.endswith(" delta")) for k in storage]


def _narrowed(col: np.ndarray, width: int) -> tuple[np.ndarray, int]:
    """``col`` (float64) rounded to ``width`` bytes, widened until no finite value becomes inf; (values, width)."""
    while width < 8:
        with np.errstate(over="ignore"):  # an overflow is found just below, and widens
            v = col.astype(_FLOAT[width])
        if not np.any(np.isfinite(col) & ~np.isfinite(v)):
            return v, width
        width *= 2
    return col.astype(_FLOAT[8]), 8


def _header(columns: Sequence[str], storage: Sequence[str] | None, meta: dict[str, Any] | None) -> bytes:
    kinds = list(storage) if storage is not None else ["f8"] * len(columns)
    body = json.dumps({"columns": list(columns), "storage": kinds, "meta": meta or {}}).encode("utf-8")
    return MAGIC + struct.pack("<I", len(body)) + body


def encode_block(rows: np.ndarray, storage: Sequence[str] | None = None) -> bytes:
    """One block of ``rows`` (n x columns, converted to float64) stored as ``storage`` says (None: all float64),
    head and payload."""
    a = np.asarray(rows, dtype="<f8")
    kinds = _parse_storage(range(a.shape[1]), storage)
    codes, parts = bytearray(), []
    for j, (width, delta) in enumerate(kinds):
        v, width = _narrowed(np.ascontiguousarray(a[:, j]), width)
        u = v.view(_UINT[width])
        if delta and len(u) > 1:
            u = np.concatenate((u[:1], np.diff(u)))  # unsigned: wraps, and the reader's cumsum wraps back
        codes.append(width | (DELTA if delta else 0))
        parts.append(u.view(np.uint8).reshape(-1, width).T.tobytes())  # byte-shuffled
    payload = zlib.compress(bytes(codes) + b"".join(parts), _ZLIB_LEVEL)
    return _BLOCK_HEAD.pack(BLOCK_MAGIC, a.shape[0], len(payload), zlib.crc32(payload)) + payload


def _decode_v2(raw: bytes, n_columns: int, rows: int) -> np.ndarray:
    """The rows x columns float64 of a block's decompressed payload (ValueError if it does not decode)."""
    codes, pos = raw[:n_columns], n_columns
    if len(codes) != n_columns:
        raise ValueError("short block")
    out = np.empty((rows, n_columns))
    for j, code in enumerate(codes):
        width = code & ~DELTA
        if width not in _FLOAT:
            raise ValueError(f"unknown column code {code}")
        size = width * rows
        b = np.frombuffer(raw, dtype=np.uint8, count=size, offset=pos).reshape(width, rows).T.copy()
        u = b.view(_UINT[width]).reshape(rows)
        if code & DELTA:
            u = np.cumsum(u, dtype=_UINT[width])
        out[:, j] = u.view(_FLOAT[width])
        pos += size
    if pos != len(raw):
        raise ValueError("block length")
    return out


_END = _BLOCK_HEAD.pack(BLOCK_MAGIC, 0, 0, 0)


def write_table(
    path: str | Path,
    columns: Sequence[str],
    data: np.ndarray,
    meta: dict[str, Any] | None = None,
    storage: Sequence[str] | None = None,
) -> Path:
    """Write a whole table atomically (complete, with its end mark); returns the path. ``storage``: per column,
    :data:`STORAGE_KINDS` (None: every column float64, as computed)."""
    data = np.asarray(data, dtype=float).reshape(-1, len(columns))
    _parse_storage(columns, storage)  # a wrong storage fails here, before the file is touched

    def write(p: Path) -> None:
        with open(p, "wb") as fh:
            fh.write(_header(columns, storage, meta))
            for i in range(0, len(data), WHOLE_BLOCK_ROWS):
                fh.write(encode_block(data[i : i + WHOLE_BLOCK_ROWS], storage))
            fh.write(_END)

    return write_atomic(path, write)


class TableStreamer:
    """Appends the rows a running flight adds to ``rows`` (a list the loop appends tuples to; only read here, as
    a prefix that grows) to ``path`` every :data:`STREAM_PERIOD_S`, from a background thread, each append flushed
    to the kernel: a process killed with SIGKILL leaves every block written before it. The file is created at the
    first block (a flight refused before its first tick leaves none). A write failure (full disk) stops the
    stream and is kept in ``failure`` (one line); the flight goes on, as with the tlog."""

    def __init__(
        self,
        path: str | Path,
        columns: Sequence[str],
        rows: list[Any],
        meta: dict[str, Any] | None = None,
        storage: Sequence[str] | None = None,
    ):
        self.path = Path(path)
        self.columns = tuple(columns)
        self.rows = rows
        self.meta = meta
        self.storage = None if storage is None else tuple(storage)
        _parse_storage(self.columns, self.storage)
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
                    self._fh.write(_header(self.columns, self.storage, self.meta))
                self._fh.write(encode_block(block, self.storage))
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
    version = 2 if raw.startswith(MAGIC) else 1 if raw.startswith(MAGIC_V1) else 0
    if not version:
        return _read_csv(p, raw)
    if len(raw) < len(MAGIC) + 4:
        raise UserError(f"{p}: truncated before its column names")
    (n,) = struct.unpack_from("<I", raw, len(MAGIC))
    start = len(MAGIC) + 4
    try:
        head = json.loads(raw[start : start + n].decode("utf-8"))
        columns = tuple(head["columns"])
        storage = tuple(head.get("storage") or ("f8",) * len(columns))
        _parse_storage(columns, storage)
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
            if version == 1:
                flat = np.frombuffer(zlib.decompress(payload), dtype=np.uint8)
                values = flat.reshape(len(columns), 8, rows).transpose(0, 2, 1).copy().view("<f8")
                blocks.append(values.reshape(len(columns), rows).T)
            else:
                blocks.append(_decode_v2(zlib.decompress(payload), len(columns), rows))
        except (zlib.error, ValueError):
            break  # a block that does not decode as its head says: keep what came before it
        pos += _BLOCK_HEAD.size + size
    data = np.concatenate(blocks) if blocks else np.empty((0, len(columns)))
    return Table(columns, np.ascontiguousarray(data, dtype=float), complete, dict(head.get("meta") or {}), storage)


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
    return Table(columns, data, complete=True, storage=("f8",) * len(columns))


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
    "MAGIC_V1",
    "RUN_LOG_NAME",
    "STORAGE_KINDS",
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
