"""The load identified in flight, before the move (issue 34, Build 2; ``slung fly --identify-load``).

The vehicle file's load (mass, cable length) is the prior. From the end of the take-off the loop buffers the
autopilot's accelerometer, attitude and velocity records; the hold at the reference's start (the autopilot's own
position hold) lasts until ``hover_s`` (at most :data:`MAX_HOVER_S`) of them are buffered: the identification hover.
``estimators.identification.load_id`` then tells, from the cable's pull on the vehicle seen by the accelerometer,
whether a load hangs there and its mass and cable length with 1-sigma uncertainties (it runs in another process
while the loop keeps streaming the hold's setpoints). The hold is moved 0.3 m for the first half of the hover (a
gentle excitation, ``loop_identify``): on the emulator's still hover the bare model explained the data as well.

The identified values replace the prior only when the identification is confident (:func:`decide`: a load attached,
1 sigma within :data:`MASS_REL_SIGMA` of the mass and :data:`CABLE_REL_SIGMA` of the length); otherwise the priors
fly, and the event and ``metrics.json``'s ``load_identification`` say why. The law's gains, the filter and the
feasibility check are then rebuilt for the identified vehicle (``FlightLoop``'s ``rebuild_for``, from
``slung fly``). The hover thrust is learned in the same hover (``hover_thrust_learning``), but not turned into a
mass: that needs the thrust curve the autopilot's throttle follows (ArduPilot SITL's 0.39 bare and 0.51 loaded fit
neither a linear curve nor, without the motors' own, a known expo), so it is reported beside the identification.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any

import numpy as np

from estimators.identification.load_id import LoadIdentification, identify_load, resample
from estimators.model.measurements import Attitude, Imu, Measurement, PositionVelocity
from estimators.model.vehicle import Vehicle

#: the identification hover's longest stated length, s (issue 34: within 10 s of hover)
MAX_HOVER_S = 10.0
#: the identified values are used when their 1 sigma is within these fractions of them
MASS_REL_SIGMA = 0.10
CABLE_REL_SIGMA = 0.10
#: records kept at most (a guard: 100 s of IMU at 250 Hz)
MAX_RECORDS = 25_000
#: the identification process's niceness: on a busy 2-core machine it took the CPU the loop needed while the hold
#: streamed, and the latency watchdog ended a PX4 HIL flight (122 ms, 2026-12-07)
CHILD_NICENESS = 10


class InFlightLoadId:
    """Buffers the records of the identification hover and identifies the load from them (in another process).

    ``vehicle``: the vehicle file's (its load is the prior; its own mass is taken as exact); ``hover_s``: the
    identification hover's length (s of buffered IMU)."""

    def __init__(self, vehicle: Vehicle, hover_s: float = MAX_HOVER_S) -> None:
        if not (0.0 < hover_s <= MAX_HOVER_S):
            raise ValueError(f"identification hover must be within 0..{MAX_HOVER_S:g} s, got {hover_s:g}")
        self.vehicle = vehicle
        self.hover_s = hover_s
        self.active = False
        self.imu: list[Imu] = []
        self.att: list[Attitude] = []
        self.pv: list[PositionVelocity] = []
        self.result: LoadIdentification | None = None
        self.error: str | None = None
        self._thread: threading.Thread | None = None
        self._proc: subprocess.Popen[str] | None = None
        self._tmp: tempfile.TemporaryDirectory[str] | None = None

    def start(self) -> None:
        """In the air: buffer from now on."""
        self.active = True

    def push(self, m: Measurement) -> None:
        """One record of the autopilot (others are ignored), while buffering."""
        if not self.active or len(self.imu) >= MAX_RECORDS:
            return
        if isinstance(m, Imu):
            self.imu.append(m)
        elif isinstance(m, Attitude):
            self.att.append(m)
        elif isinstance(m, PositionVelocity):
            self.pv.append(m)

    def span_s(self) -> float:
        """Seconds of IMU buffered."""
        return self.imu[-1].t - self.imu[0].t if len(self.imu) > 1 else 0.0

    def ready(self) -> bool:
        """The hover is long enough."""
        return self.span_s() >= self.hover_s

    def run_in_background(self) -> None:
        """Stop buffering and identify in another Python process (:meth:`done` tells when it has finished): the
        identification's seconds of Python and numpy, in a thread of the loop's process, held the interpreter lock
        long enough that the loop read its telemetry late and the latency watchdog ended an ArduPilot SITL flight
        (264 ms, 2026-12-07). A fresh interpreter (``python -m offboard.flight.load_identification``), not
        multiprocessing: its spawned children import the caller's main script again, which for a script that calls
        ``fly`` without a main guard flew a second flight. The records go through a temporary ``.npz`` file, the
        answer comes back as JSON. A thread is the fall-back where no process can be started."""
        self.active = False
        self._tmp = tempfile.TemporaryDirectory(prefix="slung-load-id-")
        folder = Path(self._tmp.name)
        np.savez(folder / "records.npz", **_arrays(self.imu, self.att, self.pv))
        cmd = [sys.executable, "-m", "offboard.flight.load_identification", str(folder)]
        cmd += [repr(self.vehicle.mass_vehicle), repr(self.vehicle.gravity)]
        try:
            # stderr to a file: a pipe nobody reads until the end could fill and stop the child
            with open(folder / "stderr.txt", "w", encoding="utf-8") as err:
                self._proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, text=True)
            with contextlib.suppress(OSError, AttributeError):  # below the loop: it must not starve it (POSIX)
                os.setpriority(os.PRIO_PROCESS, self._proc.pid, CHILD_NICENESS)
        except OSError:
            self._proc = None
            self._thread = threading.Thread(target=self._run, name="slung-load-id", daemon=True)
            self._thread.start()

    def done(self) -> bool:
        """The identification has finished (its answer in :attr:`result`, or why not in :attr:`error`)."""
        proc = self._proc
        if proc is not None:
            if proc.poll() is None:
                return False
            folder = Path(self._tmp.name) if self._tmp is not None else None
            err_file = folder / "stderr.txt" if folder is not None else None
            err = err_file.read_text(encoding="utf-8") if err_file is not None and err_file.is_file() else ""
            answer = folder / "answer.json" if folder is not None else None
            if proc.returncode == 0 and answer is not None and answer.is_file():
                data = json.loads(answer.read_text())
                self.result = None if data is None else LoadIdentification(**data)
                if self.result is None:
                    self.error = "too few records to identify (IMU, attitude)"
            else:
                self.error = f"the identification process failed (exit {proc.returncode}): {err.strip()[-300:]}"
            self._proc = None
            if self._tmp is not None:
                self._tmp.cleanup()
            return True
        return self._thread is not None and not self._thread.is_alive()

    def _run(self) -> None:
        try:
            self.result = identify(self.imu, self.att, self.pv, self.vehicle)
            if self.result is None:
                self.error = "too few records to identify (IMU, attitude)"
        except Exception as exc:  # reported, the priors fly
            self.error = f"{type(exc).__name__}: {exc}"


