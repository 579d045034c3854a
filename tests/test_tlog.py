"""The robust tlog reader on logs generated here: clean, truncated, bit-flipped, zero runs, MAVLink 1, unknown ids,
garbage before the first record, an empty file and files that are not tlogs."""

from __future__ import annotations

import itertools
import struct
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil
from tlog_fixtures import LogSpec, flight_log

from offboard.logs.tlog import TlogReader, encode_record


@pytest.fixture(scope="module")
def clean() -> bytes:
    return flight_log(LogSpec(seconds=2.0))


def _records(data: bytes) -> list[tuple[int, bytes]]:
    """Split a CLEAN log into (timestamp, packet) by its own framing (test oracle, not the reader)."""
    out = []
    i = 0
    while i < len(data):
        ts = struct.unpack(">Q", data[i : i + 8])[0]
        stx = data[i + 8]
        n = (8 + data[i + 9]) if stx == 0xFE else (12 + data[i + 9])
        out.append((ts, data[i + 8 : i + 8 + n]))
        i += 8 + n
    return out


def _read(data: bytes) -> tuple[list[tuple[float, object]], TlogReader]:
    r = TlogReader(data)
    return list(r), r


def _keys(msgs: list[tuple[float, object]]) -> list[tuple[int, bytes]]:
    return [(round(t * 1e6), bytes(m.get_msgbuf())) for t, m in msgs]


def test_clean_log_matches_pymavlink_reader(clean: bytes, tmp_path: Path) -> None:
    path = tmp_path / "clean.tlog"
    path.write_bytes(clean)
    ours, reader = _read(clean)
    conn = mavutil.mavlink_connection(str(path))
    theirs = []
    while True:
        m = conn.recv_match()
        if m is None:
            break
        theirs.append((m._timestamp, m.get_type(), m.to_dict()))
    assert len(ours) == len(theirs) == len(_records(clean)) > 1000
    for (t, m), (t2, kind, d) in zip(ours, theirs, strict=True):
        assert t == pytest.approx(t2, abs=1e-6)
        assert m.get_type() == kind
        assert m.to_dict() == d
    s = reader.stats
    assert (s.packets, s.bad_crc, s.garbage_bytes, s.truncated, s.resyncs) == (len(ours), 0, 0, 0, 0)


def test_truncated_final_packet_is_tolerated(clean: bytes) -> None:
    recs = _records(clean)
    whole = clean[: len(clean) - (8 + len(recs[-1][1]))]
    for cut in (1, 5, 8, 9, 11, 8 + len(recs[-1][1]) - 1):
        msgs, r = _read(whole + clean[len(whole) : len(whole) + cut])
        assert _keys(msgs) == recs[:-1]
        assert r.stats.truncated == 1
        assert r.stats.garbage_bytes == 0


def test_flipped_bytes_are_skipped_and_counted_never_invented(clean: bytes) -> None:
    rng = np.random.default_rng(7)
    recs = _records(clean)
    data = bytearray(clean)
    n_flips = 40
    for pos in rng.choice(len(data), size=n_flips, replace=False):
        data[pos] ^= int(rng.integers(1, 256))
    msgs, r = _read(bytes(data))
    got = _keys(msgs)
    # a packet passes only intact (CRC); a flipped timestamp bit cannot be detected (no checksum covers it)
    packets = [pkt for _, pkt in recs]
    assert all(pkt in packets for _, pkt in got), "a corrupted packet was accepted"
    it = iter(packets)
    assert all(any(pkt == q for q in it) for _, pkt in got)  # a subsequence: order kept
    assert sum(k not in set(recs) for k in got) <= n_flips
    assert len(got) >= len(recs) - 3 * n_flips
    assert len(got) < len(recs)
    assert r.stats.bad_crc + r.stats.resyncs > 0
    assert r.stats.packets == len(got)


def test_runs_of_zeros_between_records_are_counted_exactly(clean: bytes) -> None:
    recs = _records(clean)
    rng = np.random.default_rng(3)
    where = sorted(rng.choice(np.arange(1, len(recs)), size=5, replace=False).tolist())
    out = bytearray()
    inserted = 0
    for i, (ts, pkt) in enumerate(recs):
        if i in where:
            run = 17 + 31 * where.index(i)
            out += bytes(run)
            inserted += run
        out += encode_record(ts, pkt)
    msgs, r = _read(bytes(out))
    assert _keys(msgs) == recs
    assert r.stats.garbage_bytes == inserted
    assert r.stats.resyncs == 5


