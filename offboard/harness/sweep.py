"""``slung sweep``: Monte Carlo robustness of the controllers over parameter distributions from a TOML file.

Each run draws the TRUE plant's parameters (vehicle mass, load mass, cable length, inertia, motor time constant),
the sensors' noise and latency, a wind gust and an initial swing from the distributions of the file; the
controllers keep the nominal vehicle (the file's, default the paper's Table 1): what a controller tuned for one
vehicle does with the vehicle it really flies. Every controller flies the same drawn runs (run ``i`` draws from
the seed ``(seed, i)`` whatever the chunking, the worker or the order runs finish in), with the Kalman filter in
the loop on the drawn sensors, run by run (``engine = "scalar"``, ``offboard.harness.sim.run``) or run by run as
machine code (``engine = "compiled"``, ``offboard.harness.compiled``: the same equations compiled with numba, the
default). The compiled engine flies every controller; a file asking for an estimator or actuators it does not
model is flown by the scalar path (the summary says per controller).

The file (``offboard/harness/sweeps/default.toml`` is the default and the documentation of every key)::

    [run]        scenario (rest-to-rest), move_time_s, distance_m, hold_s, estimator, sensors, actuators, seed
    [vehicle]    file = "..." (optional nominal vehicle file)
    [parameters] name = {relative = r} | {low = a, high = b}     (uniform; see PARAMETERS)
    [success]    max_swing_rad, residual_swing_rad, tracking_rms_m, final_error_m, divergence_m

A run succeeds when it completes (finite state), no watchdog of the live loop would have ended it (the swing
watchdog ``max_swing_rad``, the estimator-divergence watchdog ``divergence_m`` between estimate and truth), the
cable never went slack, and its residual swing (largest from 2 s after arrival to the end), tracking RMS and
final position error are within the bounds.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from estimators.errors import UserError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised only on Python 3.10
    import tomli as tomllib

DEFAULT_FILE = Path(__file__).with_name("sweeps") / "default.toml"

#: parameter name -> (unit, what it scales). ``relative`` ranges multiply the nominal value; absolute ones are set.
PARAMETERS: dict[str, tuple[str, str]] = {
    "mass_vehicle": ("kg", "vehicle mass"),
    "mass_load": ("kg", "load mass"),
    "cable_length": ("m", "cable length"),
    "inertia": ("x", "factor on all three moments of inertia"),
    "motor_time_constant": ("s", "motor lag (with actuators = mixer)"),
    "sensor_noise": ("x", "factor on every sensor noise and the accelerometer bias"),
    "sensor_latency_s": ("s", "latency added to every sensor stream"),
    "gust_n": ("N", "peak of a 1 - cos gust on the vehicle (30 % of it on the load), random horizontal direction"),
    "gust_start_s": ("s", "start of the gust"),
    "initial_swing_rad": ("rad", "initial swing, random direction"),
}

#: the result table's columns after the parameters
RESULT_COLUMNS: tuple[str, ...] = (
    "peak_swing_rad",
    "residual_swing_rad",
    "tracking_rms_m",
    "final_error_m",
    "max_estimate_error_m",
    "slack_steps",
    "completed",
    "success",
    "failure",
    "sim_s",
)

_NOMINAL = {"mass_vehicle", "mass_load", "cable_length", "inertia", "motor_time_constant"}


@dataclass(frozen=True)
class Distribution:
    """Uniform on [low, high] (absolute) or nominal * [1 - relative, 1 + relative]."""

    low: float | None = None
    high: float | None = None
    relative: float | None = None

    def draw(self, rng: np.random.Generator, nominal: float) -> float:
        if self.relative is not None:
            return float(nominal * (1.0 + self.relative * (2.0 * rng.random() - 1.0)))
        assert self.low is not None and self.high is not None
        return float(self.low + (self.high - self.low) * rng.random())


@dataclass(frozen=True)
class SweepConfig:
    """The parsed file (see the module docstring)."""

    scenario: str = "rest-to-rest"
    move_time_s: float = 4.0
    distance_m: float = 3.0
    hold_s: float = 8.0
    estimator: str = "kf"
    sensors: str = "px4-typical"
    actuators: str = "mixer"
    engine: str = "scalar"
    seed: int = 0
    vehicle_file: str | None = None
    parameters: dict[str, Distribution] = field(default_factory=dict)
    success: dict[str, float] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return 1.0 + self.move_time_s + self.hold_s

    def to_dict(self) -> dict[str, Any]:
        """Every field by its name, in order; the distributions without their unset bounds, copies of the dicts."""
        out: dict[str, Any] = {f.name: getattr(self, f.name) for f in fields(self)}
        out["parameters"] = {
            k: {kk: vv for kk, vv in vars(d).items() if vv is not None} for k, d in self.parameters.items()
        }
        out["success"] = dict(self.success)
        return out


#: the paths a sweep's runs can be flown by (see the module docstring)
ENGINES = ("scalar", "compiled")
SUCCESS_KEYS = ("max_swing_rad", "residual_swing_rad", "tracking_rms_m", "final_error_m", "divergence_m")


def load_config(path: str | Path | None) -> SweepConfig:
    """Parse a sweep file (default: the shipped one); UserError with the key for anything wrong."""
    p = Path(path) if path is not None else DEFAULT_FILE
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise UserError(f"cannot read sweep file {p}: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"sweep file {p}: {exc}") from None
    unknown = set(data) - {"run", "vehicle", "parameters", "success"}
    if unknown:
        raise UserError(f"sweep file {p}: unknown section(s) {', '.join(sorted(unknown))}")
    run = dict(data.get("run", {}))
    kw: dict[str, Any] = {}
    for key, typ in (
        ("scenario", str),
        ("move_time_s", float),
        ("distance_m", float),
        ("hold_s", float),
        ("estimator", str),
        ("sensors", str),
        ("actuators", str),
        ("engine", str),
        ("seed", int),
    ):
        if key in run:
            v = run.pop(key)
            if typ is float and isinstance(v, int) and not isinstance(v, bool):
                v = float(v)
            if not isinstance(v, typ) or isinstance(v, bool):
                raise UserError(f"sweep file {p}: run.{key} must be a {typ.__name__}, got {v!r}")
            kw[key] = v
    if run:
        raise UserError(f"sweep file {p}: unknown key(s) run.{', run.'.join(sorted(run))}")
    if kw.get("scenario", "rest-to-rest") != "rest-to-rest":
        raise UserError(f"sweep file {p}: run.scenario: only 'rest-to-rest' is supported, got {kw['scenario']!r}")
    if kw.get("engine", "scalar") not in ENGINES:
        raise UserError(f"sweep file {p}: run.engine must be one of {', '.join(ENGINES)}, got {kw['engine']!r}")
    for key in ("move_time_s", "distance_m", "hold_s"):
        if key in kw and not (math.isfinite(kw[key]) and kw[key] > 0):
            raise UserError(f"sweep file {p}: run.{key} must be > 0, got {kw[key]!r}")
    veh = data.get("vehicle", {})
    if set(veh) - {"file"}:
        raise UserError(f"sweep file {p}: [vehicle] takes only 'file'")
    if "file" in veh:
        vf = Path(veh["file"])
        kw["vehicle_file"] = str(vf if vf.is_absolute() else p.parent / vf)
    from estimators.model.vehicle import load_vehicle
    from offboard.harness.compare import require_load

    require_load(load_vehicle(kw.get("vehicle_file")), f"sweep file {p}: ")
    params: dict[str, Distribution] = {}
    for name, spec in data.get("parameters", {}).items():
        if name not in PARAMETERS:
            raise UserError(f"sweep file {p}: unknown parameter {name!r} (known: {', '.join(PARAMETERS)})")
        if not isinstance(spec, dict) or not (set(spec) <= {"low", "high", "relative"}):
            raise UserError(f"sweep file {p}: parameters.{name} must be {{relative = r}} or {{low = a, high = b}}")
        if "relative" in spec:
            r = spec["relative"]
            if set(spec) != {"relative"} or not isinstance(r, int | float) or not 0 <= r < 1:
                raise UserError(f"sweep file {p}: parameters.{name}.relative must be alone and in [0, 1)")
            if name not in _NOMINAL:
                raise UserError(f"sweep file {p}: parameters.{name} has no nominal value: give low and high")
            params[name] = Distribution(relative=float(r))
        else:
            lo, hi = spec.get("low"), spec.get("high")
            if not all(isinstance(v, int | float) and math.isfinite(v) for v in (lo, hi)) or hi < lo:  # type: ignore[operator]
                raise UserError(f"sweep file {p}: parameters.{name} needs finite low <= high")
            params[name] = Distribution(low=float(lo), high=float(hi))  # type: ignore[arg-type]
    success = {}
    for k, v in data.get("success", {}).items():
        if k not in SUCCESS_KEYS:
            raise UserError(f"sweep file {p}: unknown success criterion {k!r} (known: {', '.join(SUCCESS_KEYS)})")
        if not isinstance(v, int | float) or not v > 0:
            raise UserError(f"sweep file {p}: success.{k} must be a number > 0")
        success[k] = float(v)
    return SweepConfig(parameters=params, success=success, **kw)


def draw(config: SweepConfig, run: int, nominal: Any) -> dict[str, float]:
    """The parameters of run ``run``: a pure function of (config.seed, run). Directions of the gust and of the
    initial swing are drawn too (``gust_dir_rad``, ``swing_dir_rad``)."""
    rng = np.random.default_rng([config.seed, run])
    out: dict[str, float] = {}
    for name in PARAMETERS:  # fixed order: adding a parameter to the file does not reshuffle the others' draws
        u = config.parameters.get(name)
        nom = _nominal(name, nominal)
        val = rng.random()  # always one draw per parameter
        if u is None:
            out[name] = nom
        elif u.relative is not None:
            out[name] = float(nom * (1.0 + u.relative * (2.0 * val - 1.0)))
        else:
            out[name] = float(u.low + (u.high - u.low) * val)  # type: ignore[operator]
    out["gust_dir_rad"] = float(2.0 * math.pi * rng.random())
    out["swing_dir_rad"] = float(2.0 * math.pi * rng.random())
    out["sensor_seed"] = float(rng.integers(0, 2**31 - 1))
    return out


def _nominal(name: str, v: Any) -> float:
    if name == "inertia":
        return 1.0  # a factor on the nominal inertia
    if name in _NOMINAL:
        return float(getattr(v, name))
    return {"sensor_noise": 1.0, "sensor_latency_s": 0.0, "gust_n": 0.0, "gust_start_s": 2.0}.get(name, 0.0)


@dataclass(frozen=True)
class _Gust:
    """A 1 - cos gust: peak ``force`` (N) on the vehicle, 30 % of it on the load, horizontal direction ``dir``."""

    start: float
    force: float
    direction: float
    length: float = 1.0

    def __call__(self, t: float) -> tuple[float, ...]:
        s = (t - self.start) / self.length
        if not 0.0 <= s <= 1.0 or self.force == 0.0:
            return (0.0,) * 9
        w = 0.5 * (1.0 - math.cos(2.0 * math.pi * s)) * self.force
        c, sn = math.cos(self.direction), math.sin(self.direction)
        return (w * c, w * sn, 0.0, 0.3 * w * c, 0.3 * w * sn, 0.0, 0.0, 0.0, 0.0)


def plant_vehicle(nominal: Any, p: dict[str, float]) -> Any:
    """The TRUE vehicle of a run."""
    return nominal.with_changes(
        mass_vehicle=p["mass_vehicle"],
        mass_load=p["mass_load"],
        cable_length=p["cable_length"],
        inertia=tuple(i * p["inertia"] for i in nominal.inertia),
        motor_time_constant=p["motor_time_constant"],
    )


def scenario(config: SweepConfig, p: dict[str, float]) -> Any:
    """The run's scenario: the rest-to-rest reference with the drawn gust and initial swing."""
    from estimators.model.cable import cable_from_spherical
    from offboard.control import reference_patterns as patterns
    from offboard.logs.runlog import PlantSetup, Scenario

    t0 = 1.0
    arrival = t0 + config.move_time_s
    T = config.duration_s
    move = patterns.rest_to_rest(
        (0.0, 0.0, 2.0, 0.0), (config.distance_m, 0.0, 2.0, 0.0), t_start=t0, move_time=config.move_time_s
    )
    r, rd = cable_from_spherical(p["initial_swing_rad"], p["swing_dir_rad"], 0.0, 0.0)
    return Scenario(
        name="sweep",
        description="sweep run",
        duration=T,
        reference=move.replace(duration=T),
        arrival_time=arrival,
        disturbance=_Gust(p["gust_start_s"], p["gust_n"], p["gust_dir_rad"]),
        setup=PlantSetup(position=(0.0, 0.0, 2.0), cable=r, cable_rate=rd),
    )


