"""One linear Kalman-filter block: ``x' = A x + b w + noise``, batched over identical channels, variable steps.

The filters of ``estimators.filters.kf`` are made of a few such blocks (both horizontal axes share one block with a
batch of 2; heading and height have a batch of 1). A block holds no state; it gives the discretized model
for a step ``h`` (cached per step, so a run with fixed sensor and control rates computes each matrix once)
and the two Kalman operations on caller-owned arrays ``x`` (batch, n) and ``P`` (batch, n, n).

Discretization: ``Phi = expm(A h)`` and the zero-order-hold input matrix ``Gamma = int_0^h expm(A s) B ds``
from one matrix exponential of the augmented matrix; the process-noise covariance ``Q(h)`` by Van Loan's
method (the arithmetic of ``filterpy.common.van_loan_discretization``, done here: importing ``filterpy.common``
imports ``scipy.stats``, which costs about half a second at every start of ``slung fly`` / ``slung replay``) from the
diagonal continuous spectral densities.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar, NamedTuple

import numpy as np
from scipy.linalg import expm


def van_loan_discretization(f: np.ndarray, g: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``(Phi, Q)`` of ``x' = F x + G u`` (u unit white noise) for a step ``dt`` by Van Loan's method: the same
    operations, in the same order, as ``filterpy.common.van_loan_discretization`` (identical results)."""
    n = f.shape[0]
    a = np.zeros((2 * n, 2 * n))
    a[0:n, 0:n] = -f.dot(dt)
    a[0:n, n : 2 * n] = g.dot(g.T).dot(dt)
    a[n : 2 * n, n : 2 * n] = f.T.dot(dt)
    b = expm(a)
    sigma = b[n : 2 * n, n : 2 * n].T
    return sigma, sigma.dot(b[0:n, n : 2 * n])


class Discrete(NamedTuple):
    """Discretized model for one step: Phi (n, n), its transpose, the transposed input matrix Gamma^T (k, n),
    Q (n, n)."""

    phi: np.ndarray
    phi_t: np.ndarray
    gamma_t: np.ndarray
    q: np.ndarray


