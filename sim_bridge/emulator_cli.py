"""``slung emulate``: run the MAVLink autopilot emulator (PX4 or ArduPilot flavour) around the plant.

Examples::

    slung emulate                                   # PX4, real time, sends to udp 127.0.0.1:14540
    slung emulate --flavor ardupilot --lockstep --lockstep-period 0.01
    slung emulate --mavlink udpout:127.0.0.1:14540 --mavlink udpin:127.0.0.1:14550   # controller + GCS
    slung emulate --tlog flight.tlog --duration 60 --summary summary.json
    slung emulate --lockstep --sensors px4-typical --disturbance paper --seed 3   # sensor models + disturbances

At the end (``--duration`` reached, SIGINT or SIGTERM) a one-line JSON summary with the link counters is
printed on stdout (and written to ``--summary`` if given).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import logging
import math
import signal
import sys
from typing import Any

from estimators.errors import UserError
from estimators.mavlink_signing import parse_key
from sim_bridge.emulator_api import REFUSALS, EmulatorConfig, build_emulator
from sim_bridge.plant.sensors import PRESETS

log = logging.getLogger(__name__)


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``emulate`` options."""
    parser.add_argument("--flavor", choices=("px4", "ardupilot"), default="px4", help="autopilot to emulate")
    parser.add_argument(
        "--mavlink",
        action="append",
        metavar="URL",
        help="udpout:HOST:PORT (send there, answer whoever talks) or udpin:HOST:PORT (listen); "
        "repeatable; default udpout:127.0.0.1:14540 like PX4 SITL's offboard link",
    )
    clock = parser.add_mutually_exclusive_group()
    clock.add_argument(
        "--realtime",
        dest="clock",
        action="store_const",
        const="realtime",
        help="pace the simulation by the wall clock (default)",
    )
    clock.add_argument(
        "--lockstep",
        dest="clock",
        action="store_const",
        const="lockstep",
        help="advance one control period per setpoint received (free-runs when none arrive)",
    )
    parser.set_defaults(clock="realtime")
    parser.add_argument(
        "--lockstep-period",
        type=float,
        default=0.01,
        metavar="S",
        help="simulation time advanced per setpoint in lockstep, s (default 0.01)",
    )
    parser.add_argument(
        "--lockstep-grace",
        type=float,
        default=0.05,
        metavar="S",
        help="wall time without setpoints after which lockstep free-runs, s (default 0.05)",
    )
    parser.add_argument("--vehicle", metavar="FILE", help="vehicle TOML (default: the paper's Table 1 vehicle)")
    parser.add_argument(
        "--attitude-model",
        choices=("rigid", "paper"),
        default="rigid",
        help="plant rotation model (default rigid body)",
    )
    parser.add_argument("--duration", type=float, metavar="S", help="stop after S seconds of simulation time")
    parser.add_argument("--tlog", metavar="FILE", help="write every packet sent and received to a .tlog")
    parser.add_argument("--summary", metavar="FILE", help="also write the final JSON summary to FILE")
    parser.add_argument("--sysid", type=int, default=1, help="autopilot system id (default 1)")
    parser.add_argument("--load-sysid", type=int, default=2, help="system id of the load (default 2)")
    parser.add_argument(
        "--signing-key",
        metavar="HEX|@FILE",
        help="MAVLink 2 signing key: 64 hex digits, or @FILE holding them (or the 32 raw bytes)",
    )
    parser.add_argument("--loss-in", type=float, default=0.0, help="incoming packet loss probability")
    parser.add_argument("--loss-out", type=float, default=0.0, help="outgoing packet loss probability")
    parser.add_argument("--latency", type=float, default=0.0, metavar="S", help="one-way link latency, s")
    parser.add_argument("--jitter", type=float, default=0.0, metavar="S", help="extra uniform delay 0..S, s")
    parser.add_argument("--fault-seed", type=int, default=0, help="seed of the link-fault generator")
    parser.add_argument(
        "--noise",
        type=float,
        default=0.0,
        help="telemetry noise scale (0 = the plant truth, 1 = typical EKF/IMU noise)",
    )
    parser.add_argument("--noise-seed", type=int, default=1, help="seed of the telemetry noise")
    parser.add_argument(
        "--sensors",
        choices=PRESETS,
        default="ideal",
        help="sensor models of the telemetry (sim_bridge.plant.sensors: noise, accelerometer bias, "
        "latency; the stream rates stay the MAVLink intervals); default ideal = the plant truth",
    )
    parser.add_argument(
        "--disturbance",
        choices=("none", "paper"),
        default="none",
        help="external disturbances on the plant: paper = slung sim's bounded random forces on the "
        "vehicle (x, y, z <= 0.5 N) and yaw torque (<= 0.02 N m); default none",
    )
    parser.add_argument(
        "--disturbance-start",
        type=float,
        default=25.0,
        metavar="S",
        help="onset of the disturbances, s on the disturbance clock (default 25, the paper's)",
    )
    parser.add_argument(
        "--disturbance-origin",
        choices=("offboard", "boot", "harness"),
        default="offboard",
        help="t = 0 of the disturbance clock: the first OFFBOARD / GUIDED / GUIDED_NOGPS entry "
        "(default), boot (--disturbance-start is then absolute simulation time), or harness: "
        "set by the program running the emulator in-process (Emulator.set_disturbance_origin, "
        "slung demo); none until then",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=0,
        metavar="N",
        help="seed of the sensor models and the disturbances (as slung sim --seed; default 0)",
    )
    parser.add_argument(
        "--est-ready",
        type=float,
        default=1.5,
        metavar="S",
        help="simulation time after boot until the estimator has a position (default 1.5 s)",
    )
    parser.add_argument(
        "--ekf",
        choices=("none", "px4-sih"),
        default="none",
        help="the emulated autopilot's position / velocity estimate: none = the truth (default); px4-sih = "
        "EKF-like errors that wander as PX4 SITL's SIH + EKF2 do, and a local origin offset from the ground; "
        "the autopilot's own modes then fly on the estimate",
    )

    parser.add_argument(
        "--refuse",
        action="append",
        choices=REFUSALS,
        default=[],
        help="emulate a failing check (repeatable): arm = a pre-arm check fails (PX4 'Preflight Fail', result 1; "
        "ArduPilot 'PreArm', result 4); takeoff = the take-off is refused (PX4 result 1, ArduPilot result 4); "
        "offboard = OFFBOARD / GUIDED cannot be entered (PX4 result 1, ArduPilot result 4)",
    )
    parser.add_argument(
        "--param",
        action="append",
        metavar="NAME=VALUE",
        default=[],
        help="set an autopilot parameter before the start (repeatable), as a ground station would: e.g. "
        "MC_ROLL_P=2 for a PX4 with a slower attitude loop (the flavour's parameters and ranges: slung emulate "
        "answers PARAM_REQUEST_LIST)",
    )