def sensor_preset(config: SweepConfig, p: dict[str, float]) -> Any:
    """The run's sensors: the named preset with noise scaled and latency added."""
    from sim_bridge.plant.sensors import preset_spec

    base = preset_spec(config.sensors)
    k, lat = p["sensor_noise"], p["sensor_latency_s"]

    def s(spec: Any) -> Any:
        return spec._replace(latency_s=spec.latency_s + lat, noise=tuple(k * n for n in spec.noise))

    return base._replace(
        position=s(base.position),
        attitude=s(base.attitude),
        imu=s(base.imu),
        load=s(base.load),
        accel_bias=k * base.accel_bias,
    )


def evaluate(config: SweepConfig, data: np.ndarray, arrival: float, slack: int) -> dict[str, Any]:
    """The run's figures and verdict from its log table (``offboard.logs.runlog.COL`` columns)."""
    from offboard.logs.runlog import COL

    t = data[:, COL["t"]]
    alpha = data[:, COL["alpha"]]
    completed = bool(len(t) and t[-1] >= config.duration_s - 1e-6 and np.isfinite(data[:, 1:19]).all())
    e = data[:, [COL["e_Fx"], COL["e_Fy"], COL["e_z"]]]
    est_err = np.hypot(data[:, COL["est_Fx0"]], data[:, COL["est_Fy0"]])
    out: dict[str, Any] = {
        "peak_swing_rad": float(np.nanmax(alpha)) if len(alpha) else math.nan,
        "residual_swing_rad": float(np.nanmax(alpha[t >= arrival + 2.0])) if (t >= arrival + 2.0).any() else math.nan,
        "tracking_rms_m": float(np.sqrt(np.nanmean((e * e).sum(axis=1)))),
        "final_error_m": float(np.linalg.norm(e[-1])) if len(e) else math.nan,
        "max_estimate_error_m": float(np.nanmax(est_err)) if len(est_err) else math.nan,
        "slack_steps": int(slack),
        "completed": completed,
    }
    failure = verdict(config, out)
    out["success"] = failure == ""
    out["failure"] = failure
    out["sim_s"] = float(t[-1]) if len(t) else 0.0
    return out


