"""Live status of ``slung fly`` / ``slung demo`` on the terminal: the phase of the flight (connecting, arming,
take-off, approach, control, hand-over) and, while controlling, one line refreshed a few times a second (reference
time, tracking error, swing, loop rate, link age).

It costs the control loop nothing: a daemon thread of its own wakes every ``interval_s`` (0.25 s), reads the
loop's newest logged row and counters (plain attribute reads; the loop's lists are only appended to), and writes
to the stream. The loop does no I/O and calls nothing of this module. On a terminal the status line is redrawn in
place (carriage return); when the stream is not a terminal (a pipe, a file, CI) every phase is one plain line and
the status is a plain line every ``plain_every_s`` (5 s). Everything goes to stderr: stdout keeps the results.

Phases are read from what the loop and its vehicle management record anyway (``FlightLoop.events``,
``Manager.events``), so a phase shows up here with the same words as in ``events.json``. While a status is open,
the loop's own log records (``offboard.flight.loop``: every event, at INFO or WARNING) are therefore not printed a
second time by the default log handler, unless ``-v`` asked for the log (the logger's level at INFO or below).
"""

from __future__ import annotations

import contextlib
import logging
import math
import sys
import threading
import time
from typing import Any, TextIO

#: the logger whose every record is also a loop event that the status prints (offboard.flight.loop.FlightLoop.event)
_LOOP_LOGGER = "offboard.flight.loop"


class _ShownByStatus(logging.Filter):
    """Drops the loop's records while the status shows them as events, unless the log was asked for (-v)."""

    def filter(self, record: logging.LogRecord) -> bool:
        return record.levelno >= logging.ERROR or logging.getLogger(_LOOP_LOGGER).getEffectiveLevel() <= logging.INFO


#: management event kind -> phase it starts (``offboard.flight.link.management.Manager.note``)
_MANAGEMENT_PHASES = {"arm": "arming", "takeoff": "take-off", "takeoff_done": "take-off"}


