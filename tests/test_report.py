"""The run report as people see it: ``report.html`` of a real demo run opened in headless Chromium, the live
status of ``slung demo`` on a terminal (a pty) and through a pipe, the command line's manners, and the data
behind the fixed figures (``offboard.report.report.figure_specs``).

One demo runs on a pty for the whole module (``demo_tty``) and one in-process with its stderr captured
(``demo_piped``); the other tests read their outputs.
"""

from __future__ import annotations

import io
import itertools
import json
import math
import os
import pty
import select
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cdp_browser import Browser, chromium_path
from real_components import require

from offboard.logs.timeseries_file import read_table

ROOT = Path(__file__).resolve().parents[1]
#: the piped demo of this module flies the paper scenario's first seconds (then its smooth stop and the settle)
DEMO_DURATION_S = 3.0
PHASES = ("[connecting]", "[arming]", "[take-off]", "[approach]", "[control]", "[hand-over]")


def _run_on_pty(argv: list[str], timeout_s: float = 300.0) -> tuple[int, str]:
    """Run ``argv`` with stdin, stdout and stderr on a new pseudo-terminal; returns (exit code, everything it
    wrote, with the terminal's carriage returns kept)."""
    master, slave = pty.openpty()
    proc = subprocess.Popen(argv, stdin=slave, stdout=slave, stderr=slave, cwd=ROOT, close_fds=True)
    os.close(slave)
    chunks = []
    deadline = time.monotonic() + timeout_s
    try:
        while time.monotonic() < deadline:
            r, _, _ = select.select([master], [], [], 1.0)
            if r:
                try:
                    data = os.read(master, 65536)
                except OSError:  # EIO: the child closed the terminal
                    break
                if not data:
                    break
                chunks.append(data)
            elif proc.poll() is not None:
                break
        rc = proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(master)
    return rc, b"".join(chunks).decode("utf-8", "replace")


@pytest.fixture(scope="module")
def demo_tty(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, str, Path]:
    """``slung demo --duration 6`` on a pty: (exit code, terminal output, report folder)."""
    out = tmp_path_factory.mktemp("demo-tty") / "report"
    rc, text = _run_on_pty([sys.executable, "-m", "offboard.cli", "demo", "--duration", "6", "--out", str(out)])
    return rc, text, out