class LinearBlock:
    """Model ``x' = A x + B w + G nu``, ``nu`` unit white noise, ``G G^T = diag(q_c)`` (spectral densities).

    b: the input matrix B (n, k), or one column (n,).

    batch: number of identical channels filtered side by side (independent, same model).
    """

    _CACHE_LIMIT = 4096
    #: discretizations shared by every block with the same model (a run builds one filter per process, but
    #: tests and benchmarks build many): model bytes -> step key -> Discrete
    _SHARED: ClassVar[dict[bytes, dict[int, Discrete]]] = {}

    def __init__(self, a: np.ndarray, b: Sequence[float], q_c: Sequence[float], batch: int) -> None:
        self.a = np.asarray(a, dtype=float)
        self.n = self.a.shape[0]
        self.b = np.asarray(b, dtype=float).reshape(self.n, -1)
        self.g = np.diag(np.sqrt(np.asarray(q_c, dtype=float)))
        self.batch = batch
        model = self.a.tobytes() + self.b.tobytes() + self.g.tobytes()
        if len(self._SHARED) > 64:
            self._SHARED.clear()
        self._cache: dict[int, Discrete] = self._SHARED.setdefault(model, {})
        self._n_predict = 0

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
        n, k = self.n, self.b.shape[1]
        m = np.zeros((n + k, n + k))
        m[:n, :n] = self.a * h
        m[:n, n:] = self.b * h
        e = expm(m)
        phi = np.ascontiguousarray(e[:n, :n])
        gamma_t = np.ascontiguousarray(e[:n, n:].T)
        if h > 0.0:
            _, q = van_loan_discretization(self.a, self.g, h)
            q = 0.5 * (q + q.T)
        else:
            q = np.zeros((n, n))
        return Discrete(phi, np.ascontiguousarray(phi.T), gamma_t, q)

    # Kalman operations on caller-owned arrays ---------------------------------------------------------------
    # The channels of a batch share one model, one measurement row and one noise, so they share one covariance
    # P (n, n); only their means x (batch, n) differ.
    def predict_mean(self, x: np.ndarray, h: float, w: np.ndarray) -> np.ndarray:
        """Mean after ``h`` s with the inputs ``w`` (batch, k) held: ``x Phi^T + w Gamma^T`` (new array)."""
        d = self.discrete(h)
        return x @ d.phi_t + w @ d.gamma_t

    def predict_cov(self, p: np.ndarray, h: float) -> np.ndarray:
        """Covariance after ``h`` s: ``Phi P Phi^T + Q`` (new array)."""
        d = self.discrete(h)
        p = d.phi @ p @ d.phi_t + d.q
        self._n_predict += 1
        if self._n_predict % 16 == 0:  # the updates keep P symmetric up to rounding; re-symmetrize now and then
            p = 0.5 * (p + p.T)
        return p

    @staticmethod
    def update_states(
        x: np.ndarray,
        p: np.ndarray,
        idx: tuple[int, int],
        z: tuple[float, ...],
        r: tuple[float, float],
        gate: float,
    ) -> np.ndarray | None:
        """Measure the two states ``idx`` of every channel directly, in place.

        z: the measured values, channel-major (``z[2 c + j]`` is state ``idx[j]`` of channel ``c``);
        r: the variances of the two (independent) measurement noises. All innovations are gated together
        (their NIS summed over the channels, compared with ``gate``); when gated nothing changes.
        Returns the state correction (batch, n), or None when gated.
        """
        i, j = idx
        ph = p[:, idx]  # (n, 2) copy
        s11 = float(ph[i, 0]) + r[0]
        s12 = float(ph[i, 1])
        s22 = float(ph[j, 1]) + r[1]
        det = s11 * s22 - s12 * s12
        if not det > 0.0:
            return None
        s_inv = np.array(((s22 / det, -s12 / det), (-s12 / det, s11 / det)))
        y = np.subtract(z, x[:, idx].ravel()).reshape(-1, 2)
        ys = y @ s_inv
        if not float(np.vdot(ys, y)) <= gate:
            return None
        dx = ys @ ph.T
        x += dx
        p -= (ph @ s_inv) @ ph.T  # symmetric up to rounding; predict_cov re-symmetrizes
        return dx

    @staticmethod
    def update_state(
        x: np.ndarray, p: np.ndarray, i: int, z: tuple[float, ...], r: float, gate: float
    ) -> np.ndarray | None:
        """Measure state ``i`` of every channel, ``z`` (one value per channel) with variance ``r``, in place.

        The channels' innovations are gated together: if their summed normalized squares exceed ``gate``
        nothing changes. Returns the state correction (batch, n), or None when gated.
        """
        ph = p[:, i].copy()
        s = float(ph[i]) + r
        y = np.subtract(z, x[:, i])
        if not (s > 0.0 and float(y @ y) <= gate * s):
            return None
        return _correct(x, p, ph, y, s)

    @staticmethod
    def update_row(
        x: np.ndarray, p: np.ndarray, h: np.ndarray, z: tuple[float, ...], r: float, gate: float
    ) -> np.ndarray | None:
        """Measure ``h . x`` of every channel (``h`` (n,)), like :meth:`update_unit`."""
        ph = p @ h
        s = float(ph @ h) + r
        y = np.subtract(z, x @ h)
        if not float(y @ y) <= gate * s:
            return None
        return _correct(x, p, ph, y, s)


def _correct(x: np.ndarray, p: np.ndarray, ph: np.ndarray, y: np.ndarray, s: float) -> np.ndarray:
    """The accepted scalar update of :meth:`LinearBlock.update_unit` / :meth:`LinearBlock.update_row`, in place:
    gain ``P h / s`` for every channel's innovation ``y``; returns the state correction (batch, n)."""
    k = ph / s
    dx = np.multiply.outer(y, k)
    x += dx
    p -= np.multiply.outer(ph, ph) * (1.0 / s)  # exactly symmetric
    return dx


# Allocation-lean versions of the updates above, used by the filter's hot path -----------------------------------
# Same arithmetic (to rounding) as the methods of LinearBlock, on one array ``aug = [P; x]`` (n + batch, n)
# holding the covariance and the channels' means, so that one product serves both; the 2 x 2 algebra is done in
# plain floats and ndarray.dot (several times cheaper than ``@`` on tiny arrays, and a little cheaper than the function
# np.dot, which dispatches first) does the rest, into the preallocated buffers and through the prepared views of an
# :class:`AugWorkspace` (numpy's cost here is per call, a slice or an allocation costing as much as an 8 x 8 product).
# Each returns the NEGATED state correction (batch, n) (one negation fewer; a view of a workspace buffer, valid until
# the next update), or None when gated (then nothing changes).


