"""Robustness and security of ``slung emulate`` over real UDP on 127.0.0.1: fuzzing with 100,000 datagrams,
MAVLink 2 signing, injected loss and latency, the tlog, and lockstep determinism."""

from __future__ import annotations

import os
import time
from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np
import pytest
from emulator_helpers import MAV_CMD_ARM, Emu, fly_lockstep_hold
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as apm

from estimators.model.vehicle import Vehicle

V = Vehicle()
KEY = bytes(range(32))


def _packer(sysid: int = 255, compid: int = 190) -> apm.MAVLink:
    return apm.MAVLink(None, srcSystem=sysid, srcComponent=compid)


def _valid_pool(mav: apm.MAVLink) -> dict[str, list[bytes]]:
    """Valid packets: harmless ones for us, and ones addressed to another system (7)."""
    harmless = [
        mav.heartbeat_encode(6, 8, 0, 0, 4).pack(mav),
        mav.system_time_encode(1_700_000_000_000_000, 1234).pack(mav),
        mav.statustext_encode(6, b"hello from the fuzzer").pack(mav),
    ]
    foreign = [
        mav.command_long_encode(7, 1, MAV_CMD_ARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav),
        mav.set_attitude_target_encode(0, 7, 1, 7, [1, 0, 0, 0], 0, 0, 0, 0.9).pack(mav),
        mav.param_set_encode(7, 1, b"COM_OF_LOSS_T", 9.0, 9).pack(mav),
        mav.set_mode_encode(7, 1, 0).pack(mav),
    ]
    return {"harmless": harmless, "foreign": foreign}


class Sender:
    """Raw datagrams to the emulator, paced by PING round trips so no datagram is lost in a socket buffer."""

    def __init__(self, e: Emu) -> None:
        self.e = e
        self.ping_mav = _packer(250, 1)
        self.pings = 0

    def send(self, data: bytes) -> None:
        self.e.send_raw(data)

    def barrier(self) -> None:
        """Send a PING and wait for its answer: every earlier datagram has been read by the emulator."""
        self.pings += 1
        seq = self.pings & 0xFFFFFFFF
        self.send(self.ping_mav.ping_encode(self.pings, seq, 0, 0).pack(self.ping_mav))
        m = self.e.recv("PING", 10.0, cond=lambda m: m.seq == seq and m.target_system == 250)
        assert m is not None, "emulator stopped answering"


def _fly_to_hold(e: Emu) -> None:
    e.wait_heartbeat()
    e.wait_ready()
    assert e.command(MAV_CMD_ARM, 1, 0).result == 0
    assert e.command(22, 0, 0, 0, 0, 0, 0, float("nan")).result == 0  # NAV_TAKEOFF to MIS_TAKEOFF_ALT
    assert e.recv("HEARTBEAT", 10.0, cond=lambda m: m.custom_mode == 50593792 and m.base_mode & 128)


def _still_flying(e: Emu) -> None:
    stamps = []
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        m = e.recv("ATTITUDE", 0.5)
        if m is not None:
            stamps.append(m.time_boot_ms)
    assert (len(stamps) - 1) / ((stamps[-1] - stamps[0]) / 1000.0) == pytest.approx(100.0, rel=0.05)
    pos = e.latest("LOCAL_POSITION_NED")
    assert pos.z == pytest.approx(-2.5, abs=0.3) and abs(pos.vz) < 0.3
    hb = e.recv("HEARTBEAT", 2.0)
    assert hb.custom_mode == 50593792 and hb.base_mode & 128  # still armed, still in Hold


def _fuzz_while_flying(packets: Iterable[bytes]) -> tuple[dict[str, Any], int]:
    """Fly the emulator to Hold, send it every datagram of ``packets`` (a barrier every 1500) and check that it still
    flies; its summary and the number of pings the barriers sent."""
    with Emu("--est-ready", "0.2") as e:
        _fly_to_hold(e)
        s = Sender(e)
        for i, data in enumerate(packets):
            s.send(data)
            if i % 1500 == 1499:
                s.barrier()
        s.barrier()
        _still_flying(e)
        return e.stop(), s.pings


