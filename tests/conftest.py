"""How the suite shares a machine when pytest-xdist runs it on several workers (``pytest -n auto``, the default in
``pyproject.toml``).

Each test file is one ``xdist_group``, so a file's module fixtures (a demo flight, PX4 flights) run once, on one
worker, as they would serially. The files that start PX4 SITL share a single group: they run one after another on
one worker, so no two PX4 instances (each a real-time simulation plus a 250 Hz loop) compete for the two cores of
a CI machine, and the fixed instance numbers of those files cannot collide. Without xdist (``-p no:xdist`` or
``-n 0``) the marks are inert.
"""

from __future__ import annotations

import functools
from pathlib import Path

import pytest

#: the group of every test file that starts PX4 SITL (it calls ``real_components.require_px4_sitl``)
PX4_SITL_GROUP = "px4-sitl"


@functools.cache
def _group_of(path: Path) -> str:
    return PX4_SITL_GROUP if "require_px4_sitl()" in path.read_text(encoding="utf-8") else path.name


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        item.add_marker(pytest.mark.xdist_group(_group_of(item.path)))
