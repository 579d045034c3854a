"""How the suite shares a machine when pytest-xdist runs it on several workers (``pytest -n auto``, the default in
``pyproject.toml``).

Work is handed out by test file, so a file's module fixtures (a demo flight, PX4 flights) run once, on one worker, as
they would serially. The files that start a real autopilot's SITL, PX4's or ArduPilot's, form one unit: they run one
after another on one worker, so no two SITLs (each a real-time simulation plus a 250 Hz loop) compete for the two
cores of a CI machine, the fixed instance numbers of the PX4 files cannot collide, and ArduPilot's payload
simulation, which connects to instance 0 whatever the instance, serves one flight at a time. With ``-n 0`` (one
process), or another ``--dist`` than xdist's default ``load``, none of this applies.

The grouping is a scheduler of its own rather than ``--dist loadgroup`` with ``xdist_group`` marks: pytest-xdist
3.8 forms those groups by rewriting ``item._nodeid``, which pytest 9.2 no longer reads, so the marks were silently
ignored (seen: PX4 flights on both workers, "PX4 server already running for instance 0").
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import pytest

#: the work unit of every test file that starts PX4 or ArduPilot SITL (it calls ``real_components.require_px4_sitl``
#: or ``require_ardupilot_sitl``)
PX4_SITL_UNIT = "px4-sitl"
SITL_MARKERS = ("require_px4_sitl()", "require_ardupilot_sitl()")


@functools.cache
def _starts_px4_sitl(path: Path) -> bool:
    if not path.is_file():
        return False
    text = path.read_text(encoding="utf-8")
    return any(marker in text for marker in SITL_MARKERS)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
    if config.getvalue("dist") != "load":  # another --dist asked for on the command line: xdist's own scheduler
        return None
    from xdist.scheduler import LoadFileScheduling

    class ByFilePx4Serial(LoadFileScheduling):
        """``--dist loadfile``, but every PX4 or ArduPilot SITL file in one unit."""

        def _split_scope(self, nodeid: str) -> str:
            file = super()._split_scope(nodeid)
            return PX4_SITL_UNIT if _starts_px4_sitl(config.rootpath / file) else file

    return ByFilePx4Serial(config, log)
