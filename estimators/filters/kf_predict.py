"""The torque-driven Kalman filter's prediction (``estimators.filters.kf``): its blocks' discrete models for a step
and their prediction, of the delayed state to a measurement's time and of the output to the control tick.

A mixin of :class:`~estimators.filters.kf.KalmanEstimator` (it uses the estimator's state: ``_core``, ``_cmds``,
``_out``, the blocks ``_hb``, ``_yb``, ``_zb`` and the model caches), kept apart from the gated updates
(``kf_update``) and the public class. The heading (2 states) and height (4 states) blocks are hand-unrolled plain
floats: against the same blocks as 2 x 2 / 4 x 4 numpy arrays they made a tick 1.2-2x cheaper (issue 12's
measurement; ``bench/bench_estimator_ops.py`` times each step against the frozen reference filter, and
``bench/bench_kf_unrolled.py`` the updates, about 10x).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

from estimators.filters.kf_model import N_INPUTS


class KfPrediction:
    """Prediction of :class:`~estimators.filters.kf.KalmanEstimator`'s blocks (see the module docstring)."""

    _aug: np.ndarray
    _blocks: tuple
    _cmds: list
    _core: list
    _hb: Any
    _out: np.ndarray
    _out_cache: dict[int, np.ndarray]
    _outw: np.ndarray
    _t_out: float
    _ws: Any
    _yb: Any
    _ycache: dict[int, tuple[float, ...]]
    _zb: Any
    _zcache: dict[int, tuple[float, ...]]

    def _advance_core(self, bi: int, t: float) -> None:
        """Predict block ``bi`` of the delayed state to ``t`` with the commands in force (mean piecewise,
        covariance in one step: it does not depend on the input)."""
        core = self._core[bi]
        t0 = core.t
        if t <= t0:
            return
        cmds = self._cmds
        ncmd = len(cmds)
        j = 0
        while j + 1 < ncmd and cmds[j + 1][0] <= t0:
            j += 1
        if bi == 1:
            self._advance_heading(core, t0, t, j)
        elif bi == 2:
            self._advance_height(core, t0, t, j)
        else:
            self._advance_horizontal(core, t0, t, j)
        core.t = t

    def _forget_commands(self) -> None:
        """Drop the commands no block needs any more (those replaced before every block's time)."""
        c = self._core
        tmin = min(c[0].t, c[1].t, c[2].t)
        cmds = self._cmds
        ncmd = len(cmds)
        k = 0
        while k + 1 < ncmd and cmds[k + 1][0] <= tmin:
            k += 1
        if k:
            del cmds[:k]

    @staticmethod
    def _command_views(w: np.ndarray) -> tuple:
        """(all 6 inputs, horizontal (2, 2), heading (float), height (float)): the inputs of each block."""
        return (w, w[0:4].reshape(2, 2), float(w[4]), float(w[5]))

    def _active_command(self, t: float) -> tuple:
        """The command in force at time ``t`` (s), as the block inputs of :meth:`_command_views`."""
        cmds = self._cmds
        j = len(cmds) - 1
        while j > 0 and cmds[j][0] > t:
            j -= 1
        return cmds[j][1]

    def _advance_horizontal(self, core: list, t0: float, t: float, j: int) -> None:
        """:meth:`_advance_core` for the horizontal block, stored as one array ``[P; x]`` (10, 8) whose views
        are ``core.p`` (P) and ``core.x`` (x): with one command over the step, ``[P; x] Phi^T`` gives both
        ``P Phi^T`` and the mean's ``x Phi^T`` in one product."""
        blk = self._hb
        h = t - t0
        d = blk.discrete(h)
        cmds = self._cmds
        ncmd = len(cmds)
        p, x = core.p, core.x
        ws = self._ws
        self._aug.dot(d.phi_t, out=ws.pred)  # [P Phi^T; x Phi^T]
        d.phi.dot(ws.pred_p, out=p)
        p += d.q
        if j + 1 >= ncmd or cmds[j + 1][0] >= t:  # one command in force over the whole step
            np.add(ws.pred_x, cmds[j][1][1].dot(d.gamma_t), out=x)
        else:  # the mean piecewise, one segment per command
            for hs, w in self._segments(j, t0, t):
                d = blk.discrete(hs)
                np.add(x.dot(d.phi_t), w[1].dot(d.gamma_t), out=x)
        blk._n_predict += 1
        if blk._n_predict % 16 == 0:  # the updates keep P symmetric up to rounding; re-symmetrize now and then
            p[...] = 0.5 * (p + p.T)

    def _heading_model(self, h: float) -> tuple[float, ...]:
        """The heading block's discrete model for a step ``h`` as plain floats (phi00, phi01, phi10, phi11,
        gamma0, gamma1, q00, q01, q10, q11), cached like :meth:`LinearBlock.discrete`."""
        key = round(h * 1e7)
        mdl = self._ycache.get(key)
        if mdl is None:
            d = self._yb.discrete(h)
            (f00, f01), (f10, f11) = d.phi.tolist()
            g0, g1 = d.gamma_t[0].tolist()
            (q00, q01), (q10, q11) = d.q.tolist()
            if len(self._ycache) >= 4096:
                self._ycache.clear()
            mdl = self._ycache[key] = (f00, f01, f10, f11, g0, g1, q00, q01, q10, q11)
        return mdl

    def _heading_cov(self, p: list[float], h: float, count: bool = True) -> list[float]:
        """The heading covariance (row-major floats) predicted by ``h`` s: ``Phi P Phi^T + Q`` (re-symmetrized
        every 16th prediction of the block, like :meth:`LinearBlock.predict_cov`; ``count=False``: a read for the
        output, which neither counts nor re-symmetrizes, so that reading it leaves the filter as it was)."""
        f00, f01, f10, f11, _, _, q00, q01, q10, q11 = self._heading_model(h)
        p00, p01, p10, p11 = p
        a0, a1 = p00 * f00 + p01 * f01, p00 * f10 + p01 * f11  # (P Phi^T) row 0
        b0, b1 = p10 * f00 + p11 * f01, p10 * f10 + p11 * f11  # row 1
        p00, p01 = f00 * a0 + f01 * b0 + q00, f00 * a1 + f01 * b1 + q01
        p10, p11 = f10 * a0 + f11 * b0 + q10, f10 * a1 + f11 * b1 + q11
        if not count:
            return [p00, p01, p10, p11]
        yb = self._yb
        yb._n_predict += 1
        if yb._n_predict % 16 == 0:
            p01 = p10 = 0.5 * (p01 + p10)
        return [p00, p01, p10, p11]

    def _advance_heading(self, core: list, t0: float, t: float, j: int) -> None:
        """:meth:`_advance_core` for the heading block, whose mean and covariance are plain floats."""
        core.p = self._heading_cov(core.p, t - t0)
        x0, x1 = core.x
        for hs, cmd in self._segments(j, t0, t):
            f00, f01, f10, f11, g0, g1 = self._heading_model(hs)[:6]
            w = cmd[2]
            x0, x1 = x0 * f00 + x1 * f01 + w * g0, x0 * f10 + x1 * f11 + w * g1
        core.x = [x0, x1]

    def _height_model(self, h: float) -> tuple[float, ...]:
        """The height block's discrete model for a step ``h`` as plain floats: the three off-diagonal entries
        (phi01, phi02, phi12) of Phi (the rest of Phi is the identity exactly: ``A`` is nilpotent and only
        chains z, z', d_z), the input column (gamma0, gamma1; the rest is zero) and the 10 entries of the upper
        triangle of Q, row-major; cached like :meth:`LinearBlock.discrete`."""
        key = round(h * 1e7)
        mdl = self._zcache.get(key)
        if mdl is None:
            d = self._zb.discrete(h)
            f = d.phi
            structure = f.copy()
            structure[0, 1] = structure[0, 2] = structure[1, 2] = 0.0
            g = d.gamma_t[0]
            if not (np.array_equal(structure, np.eye(4)) and g[2] == 0.0 and g[3] == 0.0):  # pragma: no cover
                raise RuntimeError("height model: Phi or Gamma lost the structure the float code relies on")
            q = d.q
            mdl = (
                float(f[0, 1]),
                float(f[0, 2]),
                float(f[1, 2]),
                float(g[0]),
                float(g[1]),
                *(float(q[i, j]) for i in range(4) for j in range(i, 4)),
            )
            if len(self._zcache) >= 4096:
                self._zcache.clear()
            self._zcache[key] = mdl
        return mdl

    def _height_cov(self, p: list[float], h: float) -> list[float]:
        """The height covariance (upper triangle, row-major floats) predicted by ``h`` s: ``Phi P Phi^T + Q``."""
        a, b, c, _, _, q00, q01, q02, q03, q11, q12, q13, q22, q23, q33 = self._height_model(h)
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = p
        # M = Phi P (rows 0 and 1 change), then Phi M Phi^T's upper triangle
        m00, m01, m02, m03 = (
            p00 + a * p01 + b * p02,
            p01 + a * p11 + b * p12,
            p02 + a * p12 + b * p22,
            p03 + a * p13 + b * p23,
        )
        m11, m12, m13 = p11 + c * p12, p12 + c * p22, p13 + c * p23
        return [
            m00 + a * m01 + b * m02 + q00,
            m01 + c * m02 + q01,
            m02 + q02,
            m03 + q03,
            m11 + c * m12 + q11,
            m12 + q12,
            m13 + q13,
            p22 + q22,
            p23 + q23,
            p33 + q33,
        ]

    def _advance_height(self, core: list, t0: float, t: float, j: int) -> None:
        """:meth:`_advance_core` for the height block (mean and covariance plain floats; the covariance is kept
        as its upper triangle, row-major: P00 P01 P02 P03 P11 P12 P13 P22 P23 P33)."""
        core.p = self._height_cov(core.p, t - t0)
        x0, x1, x2, x3 = core.x
        for hs, cmd in self._segments(j, t0, t):
            a, b, c, g0, g1 = self._height_model(hs)[:5]
            w = cmd[3]
            x0, x1 = x0 + a * x1 + b * x2 + g0 * w, x1 + c * x2 + g1 * w
        core.x = [x0, x1, x2, x3]

    def _advance_output(self, t: float) -> None:
        """Predict the output means to ``t`` with the commands in force: per command segment one product
        ``[out, w] [Phi^T; Gamma^T]``."""
        cmds = self._cmds
        t0 = self._t_out
        j = len(cmds) - 1
        while j > 0 and cmds[j][0] > t0:
            j -= 1
        outw = self._outw
        out = self._out
        for hs, w in self._segments(j, t0, t):
            outw[22:] = w[0]
            out[:] = outw.dot(self._output_model(hs))
        self._t_out = t

    def _segments(self, j: int, t0: float, t: float) -> Iterator[tuple[float, tuple]]:
        """The command segments of the step from ``t0`` to ``t`` (s), command ``j`` being in force at ``t0``: per
        segment its length (s) and the block inputs of its command (:meth:`_command_views`)."""
        cmds = self._cmds
        ncmd = len(cmds)
        tc = t0
        while True:
            end = cmds[j + 1][0] if j + 1 < ncmd and cmds[j + 1][0] < t else t
            if end > tc:
                yield end - tc, cmds[j][1]
                tc = end
            if end >= t:
                return
            j += 1

    def _output_model(self, h: float) -> np.ndarray:
        """``[Phi^T; Gamma^T]`` (28, 22), block diagonal per block, of all 22 output means and the 6 command
        inputs for a step ``h`` (cached)."""
        key = round(h * 1e7)
        mdl = self._out_cache.get(key)
        if mdl is None:
            mdl = np.zeros((22 + N_INPUTS, 22))
            phi_t, gamma_t = mdl[:22], mdl[22:]
            dh, dy, dz = (blk.discrete(h) for blk in self._blocks)
            phi_t[0:8, 0:8] = dh.phi_t
            phi_t[8:16, 8:16] = dh.phi_t
            phi_t[16:18, 16:18] = dy.phi_t
            phi_t[18:22, 18:22] = dz.phi_t
            gamma_t[0:2, 0:8] = dh.gamma_t
            gamma_t[2:4, 8:16] = dh.gamma_t
            gamma_t[4, 16:18] = dy.gamma_t[0]
            gamma_t[5, 18:22] = dz.gamma_t[0]
            if len(self._out_cache) >= 4096:
                self._out_cache.clear()
            self._out_cache[key] = mdl
        return mdl

    def _output_covariances_raw(self) -> tuple[np.ndarray, list[float], list[float]]:
        """The blocks' covariances predicted to the output time, in their storage forms: horizontal (8, 8),
        heading row-major floats (4), height upper-triangle floats (10). A read: the blocks' prediction counters
        (which time their re-symmetrization) are not moved, so that reading changes no later estimate."""
        c = self._core
        t_out = self._t_out
        hp = c[0].p
        h = t_out - c[0].t
        if h > 0.0:
            d = self._hb.discrete(h)
            hp = d.phi.dot(hp).dot(d.phi_t)
            hp += d.q
        h = t_out - c[1].t
        yp = self._heading_cov(c[1].p, h, count=False) if h > 0.0 else c[1].p
        h = t_out - c[2].t
        zp = self._height_cov(c[2].p, h) if h > 0.0 else c[2].p
        return hp, yp, zp

    def _output_covariances(self) -> list[np.ndarray]:
        hp, yp, zp = self._output_covariances_raw()
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = zp
        return [
            hp.copy(),
            np.array(yp).reshape(2, 2),
            np.array(((p00, p01, p02, p03), (p01, p11, p12, p13), (p02, p12, p22, p23), (p03, p13, p23, p33))),
        ]


__all__ = ["KfPrediction"]
