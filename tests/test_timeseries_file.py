"""The run folder's time series format (offboard/logs/timeseries_file.py): bit-exact round trip, a truncated file
read up to its last whole block, the streamer appending while a writer thread adds rows, the CSV of older run
folders still read, ``slung export --csv``, and a real flight killed with SIGKILL read back to within 1 s of the
kill."""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
import threading
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

from estimators.errors import UserError
from offboard.logs.live_storage import live_storage
from offboard.logs.timeseries_file import (
    MAGIC,
    MAGIC_V1,
    STREAM_BLOCK_ROWS,
    STREAM_PERIOD_S,
    WHOLE_BLOCK_ROWS,
    TableStreamer,
    read_table,
    table_path,
    write_table,
)

COLS = ("t", "a", "b")


def _data(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    d = np.column_stack([np.arange(n) * 0.004, rng.standard_normal(n), np.cumsum(rng.standard_normal(n))])
    d[3, 1] = np.nan
    d[4, 2] = np.inf
    d[5, 2] = -0.0
    return d


def test_round_trip_is_bit_exact(tmp_path: Path) -> None:
    d = _data(10_000)
    p = write_table(tmp_path / "x.slts", COLS, d, meta={"rate_hz": 250})
    t = read_table(p)
    assert t.complete and t.columns == COLS and t.meta == {"rate_hz": 250}
    assert t.data.tobytes() == d.tobytes()  # every bit, NaN, inf and -0.0 included
    assert np.isnan(t["a"][3]) and np.isinf(t["b"][4]) and np.signbit(t["b"][5])
    assert p.stat().st_size < d.nbytes  # compressed


def test_each_column_reads_back_at_its_stored_precision(tmp_path: Path) -> None:
    """float64 columns bit for bit, float32 / float16 ones rounded to that type (NaN, inf and -0.0 kept), the delta
    coding exact; a finite value the narrow type would turn into inf keeps its block's column wider."""
    rng = np.random.default_rng(1)
    n = WHOLE_BLOCK_ROWS + 4000  # two blocks
    d = np.column_stack(
        [
            np.arange(n) * 0.004 + 1e5,  # a time far from 0: float32 would lose it, float64 delta keeps it
            rng.standard_normal(n),
            np.cumsum(rng.standard_normal(n)) * 1e-3,
            np.abs(rng.standard_normal(n)) * 0.01,
            rng.standard_normal(n),
        ]
    )
    d[3, 1], d[4, 2], d[5, 3], d[6, 4] = np.nan, np.inf, -0.0, np.nan
    d[n - 10, 3] = 1e6  # beyond float16 (65504): its block (the second) keeps that column as float32
    d[100, 2] = 1e40  # beyond float32: its block keeps that column as float64
    cols = ("t", "a", "b", "c", "e")
    storage = ("f8 delta", "f4", "f4 delta", "f2", "f2 delta")
    p = write_table(tmp_path / "x.slts", cols, d, storage=storage)
    t = read_table(p)
    assert t.complete and t.storage == storage and t.stored_as("a") == np.float32 and t.stored_as("c") == np.float16
    assert t["t"].tobytes() == d[:, 0].tobytes()
    np.testing.assert_array_equal(t["a"], d[:, 1].astype(np.float32))
    assert t["b"][100] == 1e40 and t["c"][n - 10] == 1e6 and np.signbit(t["c"][5]) and np.isinf(t["b"][4])
    block0 = slice(0, WHOLE_BLOCK_ROWS)  # the first block has no overflow in "c": rounded
    np.testing.assert_array_equal(t["c"][block0], d[block0, 3].astype(np.float16))
    np.testing.assert_array_equal(t["e"], d[:, 4].astype(np.float16))
    assert p.stat().st_size < 0.6 * write_table(tmp_path / "y.slts", cols, d).stat().st_size  # it pays


def test_a_file_of_the_first_version_is_still_read(tmp_path: Path) -> None:
    """Run folders written by main 6595949 and before (7 Dec 2026) hold SLTS1 files: every column float64, blocks
    without code bytes."""
    d = _data(5000)
    head = json.dumps({"columns": list(COLS), "dtype": "<f8", "meta": {}}).encode()
    blocks = b""
    for i in range(0, len(d), 4096):
        a = np.ascontiguousarray(d[i : i + 4096].T)
        payload = zlib.compress(a.view(np.uint8).reshape(a.shape[0], a.shape[1], 8).transpose(0, 2, 1).tobytes())
        blocks += struct.pack("<4sIII", b"SLB1", a.shape[1], len(payload), zlib.crc32(payload)) + payload
    raw = MAGIC_V1 + struct.pack("<I", len(head)) + head + blocks + struct.pack("<4sIII", b"SLB1", 0, 0, 0)
    (tmp_path / "old.slts").write_bytes(raw)
    t = read_table(tmp_path / "old.slts")
    assert t.complete and t.columns == COLS and t.storage == ("f8",) * 3 and t.data.tobytes() == d.tobytes()


def test_the_tick_logs_storage_keeps_times_whole_and_the_wire_at_float32() -> None:
    """offboard.logs.live_storage: the columns the replay finds its ticks by stay float64; the estimate, command and
    the setpoint (float32 on the MAVLink wire) float32; only the filter's account, the law's internals and the
    timing float16."""
    from offboard.flight.loop_records import LIVE_COLUMNS

    kinds = dict(zip(LIVE_COLUMNS, live_storage(LIVE_COLUMNS), strict=True))
    assert all(kinds[c].startswith("f8") for c in ("t_vehicle", "t_ref", "t_local", "n_meas"))
    assert all(kinds[c] == "f4" for c in LIVE_COLUMNS if c.startswith(("est_", "sp")))
    assert all(kinds[c] == "f4" for c in ("cmd_thrust", "cmd_tau_phi", "cmd_tau_theta", "cmd_tau_psi"))
    diagnostics = ("sd_", "nu_", "int_", "cmd_s_", "cmd_sigma_")
    assert {c for c, k in kinds.items() if k.startswith("f2")} == {
        c for c in LIVE_COLUMNS if c.startswith(diagnostics) or c in ("compute_s", "latency_s")
    }
    assert live_storage(("something_new",)) == ("f8",)  # unknown: whole


def test_truncated_file_keeps_every_whole_block(tmp_path: Path) -> None:
    rows: list[tuple[float, ...]] = []
    s = TableStreamer(tmp_path / "live.slts", COLS, rows)
    d = _data(900)
    sizes = []
    for k in range(0, 900, 100):  # nine blocks of 100 rows, appended as the thread would
        rows.extend(map(tuple, d[k : k + 100]))
        s._append()
        sizes.append(s.path.stat().st_size)
    s._fh.close()  # as a killed process leaves it: no end mark
    raw = s.path.read_bytes()
    # each append of 100 rows is a block of STREAM_BLOCK_ROWS (64) and one of 36
    for cut, kept in [(len(raw), 900), (sizes[4] + 10, 500), (sizes[4], 500), (sizes[0] - 1, 64), (sizes[0] - 1000, 0)]:
        (tmp_path / "cut.slts").write_bytes(raw[:cut])
        t = read_table(tmp_path / "cut.slts")
        assert not t.complete
        assert len(t) == kept
        assert t.data.tobytes() == d[:kept].tobytes()


def test_a_large_append_is_split_so_a_full_disk_loses_one_block(tmp_path: Path) -> None:
    """What a flight adds between two appends depends on the machine's speed (lockstep flights outrun the wall
    clock); the streamer writes it in blocks of at most STREAM_BLOCK_ROWS, each flushed, so a write that fails
    keeps every block before it (CI's full-disk flight once kept none: one 0.5 s block did not fit)."""
    d = _data(1000)
    rows: list[tuple[float, ...]] = list(map(tuple, d))
    s = TableStreamer(tmp_path / "live.slts", COLS, rows)
    s._append()
    s._fh.close()
    blocks = _block_rows(s.path.read_bytes())
    assert sum(blocks) == 1000 and max(blocks) == STREAM_BLOCK_ROWS and len(blocks) == -(-1000 // STREAM_BLOCK_ROWS)
    raw = s.path.read_bytes()
    (tmp_path / "cut.slts").write_bytes(raw[: len(raw) // 2])  # the disk filled half way through the append
    t = read_table(tmp_path / "cut.slts")
    assert 0 < len(t) < 1000 and len(t) % STREAM_BLOCK_ROWS == 0 and t.data.tobytes() == d[: len(t)].tobytes()


def _block_rows(raw: bytes) -> list[int]:
    """Rows of each block in a file of this format (header skipped, end mark not counted)."""
    (n,) = struct.unpack_from("<I", raw, len(MAGIC))
    pos, out = len(MAGIC) + 4 + n, []
    while pos + 16 <= len(raw):
        _, rows, size, _ = struct.unpack_from("<4sIII", raw, pos)
        if rows == 0:
            break
        out.append(rows)
        pos += 16 + size
    return out


def test_streamer_appends_while_rows_grow(tmp_path: Path) -> None:
    rows: list[tuple[float, ...]] = []
    s = TableStreamer(tmp_path / "live.slts", COLS, rows).start()
    d = _data(600)

    def producer() -> None:
        for r in d:
            rows.append(tuple(r))
            time.sleep(0.004)

    th = threading.Thread(target=producer)
    th.start()
    time.sleep(4 * STREAM_PERIOD_S)
    mid = read_table(s.path)  # while it is written: complete blocks, no end mark yet
    assert not mid.complete and 0 < len(mid) < 600
    assert mid.data.tobytes() == d[: len(mid)].tobytes()
    th.join()
    s.close()
    t = read_table(s.path)
    assert t.complete and t.data.tobytes() == d.tobytes()


def test_streamer_writes_nothing_before_the_first_row(tmp_path: Path) -> None:
    s = TableStreamer(tmp_path / "live.slts", COLS, []).start()
    s.close()
    assert not s.path.exists()


def test_older_csv_folder_is_still_read(tmp_path: Path) -> None:
    d = _data(50)
    np.savetxt(tmp_path / "timeseries_live.csv", d, delimiter=",", header=",".join(COLS), comments="", fmt="%.17g")
    p = table_path(tmp_path, "timeseries_live")
    assert p == tmp_path / "timeseries_live.csv"
    t = read_table(p)
    assert t.columns == COLS and t.data.tobytes() == d.tobytes()


def test_not_a_table_is_one_line_error(tmp_path: Path) -> None:
    (tmp_path / "x.slts").write_bytes(b"\x00\x01garbage")
    with pytest.raises(UserError, match="neither a slung time series"):
        read_table(tmp_path / "x.slts")
    with pytest.raises(UserError, match="cannot read"):
        read_table(tmp_path / "missing.slts")


def _slung(*args: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "offboard.cli", *args], capture_output=True, text=True, **kw)


def test_export_csv(tmp_path: Path) -> None:
    d = _data(300)
    write_table(tmp_path / "timeseries.slts", COLS, d)
    r = _slung("export", "--csv", str(tmp_path))
    assert r.returncode == 0, r.stderr
    assert "300 rows, 3 columns" in r.stdout
    back = np.loadtxt(tmp_path / "timeseries.csv", delimiter=",", skiprows=1)
    assert back.tobytes() == d.tobytes()  # %.17g: the same doubles
    bad = _slung("export", "--csv", str(tmp_path / "nowhere"))
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "Traceback" not in bad.stderr


@pytest.mark.slow
def test_flight_killed_with_sigkill_leaves_its_ticks(tmp_path: Path) -> None:
    """A real ``slung demo`` (emulator in its process, lockstep) killed with SIGKILL in mid-flight: the tick log
    on disk is read up to within 1 s (of the monotonic clock the loop stamps ``t_local`` with) of the kill."""
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "offboard.cli", "demo", "--out", str(out), "--no-figures"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    live = out / "timeseries_live.slts"
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline:  # wait until a few seconds of control are on disk
            if live.exists():
                try:
                    if len(read_table(live)) >= 1000:
                        break
                except UserError:
                    pass
            assert proc.poll() is None, "the demo ended before it was killed"
            time.sleep(0.2)
        else:
            pytest.fail("no tick log appeared within 240 s")
        time.sleep(1.3)
        t_kill = time.monotonic()
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == -signal.SIGKILL
    t = read_table(live)
    assert not t.complete  # no end mark: the flight did not finish
    t_local = t["t_local"]
    assert np.all(np.diff(t_local) >= 0)
    lost = t_kill - float(t_local[-1])
    assert 0.0 <= lost <= 1.0, f"the last tick on disk is {lost:.2f} s before the kill"