def verdict(config: SweepConfig, fig: dict[str, Any]) -> str:
    """The first failed criterion of a run's figures ("" when it succeeds), in the order of the module docstring."""
    s = config.success
    if not fig["completed"]:
        return "diverged"
    if fig["peak_swing_rad"] > s.get("max_swing_rad", math.inf):
        return "swing_watchdog"
    if fig["max_estimate_error_m"] > s.get("divergence_m", math.inf):
        return "estimator_divergence"
    if fig["slack_steps"] > 0:
        return "cable_slack"
    if not fig["residual_swing_rad"] <= s.get("residual_swing_rad", math.inf):
        return "residual_swing"
    if not fig["tracking_rms_m"] <= s.get("tracking_rms_m", math.inf):
        return "tracking"
    if not fig["final_error_m"] <= s.get("final_error_m", math.inf):
        return "final_error"
    return ""


def run_one(config: SweepConfig, controller: str, run: int) -> dict[str, Any]:
    """One run of one controller with the scalar path (``offboard.harness.sim.run``, the filter in the loop)."""
    from estimators.model.vehicle import load_vehicle
    from offboard.control import smc
    from offboard.control.controllers import registry
    from offboard.harness import sim
    from offboard.harness.compare import controller_as_flown
    from offboard.logs.runlog import SimConfig

    nominal = load_vehicle(config.vehicle_file)
    p = draw(config, run, nominal)
    true_vehicle = plant_vehicle(nominal, p)
    sc = scenario(config, p)
    sim_cfg = SimConfig(
        estimator=config.estimator,
        sensors=config.sensors if config.estimator == "kf" else None,
        actuators=config.actuators,
        seed=int(p["sensor_seed"]),
    )
    params = smc.ControllerParams.for_vehicle(nominal)
    # the attitude-level law through PX4's attitude loops and designed for them, as slung compare flies it
    sim_cfg, law = controller_as_flown(controller, nominal, sim_cfg)
    tuning = registry.filter_tuning(controller, config.estimator)
    log = sim.run(
        sc,
        true_vehicle,
        params,
        sim_cfg,
        controller=law,
        sensor_preset=sensor_preset(config, p),
        command_lag=True,
        tuning=tuning,
    )
    row: dict[str, Any] = {"run": run, "controller": controller}
    row.update({k: p[k] for k in PARAMETERS})
    row.update(evaluate(config, log.data, sc.arrival_time, log.slack_steps))
    return row