def test_fuzz_classified_datagrams_counted_exactly_while_flying() -> None:
    rng = np.random.default_rng(20261122)
    pool = _valid_pool(_packer())
    expect = {
        "garbage_datagrams": 0,
        "garbage_bytes": 0,
        "truncated": 0,
        "bad_crc": 0,
        "foreign_target": 0,
        "packets_ok": 0,
    }
    n = 60_000

    def packets() -> Iterator[bytes]:
        kinds = rng.integers(0, 5, n)
        for k in kinds:
            if k == 0:  # garbage without any frame start byte
                g = rng.integers(0, 256, int(rng.integers(1, 300)), dtype=np.uint8)
                g[(g == 0xFD) | (g == 0xFE)] = 0
                data = g.tobytes()
                expect["garbage_datagrams"] += 1
                expect["garbage_bytes"] += len(data)
            elif k == 1:  # a valid packet cut short
                pkt = pool["foreign"][int(rng.integers(0, 4))]
                data = pkt[: int(rng.integers(1, len(pkt)))]
                expect["truncated"] += 1
            elif k == 2:  # one bit flipped after the header (payload or checksum): CRC must catch it
                pkt = bytearray(pool["foreign"][int(rng.integers(0, 4))])
                pos = int(rng.integers(10, len(pkt)))
                pkt[pos] ^= 1 << int(rng.integers(0, 8))
                data = bytes(pkt)
                expect["bad_crc"] += 1
            elif k == 3:  # valid, for another system
                data = pool["foreign"][int(rng.integers(0, 4))]
                expect["packets_ok"] += 1
                expect["foreign_target"] += 1
            else:  # valid and harmless
                data = pool["harmless"][int(rng.integers(0, 3))]
                expect["packets_ok"] += 1
            yield data

    summary, pings = _fuzz_while_flying(packets())
    rx = summary["link"]["rx"]
    assert rx["datagrams"] == n + pings + summary["counters"]["commands"]
    assert rx["packets_ok"] == expect["packets_ok"] + pings + summary["counters"]["commands"]
    for key in ("garbage_datagrams", "garbage_bytes", "truncated", "bad_crc", "foreign_target"):
        assert rx[key] == expect[key], key
    assert rx["malformed"] == 0 and rx["unknown_msgid"] == 0
    assert summary["counters"]["setpoints_accepted"] == 0  # no fuzz packet got through as a setpoint
    assert summary["counters"]["handler_errors"] == 0


def test_fuzz_random_mutations_never_stop_the_emulator() -> None:
    rng = np.random.default_rng(7)
    mav = _packer()
    pool = [p for v in _valid_pool(mav).values() for p in v]
    v1 = mav.set_attitude_target_encode(0, 7, 1, 7, [1, 0, 0, 0], 0, 0, 0, 0.9)
    pool.append(v1.pack(mav, force_mavlink1=True))
    n = 40_000

    def packets() -> Iterator[bytes]:
        for _ in range(n):
            k = int(rng.integers(0, 4))
            pkt = bytearray(pool[int(rng.integers(0, len(pool)))])
            if k == 0:  # several random byte changes anywhere, including the header
                for _ in range(int(rng.integers(1, 6))):
                    pkt[int(rng.integers(0, len(pkt)))] = int(rng.integers(0, 256))
            elif k == 1:  # concatenations, some cut, some with garbage between
                other = pool[int(rng.integers(0, len(pool)))]
                pkt = pkt + rng.integers(0, 256, int(rng.integers(0, 8)), dtype=np.uint8).tobytes() + other
                pkt = pkt[: int(rng.integers(1, len(pkt) + 1))]
            elif k == 2:  # pure random bytes, frame start bytes allowed
                pkt = bytearray(rng.integers(0, 256, int(rng.integers(1, 400)), dtype=np.uint8).tobytes())
            else:  # a header that announces a huge or tiny payload, or a signed flag without signature
                pkt[1] = int(rng.integers(0, 256))
                if pkt[0] == 0xFD:
                    pkt[2] = int(rng.integers(0, 4))
            yield bytes(pkt)

    summary, pings = _fuzz_while_flying(packets())
    rx = summary["link"]["rx"]
    assert rx["datagrams"] == n + pings + summary["counters"]["commands"]
    outcomes = (
        rx["packets_ok"]
        + rx["garbage_datagrams"]
        + rx["truncated"]
        + rx["bad_crc"]
        + rx["malformed"]
        + rx["unknown_msgid"]
        + rx["unsigned_rejected"]
        + rx["bad_signature"]
    )
    assert outcomes >= rx["datagrams"]  # every datagram was accounted for at least once
    assert rx["bad_crc"] > 1000 and rx["truncated"] > 1000 and rx["garbage_datagrams"] > 100
    assert summary["nonfinite_resets"] == 0 and summary["counters"]["handler_errors"] == 0


