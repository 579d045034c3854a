"""Bounded, band-limited, seeded random disturbances (the paper's Figure 7, whose amplitudes it does not give).

The environment acting on the plant: used by ``slung sim`` (``offboard.harness.sim`` builds them from a scenario's plant
setup) and by the emulator (``slung emulate --disturbance paper``), which may not import ``offboard``.

Each channel is a sum of sinusoids with random frequencies in a band, random phases and random weights,
scaled so that the sum of the amplitudes equals the channel's bound: the signal can never exceed it. A smooth
onset (the C^7 step of the references, over ``ramp`` seconds) starts it at ``start`` without a jump.
The generator is a pure function of its seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DisturbanceSpec:
    """Bounds and band of the disturbances (SI).

    force_xyz: bound of each force on the vehicle, world x, y, z (N); torque_psi: bound of the yaw torque
    (N m); band: (lowest, highest) frequency (Hz); components: sinusoids per channel; start: onset (s);
    ramp: onset duration (s).
    """

    force_xyz: tuple[float, float, float] = (0.5, 0.5, 0.5)
    torque_psi: float = 0.02
    band: tuple[float, float] = (0.1, 2.0)
    components: int = 8
    start: float = 25.0
    ramp: float = 1.0


def _onset(t: float, start: float, ramp: float) -> float:
    """0 before ``start``, 1 after ``start + ramp``, the degree-15 C^7 smooth step in between."""
    if t <= start:
        return 0.0
    if ramp <= 0.0 or t >= start + ramp:
        return 1.0
    x = (t - start) / ramp
    # order-7 smooth step S(x) = x^8 sum_k C(7+k, k) C(15, 7-k) (-x)^k
    coeffs = (6435.0, -40040.0, 108108.0, -163800.0, 150150.0, -83160.0, 25740.0, -3432.0)
    acc = 0.0
    for c in reversed(coeffs):
        acc = acc * x + c
    return acc * x**8


class RandomDisturbance:
    """Callable ``d(t) -> 9-tuple`` (force on vehicle xyz N world, force on load xyz N world, torque xyz N m
    body) as the plant input expects (``sim_bridge.plant.dynamics``); the load force and roll/pitch torques are 0."""

    def __init__(self, spec: DisturbanceSpec, seed: int) -> None:
        rng = np.random.default_rng(seed)
        lo, hi = spec.band
        self.spec = spec
        bounds = (*spec.force_xyz, spec.torque_psi)
        self._channels: list[tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]] = []
        for bound in bounds:
            w = 2.0 * math.pi * rng.uniform(lo, hi, spec.components)
            ph = rng.uniform(0.0, 2.0 * math.pi, spec.components)
            a = rng.uniform(0.2, 1.0, spec.components)
            a = bound * a / a.sum()
            self._channels.append((tuple(a.tolist()), tuple(w.tolist()), tuple(ph.tolist())))

    def channel(self, t: float, i: int) -> float:
        """Channel ``i`` (0..2 forces, 3 yaw torque) before the onset envelope."""
        a, w, ph = self._channels[i]
        return sum(ai * math.sin(wi * t + pi) for ai, wi, pi in zip(a, w, ph))

    def sample_grid(self, times: np.ndarray) -> np.ndarray:
        """The disturbance at many times at once, shape (len(times), 9); equal to calling it at each time."""
        s = self.spec
        out = np.zeros((len(times), 9))
        k = np.array([_onset(float(t), s.start, s.ramp) for t in times])
        for col, i in ((0, 0), (1, 1), (2, 2), (8, 3)):
            a, w, ph = (np.asarray(v) for v in self._channels[i])
            out[:, col] = k * np.sum(a[None, :] * np.sin(np.outer(times, w) + ph[None, :]), axis=1)
        return out

    def __call__(self, t: float) -> tuple[float, ...]:
        s = self.spec
        k = _onset(t, s.start, s.ramp)
        if k == 0.0:
            return (0.0,) * 9
        fx, fy, fz, tz = (k * self.channel(t, i) for i in range(4))
        return (fx, fy, fz, 0.0, 0.0, 0.0, 0.0, 0.0, tz)