def run_chunk(config_dict: dict[str, Any], controller: str, runs: list[int]) -> list[dict[str, Any]]:
    """A chunk of runs of one controller (what one Dask task does). ``config_dict``: :meth:`SweepConfig.to_dict`
    (plain data, so that a remote worker needs only the installed package, not the file)."""
    import time

    config = config_from_dict(config_dict)
    cpu0 = time.process_time()
    engine = engine_for(config, controller)
    if engine == "compiled":
        from offboard.harness.compiled.engine import run_batch as run_compiled

        rows = run_compiled(config, controller, runs)
    else:
        rows = [run_one(config, controller, r) for r in runs]
    cpu = (time.process_time() - cpu0) / max(len(rows), 1)
    for row in rows:  # not a column of the table (a resumed table must equal an uninterrupted one)
        row["cpu_s"] = cpu
    return rows


def warm_up(config: SweepConfig, controllers: list[str]) -> float:
    """Load (or, the first time on a machine, compile: about 2 minutes, said on stderr) the compiled engine's kernels
    for the ``controllers`` it flies, in this process, by flying run 0 of each over a 0.2 s move (1.4 s of flight);
    returns the wall seconds it took. Done before the Dask workers start, so that they load the kernels from numba's
    cache instead of each compiling them again, and so that a first sweep says why it waits."""
    import time

    compiled = [c for c in controllers if engine_for(config, c) == "compiled"]
    if not compiled:
        return 0.0
    from offboard.harness.compiled.engine import run_batch as run_compiled

    w0 = time.perf_counter()
    short = replace(config, move_time_s=0.2, hold_s=0.2)
    for c in compiled:
        run_compiled(short, c, [0])
    return time.perf_counter() - w0