def _raw_send(e: Emu, mav: apm.MAVLink, msg: Any) -> None:
    e.send_raw(msg.pack(mav))


def test_signing_accepts_signed_and_refuses_unsigned_or_badly_signed_commands() -> None:
    with Emu("--est-ready", "0.2", "--signing-key", KEY.hex(), signing_key=KEY) as e:
        hb = e.wait_heartbeat()
        assert hb.get_signed()  # the emulator signs what it sends, and the signature verifies with our key
        e.wait_ready()
        # signed by our client: accepted
        ack = e.command(512, 148)
        assert ack is not None and ack.result == 0
        # unsigned: refused silently and counted
        unsigned = _packer(254, 1)
        for _ in range(5):
            _raw_send(e, unsigned, unsigned.command_long_encode(1, 1, MAV_CMD_ARM, 0, 1, 0, 0, 0, 0, 0, 0))
            _raw_send(e, unsigned, unsigned.set_attitude_target_encode(0, 1, 1, 7, [1, 0, 0, 0], 0, 0, 0, 0.9))
        # signed with the wrong key: refused and counted
        wrong = _packer(253, 1)
        wrong.signing.secret_key = bytes(32)
        wrong.signing.sign_outgoing = True
        wrong.signing.link_id = 3
        wrong.signing.timestamp = int((time.time() - 1420070400) * 1e5)
        for _ in range(4):
            _raw_send(e, wrong, wrong.command_long_encode(1, 1, MAV_CMD_ARM, 0, 1, 0, 0, 0, 0, 0, 0))
        assert e.recv("COMMAND_ACK", 1.0, cond=lambda m: m.command == MAV_CMD_ARM) is None
        hb = e.recv("HEARTBEAT", 2.0)
        assert not hb.base_mode & 128
        # the signed client can still arm
        assert e.command(MAV_CMD_ARM, 1, 0).result == 0
        st = e.recv("SYS_STATUS", 2.0, cond=lambda m: m.errors_count1 >= 14)
        assert st is not None and st.errors_count1 == 14
        summary = e.stop()
    rx = summary["link"]["rx"]
    assert (rx["unsigned_rejected"], rx["bad_signature"]) == (10, 4)
    assert summary["counters"]["setpoints_accepted"] == 0 and summary["signing"]


def test_injected_loss_and_latency() -> None:
    with Emu(
        "--est-ready",
        "0.2",
        "--latency",
        "0.2",
        "--jitter",
        "0.02",
        "--loss-out",
        "0.5",
        "--loss-in",
        "0.3",
        "--fault-seed",
        "5",
    ) as e:
        e.wait_heartbeat()
        e.wait_ready()
        # outgoing loss: about half of the 100 Hz ATTITUDE stream arrives
        stamps = []
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            m = e.recv("ATTITUDE", 0.5)
            if m is not None:
                stamps.append(m.time_boot_ms)
        frac = (len(stamps) - 1) / ((stamps[-1] - stamps[0]) / 10.0)
        assert frac == pytest.approx(0.5, abs=0.12)
        # latency: a PING round trip takes two one-way latencies
        e.drain()
        sent: dict[int, float] = {}
        rtts = []
        t_end = time.monotonic() + 1.8
        i = 0
        while time.monotonic() < t_end:
            if i < 60:
                sent[i] = time.monotonic()
                e.mav.ping_send(i, i, 0, 0)
                i += 1
            while (m := e.conn.recv_match(type="PING", blocking=False)) is not None:
                if m.target_system == 255:
                    rtts.append(time.monotonic() - sent[m.seq])
            time.sleep(0.005)
        assert 8 <= len(rtts) <= 35  # (1 - 0.3) * 0.5 of 60 = 21 expected
        assert all(0.39 < r < 0.6 for r in rtts)  # 2 x (0.2 s + up to 0.02 s jitter) + polling, host load
        summary = e.stop()
    rx = summary["link"]["rx"]
    assert rx["dropped_in"] == pytest.approx(0.3 * rx["datagrams"], abs=0.15 * rx["datagrams"])
    assert summary["link"]["tx_dropped"] == pytest.approx(0.5 * summary["link"]["tx_packets"], rel=0.05)