def _increasing(rs: list[Any]) -> list[Any]:
    """Records sorted by time, strictly increasing (repeats dropped)."""
    out: list[Any] = []
    for r in sorted(rs, key=lambda r: r.t):
        if not out or r.t > out[-1].t:
            out.append(r)
    return out


def _arrays(imu: list[Imu], att: list[Attitude], pv: list[PositionVelocity]) -> dict[str, np.ndarray]:
    """The records as arrays: t_imu, f_body (n, 3), t_att, euler (m, 3), t_vel, v_world (k, 3)."""
    imu, att, pv = _increasing(imu), _increasing(att), _increasing(pv)
    return {
        "t_imu": np.array([r.t for r in imu], dtype=float),
        "f_body": np.array([(r.ax, r.ay, r.az) for r in imu], dtype=float).reshape(-1, 3),
        "t_att": np.array([r.t for r in att], dtype=float),
        "euler": np.array([(r.phi, r.theta, r.psi) for r in att], dtype=float).reshape(-1, 3),
        "t_vel": np.array([r.t for r in pv], dtype=float),
        "v_world": np.array([(r.vx, r.vy, r.vz) for r in pv], dtype=float).reshape(-1, 3),
    }


def identify_arrays(a: dict[str, np.ndarray], vehicle_mass_kg: float, gravity: float) -> LoadIdentification | None:
    """``load_id`` on one stretch given as :func:`_arrays` (velocity used when there are two samples or more)."""
    if len(a["t_imu"]) < 4 or len(a["t_att"]) < 4:
        return None
    vel = len(a["t_vel"]) > 1
    stretch = (
        a["t_imu"],
        a["f_body"],
        a["t_att"],
        a["euler"],
        a["t_vel"] if vel else None,
        a["v_world"] if vel else None,
    )
    sig = resample([stretch])
    if sig is None:
        return None
    return identify_load(sig, vehicle_mass_kg, gravity)