def engine_for(config: SweepConfig, controller: str) -> str:
    """The path that flies ``controller``'s runs: the file's engine, except that the compiled path flies the rows of
    ``offboard.harness.compiled.inputs.COMPILED_LAWS`` (every row) with the filter ``kf`` or the true state, and
    the ideal actuators or the mixer (and PX4's attitude loops, which ``smc-attitude`` flies); a file asking for
    others (``actuators = "px4"``, PX4's allocator behind a torque-level law; the ``kf-torque`` filter) is flown by
    the scalar path, which models them all."""
    if config.estimator not in ("truth", "kf") or config.actuators not in ("ideal", "mixer"):
        return "scalar"
    if config.engine == "compiled":
        from offboard.harness.compiled.inputs import COMPILED_LAWS  # loads numba: only for the compiled engine

        return "compiled" if controller in COMPILED_LAWS else "scalar"
    return "scalar"


def reference_feasibility(config: SweepConfig) -> Any:
    """The pre-flight feasibility check (``offboard.control.feasibility.check_reference``, as ``slung sim`` and
    ``slung fly`` run it) of the file's move for its nominal vehicle and the sliding-mode law's limits: what the
    reference asks of the vehicle before any draw moves it (the draws leave the reference alone). A move past the
    limits (3 m in 2 s asks for a 1.2 rad swing) makes every controller's runs fail for the move's sake."""
    from estimators.model.vehicle import load_vehicle
    from offboard.harness.compare import smc_feasibility

    nominal = load_vehicle(config.vehicle_file)
    sc = scenario(config, draw(config, 0, nominal))
    return smc_feasibility(sc.reference, sc.duration, nominal)


def single_run_speed(config: SweepConfig) -> dict[str, float]:
    """The baseline measured beside a sweep: run 0 of the sliding-mode law through the scalar path, as the
    scalar engine flies it (``run_one``: the file's estimator, sensors and actuators); simulated seconds per
    wall second and per CPU second of this process."""
    import time

    w0, c0 = time.perf_counter(), time.process_time()
    row = run_one(config, "smc", 0)
    w, c = time.perf_counter() - w0, time.process_time() - c0
    simulated = float(row["sim_s"])
    return {"sim_s": simulated, "wall_s": w, "cpu_s": c, "per_wall_s": simulated / w, "per_cpu_s": simulated / c}


def config_from_dict(d: dict[str, Any]) -> SweepConfig:
    params = {k: Distribution(**v) for k, v in d.get("parameters", {}).items()}
    base = {k: v for k, v in d.items() if k not in ("parameters", "success")}
    return replace(SweepConfig(**base), parameters=params, success=dict(d.get("success", {})))


def table_columns() -> list[str]:
    return ["run", "controller", *PARAMETERS, *RESULT_COLUMNS]
