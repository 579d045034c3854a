"""``zv`` / ``zvd``: input shaping of the reference in front of the stock cascade
(``offboard.control.controllers.cascade``).

A shaper convolves the reference with a few impulses ``A_i`` at times ``t_i`` (Singer & Seering 1990): the zero
vibration (ZV) shaper's two impulses and the zero-vibration-and-derivative (ZVD) shaper's three cancel the
response of one lightly damped mode (natural frequency ``w``, damping ``zeta``, damped frequency
``w_d = w sqrt(1 - zeta^2)``, ``K = exp(-zeta pi / sqrt(1 - zeta^2))``)::

    ZV:  A = [1, K] / (1 + K),                 t = [0, pi / w_d]
    ZVD: A = [1, 2K, K^2] / (1 + K)^2,         t = [0, pi / w_d, 2 pi / w_d]

The impulses sum to 1 (the shaped move ends where the reference does) and the mode's residual vibration
``|sum A_i exp(zeta w t_i) exp(j w_d t_i)|`` is zero; ZVD also zeroes its derivative with respect to ``w``
(robust to a frequency error), at the price of one more half period of delay.

The mode to cancel is the load's swing as the cascade flies it: the least damped oscillatory pair of the cascade
closed around the tangent linearization (:func:`cascade_swing_mode`, the cascade's gains differentiated
numerically at hover), not the free pendulum's ``sqrt(g / l)``: the position loop moves the suspension point and
shifts the mode.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence

import numpy as np

from estimators.model.control_state import ControlState
from estimators.model.flatness import control_state_of, flat_constants
from estimators.model.vehicle import Vehicle
from offboard.control.controllers.cascade import CascadeController, CascadeGains
from offboard.control.linear_model import linear_model
from offboard.control.smc import Command, Ref


def shaper_impulses(kind: str, omega: float, zeta: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(amplitudes, times) of the ``"zv"`` or ``"zvd"`` shaper for natural frequency ``omega`` (rad/s) and
    damping ratio ``zeta`` (0 <= zeta < 1); times in s from the first impulse."""
    if not (omega > 0.0 and math.isfinite(omega)) or not (0.0 <= zeta < 1.0):
        raise ValueError(f"a shaper needs omega > 0 and 0 <= zeta < 1, got {omega!r}, {zeta!r}")
    wd = omega * math.sqrt(1.0 - zeta * zeta)
    K = math.exp(-zeta * math.pi / math.sqrt(1.0 - zeta * zeta))
    half = math.pi / wd
    if kind == "zv":
        return (1.0 / (1.0 + K), K / (1.0 + K)), (0.0, half)
    if kind == "zvd":
        d = (1.0 + K) ** 2
        return (1.0 / d, 2.0 * K / d, K * K / d), (0.0, half, 2.0 * half)
    raise ValueError(f"unknown shaper {kind!r} (zv or zvd)")


def residual_vibration(amplitudes: Sequence[float], times: Sequence[float], omega: float, zeta: float) -> float:
    """The mode's residual vibration after the impulse sequence, relative to one unit impulse (0: cancelled)."""
    wd = omega * math.sqrt(1.0 - zeta * zeta)
    c = sum(a * math.exp(zeta * omega * t) * math.cos(wd * t) for a, t in zip(amplitudes, times))
    s = sum(a * math.exp(zeta * omega * t) * math.sin(wd * t) for a, t in zip(amplitudes, times))
    return math.exp(-zeta * omega * times[-1]) * math.hypot(c, s)


def _state_to_estimate(x: np.ndarray, vehicle: Vehicle) -> ControlState:
    """A 16-state deviation of ``offboard.control.linear_model`` (at hover, height 0) as the controller's input."""
    return control_state_of(flat_constants(vehicle), x, x[12], x[13], x[14], x[15])


def cascade_swing_mode(vehicle: Vehicle, gains: CascadeGains | None = None) -> tuple[float, float]:
    """(omega rad/s, zeta) of the least damped oscillatory mode of the cascade closed around the tangent
    linearization at hover: the cascade's response to each state deviation is differentiated numerically (its
    integrators empty), ``A_cl = A + B K``, and the swing mode is the complex pair with the largest swing-angle
    share of its eigenvector."""
    lm = linear_model(vehicle, 0.0)
    zero = (0.0,) * 7
    ref_z, ref_psi = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    h = 1e-6
    K = np.zeros((4, 16))
    hover = vehicle.hover_thrust
    for j in range(16):
        cols = []
        for sgn in (1.0, -1.0):
            c = CascadeController(vehicle, gains)
            x = np.zeros(16)
            x[j] = sgn * h
            cmd = c.step(0.0, _state_to_estimate(x, vehicle), zero, zero, ref_z, ref_psi)
            cols.append(np.array([cmd.thrust - hover, cmd.tau_phi, cmd.tau_theta, cmd.tau_psi]))
        K[:, j] = (cols[0] - cols[1]) / (2.0 * h)
    eig, vec = np.linalg.eig(lm.A + lm.B @ K)
    best = None
    for lam, v in zip(eig, vec.T):
        if lam.imag <= 1e-6:
            continue
        share = float(np.linalg.norm(v[12:16]) / np.linalg.norm(v))
        if best is None or share > best[0]:
            best = (share, lam)
    if best is None:
        raise ValueError("the cascade's closed loop has no oscillatory mode")
    lam = best[1]
    omega = abs(lam)
    return float(omega), float(-lam.real / omega)