class AugWorkspace:
    """Views of one ``aug = [P; x]`` array (n + batch, n) and the scratch buffers of the updates below and of a
    prediction (``pred``: ``aug Phi^T``, with its views ``pred_p`` and ``pred_x``)."""

    def __init__(self, aug: np.ndarray) -> None:
        rows, n = aug.shape
        batch = rows - n
        self.aug, self.n = aug, n
        self.p, self.x = aug[:n], aug[n:]
        self.pred = np.empty((rows, n))
        self.pred_p, self.pred_x = self.pred[:n], self.pred[n:]
        self.buf = np.empty(2 * (2 + batch))  # [S^-1; -y S^-1] of a pair update, flat
        self.buf2 = self.buf.reshape(2 + batch, 2)
        self.kd = np.empty((2 + batch, n))  # [S^-1; -y S^-1] P[i:i+2]
        self.kd_gain, self.kd_dx = self.kd[:2], self.kd[2:]
        self.pp = np.empty((n, n))  # P[:, i:i+2] S^-1 P[i:i+2]
        self.v = np.empty(rows)  # aug h, or column i of aug
        self.outer = np.empty((rows, n))  # rank-1 update
        self.outer_dx = self.outer[n:]
        self._pair: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def pair(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(aug[:, i:i+2], P[i:i+2], P[i:i+2].T): views for a pair update of states i, i + 1."""
        v = self._pair.get(i)
        if v is None:
            pr = self.aug[i : i + 2]
            v = self._pair[i] = (self.aug[:, i : i + 2], pr, pr.T)
        return v


def update_pair(
    ws: AugWorkspace, i: int, z: tuple[float, ...], r: tuple[float, float], gate: float
) -> np.ndarray | None:
    """:meth:`LinearBlock.update_states` for the adjacent pair of states ``(i, i + 1)``.

    Uses rows ``i, i + 1`` of P where the original uses its columns (P is symmetric): the gain and the state
    corrections come from one product ``[S^-1; y S^-1] P[i:i+2]``.
    """
    n = ws.n
    cols_v, pr, pr_t = ws.pair(i)
    cols = cols_v.tolist()  # columns i, i + 1: rows i, i + 1 hold S - R, the tail the channels' means
    s11, s12 = cols[i]
    s22 = cols[i + 1][1] + r[1]
    s11 += r[0]
    det = s11 * s22 - s12 * s12
    if not det > 0.0:
        return None
    a, b, d = s22 / det, -s12 / det, s11 / det
    rows = [a, b, b, d]
    nis = 0.0
    k = 0
    for x0, x1 in cols[n:]:
        y0, y1 = z[k] - x0, z[k + 1] - x1
        ys0, ys1 = y0 * a + y1 * b, y0 * b + y1 * d
        nis += ys0 * y0 + ys1 * y1
        rows.append(-ys0)
        rows.append(-ys1)
        k += 2
    if not nis <= gate:
        return None
    ws.buf[:] = rows
    kd = ws.kd
    ws.buf2.dot(pr, out=kd)  # rows 0-1: S^-1 P[i:i+2] (the gain, transposed); then -corrections
    pp = ws.pp
    pr_t.dot(ws.kd_gain, out=pp)
    ws.p -= pp
    ndx = ws.kd_dx
    ws.x -= ndx
    return ndx


def _rank1(ws: AugWorkspace, v: np.ndarray, y: list[float], s: float) -> np.ndarray:
    """``P -= (P h)(P h)^T / s`` and ``x_c += y_c (P h) / s``, from ``v = aug h`` (a workspace buffer) whose tail
    (the channels' ``h . x``) is overwritten with ``-y``; returns the negated corrections."""
    n = ws.n
    for c, yc in enumerate(y):
        v[n + c] = -yc
    kd = ws.outer
    np.multiply.outer(v, v[:n], out=kd)
    kd *= 1.0 / s
    ws.aug -= kd
    return ws.outer_dx


def update_row(ws: AugWorkspace, h: np.ndarray, z: tuple[float, ...], r: float, gate: float) -> np.ndarray | None:
    """:meth:`LinearBlock.update_row`."""
    n = ws.n
    v = ws.v
    ws.aug.dot(h, out=v)  # P h, then the channels' h . x
    vl = v.tolist()
    s = r
    for a, b in zip(vl, h.tolist()):
        s += a * b
    y = [zc - xc for zc, xc in zip(z, vl[n:])]
    yy = 0.0
    for e in y:
        yy += e * e
    if not yy <= gate * s:
        return None
    return _rank1(ws, v, y, s)


def update_one(ws: AugWorkspace, i: int, z: tuple[float, ...], r: float, gate: float) -> np.ndarray | None:
    """:meth:`LinearBlock.update_state`."""
    n = ws.n
    v = ws.v
    v[:] = ws.aug[:, i]  # P[:, i], then the channels' x_i
    vl = v.tolist()
    s = vl[i] + r
    y = [zc - xc for zc, xc in zip(z, vl[n:])]
    yy = 0.0
    for e in y:
        yy += e * e
    if not (s > 0.0 and yy <= gate * s):
        return None
    return _rank1(ws, v, y, s)