class FlightStatus:
    """The status display of one flight. ``phase()`` from the flight's thread for phases before the loop exists;
    ``attach(loop)`` once the loop is built; ``close()`` at the end (also as a context manager)."""

    def __init__(
        self,
        stream: TextIO | None = None,
        *,
        interval_s: float = 0.25,
        plain_every_s: float = 5.0,
        tty: bool | None = None,
    ) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(tty if tty is not None else getattr(self.stream, "isatty", lambda: False)())
        self.interval_s = interval_s
        self.plain_every_s = plain_every_s
        self.loop: Any = None
        self.current = ""
        self._seen_loop = 0
        self._seen_mgr = 0
        self._line_open = False
        self._last_plain = -math.inf
        self._last_ticks = 0
        self._last_wall = time.monotonic()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="slung-status", daemon=True)
        self._filter = _ShownByStatus()
        logging.getLogger(_LOOP_LOGGER).addFilter(self._filter)
        self._thread.start()

    # -------------------------------------------------------------------------------------------- API ---
    def phase(self, name: str, detail: str = "") -> None:
        """Announce a phase (one line; on a terminal it replaces the status line)."""
        with self._lock, contextlib.suppress(OSError, ValueError):  # a closed stderr must not stop the flight
            self._phase(name, detail)

    def attach(self, loop: Any) -> None:
        """Follow ``loop`` (a :class:`offboard.flight.loop.FlightLoop`): its events and, while it controls, its rows."""
        self.loop = loop

    def close(self) -> None:
        """Stop the thread (after one last poll, so that the hand-over is shown) and end the status line."""
        self._stop.set()
        self._thread.join(timeout=2.0)
        logging.getLogger(_LOOP_LOGGER).removeFilter(self._filter)
        with self._lock, contextlib.suppress(OSError, ValueError):  # a closed stderr must not lose the report
            self._poll_events()
            self._end_line()

    def __enter__(self) -> FlightStatus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------------------------------ thread ---
    def _run(self) -> None:
        while not self._stop.wait(self.interval_s):
            try:
                with self._lock:
                    self._poll_events()
                    if self.current == "control":
                        self._status_line()
            except Exception:  # the display must never take the flight down
                continue

    def _poll_events(self) -> None:
        loop = self.loop
        if loop is None:
            return
        mgr = getattr(loop, "mgr", None)
        mev = list(getattr(mgr, "events", []))
        lev = list(loop.events)
        # both lists in the order things happened (both carry local monotonic time)
        new = sorted(
            [(ev.t, "mgr", ev) for ev in mev[self._seen_mgr :]]
            + [(ev.t_local, "loop", ev) for ev in lev[self._seen_loop :]],
            key=lambda x: x[0],
        )
        self._seen_mgr, self._seen_loop = len(mev), len(lev)
        for _, source, ev in new:
            if source == "mgr":
                if ev.kind in _MANAGEMENT_PHASES:
                    self._phase(_MANAGEMENT_PHASES[ev.kind], ev.detail)
                elif ev.kind == "set_mode" and ev.detail.startswith("offboard"):
                    self._phase("approach", "offboard mode: " + ev.detail + "; flying to the start of the reference")
            elif ev.kind == "phase" and ev.reason.startswith("offboard control started"):
                self._phase("control", f"following the reference for {loop.duration:g} s")
                self._last_ticks, self._last_wall = loop.stats.ticks, time.monotonic()
            elif ev.kind == "phase":
                self._phase("pre-flight" if ev.reason.startswith("preflight") else self.current, ev.reason)
            elif ev.kind == "exit":
                self._phase("hand-over", ev.reason)
            elif ev.kind == "exit_done":
                # the reason names the mode already when the vehicle was left to it ("in POSCTL, armed (...)")
                said = ev.reason if ev.reason.startswith("in ") else f"in {ev.reason}"
                self._phase("hand-over", f"autopilot {said}")
            else:
                self._phase(self.current or "pre-flight", f"{ev.kind}: {ev.reason}")

    def _status_line(self) -> None:
        loop = self.loop
        rows = loop.rows
        if not rows:
            return
        now = time.monotonic()
        if not self.tty and now - self._last_plain < self.plain_every_s:
            return
        text = status_text(loop, rows[-1], now, self._last_ticks, self._last_wall)
        self._last_ticks, self._last_wall = loop.stats.ticks, now
        if self.tty:
            self.stream.write("\r" + text + "\x1b[K")
            self._line_open = True
        else:
            self.stream.write(text + "\n")
            self._last_plain = now
        self.stream.flush()

    # ------------------------------------------------------------------------------------------ output ---
    def _phase(self, name: str, detail: str) -> None:
        self._end_line()
        self.current = name
        self.stream.write(f"[{name}] {detail}\n" if detail else f"[{name}]\n")
        self.stream.flush()

    def _end_line(self) -> None:
        if self._line_open:
            self.stream.write("\n")
            self.stream.flush()
            self._line_open = False


def status_text(loop: Any, row: tuple[float, ...], now: float, last_ticks: int, last_wall: float) -> str:
    """One status line from the loop's newest row: reference time, horizontal and vertical tracking error of the
    estimate (m), estimated swing (deg), ticks per second of wall time since the last line, age of the newest
    telemetry (ms, local clock)."""
    from offboard.flight.loop import LIVE_COL as L

    ex = row[L["est_fx0"]] - row[L["ref_fx0"]]
    ey = row[L["est_fy0"]] - row[L["ref_fy0"]]
    ez = row[L["est_z"]] - row[L["ref_z0"]]
    swing = math.degrees(math.hypot(row[L["est_alpha_x"]], row[L["est_alpha_y"]]))
    dt = now - last_wall
    rate = (loop.stats.ticks - last_ticks) / dt if dt > 0 else math.nan
    rx = getattr(loop, "last_rx_local", {}) or {}
    age_ms = 1e3 * (now - max(rx.values())) if rx else math.nan
    return (
        f"t {row[L['t_ref']]:6.2f}/{loop.duration:g} s | error xy {math.hypot(ex, ey):.3f} m z {ez:+.3f} m | "
        f"swing {swing:4.1f} deg | loop {rate:5.0f} Hz | link age {age_ms:4.0f} ms"
    )