def parse_signing_key(text: str | None) -> bytes | None:
    """The 32-byte key of ``--signing-key HEX|@FILE`` (None for None); UserError for a bad one. The one parser
    ``slung fly`` uses too (:func:`estimators.mavlink_signing.parse_key`), so both ends of a link take the same
    key files (64 hex digits, or the 32 raw bytes)."""
    return None if text is None else parse_key(text)


def config_from_args(args: argparse.Namespace) -> EmulatorConfig:
    """The typed configuration of parsed ``slung emulate`` options: each field is the option of its name (the
    names are the same by :class:`EmulatorConfig`'s rule), but for the four converted here (the link URLs, the
    signing key read and checked, the refusals, the parameters parsed)."""
    converted = {
        "mavlink": tuple(args.mavlink or ()),
        "signing_key": parse_signing_key(args.signing_key),
        "refuse": tuple(args.refuse),
        "params": tuple(parse_param(text) for text in args.param),
    }
    same = {f.name: getattr(args, f.name) for f in dataclasses.fields(EmulatorConfig) if f.name not in converted}
    return EmulatorConfig(**same, **converted)


def parse_param(text: str) -> tuple[str, float]:
    """``NAME=VALUE`` of ``--param`` -> (name, value); UserError for a malformed one."""
    name, sep, value = text.partition("=")
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if not sep or not name.strip() or not math.isfinite(number):
        raise UserError(f"--param must be NAME=VALUE with a finite number, got {text!r}")
    return name.strip(), number


def build(args: argparse.Namespace) -> Any:
    """Create (emulator, autopilot, link) from parsed arguments; UserError on bad input."""
    cfg = config_from_args(args)
    cfg.validate()  # before any socket is opened
    return build_emulator(cfg)


def run(args: argparse.Namespace) -> int:
    """Run the emulator until --duration, SIGINT or SIGTERM; print the JSON summary."""
    emu, ap, link = build(args)
    print(
        f"slung emulate: {args.flavor} ({args.clock}) on "
        + ", ".join(f"{ep.url} (local port {ep.local_port})" for ep in link.endpoints),
        file=sys.stderr,
        flush=True,
    )

    def _stop(signum: int, frame: Any) -> None:
        emu.stop()

    old = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(ValueError):  # ValueError: not the main thread
            old[sig] = signal.signal(sig, _stop)
    try:
        emu.run(args.duration)
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)
        summary = {**ap.summary(), **emu.summary(), "link": link.summary()}
        link.close()
    text = json.dumps(summary, sort_keys=True)
    print(text, flush=True)
    if args.summary:
        try:
            with open(args.summary, "w", encoding="utf-8") as f:
                f.write(text + "\n")
        except OSError as exc:
            raise UserError(f"cannot write summary {args.summary}: {exc.strerror}") from None
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m sim_bridge.emulator_cli``: the same as ``slung emulate``."""
    parser = argparse.ArgumentParser(prog="slung emulate", description=__doc__.splitlines()[0])
    configure(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    try:
        return run(args)
    except UserError as exc:
        print(f"slung emulate: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
