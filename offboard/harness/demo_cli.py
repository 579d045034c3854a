"""``slung demo``: one command, no arguments needed. Starts the bundled autopilot emulator (``slung emulate``'s
public entry point, in a thread of this process) on a free loopback UDP port, flies the ``paper`` scenario end to
end over real UDP on 127.0.0.1 with the Kalman filter in the loop (the same code as ``slung fly``), prints the
metrics table and writes a report folder (figures, metrics, tlog) whose path it prints.

Usage::

    slung demo [--flavor px4|ardupilot] [--realtime] [--output attitude|actuator] [--duration S] [--rate HZ]
               [--sensors px4-typical|px4-fast|ideal] [--seed N] [--disturbance paper|none] [--emulator-tlog]
               [--out DIR]

By default the demo IS ``slung sim``'s paper scenario over the wire: the emulator's telemetry has the
``px4-typical`` sensor models (noise, bias, latency), the paper's disturbances start 25 s after the loop's
reference start (the loop tells the emulator that time, ``EmulatorThread.set_reference_start``), seed 0; compare
with ``slung sim --scenario paper --sensors px4-fast --estimator kf --control-rate 250 --attitude-model rigid``.

Lockstep by default (the emulator advances one control period per setpoint, so the run does not depend on the
machine's speed); ``--realtime`` paces both by the wall clock. The emulator runs in this process only so that the
report can show the TRUE plant state (tracking errors, swing) beside the estimate: the controller never sees it,
and the two sides talk only MAVLink over UDP. Default folder: ``runs/demo-<UTC timestamp>``.
"""

from __future__ import annotations

import argparse
import math
import socket
import sys
import time
from pathlib import Path
from typing import Any

from estimators.errors import UserError
from offboard.cli_args import add_seed_argument, positive_float
from offboard.control.options import Flavour, values
from offboard.flight.fly_args import add_flight_arguments
from offboard.flight.fly_cli import check_rate, fly
from offboard.flight.supervisor import exit_code
from offboard.outputs import prepare_output_dir, write_json_atomic
from sim_bridge.plant.sensors import PRESETS as SENSOR_PRESETS


def add_flavor_argument(p: argparse.ArgumentParser, help_text: str = "autopilot the emulator imitates") -> None:
    """``--flavor px4|ardupilot`` (alias ``--flavour``), default px4."""
    p.add_argument(
        "--flavor",
        "--flavour",
        dest="flavor",
        choices=values(Flavour),
        default="px4",
        help=f"{help_text} (default px4)",
    )


def configure(p: argparse.ArgumentParser) -> None:
    """Arguments of ``slung demo`` (all optional)."""
    add_flavor_argument(p)
    p.add_argument("--realtime", action="store_true", help="pace by the wall clock instead of lockstep")
    p.add_argument("--scenario", default="paper", help="scenario to fly (default paper)")
    p.add_argument("--duration", type=positive_float, metavar="S", help="offboard flight time (default: scenario's)")
    p.add_argument(
        "--sensors",
        choices=SENSOR_PRESETS,
        default="px4-typical",
        help="emulator telemetry: sensor models of slung sim (noise, bias, latency; default px4-typical; "
        "ideal: exact telemetry); the rates are the ones the loop requests",
    )
    add_seed_argument(p)
    p.add_argument(
        "--disturbance",
        choices=("paper", "none"),
        default="paper",
        help="paper: the paper scenario's random disturbances from reference time 25 s (default)",
    )
    p.add_argument(
        "--noise",
        type=float,
        default=0.0,
        help="legacy ad-hoc telemetry noise scale (only with --sensors ideal; 0: exact telemetry)",
    )
    p.add_argument(
        "--attitude-model",
        choices=("rigid", "paper"),
        default="rigid",
        help="emulated plant rotation model (default rigid)",
    )
    p.add_argument("--loss", type=float, default=0.0, help="emulated packet loss probability, both directions")
    p.add_argument(
        "--emulator-tlog",
        action="store_true",
        help="also write the emulator's own tlog (emulator.tlog): the same link as flight.tlog seen from the "
        "autopilot's end, for debugging the link (doubles the folder's size)",
    )
    add_flight_arguments(p, demo=True)
    p.add_argument("--out", metavar="DIR", help="report folder (default runs/demo-<timestamp>)")


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that was free a moment ago."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
    finally:
        s.close()