def test_runs_of_zeros_inside_packets_lose_only_those_packets(clean: bytes) -> None:
    recs = _records(clean)
    rng = np.random.default_rng(11)
    damaged = sorted(rng.choice(np.arange(1, len(recs) - 1), size=6, replace=False).tolist())
    out = bytearray()
    for i, (ts, pkt) in enumerate(recs):
        rec = encode_record(ts, pkt)
        if i in damaged:
            rec = rec[:12] + bytes(50) + rec[12:]
        out += rec
    msgs, r = _read(bytes(out))
    assert _keys(msgs) == [rec for i, rec in enumerate(recs) if i not in damaged]
    assert r.stats.garbage_bytes >= 6 * 50


def test_mavlink1_only_log() -> None:
    data = flight_log(LogSpec(seconds=1.0, mavlink1=True))
    msgs, r = _read(data)
    assert len(msgs) == len(_records(data)) > 300
    assert all(m.get_msgbuf()[0] == 0xFE for _, m in msgs)
    assert (r.stats.mavlink1, r.stats.mavlink2) == (len(msgs), 0)
    assert {m.get_type() for _, m in msgs} >= {"HEARTBEAT", "ATTITUDE", "LOCAL_POSITION_NED"}


def test_unknown_message_id_is_counted_not_fatal(clean: bytes) -> None:
    recs = _records(clean)
    # a MAVLink 2 packet of id 60123 (not in the dialect): header, 4 payload bytes, any checksum
    unknown = bytes([0xFD, 4, 0, 0, 9, 1, 1]) + (60123).to_bytes(3, "little") + b"\x01\x02\x03\x04" + b"\xaa\xbb"
    out = bytearray()
    for i, (ts, pkt) in enumerate(recs):
        out += encode_record(ts, pkt)
        if i in (10, 20):
            out += encode_record(ts + 4, unknown)
    msgs, r = _read(bytes(out))
    assert _keys(msgs) == recs
    assert r.stats.unknown_ids == {60123: 2}
    assert r.stats.garbage_bytes == 0


def test_garbage_before_the_first_record(clean: bytes) -> None:
    rng = np.random.default_rng(5)
    junk = rng.integers(0, 256, size=333, dtype=np.uint8).tobytes()
    msgs, r = _read(junk + clean)
    assert _keys(msgs) == _records(clean)
    assert r.stats.garbage_bytes == 333


def test_empty_file_and_files_that_are_not_tlogs(tmp_path: Path) -> None:
    empty = tmp_path / "empty.tlog"
    empty.write_bytes(b"")
    r = TlogReader.from_path(empty)
    assert list(r) == [] and r.stats.packets == 0 and r.stats.bytes_total == 0
    text = ("time,x,y\n" + "0.1,2,3\n" * 500).encode()
    msgs, r = _read(text)
    assert msgs == [] and r.stats.garbage_bytes == len(text)
    noise = np.random.default_rng(9).integers(0, 256, size=20000, dtype=np.uint8).tobytes()
    msgs, r = _read(noise)
    assert msgs == [] and r.stats.garbage_bytes == len(noise)


def test_progress_callback_reaches_one(clean: bytes) -> None:
    seen: list[float] = []
    list(TlogReader(clean, progress=seen.append))
    assert seen and seen[-1] == 1.0 and all(a <= b for a, b in itertools.pairwise(seen))


def test_signed_mavlink2_packets_are_read_and_counted(clean: bytes) -> None:
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    mav.signing.secret_key = bytes(range(32))
    mav.signing.sign_outgoing = True
    mav.signing.link_id = 1
    mav.signing.timestamp = 1000
    recs = _records(clean)
    out = bytearray()
    for i, (ts, pkt) in enumerate(recs[:50]):
        out += encode_record(ts, pkt)
        if i % 10 == 0:
            out += encode_record(ts + 4, mav.attitude_encode(i, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0).pack(mav))
    msgs, r = _read(bytes(out))
    assert len(msgs) == 55 and r.stats.signed == 5 and r.stats.garbage_bytes == 0
    assert [
        m.time_boot_ms
        for _, m in msgs
        if m.get_srcSystem() == 1 and m.get_type() == "ATTITUDE" and m.roll == pytest.approx(0.1)
    ] == [0, 10, 20, 30, 40]