class ReferenceShaper:
    """The shaped reference ``sum A_i ref(t - t_i)`` for every derivative order, from the reference samples given
    at the ticks so far (at most the shaper's length back kept), linearly interpolated between ticks; before the
    first tick the first sample holds (a flight starts at rest). Shared by :class:`ShapedCascade` and the compiled
    sweep engine (one reference for all runs: shaped once per tick)."""

    def __init__(self, amplitudes: Sequence[float], delays: Sequence[float]) -> None:
        self.amplitudes, self.delays = tuple(amplitudes), tuple(delays)
        self.reset()

    def reset(self) -> None:
        self._t: list[float] = []
        self._r: list[tuple[tuple[float, ...], ...]] = []

    def _at(self, t: float) -> tuple[tuple[float, ...], ...]:
        ts = self._t
        i = bisect.bisect_right(ts, t)
        if i == 0:
            return self._r[0]
        if i == len(ts):
            return self._r[-1]
        t0, t1 = ts[i - 1], ts[i]
        w = (t - t0) / (t1 - t0) if t1 > t0 else 1.0
        a, b = self._r[i - 1], self._r[i]
        return tuple(tuple(p + w * (q - p) for p, q in zip(pa, pb)) for pa, pb in zip(a, b))

    def shaped(self, t: float) -> tuple[tuple[float, ...], ...]:
        """The shaped (fx, fy, z, psi) at ``t`` from the samples given so far."""
        parts = [self._at(t - d) for d in self.delays]
        return tuple(
            tuple(sum(a * p[k][n] for a, p in zip(self.amplitudes, parts)) for n in range(len(parts[0][k])))
            for k in range(4)
        )

    def __call__(self, t: float, ref_fx: Ref, ref_fy: Ref, ref_z: Ref, ref_psi: Ref) -> tuple[tuple[float, ...], ...]:
        """Take the tick's reference sample (a repeated tick replaces its sample) and give the shaped
        (fx, fy, z, psi) at ``t``."""
        if self._t and t <= self._t[-1]:
            self._t.pop()
            self._r.pop()
        self._t.append(t)
        self._r.append((tuple(ref_fx), tuple(ref_fy), tuple(ref_z), tuple(ref_psi)))
        horizon = t - self.delays[-1] - 0.1
        if len(self._t) > 2 and self._t[1] < horizon:  # forget what no impulse reaches any more
            cut = bisect.bisect_left(self._t, horizon) - 1
            if cut > 0:
                del self._t[:cut], self._r[:cut]
        return self.shaped(t)


class ShapedCascade:
    """``zv`` / ``zvd``: the stock cascade flying the shaped reference (see the module docstring and
    :class:`ReferenceShaper`)."""

    def __init__(
        self,
        vehicle: Vehicle,
        kind: str = "zv",
        gains: CascadeGains | None = None,
        mode: tuple[float, float] | None = None,
    ) -> None:
        self.name = kind
        self.cascade = CascadeController(vehicle, gains, name=kind)
        self.omega, self.zeta = mode if mode is not None else cascade_swing_mode(vehicle, gains)
        self.amplitudes, self.delays = shaper_impulses(kind, self.omega, self.zeta)
        self.shaper = ReferenceShaper(self.amplitudes, self.delays)
        self.reset()

    #: a position-level controller, as the cascade it shapes the reference of (``flight_output``)
    level = "position"

    @property
    def attitude_sp(self) -> tuple[float, float, float] | None:
        """The cascade's attitude setpoint of the last step (roll, pitch, heading, rad; None before the first)."""
        return self.cascade.attitude_sp

    def reset(self) -> None:
        self.cascade.reset()
        self.shaper.reset()

    def step(self, t: float, est: ControlState, ref_fx: Ref, ref_fy: Ref, ref_z: Ref, ref_psi: Ref) -> Command:
        fx, fy, z, psi = self.shaper(t, ref_fx, ref_fy, ref_z, ref_psi)
        return self.cascade.step(t, est, fx, fy, z, psi)

    def memory_fields(self) -> tuple[float, float, float, float]:
        return self.cascade.memory_fields()