def test_tlog_records_everything_sent_and_received(tmp_path: Any) -> None:
    path = tmp_path / "emu.tlog"
    t_start = time.time()
    with Emu("--est-ready", "0.2", "--tlog", str(path)) as e:
        e.wait_heartbeat()
        assert e.command(31000).result == 3
        e.mav.param_request_read_send(1, 1, b"COM_OF_LOSS_T", -1)
        assert e.recv("PARAM_VALUE", 2.0) is not None
        time.sleep(0.5)
        summary = e.stop()
    assert os.path.getsize(path) > 0
    log = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    n = 0
    last = 0.0
    seen = set()
    while True:
        m = log.recv_match()
        if m is None:
            break
        assert m.get_type() != "BAD_DATA"
        assert t_start - 1 <= m._timestamp <= time.time() + 1 and m._timestamp >= last
        last = m._timestamp
        seen.add((m.get_srcSystem(), m.get_type()))
        n += 1
    assert n == summary["link"]["tlog_records"] == summary["link"]["tx_packets"] + summary["link"]["rx"]["packets_ok"]
    for item in [
        (255, "COMMAND_LONG"),
        (255, "PARAM_REQUEST_READ"),
        (1, "COMMAND_ACK"),
        (1, "PARAM_VALUE"),
        (1, "HEARTBEAT"),
        (1, "ATTITUDE"),
        (2, "GLOBAL_POSITION_INT"),
    ]:
        assert item in seen, item


def _lockstep_trace() -> tuple[list[tuple[float, float, float]], dict[str, Any]]:
    with Emu("--lockstep", "--est-ready", "0.2") as e:
        r = fly_lockstep_hold(e, 3.0, V)
        summary = e.stop()
    return r["trace"], summary


def test_lockstep_is_deterministic_and_fast() -> None:
    t1, s1 = _lockstep_trace()
    t2, _ = _lockstep_trace()
    assert len(t1) > 250
    assert t1 == t2  # bit-identical telemetry over the flight
    assert t1[-1][2] == pytest.approx(-2.0, abs=0.2)
    assert s1["lockstep_handshakes"] >= 300 and s1["mode"] == "OFFBOARD"


def test_lockstep_with_fault_injection_answers_between_steps() -> None:
    """With faults configured (here: a negligible loss), replies due now go out at once even while the lockstep
    clock waits for the next setpoint (a client may wait for an ACK before it sends one)."""
    with Emu(
        "--lockstep", "--lockstep-grace", "5", "--est-ready", "0.2", "--loss-in", "1e-12", "--loss-out", "1e-12"
    ) as e:
        e.wait_heartbeat()
        e.wait_ready()
        for _ in range(10):
            e.mav.set_attitude_target_send(0, 1, 1, 7, [1, 0, 0, 0], 0, 0, 0, 0.0)
            assert e.recv("SYSTEM_TIME", 2.0) is not None
        t0 = time.monotonic()
        ack = e.command(MAV_CMD_ARM, 1, 0)
        assert ack is not None and ack.result == 0 and time.monotonic() - t0 < 0.3
        summary = e.stop()
    assert summary["lockstep_handshakes"] == 10
