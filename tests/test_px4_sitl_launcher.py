"""The PX4 SITL launcher (``sim_bridge.sitl.px4_sitl``), the ULog reader (``sim_bridge.sitl.px4_ulog``) and the
skip-or-fail rule for real components (``tests/real_components.py``), against the real SITL where it is installed.
PX4 instance 3 (the flight tests use 0-2)."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from pymavlink import mavutil
from real_components import require_px4_sitl

from estimators.model.vehicle import load_vehicle
from offboard.flight.link.connection import MavConnection
from offboard.flight.link.management import Manager
from sim_bridge.sitl.px4_sitl import Px4Sitl, Px4SitlError, make_bin_dir, why_no_px4_sitl
from sim_bridge.sitl.px4_ulog import read_px4_ulog

ROOT = Path(__file__).resolve().parents[1]


def test_bin_dir_turns_flattened_aliases_into_symlinks(tmp_path: Path) -> None:
    src = tmp_path / "bin"
    src.mkdir()
    (src / "px4").write_bytes(b"\x7fELF fake")
    (src / "px4-param").write_text("px4")  # a flattened alias, as shipped
    (src / "px4-alias.sh").write_text("#!/bin/sh\nalias x=y\n")
    out = make_bin_dir(src, tmp_path / "private")
    assert (out / "px4-param").is_symlink() and (out / "px4-param").resolve() == (src / "px4").resolve()
    assert (out / "px4").resolve() == (src / "px4").resolve()
    assert not (out / "px4-alias.sh").is_symlink() and (out / "px4-alias.sh").read_text().startswith("#!/bin/sh")


def test_absent_sitl_is_reported_with_its_path(tmp_path: Path) -> None:
    why = why_no_px4_sitl(tmp_path / "nowhere")
    assert why is not None and "nowhere" in why
    with pytest.raises(Px4SitlError, match="no PX4 SITL binary"):
        Px4Sitl(instance=3, root=tmp_path / "nowhere").start()


def _run_snippet(code: str, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--rootdir", str(ROOT), "-x", "snippet.py"],
        cwd=env["SNIPPET_DIR"],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_missing_component_skips_or_fails_under_require_real(tmp_path: Path) -> None:
    """A missing real component skips with its reason; with SLUNG_REQUIRE_REAL=1 the same test fails."""
    (tmp_path / "snippet.py").write_text(
        textwrap.dedent(
            f"""
            import sys
            sys.path.insert(0, {str(ROOT / "tests")!r})
            from real_components import require_px4_sitl

            def test_needs_px4():
                require_px4_sitl()
            """
        )
    )
    env = {**os.environ, "SNIPPET_DIR": str(tmp_path), "SLUNG_PX4_SITL": str(tmp_path / "no-sitl")}
    env.pop("SLUNG_REQUIRE_REAL", None)
    skipped = _run_snippet("", env)
    assert skipped.returncode == 0 and "1 skipped" in skipped.stdout, skipped.stdout
    failed = _run_snippet("", {**env, "SLUNG_REQUIRE_REAL": "1"})
    assert failed.returncode == 1 and "1 failed" in failed.stdout, failed.stdout
    assert "PX4 SITL absent" in failed.stdout


@pytest.mark.slow
def test_sitl_starts_speaks_mavlink_logs_and_stops(tmp_path: Path) -> None:
    root = require_px4_sitl()
    sitl = Px4Sitl(instance=3, workdir=tmp_path / "px4", root=root, params={"COM_OBL_RC_ACT": 5})
    with sitl:
        assert sitl.running and sitl.ready_after_s is not None
        conn = mavutil.mavlink_connection(sitl.connection_url, source_system=255)
        try:
            hb = conn.wait_heartbeat(timeout=10)
            assert hb is not None and hb.get_srcSystem() == sitl.system_id and hb.autopilot == 12
            conn.mav.param_request_read_send(sitl.system_id, 1, b"COM_OBL_RC_ACT", -1)
            t_end = time.monotonic() + 10
            value = None
            while time.monotonic() < t_end and value is None:
                m = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=1)
                if m is not None and m.param_id.rstrip("\x00") == "COM_OBL_RC_ACT":
                    assert m.param_type == mavutil.mavlink.MAV_PARAM_TYPE_INT32
                    # PX4 sends integer parameters bytewise: the int32's bytes in the float field
                    value = struct.unpack("<i", struct.pack("<f", m.param_value))[0]
            assert value == 5  # the parameter given at start reached PX4
        finally:
            conn.close()
        # the flight path's own parameter reading: PX4's allocator effectiveness and tilt limit
        link = MavConnection(sitl.connection_url)
        try:
            link.wait_heartbeat(timeout=10)
            mgr = Manager(link)
            assert link.param_get("CA_ROTOR_COUNT") == 4  # an INT32, sent bytewise
            unit = mgr.read_px4_unit_torques(load_vehicle("px4-sih"))
            assert (
                unit is not None
                and unit[0] == pytest.approx(2.828, abs=0.01)
                and unit[1] == pytest.approx(2.828, abs=0.01)
            )
            tilt = mgr.read_tilt_limit()
            assert tilt is not None and 0.1 < tilt < 1.5
        finally:
            link.close()
        # PX4's own clock, not the wall clock: run_for waits for it (and nobody else is on the link now)
        ran = sitl.run_for(2.0)
        assert 2.0 <= ran < 3.0, ran
        assert sitl.ulogs(), "PX4 logs from boot (SDLOG_MODE 1)"
    assert not sitl.running
    assert "Ready for takeoff!" in sitl.log_text()
    log = read_px4_ulog(sitl.ulogs()[-1])
    assert len(log.truth_pos) > 10 and len(log.truth_att) > 10 and len(log.ekf_pos) > 10
    # on the ground, level: truth tilt under 2 degrees
    assert float(abs(log.truth_att["tilt"]).max()) < 0.035
