"""Real components the tests use when the machine has them (PX4 SITL, a browser, ...), and one rule for when it
does not: the test **skips saying which component is missing**, unless ``SLUNG_REQUIRE_REAL=1`` is set (``.ci/run``
sets it), in which case it **fails** with the same reason, so that CI cannot pass by skipping the real thing.

Usage::

    from real_components import require, require_px4_sitl   # tests/ is on sys.path under pytest

    def test_something():
        root = require_px4_sitl()          # the px4-sitl folder, or skip / fail
        require("Chromium", None if shutil.which("chromium") else "chromium not on PATH")
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

#: set to 1 to turn every missing-component skip into a failure (CI)
ENV_REQUIRE_REAL = "SLUNG_REQUIRE_REAL"


def real_required() -> bool:
    """Whether ``SLUNG_REQUIRE_REAL`` asks for every real component (any value but empty / 0 / false / no)."""
    return os.environ.get(ENV_REQUIRE_REAL, "").strip().lower() not in ("", "0", "false", "no")


def require(component: str, why_missing: str | None) -> None:
    """Nothing when ``why_missing`` is None (the component is there); else skip the test with
    ``"<component> absent: <why>"``, or fail with it under ``SLUNG_REQUIRE_REAL=1``."""
    if why_missing is None:
        return
    text = f"{component} absent: {why_missing}"
    if real_required():
        pytest.fail(f"{text} ({ENV_REQUIRE_REAL}=1: real components are required)", pytrace=False)
    pytest.skip(text)


def require_px4_sitl() -> Path:
    """The PX4 SITL folder (``sim_bridge.sitl.px4_sitl.default_sitl_path``), or skip / fail saying why it is
    unusable."""
    from sim_bridge.sitl.px4_sitl import default_sitl_path, why_no_px4_sitl

    root = default_sitl_path()
    require("PX4 SITL", why_no_px4_sitl(root))
    return root


def require_ardupilot_sitl() -> Path:
    """The ArduPilot SITL folder (``sim_bridge.sitl.ardupilot_sitl.default_sitl_path``), or skip / fail saying why it
    is unusable."""
    from sim_bridge.sitl.ardupilot_sitl import default_sitl_path, why_no_ardupilot_sitl

    root = default_sitl_path()
    require("ArduPilot SITL", why_no_ardupilot_sitl(root))
    return root
