"""The emulator's programmatic API: a typed configuration, a builder, a truth record and an in-process runner.

``slung emulate`` turns its command line into an :class:`EmulatorConfig`; programs that run the emulator in their
own process (``slung demo``, benchmarks, calibration) build one directly::

    cfg = EmulatorConfig(flavor="px4", vehicle="px4-sih", mavlink=("udpout:127.0.0.1:14540",))
    running = start_emulator(cfg)          # a daemon thread
    ...                                    # talk MAVLink to it
    rec = running.emulator.truth()         # EmulatorTruth: the plant as it is now (metrics only)
    summary = running.stop()

The truth is for measuring a flight, never for flying one: the controller sees only the MAVLink wire.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

from estimators.errors import UserError

#: what ``--refuse`` can make the emulated autopilot refuse (``sim_bridge.modes.autopilot_modes``)
REFUSALS: tuple[str, ...] = ("arm", "takeoff", "offboard")


@dataclass(frozen=True)
class EmulatorConfig:
    """Everything ``slung emulate`` can be told (same names and units as its options, which
    ``emulator_cli.config_from_args`` relies on; see docs/emulator.md).

    vehicle: a vehicle TOML path or the name of a shipped vehicle (``px4-sih``), None for the paper's.
    ekf: the estimate's error model (``sim_bridge.plant.ekf_error.EKF_PRESETS``: ``none`` = the truth, ``px4-sih``).
    mavlink: link URLs (empty: ``udpout:127.0.0.1:14540``). clock: ``realtime`` or ``lockstep``.
    Times in s, probabilities 0..1.
    """

    flavor: str = "px4"
    vehicle: str | None = None
    mavlink: tuple[str, ...] = ()
    clock: str = "realtime"
    lockstep_period: float = 0.01
    lockstep_grace: float = 0.05
    attitude_model: str = "rigid"
    duration: float | None = None
    tlog: str | None = None
    sysid: int = 1
    load_sysid: int = 2
    signing_key: bytes | None = None
    loss_in: float = 0.0
    loss_out: float = 0.0
    latency: float = 0.0
    jitter: float = 0.0
    fault_seed: int = 0
    noise: float = 0.0
    noise_seed: int = 1
    sensors: str = "ideal"
    disturbance: str = "none"
    disturbance_start: float = 25.0
    disturbance_origin: str = "offboard"
    seed: int = 0
    est_ready: float = 1.5
    ekf: str = "none"
    #: failing checks to emulate (``REFUSALS``): the autopilot refuses to arm, to take off, or to enter its
    #: offboard mode (PX4 OFFBOARD, ArduPilot GUIDED) with the answer and message the real one gives
    refuse: tuple[str, ...] = ()
    #: parameters set before the start, as a ground station would (``--param NAME=VALUE``): e.g. a tuned
    #: autopilot's attitude gains
    params: tuple[tuple[str, float], ...] = ()

    def validate(self) -> None:
        """UserError (one line) for a value out of range."""
        if self.flavor not in ("px4", "ardupilot"):
            raise UserError(f"flavor must be px4 or ardupilot, got {self.flavor!r}")
        if self.clock not in ("realtime", "lockstep"):
            raise UserError(f"clock must be realtime or lockstep, got {self.clock!r}")
        if not (0.001 <= self.lockstep_period <= 1.0):
            raise UserError(f"--lockstep-period must be in [0.001, 1] s, got {self.lockstep_period!r}")
        if not (0.001 <= self.lockstep_grace <= 10.0):
            raise UserError(f"--lockstep-grace must be in [0.001, 10] s, got {self.lockstep_grace!r}")
        if self.duration is not None and not (self.duration > 0):
            raise UserError(f"--duration must be > 0 s, got {self.duration!r}")
        if not (1 <= self.sysid <= 255 and 1 <= self.load_sysid <= 255 and self.sysid != self.load_sysid):
            raise UserError("--sysid and --load-sysid must be different numbers in 1..255")
        if not (self.noise >= 0.0 and self.noise <= 100.0):
            raise UserError(f"--noise must be in [0, 100], got {self.noise!r}")
        if self.noise > 0.0 and self.sensors != "ideal":
            raise UserError("--noise (the legacy ad-hoc noise) and --sensors other than ideal exclude each other")
        if not (0.0 <= self.disturbance_start <= 1e6):
            raise UserError(f"--disturbance-start must be in [0, 1e6] s, got {self.disturbance_start!r}")
        if not (0 <= self.seed < 2**63):
            raise UserError(f"--seed must be an integer >= 0, got {self.seed!r}")
        if not (0.0 <= self.est_ready <= 60.0):
            raise UserError(f"--est-ready must be in [0, 60] s, got {self.est_ready!r}")
        from sim_bridge.plant.ekf_error import EKF_PRESETS

        if self.ekf not in EKF_PRESETS:
            raise UserError(f"--ekf must be one of {', '.join(EKF_PRESETS)}, got {self.ekf!r}")
        bad = [r for r in self.refuse if r not in REFUSALS]
        if bad:
            raise UserError(f"--refuse must be one of {', '.join(REFUSALS)}, got {bad[0]!r}")
        if self.signing_key is not None and len(self.signing_key) != 32:
            raise UserError(f"--signing-key must be 32 bytes (64 hex digits), got {len(self.signing_key)} bytes")


@dataclass(frozen=True)
class EmulatorTruth:
    """The plant at one instant (model frame: world NWU z up, body FLU; SI). For metrics, never for control.

    time_s: simulation time. position_m, velocity_m_s: vehicle, world. euler_rad (phi, theta, psi, ZYX) and
    euler_rate_rad_s. cable_direction (unit, vehicle to load) and cable_rate_1_s. thrust_n: collective thrust of
    the motors; torque_n_m: their body torques (FLU). disturbance: plant input slots 4-12 (force on the vehicle
    N world, with the vehicle's linear drag in it, force on the load N world, torque N m body) applied over the
    current step. tension_n: cable
    tension. on_ground: resting on the ground plane. state: the 18-float plant state (``sim_bridge.plant.dynamics``).
    """

    time_s: float
    position_m: tuple[float, float, float]
    velocity_m_s: tuple[float, float, float]
    euler_rad: tuple[float, float, float]
    euler_rate_rad_s: tuple[float, float, float]
    cable_direction: tuple[float, float, float]
    cable_rate_1_s: tuple[float, float, float]
    thrust_n: float
    torque_n_m: tuple[float, float, float]
    disturbance: tuple[float, ...]
    tension_n: float
    on_ground: bool
    state: tuple[float, ...]


def build_emulator(cfg: EmulatorConfig) -> tuple[Any, Any, Any]:
    """(emulator, autopilot, link) for a configuration; UserError on bad input (the link's sockets are open)."""
    import numpy as np

    from estimators.model.vehicle import load_vehicle
    from sim_bridge.autopilot import Autopilot
    from sim_bridge.emulator import Emulator
    from sim_bridge.plant.ekf_error import EKF_PRESETS, EkfError
    from sim_bridge.protocol.link import Link, LinkFaults

    cfg.validate()
    vehicle = load_vehicle(cfg.vehicle)
    spec = EKF_PRESETS[cfg.ekf]
    # its own generator (seeded by --seed), so the sensor models' draws are the same with and without it
    ekf = None if spec is None else EkfError(spec, np.random.default_rng([cfg.seed, 0x45]))
    faults = LinkFaults(cfg.loss_in, cfg.loss_out, cfg.latency, cfg.jitter, cfg.fault_seed)
    link = Link(list(cfg.mavlink), faults, cfg.tlog)
    ap = Autopilot(
        cfg.flavor,
        vehicle,
        link,
        sysid=cfg.sysid,
        load_sysid=cfg.load_sysid,
        signing_key=cfg.signing_key,
        noise=cfg.noise,
        rng=np.random.default_rng(cfg.noise_seed),
        est_ready_s=cfg.est_ready,
        attitude_model=cfg.attitude_model,
        sensors=cfg.sensors,
        sensor_rng=np.random.default_rng(cfg.seed),
        ekf=ekf,
    )
    ap.refuse = frozenset(cfg.refuse)
    for name, value in cfg.params:
        refused = ap.set_param(name, value)
        if refused is not None:
            link.close()
            raise UserError(f"--param {name}={value:g}: {refused.removeprefix(f'param {name}: ')}")
    disturbance = None
    if cfg.disturbance == "paper":
        from sim_bridge.plant.disturbances import DisturbanceSpec, RandomDisturbance

        disturbance = RandomDisturbance(DisturbanceSpec(start=cfg.disturbance_start), cfg.seed)
    emu = Emulator(
        ap,
        link,
        vehicle,
        clock=cfg.clock,
        period=cfg.lockstep_period,
        grace=cfg.lockstep_grace,
        attitude_model=cfg.attitude_model,
        disturbance=disturbance,
        disturbance_origin=cfg.disturbance_origin,
    )
    return emu, ap, link


class RunningEmulator:
    """An emulator running in a daemon thread of this process (``start_emulator``)."""

    def __init__(self, cfg: EmulatorConfig) -> None:
        self.config = cfg
        self.emulator, self.autopilot, self.link = build_emulator(cfg)
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, name="slung-emulator", daemon=True)

    def _run(self) -> None:
        try:
            self.emulator.run(self.config.duration)
        except BaseException as exc:  # reported by stop()
            self.error = exc

    def stop(self) -> dict[str, Any]:
        """Stop, join, close the link; the emulator's summary (RuntimeError if its thread failed)."""
        self.emulator.stop()
        self.thread.join(timeout=10.0)
        summary = {**self.autopilot.summary(), **self.emulator.summary(), "link": self.link.summary()}
        self.link.close()
        if self.error is not None:
            raise RuntimeError(f"the emulator failed: {self.error!r}")
        return summary


def start_emulator(cfg: EmulatorConfig) -> RunningEmulator:
    """Build the emulator for ``cfg`` and start it in a daemon thread."""
    r = RunningEmulator(cfg)
    r.thread.start()
    return r


__all__ = ["REFUSALS", "EmulatorConfig", "EmulatorTruth", "RunningEmulator", "build_emulator", "start_emulator"]