class EmulatorThread:
    """The bundled emulator running in a daemon thread (``sim_bridge.emulator_api.RunningEmulator``), configured
    for ``slung demo`` and the tests that fly against it. Defaults: the paper's vehicle, rigid-body attitude, exact
    telemetry (no noise), no packet loss, no tlog, ideal sensors."""

    def __init__(
        self,
        flavor: str,
        port: int,
        *,
        lockstep: bool,
        period: float,
        vehicle: str | None = None,
        attitude_model: str = "rigid",
        noise: float = 0.0,
        loss: float = 0.0,
        tlog: Path | None = None,
        sensors: str = "ideal",
        seed: int = 0,
        disturbance: str = "none",
        signing_key: str | None = None,
        refuse: tuple[str, ...] = (),
        params: tuple[tuple[str, float], ...] = (),
    ) -> None:
        from sim_bridge.emulator_api import EmulatorConfig, RunningEmulator
        from sim_bridge.emulator_cli import parse_signing_key

        self.config = EmulatorConfig(
            flavor=flavor,
            mavlink=(f"udpout:127.0.0.1:{port}",),
            clock="lockstep" if lockstep else "realtime",
            lockstep_period=period,
            # lockstep: free-run only when the loop is really not streaming
            lockstep_grace=1.0 if lockstep else 0.05,
            attitude_model=attitude_model,
            sensors=sensors,
            seed=seed,
            noise=noise if sensors == "ideal" else 0.0,
            # the disturbance clock starts when the loop's reference starts (set_reference_start)
            disturbance=disturbance,
            disturbance_origin="harness" if disturbance != "none" else "offboard",
            loss_in=loss,
            loss_out=loss,
            vehicle=vehicle or None,
            tlog=None if tlog is None else str(tlog),
            signing_key=parse_signing_key(signing_key) if signing_key else None,
            refuse=refuse,
            params=params,
        )
        #: the emulator's own in-process runner (its thread, and its failure reported by stop())
        self.running = RunningEmulator(self.config)
        self.emu, self.ap, self.link = self.running.emulator, self.running.autopilot, self.running.link

    def start(self) -> EmulatorThread:
        """Start the emulator thread."""
        self.running.thread.start()
        return self

    def set_reference_start(self, t0: float) -> None:
        """The loop's reference starts at simulation time ``t0`` (s): the disturbance clock starts there, so the
        plant sees the disturbance ``slung sim`` applies at the same reference time."""
        self.emu.set_disturbance_origin(t0)

    def truth(self, t: float) -> tuple[list[float], float, tuple[float, float, float, float]]:
        """The plant state (18 floats, model frame) and cable tension (N) right now, and the disturbance the plant
        receives from simulation time ``t`` on (force on the vehicle x, y, z world N, yaw torque N m; the columns
        ``dist_*`` of ``slung sim``; zeros before the disturbance clock starts). Metrics only."""
        tr = self.emu.truth()
        d = self.emu.disturbance_at(t)
        return list(tr.state), tr.tension_n, (d[0], d[1], d[2], d[8])

    def stop(self) -> dict[str, Any]:
        """Stop, join, close the link; the emulator's summary (RuntimeError if its thread failed)."""
        return self.running.stop()


def default_out_dir() -> Path:
    """runs/demo-<UTC timestamp>."""
    return Path("runs") / ("demo-" + time.strftime("%Y%m%d-%H%M%S", time.gmtime()))


def run_demo(
    args: argparse.Namespace,
    *,
    inject: tuple[tuple[str, float, float], ...] = (),
    quiet: bool = False,
    **fly_options: Any,
) -> tuple[dict[str, Any], Path, dict[str, Any]]:
    """Do the demo; returns (metrics, report folder, emulator summary). Used by tests and ``slung compare
    --mavlink``; ``fly_options``: ``scenario``, ``controller``, ``on_log`` of :func:`offboard.flight.fly_cli.fly`."""
    if args.flavor == "ardupilot" and args.output == "actuator":
        raise UserError(
            "ArduPilot has no actuator-control setpoint (SET_ACTUATOR_CONTROL_TARGET is PX4 <= v1.13): "
            "use --output attitude with --flavor ardupilot"
        )
    check_rate(args.rate)
    if not (0.0 <= args.loss < 1.0):
        raise UserError(f"--loss must be in [0, 1), got {args.loss!r}")
    if not (0.0 <= args.noise <= 10.0):
        raise UserError(f"--noise must be in [0, 10], got {args.noise!r}")
    if args.noise > 0.0 and args.sensors != "ideal":
        raise UserError("--noise is the legacy ad-hoc noise of exact telemetry: use it only with --sensors ideal")
    out = prepare_output_dir(args.out or default_out_dir())
    args.out = str(out)
    lockstep = not args.realtime
    port = free_udp_port()
    emu = EmulatorThread(
        args.flavor,
        port,
        lockstep=lockstep,
        period=1.0 / args.rate,
        vehicle=args.vehicle,
        attitude_model=args.attitude_model,
        noise=args.noise,
        loss=args.loss,
        # the link's record is flight.tlog; the emulator's mirror of it only when asked (it doubled the folder)
        tlog=out / "emulator.tlog" if getattr(args, "emulator_tlog", False) else None,
        sensors=args.sensors,
        seed=args.seed,
        disturbance=args.disturbance,
    )
    fly_args = argparse.Namespace(**vars(args))
    fly_args.connect = f"udpin:127.0.0.1:{port}"
    fly_args.trajectory = None
    old_switch = sys.getswitchinterval()
    if not lockstep:
        sys.setswitchinterval(0.0002)  # two real-time loops share the interpreter
    emu.start()
    summary: dict[str, Any] = {}
    try:
        m, folder = fly(
            fly_args,
            lockstep=lockstep,
            truth_probe=emu.truth,
            inject=inject,
            quiet=quiet,
            on_reference_start=emu.set_reference_start,
            **fly_options,
        )
    finally:
        sys.setswitchinterval(old_switch)
        summary = emu.stop()
    write_json_atomic(folder / "emulator.json", summary)
    m["emulator"] = {
        k: summary.get(k)
        for k in ("flavor", "mode", "armed", "sim_time_s", "realtime_factor", "lockstep_handshakes", "counters")
    }
    write_json_atomic(folder / "metrics.json", m)
    return m, folder, summary


def run(args: argparse.Namespace) -> int:
    """Entry point of ``slung demo``: 0 when the scenario was flown to its end with finite values, else the exit
    code of how the flight ended (``offboard.flight.supervisor.exit_code``; 1 for non-finite values)."""
    m, _, summary = run_demo(args)
    ended_by = m.get("flight", {}).get("ended_by", "internal_error")
    ok = ended_by == "completed" and m.get("all_finite", False)
    print(
        f"emulator: {summary.get('flavor')} ended in {summary.get('mode')}, "
        f"{summary.get('sim_time_s', math.nan):.1f} s simulated"
    )
    return 0 if ok else max(exit_code(ended_by), 1)
