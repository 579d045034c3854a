"""MAVLink 2 signing (issue 10, item 4): pymavlink's check stores a packet's timestamp before it verifies the
signature, so one forged packet near 2^48 blocks every later signed packet of its stream; the check installed by
``estimators.mavlink_signing`` verifies first, in the loop's connection and in the emulator. ``slung fly
--signing-key`` flies the signing emulator, its timestamps persisted between sessions. Real UDP on 127.0.0.1."""

from __future__ import annotations

import argparse
import json
import os
import socket
import threading
import time
from pathlib import Path
from typing import Any

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from estimators.errors import UserError
from estimators.mavlink_signing import (
    clock_timestamp,
    install_checked_signing,
    next_timestamp,
    parse_key,
    save_timestamp,
)
from offboard.flight.fly_cli import configure as fly_configure
from offboard.flight.fly_cli import fly
from offboard.flight.link.connection import MavConnection, SigningConfig
from offboard.harness.demo_cli import EmulatorThread, free_udp_port

KEY = bytes(range(32))
NEAR_2_48 = (1 << 48) - 10


def _signer(system: int, component: int, link_id: int, key: bytes = KEY, ts: int | None = None) -> Any:
    m = mavlink2.MAVLink(None, srcSystem=system, srcComponent=component)
    m.signing.secret_key, m.signing.sign_outgoing, m.signing.link_id = key, True, link_id
    m.signing.timestamp = clock_timestamp() if ts is None else ts
    return m


def _receiver(checked: bool) -> Any:
    r = mavlink2.MAVLink(None)
    r.signing.secret_key = KEY
    r.signing.timestamp = clock_timestamp()
    if checked:
        install_checked_signing(r)
    return r


def _accepted(r: Any, frame: bytes) -> bool:
    try:
        return r.decode(bytearray(frame)) is not None
    except mavlink2.MAVError:
        return False


def _forged(system: int, component: int, link_id: int) -> bytes:
    """A frame of the genuine stream (link id, system, component) with a timestamp near 2^48, signed with the
    wrong key: what an attacker without the key can send."""
    bad = _signer(system, component, link_id, key=b"\x55" * 32, ts=NEAR_2_48)
    return bad.heartbeat_encode(6, 8, 0, 0, 4).pack(bad)


@pytest.mark.parametrize("checked", [False, True])
def test_a_forged_timestamp_blocks_pymavlink_but_not_the_checked_signing(checked: bool) -> None:
    good = _signer(255, 191, 1)
    r = _receiver(checked)
    assert _accepted(r, good.heartbeat_encode(6, 8, 0, 0, 4).pack(good))
    assert not _accepted(r, _forged(255, 191, 1))  # refused either way
    later = [good.heartbeat_encode(6, 8, 0, 0, 4).pack(good) for _ in range(5)]
    results = [_accepted(r, f) for f in later]
    if checked:
        assert all(results)  # the forged packet left nothing behind
    else:
        # pymavlink 2.4.x as documented in docs/deploy.md: the forged timestamp was stored before the signature
        # was checked, and every later genuine packet of the stream is now an "old timestamp"
        assert not any(results)
        assert r.signing.stream_timestamps[(1, 255, 191)] == NEAR_2_48


def test_the_loop_connection_is_not_poisoned_by_a_forged_packet_from_the_autopilot_address() -> None:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    conn = MavConnection(f"udpin:127.0.0.1:{port}", signing=SigningConfig(KEY, 1, None))
    ap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ap.bind(("127.0.0.1", 0))
    sig = _signer(1, 1, 0)
    try:
        ap.sendto(sig.heartbeat_encode(2, 12, 0, 0, 3).pack(sig), ("127.0.0.1", port))
        assert conn.wait_heartbeat(timeout=3.0).system == 1
        ap.sendto(_forged(1, 1, 0), ("127.0.0.1", port))
        for i in range(5):
            ap.sendto(sig.attitude_encode(100 + i, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1).pack(sig), ("127.0.0.1", port))
        got: list[Any] = []
        t_end = time.monotonic() + 3.0
        while len(got) < 5 and time.monotonic() < t_end:
            got += [r for r in conn.poll() if r.msg.get_type() == "ATTITUDE"]
            time.sleep(0.01)
        assert len(got) == 5 and conn.mav.signing.badsig_count >= 1
        # and what we send is signed (link id 1)
        buf = conn.send(conn.mav.heartbeat_encode(18, 8, 0, 0, 4))
        assert buf[2] & 0x01 and buf[-13] == 1
    finally:
        conn.close()
        ap.close()


def test_a_signing_loop_facing_an_unsigned_or_other_key_autopilot_says_so() -> None:
    """Issue 39: a signing ``slung fly`` facing an autopilot that does not sign said only "no autopilot heartbeat";
    the refused packets tell why, over a real UDP socket."""
    plain = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    other_key = _signer(1, 1, 0, key=bytes(range(32, 64)))
    for sender, words in ((plain, "unsigned packets refused"), (other_key, "bad signature")):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        s.close()
        conn = MavConnection(f"udpin:127.0.0.1:{port}", signing=SigningConfig(KEY, 1, None))
        ap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        stop = threading.Event()

        def beat(mav: Any, sock: socket.socket, to: int, done: threading.Event) -> None:
            while not done.is_set():
                sock.sendto(mav.heartbeat_encode(2, 12, 0, 0, 3).pack(mav), ("127.0.0.1", to))
                time.sleep(0.05)

        th = threading.Thread(target=beat, args=(sender, ap, port, stop), daemon=True)
        th.start()
        try:
            with pytest.raises(UserError, match=words) as e:
                conn.wait_heartbeat(timeout=1.0)
            assert "no signed autopilot heartbeat" in str(e.value)
        finally:
            stop.set()
            th.join()
            conn.close()
            ap.close()


