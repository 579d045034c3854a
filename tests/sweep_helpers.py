"""What the sweep's tests share: a short version of the default sweep file, and the check that two engines write
the same table."""

from __future__ import annotations

import csv
import re
from pathlib import Path

from offboard.harness import sweep
from offboard.harness.sweep_cli import execute

#: the figures of a sweep's table that two engines must give alike (to 1e-9)
FIGURES = ("peak_swing_rad", "residual_swing_rad", "tracking_rms_m", "final_error_m", "max_estimate_error_m")


def short_file(
    tmp_path: Path,
    engine: str = "scalar",
    estimator: str = "truth",
    move: float = 2.0,
    hold: float = 2.0,
    gust_start: tuple[float, float] = (0.5, 3.0),
) -> Path:
    """The default distribution with a short move and hold and the gusts early (cheap runs, the same parameters
    otherwise), written to ``tmp_path / "sweep.toml"``."""
    text = sweep.DEFAULT_FILE.read_text(encoding="utf-8")
    text = text.replace("move_time_s = 4.0", f"move_time_s = {move}").replace("hold_s = 8.0", f"hold_s = {hold}")
    text = text.replace('estimator = "kf"', f'estimator = "{estimator}"')
    text = re.sub(r'engine = "\w+"', f'engine = "{engine}"', text)
    lo, hi = gust_start
    text = text.replace("gust_start_s = {low = 1.0, high = 5.0}", f"gust_start_s = {{low = {lo}, high = {hi}}}")
    p = tmp_path / "sweep.toml"
    p.write_text(text, encoding="utf-8")
    return p


def assert_engines_write_the_same_table(
    tmp_path: Path, controller: str, engines: tuple[str, str], runs: int = 3
) -> None:
    """``slung sweep`` of ``runs`` runs of ``controller`` (the filter and the mixer, a 1 s move, 2.2 s hold) with
    each of two engines: the same verdicts, the same figures to 1e-9, and each engine really flew it."""
    tables = {}
    for eng in engines:
        (tmp_path / eng).mkdir()
        f = short_file(tmp_path / eng, engine=eng, estimator="kf", move=1.0, hold=2.2, gust_start=(0.5, 2.0))
        s = execute(runs, [controller], tmp_path / eng / "out", file=str(f), workers=0, figures=False, progress=False)
        assert s["engine_by_controller"] == {controller: eng}
        with open(tmp_path / eng / "out" / "results.csv", encoding="utf-8") as fh:
            tables[eng] = list(csv.DictReader(fh))
    a_rows, b_rows = (tables[e] for e in engines)
    assert len(a_rows) == len(b_rows) == runs
    for a, b in zip(a_rows, b_rows):
        for k in ("run", "success", "failure", "completed", "slack_steps", "sim_s"):
            assert a[k] == b[k], k
        for k in FIGURES:
            assert abs(float(a[k]) - float(b[k])) <= 1e-9, k  # (a NaN fails: every figure exists here)