def identify(
    imu: list[Imu], att: list[Attitude], pv: list[PositionVelocity], vehicle: Vehicle
) -> LoadIdentification | None:
    """``load_id`` on one stretch of records (the vehicle file's own mass taken as exact)."""
    return identify_arrays(_arrays(imu, att, pv), vehicle.mass_vehicle, vehicle.gravity)


def decide(
    ident: LoadIdentification | None, vehicle: Vehicle, error: str | None = None
) -> tuple[Vehicle | None, dict[str, Any]]:
    """(the vehicle to fly with the identified load, or None to keep the priors; ``metrics.json``'s
    ``load_identification``: prior, identified, uncertainty (1 sigma), used, why)."""
    block: dict[str, Any] = {
        "prior": {"mass_kg": vehicle.mass_load, "cable_m": vehicle.cable_length},
        "identified": None,
        "uncertainty": None,
        "attached": None,
        "used": False,
    }
    if ident is None:
        block["why"] = f"not identified ({error or 'no result'}): flying the vehicle file's load"
        return None, block
    block["attached"] = ident.attached
    block["identification"] = {
        k: ident.as_dict()[k] for k in ("mass_ratio", "coupled_mode_rad_s", "bic_margin", "samples", "reason")
    }
    if not ident.attached or ident.mass_kg is None or ident.cable_m is None:
        block["why"] = f"no load identified ({ident.reason}): flying the vehicle file's load"
        return None, block
    m, cable = ident.mass_kg, ident.cable_m
    sm, sl = ident.uncertainty.get("mass_kg"), ident.uncertainty.get("cable_m")
    block["identified"] = {"mass_kg": m, "cable_m": cable}
    block["uncertainty"] = {"mass_kg": sm, "cable_m": sl}
    confident = (
        sm is not None
        and sl is not None
        and math.isfinite(sm)
        and math.isfinite(sl)
        and sm <= MASS_REL_SIGMA * m
        and sl <= CABLE_REL_SIGMA * cable
    )
    said = f"{m:.3f} +- {sm:.3f} kg on {cable:.3f} +- {sl:.3f} m (the file: {vehicle.mass_load:g} kg on "
    said += f"{vehicle.cable_length:g} m)"
    if not confident:
        block["why"] = (
            f"identified {said}, not confident (1 sigma above {MASS_REL_SIGMA:.0%} of the mass or "
            f"{CABLE_REL_SIGMA:.0%} of the length): flying the vehicle file's load"
        )
        return None, block
    try:
        flown = vehicle.with_changes(mass_load=m, cable_length=cable)
    except Exception as exc:  # a value the vehicle file's checks refuse: the priors fly
        block["why"] = f"identified {said}, refused as a vehicle ({exc}): flying the vehicle file's load"
        return None, block
    block["used"] = True
    block["why"] = f"identified {said}: the law, the filter and the feasibility check use it"
    return flown, block


def main(argv: list[str]) -> int:
    """``python -m offboard.flight.load_identification FOLDER MASS_KG GRAVITY``: identify from ``FOLDER/records.npz``,
    write ``FOLDER/answer.json`` (``null`` when there is too little to identify from)."""
    folder, mass, gravity = Path(argv[0]), float(argv[1]), float(argv[2])
    with np.load(folder / "records.npz") as z:
        arrays = {k: z[k] for k in z.files}
    ident = identify_arrays(arrays, mass, gravity)
    tmp = folder / "answer.json.tmp"
    tmp.write_text(json.dumps(None if ident is None else ident.as_dict()), encoding="utf-8")
    tmp.replace(folder / "answer.json")
    return 0


__all__ = [
    "CABLE_REL_SIGMA",
    "MASS_REL_SIGMA",
    "MAX_HOVER_S",
    "InFlightLoadId",
    "decide",
    "identify",
    "identify_arrays",
]

if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
