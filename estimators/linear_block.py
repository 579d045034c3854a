"""One linear Kalman-filter block: ``x' = A x + b w + noise``, batched over identical channels, variable steps.

The filters of ``estimators.kf`` are made of a few such blocks (both horizontal axes share one block with a
batch of 2; heading and height have a batch of 1). A block holds no state; it gives the discretized model
for a step ``h`` (cached per step, so a run with fixed sensor and control rates computes each matrix once)
and the two Kalman operations on caller-owned arrays ``x`` (batch, n) and ``P`` (batch, n, n).

Discretization: ``Phi = expm(A h)`` and the zero-order-hold input column ``gamma = int_0^h expm(A s) b ds``
from one matrix exponential of the augmented matrix; the process-noise covariance ``Q(h)`` by Van Loan's
method (``filterpy.common.van_loan_discretization``) from the diagonal continuous spectral densities.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from filterpy.common import van_loan_discretization
from scipy.linalg import expm


class Discrete(NamedTuple):
    """Discretized model for one step: Phi (n, n), its transpose, the input column gamma (n,), Q (n, n)."""

    phi: np.ndarray
    phi_t: np.ndarray
    gamma: np.ndarray
    q: np.ndarray


class LinearBlock:
    """Model ``x' = A x + b w + G nu``, ``nu`` unit white noise, ``G G^T = diag(q_c)`` (spectral densities).

    batch: number of identical channels filtered side by side (independent, same model).
    """

    _CACHE_LIMIT = 4096

    def __init__(self, a: np.ndarray, b: Sequence[float], q_c: Sequence[float], batch: int) -> None:
        self.a = np.asarray(a, dtype=float)
        self.n = self.a.shape[0]
        self.b = np.asarray(b, dtype=float).reshape(self.n)
        self.g = np.diag(np.sqrt(np.asarray(q_c, dtype=float)))
        self.batch = batch
        self._cache: dict[int, Discrete] = {}

    def discrete(self, h: float) -> Discrete:
        """The discretized model for a step of ``h`` seconds (>= 0), cached per 0.1 microsecond."""
        key = round(h * 1e7)
        d = self._cache.get(key)
        if d is None:
            d = self._discretize(key * 1e-7)
            if len(self._cache) >= self._CACHE_LIMIT:
                self._cache.clear()
            self._cache[key] = d
        return d

    def _discretize(self, h: float) -> Discrete:
        n = self.n
        m = np.zeros((n + 1, n + 1))
        m[:n, :n] = self.a * h
        m[:n, n] = self.b * h
        e = expm(m)
        phi = np.ascontiguousarray(e[:n, :n])
        gamma = e[:n, n].copy()
        if h > 0.0:
            _, q = van_loan_discretization(self.a, self.g, h)
            q = 0.5 * (q + q.T)
        else:
            q = np.zeros((n, n))
        return Discrete(phi, np.ascontiguousarray(phi.T), gamma, q)

    # Kalman operations on caller-owned arrays ---------------------------------------------------------------
    def predict_mean(self, x: np.ndarray, h: float, w: np.ndarray) -> np.ndarray:
        """Mean after ``h`` s with the input ``w`` (batch,) held: ``x Phi^T + w gamma`` (new array)."""
        d = self.discrete(h)
        return x @ d.phi_t + w[:, None] * d.gamma

    def predict_cov(self, p: np.ndarray, h: float) -> np.ndarray:
        """Covariance after ``h`` s: ``Phi P Phi^T + Q`` (new array)."""
        d = self.discrete(h)
        return d.phi @ p @ d.phi_t + d.q

    @staticmethod
    def update_unit(
        x: np.ndarray, p: np.ndarray, i: int, z: np.ndarray, r: float, gate: float
    ) -> tuple[float, np.ndarray | None]:
        """Measure state ``i`` of every channel: ``z`` (batch,) with variance ``r``, in place.

        The channels' innovations are gated together: if their summed NIS exceeds ``gate`` nothing changes.
        Returns (NIS, the state correction (batch, n) or None when gated or not finite).
        """
        ph = p[:, :, i].copy()
        s = ph[:, i] + r
        y = z - x[:, i]
        nis = float(np.sum(y * y / s))
        if not nis <= gate:
            return nis, None
        k = ph / s[:, None]
        dx = k * y[:, None]
        x += dx
        p -= k[:, :, None] * ph[:, None, :]
        return nis, dx

    @staticmethod
    def update_row(
        x: np.ndarray, p: np.ndarray, h: np.ndarray, z: np.ndarray, r: float, gate: float
    ) -> tuple[float, np.ndarray | None]:
        """Measure ``h . x`` of every channel (``h`` (n,), the same row for all), like :meth:`update_unit`."""
        ph = p @ h
        s = ph @ h + r
        y = z - x @ h
        nis = float(np.sum(y * y / s))
        if not nis <= gate:
            return nis, None
        k = ph / s[:, None]
        dx = k * y[:, None]
        x += dx
        p -= k[:, :, None] * ph[:, None, :]
        return nis, dx
