"""The compiled engine's plant, sensors, gust and mixer (``sim_bridge.plant.compiled.plant``) against the scalar
plant (``sim_bridge.plant.dynamics``), sensors (``sim_bridge.plant.sensors.SensorSuite``), mixer
(``sim_bridge.inner.airframe.Mixer``) and true state (``estimators.model.flatness``): the same values on random
states, inputs and vehicles."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators import kernels as kern
from estimators.model.vehicle import load_vehicle
from offboard.harness import sweep
from sim_bridge.inner.airframe import Mixer
from sim_bridge.plant import dynamics
from sim_bridge.plant.compiled import plant as cp
from sim_bridge.plant.sensors import SensorSuite

V = load_vehicle(None)
RNG = np.random.default_rng(7)


def _vehicles(n: int) -> list:
    out = []
    for _ in range(n):
        k = RNG.uniform(0.7, 1.3, 5)
        out.append(
            V.with_changes(
                mass_vehicle=V.mass_vehicle * k[0],
                mass_load=V.mass_load * k[1],
                cable_length=V.cable_length * k[2],
                inertia=tuple(i * k[3] for i in V.inertia),
                motor_time_constant=0.01 + 0.03 * RNG.random(),
                linear_drag=float(RNG.choice([0.0, 0.8])),
                angular_drag=float(RNG.choice([0.0, 0.02])),
            )
        )
    return out


def _state() -> np.ndarray:
    x = RNG.normal(0.0, 0.4, 18)
    x[12:15] = RNG.normal(0.0, 0.3, 3) + np.array([0.0, 0.0, -1.0])
    dynamics.project_cable(x)  # type: ignore[arg-type]
    return x


def _input() -> np.ndarray:
    return np.concatenate([[RNG.uniform(3.0, 12.0)], RNG.normal(0.0, 0.3, 12)])


def test_derivative_rk4_and_tension_equal_the_scalar_plant() -> None:
    """Random states, inputs and true vehicles: the derivative, an RK4 step with the cable's projection and the
    tension equal ``sim_bridge.plant.dynamics`` (the scalar path) to 1e-13: the same equations, not the same
    operations (the kernel multiplies by the reciprocals of the masses, the length and the inertia where the scalar
    path divides, and moves the RK4 stages' sines by the angle-addition formulas), which costs a few ulp of the
    largest term; an error in an equation would show at 1e-3 or more."""
    work = np.empty((6, 18))
    out = np.empty(18)
    for v in _vehicles(20):
        p = cp.plant_constants(v)
        pp = dynamics.plant_params(v, "paper")
        x, u = _state(), _input()
        cp.derivative(x, u, p, out)
        np.testing.assert_allclose(out, dynamics.derivative(0.0, list(x), list(u), pp), rtol=1e-13, atol=1e-13)
        y = x.copy()
        cp.rk4_step(y, u, p, 1e-3, work)
        np.testing.assert_allclose(y, dynamics.rk4_step(list(x), list(u), pp, 1e-3), rtol=1e-13, atol=1e-13)
        assert not np.allclose(y, x)  # it moved
        assert cp.tension(x, u, p) == pytest.approx(dynamics.tension(list(x), list(u), pp), rel=1e-15, abs=1e-15)
    with pytest.raises(ValueError, match="at least"):  # the attitude's sines live in a sixth row
        cp.rk4_step(x.copy(), u, p, 1e-3, np.empty((5, 18)))


def test_rk4_stage_sines_by_angle_addition_equal_libm_and_fall_back_beyond_the_series_range() -> None:
    """The stages' sines and cosines by the angle-addition formulas: within 4 ulp of libm's ``sin(a + d)`` over
    angles to +-pi and steps to the series' limit; a vehicle tumbling at 100 rad/s (steps beyond the limit, libm's
    path) still steps as the scalar plant does."""
    shifted = cp._shifted.py_func
    for a in np.linspace(-math.pi, math.pi, 41):
        for d in (0.0, 1e-9, -3e-6, 2e-4, -0.007, 0.0299, -0.03):
            sa, ca = shifted(a, math.sin(a), math.cos(a), d)
            assert abs(sa - math.sin(a + d)) <= 4 * 2.3e-16 and abs(ca - math.cos(a + d)) <= 4 * 2.3e-16, (a, d)
    v = _vehicles(1)[0]
    p, pp = cp.plant_constants(v), dynamics.plant_params(v, "paper")
    x, u = _state(), _input()
    # 100 rad/s: every stage beyond the series' 0.03 rad (h/2 * rate = 0.05); 40 rad/s: the half steps by the series
    # (0.02), the full step by libm (0.04)
    for rate, turned in ((100.0, 0.09), (40.0, 0.035)):
        x[9:12] = (rate, -0.8 * rate, 0.9 * rate)
        y = x.copy()
        cp.rk4_step(y, u, p, 1e-3, np.empty((6, 18)))
        np.testing.assert_allclose(y, dynamics.rk4_step(list(x), list(u), pp, 1e-3), rtol=1e-13, atol=1e-13)
        assert abs(y[6] - x[6]) > turned, rate


def test_drag_equals_the_scalar_drag_and_leaves_slots_without_it() -> None:
    for v in _vehicles(12):
        p = cp.plant_constants(v)
        x, u = _state(), _input()
        force, torque = RNG.normal(0.0, 0.5, 3), RNG.normal(0.0, 0.1, 3)
        mine, scalar = u.copy(), list(u)
        cp.apply_drag(mine, x, force, torque, p)
        dynamics.apply_drag(scalar, list(x), list(force), list(torque), v.linear_drag, v.angular_drag)
        np.testing.assert_allclose(mine, scalar, rtol=1e-15, atol=1e-15)
        if v.linear_drag == 0.0:
            np.testing.assert_array_equal(mine[4:7], u[4:7])


class _GivenNoise(SensorSuite):
    """The scalar sensors with the next record's noise given (``noise``) instead of drawn."""

    noise: tuple[float, ...] = ()

    def _noise(self, sigmas: object, n: int) -> list[float]:
        return list(self.noise[:n])