def test_keys_and_timestamps(tmp_path: Path) -> None:
    assert parse_key(KEY.hex()) == KEY
    (tmp_path / "k.hex").write_text(KEY.hex() + "\n")
    (tmp_path / "k.bin").write_bytes(KEY)
    assert parse_key(f"@{tmp_path / 'k.hex'}") == KEY == parse_key(f"@{tmp_path / 'k.bin'}")
    for bad in ("abc", "00" * 31, f"@{tmp_path / 'missing'}"):
        with pytest.raises(UserError):
            parse_key(bad)
    state = tmp_path / "state.json"
    assert next_timestamp(state) >= clock_timestamp() - 1  # nothing persisted: the clock
    future = clock_timestamp() + 10**9  # a previous session whose clock ran ahead (or a clock that went back)
    assert save_timestamp(state, future, 1) is None
    assert next_timestamp(state) == future + 1
    assert save_timestamp(tmp_path / "no" / "dir" / "s.json", 1, 1) is not None  # a warning, no exception


@pytest.mark.slow
def test_fly_signed_against_the_signing_emulator_survives_a_forged_packet(tmp_path: Path) -> None:
    """The emulator signs and accepts only signed packets; ``slung fly --signing-key @FILE`` flies 4 s of hover
    in lockstep. 1.5 s into the flight a foreign sender forges a packet of the loop's own stream (system 255,
    component 191, link id 1) with a timestamp near 2^48: the emulator must keep accepting the loop's setpoints
    (without the check-before-store it refused them all, and its offboard-loss failsafe ended the flight)."""
    keyfile = tmp_path / "key.hex"
    keyfile.write_text(KEY.hex())
    state = tmp_path / "signing.json"
    port = free_udp_port()
    emu = EmulatorThread("px4", port, lockstep=True, period=0.004, signing_key=f"@{keyfile}").start()
    attacker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    emu_addr = ("127.0.0.1", emu.link.endpoints[0].local_port)
    sent = {"t0": float("inf"), "done": False}

    def probe(t: float) -> Any:
        if not sent["done"] and t >= sent["t0"] + 1.5:
            sent["done"] = True
            attacker.sendto(_forged(255, 191, 1), emu_addr)
        return emu.truth(t)

    def start(t0: float) -> None:
        sent["t0"] = t0

    p = argparse.ArgumentParser()
    fly_configure(p)
    args = p.parse_args(
        [
            *("--connect", f"udpin:127.0.0.1:{port}", "--scenario", "hover", "--duration", "4", "--lockstep"),
            *("--signing-key", f"@{keyfile}", "--signing-state", str(state), "--no-figures", "--out"),
            str(tmp_path / "f"),
        ]
    )
    before = clock_timestamp()
    try:
        m, _ = fly(args, lockstep=True, truth_probe=probe, quiet=True, on_reference_start=start)
    finally:
        summary = emu.stop()
        attacker.close()
    assert sent["done"]
    assert m["flight"]["ended_by"] == "completed", m["flight"]
    rx = summary["link"]["rx"]
    assert rx["bad_signature"] >= 1 and rx["unsigned_rejected"] == 0
    assert summary["mode"] == "AUTO.LOITER"
    sg = m["link"]["signing"]
    assert sg["good_signatures"] > 1000 and sg["bad_signatures"] == 0 and sg["unsigned_refused"] == 0
    persisted = json.loads(state.read_text())
    assert persisted["link_id"] == 1 and persisted["timestamp"] > before


@pytest.mark.slow
def test_the_mavsdk_backend_flies_signed(tmp_path: Path) -> None:
    """MAVSDK (Python) cannot sign: the backend re-signs its frames, so its arm / take-off / hold reach the signing
    emulator (which refuses unsigned packets) and the flight completes."""
    port = free_udp_port()
    emu = EmulatorThread("px4", port, lockstep=True, period=0.004, signing_key=KEY.hex()).start()
    p = argparse.ArgumentParser()
    fly_configure(p)
    args = p.parse_args(
        [
            *("--connect", f"udpin:127.0.0.1:{port}", "--scenario", "hover", "--duration", "3", "--lockstep"),
            *("--signing-key", KEY.hex(), "--signing-state", str(tmp_path / "s.json"), "--no-figures", "--out"),
            str(tmp_path / "f"),
        ]
    )
    try:
        m, _ = fly(args, lockstep=True, backend="mavsdk", truth_probe=emu.truth, quiet=True)
    finally:
        summary = emu.stop()
    assert m["flight"]["ended_by"] == "completed", m["flight"]
    assert summary["link"]["rx"]["unsigned_rejected"] == 0 and summary["link"]["rx"]["bad_signature"] == 0
    assert summary["mode"] == "AUTO.LOITER" and summary["counters"]["arms"] == 1