@pytest.fixture(scope="module")
def demo_piped(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """``slung demo --duration 3`` in this process, stdout and stderr into pipes (not a terminal), with the figure
    descriptions and report.html's panels the report drew recorded: {"rc", "stdout", "stderr", "out", "specs",
    "panels"}."""
    import offboard.report.report as report
    import offboard.report.run_report_html as run_html
    from offboard import cli

    out = tmp_path_factory.mktemp("demo-piped") / "report"
    specs: list[Any] = []
    panels: list[Any] = []
    real = report.figure_specs
    real_panels = run_html.build_panels

    def recording(*a: Any, **k: Any) -> Any:  # the real function; its result is kept for the figure tests
        s = real(*a, **k)
        specs.extend(s)
        return s

    def recording_panels(*a: Any, **k: Any) -> Any:
        s = real_panels(*a, **k)
        panels.extend(s)
        return s

    report.figure_specs = recording
    run_html.build_panels = recording_panels
    o, e = io.StringIO(), io.StringIO()
    old = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = o, e
    try:
        rc = cli.main(["demo", "--duration", str(DEMO_DURATION_S), "--out", str(out)])
    finally:
        sys.stdout, sys.stderr = old
        report.figure_specs = real
        run_html.build_panels = real_panels
    return {"rc": rc, "stdout": o.getvalue(), "stderr": e.getvalue(), "out": out, "specs": specs, "panels": panels}


# ------------------------------------------------------------------------------------------------ live status ---
@pytest.mark.slow
def test_demo_on_a_terminal_shows_the_phases_and_a_refreshed_status_line(demo_tty) -> None:
    rc, text, _ = demo_tty
    assert rc == 0, text[-2000:]
    where = [text.find(p) for p in PHASES]
    assert all(i >= 0 for i in where), (where, text[:3000])
    assert where == sorted(where), f"phases out of order: {where}"
    # the status line is redrawn in place: a carriage return without a newline, then the next state
    control = text[where[4] : where[5]]
    refreshed = [seg for seg in control.split("\r") if "link age" in seg and "swing" in seg]
    assert len(refreshed) >= 2, control[:2000]
    assert "\x1b[K" in control  # each redraw clears the rest of the old line


def test_an_open_status_keeps_the_loop_s_events_off_the_log_unless_asked(caplog: pytest.LogCaptureFixture) -> None:
    """Every loop event is a status line ("[control] swing_limit: ..."); the same words as a WARNING log record
    printed them twice. While a status is open the loop's records stay off the log, errors excepted, and with the
    log at INFO (-v) they are all kept; once it closes the log is as before."""
    import io
    import logging

    from offboard.flight.status import FlightStatus

    loop_log = logging.getLogger("offboard.flight.loop")
    other = logging.getLogger("offboard.flight.link.management")
    caplog.set_level(logging.WARNING)
    status = FlightStatus(io.StringIO(), tty=False)
    try:
        loop_log.warning("swing_limit: shown by the status")
        loop_log.error("an error is kept")
        other.warning("another module's warning is kept")
        with caplog.at_level(logging.INFO, logger="offboard.flight.loop"):
            loop_log.warning("kept with -v")
    finally:
        status.close()
    loop_log.warning("kept once the status is closed")
    got = [r.getMessage() for r in caplog.records]
    assert got == [
        "an error is kept",
        "another module's warning is kept",
        "kept with -v",
        "kept once the status is closed",
    ], got


@pytest.mark.slow
def test_demo_through_a_pipe_prints_plain_lines_and_one_report_line(demo_piped) -> None:
    err, out = demo_piped["stderr"], demo_piped["stdout"]
    assert demo_piped["rc"] == 0, err[-2000:]
    assert "\r" not in err and "\x1b[" not in err, err[:2000]
    lines = err.splitlines()
    for p in PHASES:
        assert any(line.startswith(p) for line in lines), (p, err[:3000])
    assert sum(line.startswith("report: ") for line in out.splitlines()) == 1, out
    assert not out.strip().splitlines()[-1].startswith("{"), "no JSON line repeats the report path"
    # the default demo's pre-flight note says what to do, and is not an alarm
    assert "pre-flight check: warning" not in err
    notes = [line for line in lines if line.startswith("pre-flight check, note:")]
    assert all("to avoid it" in n for n in notes), notes


@pytest.mark.slow
def test_report_files_get_the_users_umask_like_the_tlog(demo_piped) -> None:
    out: Path = demo_piped["out"]
    mask = os.umask(0o022)
    os.umask(mask)
    want = 0o666 & ~mask
    assert (out / "flight.tlog").stat().st_mode & 0o777 == want
    for name in ("report.html", "metrics.json", "events.json", "timeseries.slts", "fig05_tracking.png"):
        assert (out / name).stat().st_mode & 0o777 == want, name


def test_version_and_user_facing_help() -> None:
    r = subprocess.run([sys.executable, "-m", "offboard.cli", "--version"], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0 and r.stdout.startswith("slung ") and r.stdout.split()[1][0].isdigit(), r.stdout
    r = subprocess.run([sys.executable, "-m", "offboard.cli", "--help"], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0
    assert "the command-line front end" not in r.stdout  # the module's developer docstring
    assert "slung demo" in r.stdout and "damps the load's swing" in r.stdout


# ------------------------------------------------------------------------------------------------ report.html ---
def _require_chromium() -> str:
    path = chromium_path()
    require("Chromium", None if path else "Debian's chromium is not installed (apt-get install chromium)")
    assert path is not None
    return path


def _png_pixels(png: bytes) -> np.ndarray:
    import matplotlib.image as mpimg

    return np.asarray(mpimg.imread(io.BytesIO(png), format="png"))


_BUTTONS = """(() => Array.from(document.querySelectorAll('#slung-view .updatemenu-button')).map(e => {
  const r = e.getBoundingClientRect(); return [e.textContent, r.x + r.width / 2, r.y + r.height / 2]; }))()"""
_CURSOR = "document.getElementById('slung-plots').layout.shapes[0].x0"


@pytest.mark.slow
def test_report_html_opens_in_headless_chromium(demo_tty) -> None:
    binary = _require_chromium()
    rc, text, out = demo_tty
    assert rc == 0, text[-2000:]
    page = out / "report.html"
    # plotly's 4.8 MB embedded gzip-compressed (1.9 MB as base64) plus the decimated data of a short run
    assert page.stat().st_size < 5e6
    with Browser(binary, timeout_s=180.0) as b:
        b.open(page, settle_s=1.0)
        for _ in range(120):  # the page unpacks plotly.js (DecompressionStream), then draws: wait until it says so
            if b.eval("document.body.dataset.slungReady") == "1":
                break
            b.pump(0.5)
        assert b.eval("document.body.dataset.slungReady") == "1", b.page.errors()
        assert b.page.errors() == [], b.page.errors()
        # nothing but the page itself: plotly's JavaScript is embedded, no CDN, no fonts from the web
        foreign = [u for u in b.page.requests if u != page.resolve().as_uri() and not u.startswith(("data:", "blob:"))]
        assert foreign == [], foreign
        assert b.eval("!!document.getElementById('slung-view')._fullLayout.scene._scene") is True
        assert b.eval("document.querySelectorAll('#slung-view canvas').length") >= 1  # WebGL drew the scene
        n_plots = b.eval("document.getElementById('slung-plots')._fullLayout._subplots.cartesian.length")
        assert n_plots >= 6, n_plots
        # the estimation errors drawn with the filter's +-2 sigma band, and the innovations panel
        bands = b.eval(
            "document.getElementById('slung-plots').data.filter(d => d.fill === 'toself' && d.name.includes('±2σ'))"
            ".length"
        )
        assert bands >= 5, bands  # alpha_x, alpha_y, F_x, F_y, z
        titles = b.eval("[...document.querySelectorAll('#slung-plots .annotation-text')].map(e => e.textContent)")
        assert any(t.startswith("Filter innovations") for t in titles), titles
        # one cursor across every time plot: shape 0 spans the whole figure height on the shared x axis
        assert b.eval("JSON.stringify(document.getElementById('slung-plots').layout.shapes[0].yref)") == '"paper"'
        t_before = b.eval(_CURSOR)
        buttons = b.eval(_BUTTONS)
        labels = [x[0] for x in buttons]
        assert any("pause" in lb for lb in labels) and sum("▶" in lb for lb in labels) >= 2, labels
        play = next(x for x in buttons if x[0].startswith("▶ 1x"))
        b.click(play[1], play[2])
        b.pump(2.5)
        t_playing = b.eval(_CURSOR)
        assert t_playing > t_before + 0.1, (t_before, t_playing)
        pause = next(x for x in buttons if "pause" in x[0])
        b.click(pause[1], pause[2])
        b.pump(0.5)
        t_paused = b.eval(_CURSOR)
        b.pump(1.0)
        assert b.eval(_CURSOR) == t_paused  # paused: the cursor stays
        shot = _png_pixels(b.screenshot())
        assert b.page.errors() == [], b.page.errors()
    rgb = shot[..., :3]
    not_white = np.mean(np.any(rgb < 0.9, axis=-1))
    colours = len(np.unique((rgb * 255).astype(np.uint8).reshape(-1, 3), axis=0))
    assert not_white > 0.03 and colours > 50, (not_white, colours)


@pytest.mark.slow
def test_report_html_draws_the_filters_band_and_its_innovations(demo_piped) -> None:
    """report.html's estimation panels carry the band +-2 sigma of the standard deviations the loop logged from the
    filter's covariance, and the innovations panel the logged normalized innovations; the band says something:
    the true error (the emulator's truth) stays inside it most of the time, and it is narrower than the swing."""
    from offboard.report.filter_readouts import moving_rms

    assert demo_piped["rc"] == 0, demo_piped["stderr"][-2000:]
    out: Path = demo_piped["out"]
    table = read_table(out / "timeseries_live.slts")
    header, data = list(table.columns), table.data
    m = json.loads((out / "metrics.json").read_text())
    # the report is the reference's span; the ticks after it (the smooth stop of the 3 s reference, still climbing
    # and turning at its end, then the settle) are reported apart (metrics.json "settle")
    assert m["settle"]["flown_s"] > 1.0
    data = data[data[:, header.index("t_ref")] <= DEMO_DURATION_S + 1e-9]
    live = {n: data[:, i] for i, n in enumerate(header)}
    panels = {p.title: p for p in demo_piped["panels"]}
    for title, sds in (
        ("Swing estimate minus truth", ("sd_alpha_x", "sd_alpha_y")),
        ("Load position estimate minus truth", ("sd_fx0", "sd_fy0", "sd_z")),
    ):
        for tr, sd in zip(panels[title].traces, sds, strict=True):
            # the report draws the filter's values as computed; the tick log keeps them as float16
            # (offboard.logs.live_storage): half the band, rounded as the log rounds, is the logged value exactly
            assert tr.band is not None, (title, tr.name)
            kept = table.stored_as(sd)
            np.testing.assert_array_equal((tr.band[1] / 2.0).astype(kept), live[sd].astype(kept))
            np.testing.assert_array_equal((tr.band[0] / -2.0).astype(kept), live[sd].astype(kept))
    within = m["estimation"]["within_2sigma"]
    assert min(within.values()) >= 0.8, within  # not overconfident: a consistent filter has about 0.95
    assert np.median(live["sd_alpha_x"]) < 0.02 and np.median(live["sd_fx0"]) < 0.02  # and not vacuous
    inn = next(p for title, p in panels.items() if title.startswith("Filter innovations"))
    streams = [tr.name.split(" ")[0] for tr in inn.traces]
    assert {"pos", "z", "tilt", "psi", "acc"} <= set(streams), streams
    for tr, s in zip(inn.traces, streams, strict=True):
        # from the values as computed; the log's are within float16's relative rounding (2^-11) of them, and so is
        # a root mean square of them
        np.testing.assert_allclose(tr.y, moving_rms(inn.t, live["nu_" + s]), rtol=2.0**-11 * 1.001, atol=0.0)
        assert 0.5 < np.nanmedian(tr.y) < 2.0, (s, np.nanmedian(tr.y))  # about 1: the filter expects what it sees


# ----------------------------------------------------------------------------------- the figures' fixed data ---
@pytest.fixture(scope="module")
def sim_run() -> tuple[Any, list[Any]]:
    """Figure descriptions of a 27 s paper-scenario simulation (the disturbance starts at 25 s), sign switching,
    controller on the true state."""
    from estimators.model.vehicle import load_vehicle
    from offboard.control import smc
    from offboard.control.scenarios import make_scenario
    from offboard.harness.sim import SimConfig, run
    from offboard.report import metrics as metrics_mod
    from offboard.report.report import figure_specs

    vehicle = load_vehicle(None)
    params = smc.ControllerParams.for_vehicle(vehicle, switching="sign")
    cfg = SimConfig(plant_dt=0.001, control_rate=250.0, attitude_model="rigid", sensors=None, estimator="truth")
    log = run(make_scenario("paper", duration=27.0), vehicle, params, cfg)
    m = metrics_mod.compute(log)
    m["config"]["switching"] = "sign"
    return log, figure_specs(log, m, command="sim")


@pytest.fixture(scope="module")
def sim_specs(sim_run) -> list[Any]:
    return sim_run[1]


def _spec(specs: list[Any], name: str) -> Any:
    return next(s for s in specs if s.name == name)


def test_swing_figure_has_no_unwrapped_beta_and_marks_the_disturbance(sim_specs) -> None:
    fig08 = _spec(sim_specs, "fig08_swing.png")
    assert not any("beta" in r.ylabel for r in fig08.rows)
    for r in fig08.rows:
        y = r.lines[0].y
        assert np.all(np.abs(y[np.isfinite(y)]) < math.pi / 2), r.ylabel  # angles of a hanging load
    assert any(abs(t - 25.0) < 1e-9 and "disturbance" in label for t, label in fig08.markers), fig08.markers


def test_control_figure_draws_limits_and_a_readable_line_under_sign_switching(sim_run) -> None:
    log, specs = sim_run
    fig11 = _spec(specs, "fig11_controls.png")
    by = {r.ylabel: r for r in fig11.rows}
    assert [v for _, v in by["u [N]"].limits] == [pytest.approx(16.0), 0.0]
    tau = by["tau_phi [N m]"]
    assert sorted(v for _, v in tau.limits) == pytest.approx([-0.825, 0.825], rel=1e-3)
    line = tau.lines[0]
    lo, hi = line.envelope
    assert np.all(lo <= line.y + 1e-12) and np.all(line.y <= hi + 1e-12)
    # the drawn line varies far less from tick to tick than the raw sign-switching command (which, drawn as it
    # is, fills a solid band): the envelope keeps the switching amplitude visible
    raw = log.column("tau_phi")
    assert np.sum(np.abs(np.diff(raw))) > 20 * np.sum(np.abs(np.diff(line.y)))
    assert np.max(hi - lo) > 0.1


@pytest.mark.slow
def test_titles_say_what_ran(sim_specs, demo_piped) -> None:
    for s in sim_specs:
        assert "slung sim: paper scenario" in s.title and "sign switching" in s.title, s.title
    flight = demo_piped["specs"]
    assert flight, "the demo drew no figure"
    for s in flight:
        assert "slung demo: paper scenario, px4 emulator" in s.title and "kf estimator" in s.title, s.title
        # the controller that flew (config.controller): --law auto flies the torque-level law on the paper vehicle
        assert "smc controller" in s.title, s.title


@pytest.mark.slow
def test_flight_figures_drop_the_empty_nees_panel_and_show_setpoint_against_achieved(demo_piped) -> None:
    specs = demo_piped["specs"]
    fig14 = _spec(specs, "fig14_estimation.png")
    assert not any(r.ylabel == "NEES" for r in fig14.rows)  # a flight computes no NEES: no empty panel
    assert any("F_y" in ln.label for r in fig14.rows for ln in r.lines)  # both axes, not only F_x
    fig15 = _spec(specs, "fig15_setpoints.png")
    (roll_sent, roll_done), (pitch_sent, pitch_done) = (
        (ln.y for ln in fig15.rows[0].lines),
        (ln.y for ln in fig15.rows[1].lines),
    )
    # what was sent is the wire's quaternion (NED -> FRD) in the model frame (NWU: roll as NED, pitch negated),
    # computed here independently of estimators.model.frames; what was achieved is the emulator's true attitude
    from offboard.flight.loop import LIVE_COL

    live = read_table(demo_piped["out"] / "timeseries_live.slts").data
    live = live[live[:, LIVE_COL["t_ref"]] <= DEMO_DURATION_S + 1e-9]  # the figures are the reference's span
    w, x, y, z = (live[:, LIVE_COL[f"sp{i}"]] for i in range(4))
    np.testing.assert_allclose(roll_sent, np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)), atol=1e-9)
    np.testing.assert_allclose(pitch_sent, -np.arcsin(np.clip(2 * (w * y - z * x), -1, 1)), atol=1e-9)
    np.testing.assert_allclose(roll_done, live[:, LIVE_COL["truth_x6"]], atol=1e-12)
    np.testing.assert_allclose(pitch_done, live[:, LIVE_COL["truth_x7"]], atol=1e-12)
    assert np.mean(np.abs(roll_sent - roll_done)) < 0.05 and np.mean(np.abs(pitch_sent - pitch_done)) < 0.05
    marks = [label for _, label in _spec(specs, "fig05_tracking.png").markers]
    assert any("offboard control started" in m for m in marks), marks


def test_path3d_tick_labels_do_not_overlap(sim_run) -> None:
    import matplotlib.pyplot as plt

    from offboard.report.report import draw_path3d

    fig = draw_path3d(sim_run[0], "slung sim: paper scenario")
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        checked = 0
        for ax in fig.axes:
            for axis in [ax.xaxis, ax.yaxis] + ([ax.zaxis] if hasattr(ax, "zaxis") else []):
                boxes = [lb.get_window_extent(renderer) for lb in axis.get_ticklabels() if lb.get_text()]
                checked += len(boxes)
                for a, b in itertools.pairwise(boxes):
                    assert not a.overlaps(b), (axis.axis_name, a, b)
        assert checked >= 20
    finally:
        plt.close(fig)


@pytest.mark.slow
def test_replay_writes_its_report_html(demo_tty, tmp_path) -> None:
    from offboard import cli

    rc, text, out = demo_tty
    assert rc == 0, text[-2000:]
    assert cli.main(["replay", str(out / "flight.tlog"), "--out", str(tmp_path)]) == 0
    from offboard.report.html_plotly import unpacked

    packed = (tmp_path / "report.html").read_text(encoding="utf-8")
    page = unpacked(packed)  # the figures' scripts as the browser runs them
    assert len(page) > len(packed) and "Swing alpha_x: estimate, sensor" not in packed
    assert "slung replay: flight.tlog" in page
    assert 'id="slung-view"' in page and 'id="slung-plots"' in page  # 3D view and time plots
    assert "Swing alpha_x: estimate, sensor" in page and "Thrust setpoint: logged and recomputed" in page
    assert "Vehicle position: estimate and autopilot" in page and "Filter innovations" in page
    assert "phi estimate \\u00b12\\u03c3" in page or "phi estimate ±2σ" in page  # with the filter's band
    assert "cdn.plot.ly" not in page.split("<script", 1)[0]  # nothing to fetch before plotly's embedded bundle