@pytest.mark.parametrize("kind", [kern.POS, kern.ATT, kern.IMU, kern.LOAD])
def test_sensor_values_equal_the_scalar_sensors(kind: int) -> None:
    """A record's values from the state, the plant's derivative, gravity, the accelerometer's bias and the noise:
    the scalar ``SensorSuite._measure`` of the same state, input and noise, to 1e-14."""
    for v in _vehicles(8):
        x, u = _state(), _input()
        suite = _GivenNoise("px4-typical", v, np.random.default_rng(3), load_sensor=True)
        suite.noise = tuple(RNG.normal(0.0, 0.01, 6).tolist())
        rec = suite._measure(suite._streams[kind], 0.0, x.tolist(), u.tolist())
        want = [float(f) for f in rec[1:]]  # the record's fields after its time
        deriv = np.asarray(dynamics.derivative(0.0, x, u, dynamics.plant_params(v, "paper")))
        out = np.empty(6)
        cp.measure(kind, x, deriv, v.gravity, np.array(suite.accel_bias), np.array(suite.noise), out)
        np.testing.assert_allclose(out[: kern.FIELDS[kind]], want, rtol=1e-14, atol=1e-14)


def test_gust_equals_the_sweeps_gust() -> None:
    """The 1 - cos gust against ``offboard.harness.sweep._Gust`` (the scalar path's) over its whole span."""
    g = sweep._Gust(start=1.3, force=0.7, direction=2.1)
    c = cp.gust_constants(g)
    out = np.empty(9)
    felt = 0
    for t in np.arange(0.0, 3.0, 0.01):
        cp.gust_at(c, float(t), out)
        np.testing.assert_allclose(out, g(float(t)), rtol=1e-15, atol=1e-15)
        felt += bool(out.any())
    assert felt > 90  # the gust acted for its second
    cp.gust_at(cp.gust_constants(None), 1.5, out)
    assert not out.any()


