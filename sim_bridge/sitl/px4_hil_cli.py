"""``slung px4-hil``: real PX4 SITL with a slung load: this process is its simulator (``sim_bridge.sitl.px4_hil``).

Examples::

    slung px4-hil --px4                              # start PX4 SITL (../shared/px4-sitl) too; Ctrl-C ends both
    slung fly --connect udpin:127.0.0.1:14540 --vehicle px4-hil-load --scenario hover --out flight   # another shell
    slung px4-hil --instance 2 --truth truth.csv     # serve a PX4 started by hand with PX4_SIM_MODEL=none_iris
    slung px4-hil --px4 --load-sensor 100            # with a cable-angle sensor whose readings PX4 forwards

Without ``--px4`` it waits for a PX4 whose ``simulator_mavlink`` connects to TCP 4560 + instance (PX4 SITL started
with ``PX4_SIM_MODEL=none_iris``, and the parameters it prints set, so that PX4's allocator has the physics'
layout). At the end (SIGINT, SIGTERM or ``--duration``) one line of JSON with what it simulated is printed.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import threading
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

from estimators.errors import UserError
from estimators.model.vehicle import load_vehicle
from sim_bridge.sitl.px4_hil import HIL_MODEL, Px4HilServer, hil_params
from sim_bridge.sitl.px4_sitl import Px4Sitl, Px4SitlError


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``px4-hil`` options."""
    parser.add_argument(
        "--vehicle", default="px4-hil-load", metavar="FILE|NAME", help="the true vehicle with its load (px4-hil-load)"
    )
    parser.add_argument("--instance", type=int, default=0, help="PX4 instance: TCP 4560 + instance (0)")
    parser.add_argument("--px4", action="store_true", help="also start PX4 SITL ($SLUNG_PX4_SITL or ../shared)")
    parser.add_argument("--workdir", type=Path, help="with --px4: PX4's working folder (ULogs under log/)")
    parser.add_argument("--truth", type=Path, help="write the truth (vehicle and load, 50 Hz) to this CSV")
    parser.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (0)")
    parser.add_argument("--swing", type=float, default=0.0, metavar="RAD", help="the load's initial swing (0)")
    parser.add_argument(
        "--load-sensor",
        type=float,
        default=0.0,
        metavar="HZ",
        help="a cable-angle sensor on the vehicle: DEBUG_VECT LOADANG to PX4's MAVLink port at HZ, which PX4 streams "
        "on to the companion (0: none, the default: the swing from PX4's IMU alone)",
    )
    parser.add_argument(
        "--speed", type=float, default=1.0, help="simulated seconds per wall second (1; 0: as fast as PX4 answers)"
    )
    parser.add_argument("--duration", type=float, metavar="S", help="stop after S simulated seconds")


def run(args: argparse.Namespace) -> int:
    """Serve PX4 until interrupted; print the summary."""
    if not 0 <= args.instance <= 9:
        raise UserError(f"--instance must be 0..9, got {args.instance}")
    if args.speed < 0.0 or args.speed != args.speed:
        raise UserError(f"--speed must be >= 0, got {args.speed}")
    if not 0.0 <= args.load_sensor <= 1000.0:
        raise UserError(f"--load-sensor must be 0..1000 Hz, got {args.load_sensor}")
    if not abs(args.swing) < 1.5:
        raise UserError(f"--swing must be a finite angle within +-1.5 rad, got {args.swing}")
    if args.duration is not None and not 0.0 < args.duration < math.inf:
        raise UserError(f"--duration must be a finite number of seconds > 0, got {args.duration}")
    vehicle = load_vehicle(args.vehicle)
    if not vehicle.mass_load > 0.0:
        raise UserError(f"vehicle {vehicle.name!r} carries no load: px4-hil simulates one (try px4-hil-load)")
    server = Px4HilServer(
        vehicle,
        instance=args.instance,
        seed=args.seed,
        truth_path=args.truth,
        initial_swing_rad=args.swing,
        speed=args.speed or None,
        load_sensor_hz=args.load_sensor,
    )
    try:
        server.open_truth()
    except OSError as e:
        raise UserError(f"cannot write the truth file {args.truth}: {e.strerror or e}") from None
    try:
        server.listen()
    except OSError as e:
        raise UserError(f"cannot listen on TCP {server.port}: {e.strerror or e}") from None
    params = hil_params(vehicle)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    sitl: Px4Sitl | None = None
    server.start()
    try:
        if args.px4:
            sitl = Px4Sitl(instance=args.instance, workdir=args.workdir, model=HIL_MODEL, params=dict(params))
            try:
                sitl.start()
            except Px4SitlError as e:
                raise UserError(str(e).splitlines()[0]) from None
            print(f"PX4 SITL ready: fly it with --connect {sitl.connection_url} --vehicle {args.vehicle}", flush=True)
        else:
            names = " ".join(f"PX4_PARAM_{k}={v}" for k, v in params.items())
            print(f"waiting for PX4 on TCP {server.port}: start it with PX4_SIM_MODEL={HIL_MODEL} {names}", flush=True)
        while not stop.is_set():
            if args.duration is not None and server.stats.sim_time_s >= args.duration:
                break
            if not server.running or (sitl is not None and not sitl.running):
                break  # PX4 closed the link, or a fault (stats.error), or PX4 exited
            time.sleep(0.1)
    finally:
        server.stop()  # first: PX4 stopping first would leave the server waiting for an answer
        if sitl is not None:
            sitl.stop()
    summary: dict[str, Any] = asdict(server.stats)
    if sitl is not None and sitl.workdir is not None:
        summary["px4_workdir"] = str(sitl.workdir)
    print(json.dumps(summary), flush=True)
    if server.stats.error is not None:
        raise UserError(server.stats.error)
    return 0