def test_mixer_equals_the_scalar_mixer_through_saturation() -> None:
    """Allocation and the motors' lag over 300 plant steps of random wrenches, some far beyond the motors' limits
    (roll / pitch first, the collective shifted, yaw with what is left): the scalar ``Mixer`` to 1e-14."""
    vs = _vehicles(6)
    mixers = [Mixer(v, 1e-3) for v in vs]
    hover = [(v.mass_vehicle + v.mass_load) * v.gravity for v in vs]
    for m, h in zip(mixers, hover):
        m.reset(0.25 * h)
    consts = [cp.mixer_constants(v, 1e-3) for v in vs]
    f = [np.full(4, 0.25 * h) for h in hover]
    cmd = [fi.copy() for fi in f]
    u = np.zeros(13)
    clipped = 0
    for _ in range(300):
        w = np.stack(
            [RNG.uniform(-2.0, 20.0, len(vs)), *RNG.normal(0.0, 1.5, (2, len(vs))), RNG.normal(0, 0.2, len(vs))]
        )
        for b, (c, m) in enumerate(zip(consts, mixers)):
            want_cmd = m.allocate(*(float(wi) for wi in w[:, b]))
            want = m.step()
            cp.mixer_allocate(c, w[0, b], w[1, b], w[2, b], w[3, b], cmd[b])
            np.testing.assert_allclose(cmd[b], want_cmd, rtol=1e-14, atol=1e-14)
            clipped += bool(np.any(cmd[b] == c[cp.MIX_FMAX]) or np.any(cmd[b] == 0.0))
            cp.mixer_step(c, f[b], cmd[b], u)
            np.testing.assert_allclose(u[:4], want, rtol=1e-14, atol=1e-14)
    assert clipped > 100  # the limits were met


def test_truth_state_equals_the_scalar_true_state() -> None:
    """``truth_state`` against ``estimators.model.flatness.truth_control_state`` (the scalar path's true estimate)."""
    from estimators.model.flatness import flat_constants, truth_control_state

    k = flat_constants(V)
    out = np.empty(kern.EST_SIZE)
    for _ in range(10):
        x = _state()
        want = truth_control_state(x, k)
        cp.truth_state(x, k.l, k.g, k.c, out)
        np.testing.assert_allclose(out[kern.EST_FX : kern.EST_FX + 6], want.fx, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(out[kern.EST_FY : kern.EST_FY + 6], want.fy, rtol=1e-14, atol=1e-14)
        for name, i in (("z", kern.EST_Z), ("psi_rate", kern.EST_PSI_RATE), ("alpha_x_rate", kern.EST_ALPHA_X_RATE)):
            assert out[i] == pytest.approx(getattr(want, name), rel=1e-14, abs=1e-14)
    assert math.isfinite(out.sum())


def test_the_kernels_wrap_angle_equals_the_scalar_paths_bit_for_bit() -> None:
    """``estimators.kernels.wrap_angle`` (fmod only outside +-2 pi) gives ``estimators.model.frames.wrap_angle``'s
    value to the last bit and sign, in range and far outside it, at the edges of (-pi, pi], and for inf and NaN."""
    from estimators.kernels import wrap_angle
    from estimators.model.frames import wrap_angle as scalar

    edges = [math.pi, -math.pi, 0.0, -0.0, 2 * math.pi, -2 * math.pi, 3 * math.pi, -3 * math.pi, 1e-300, 1e300]
    edges += [float(np.nextafter(math.pi, 0.0)), float(np.nextafter(-math.pi, 0.0)), float(np.nextafter(math.pi, 4))]
    xs = [*RNG.uniform(-30.0, 30.0, 20000), *RNG.uniform(-1e6, 1e6, 200), *edges, *(-e for e in edges)]
    for x in xs:
        got, want = wrap_angle(x), scalar(x)
        assert got == want and math.copysign(1.0, got) == math.copysign(1.0, want), x
    assert all(math.isnan(wrap_angle(x)) and math.isnan(scalar(x)) for x in (math.inf, -math.inf, math.nan))


def test_the_kernels_compile_the_scalar_paths_own_functions_and_their_cache_follows_them() -> None:
    """The cable's projection, PX4's quaternion helpers and desaturation gain, the laws' switching and thrust
    direction and the filter's block models, covariance propagation, Euler rates and world tilt are one source: the
    kernels are the scalar functions themselves, compiled (``.py_func``); the file of each is among the
    ``SHARED_SOURCES`` of the kernel package that compiles it, whose change drops that package's compiled cache
    (numba keys an inlined function's code by its caller's file only); and the engine's cache depends on every kernel
    package's sources."""
    import inspect
    from pathlib import Path

    from estimators import kernels
    from estimators.filters import compiled as filter_kernels
    from estimators.filters import small_kf
    from estimators.filters.compiled import kf, kf_predict
    from estimators.model import cable, flatness, frames, rotations
    from offboard.control import compiled as law_kernels
    from offboard.control import smc
    from offboard.control.compiled import attitude_law, smc_law
    from offboard.harness.compiled import layout as engine_layout
    from sim_bridge.inner import compiled as inner_kernels
    from sim_bridge.inner import px4_inner
    from sim_bridge.inner.compiled import px4_loops
    from sim_bridge.plant import compiled as plant_kernels

    plant, inner, laws, kf_pkg = plant_kernels, inner_kernels, law_kernels, filter_kernels
    triples = [
        (plant, cp._project_cable, dynamics.project_cable),
        (plant, cp._thrust_direction, rotations.thrust_direction_trig),
        (plant, cp._planar_swing, cable.planar_swing),
        (plant, cp.body_rates, rotations.body_rates),
        (inner, px4_loops.euler_to_quaternion, frames.euler_to_quaternion),
        (inner, px4_loops._mul, rotations.quat_mul),
        (inner, px4_loops._conj, rotations.quat_conj),
        (inner, px4_loops._canonical, px4_inner.canonical),
        (inner, px4_loops._body_z, px4_inner.body_z),
        (inner, px4_loops._shortest_rotation, px4_inner.shortest_rotation),
        (inner, px4_loops._desaturation_gain, px4_inner.desaturation_gain),
        (laws, attitude_law._switching, smc.switching),
        (laws, smc_law._switching, smc.switching),
        (laws, smc_law._thrust_direction, rotations.thrust_direction_trig),
        (kf_pkg, kf_predict._pendulum_terms, small_kf.pendulum_terms),
        (kf_pkg, kf_predict._pendulum_noise, small_kf.pendulum_noise),
        (kf_pkg, kf_predict._sandwich3, small_kf.sandwich3),
        (kf_pkg, kf._euler_rates, rotations.euler_rates),
        (kf_pkg, kf._world_tilt, flatness.world_tilt),
        (kf_pkg, kf._cable_pull, cable.cable_pull),
    ]
    for package, kernel, scalar in triples:
        assert kernel.py_func is scalar
        source = Path(inspect.getsourcefile(scalar)).resolve().relative_to(kernels.ROOT).as_posix()
        assert source in package.SHARED_SOURCES, (package.__name__, source)
        assert source in engine_layout.SHARED_SOURCES
    for package in (plant, inner, laws, kf_pkg):
        assert set(package.SOURCES) <= set(engine_layout.SOURCES), package.__name__
        assert kernels.ROOT / "estimators/kernels.py" in package.SOURCES  # the shared kernels, compiled in
    assert set(plant.SOURCES) <= set(inner.SOURCES)  # PX4's loops call the plant's body rates
