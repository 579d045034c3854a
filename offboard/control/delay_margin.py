"""The torque-level law's gains with the measured loop delay as a margin (derivation: ``docs/model.md`` §11,
"Gains with the loop delay as a margin").

Each loop of ``offboard.control.smc`` is, inside its sliding surface, a chain of integrators closed by a polynomial:
height and yaw ``e'' + k1 e' + k0 e``, horizontal ``e^(6) + K5 e^(5) + ... + K0 e``. Its open loop is
``L(s) = (P(s) - s^n) / s^n`` with ``P`` the designed characteristic polynomial; a delay ``tau`` on the way from
measurement to torque multiplies it by ``exp(-s tau)`` and costs ``omega_c tau`` of phase at the crossover
``omega_c``. The loop delay is what the loop waits for, in s of vehicle time:

    tau_loop = motor time constant + telemetry age + setpoint way         (the two link delays measured in flight)

Scaling every pole of a loop by ``f`` (``P(s) -> f^n P(s / f)``, :meth:`offboard.control.smc.Gains.scaled`) scales its
crossover by ``f`` and keeps the phase of ``L`` there, so the scaled loop has at the delay ``tau / f`` exactly the
phase margin the unscaled one has at ``tau``. The schedule keeps, at any measured delay, the margin the paper's
gains have on a direct link:

    f = min(1, tau_ref / tau_loop),    tau_ref = motor time constant + the sensors' latency budget (12 ms)

On a direct link (age within the sensors' budget, no way) ``f = 1``: the paper's gains, Table 2 unchanged.
Pure numpy for the margin (:func:`phase_margin`), used by the tests and the derivation's table.
"""

from __future__ import annotations

import math

import numpy as np

from offboard.control.smc import Gains

#: the sensors' own latency budget (s) the paper's gains are kept within: the filter's base fusion horizon
#: (``offboard.flight.fly_cli.ESTIMATOR_DELAY_S``); the telemetry age of a direct link (5-6 ms in lockstep) is inside it
SENSOR_BUDGET_S = 0.012


def loop_delay(motor_time_constant_s: float, telemetry_age_s: float, setpoint_way_s: float) -> float:
    """The loop delay (s): the motors' lag plus the measured telemetry age and setpoint way (module docstring)."""
    return max(motor_time_constant_s, 0.0) + max(telemetry_age_s, 0.0) + max(setpoint_way_s, 0.0)


def gain_scale(motor_time_constant_s: float, loop_delay_s: float, budget_s: float = SENSOR_BUDGET_S) -> float:
    """The pole scale ``f`` in ``(0, 1]`` that keeps the direct link's phase margin at ``loop_delay_s``."""
    ref = max(motor_time_constant_s, 0.0) + budget_s
    if not (math.isfinite(loop_delay_s) and loop_delay_s > ref):
        return 1.0
    return ref / loop_delay_s


def loop_polynomials(gains: Gains) -> dict[str, np.ndarray]:
    """Each loop's characteristic polynomial (highest power first): height and yaw of order 2, horizontal 6."""
    return {
        "height": np.array([1.0, gains.lambda1, gains.lambda0]),
        "yaw": np.array([1.0, gains.gamma1, gains.gamma0]),
        "horizontal": np.array([1.0, *gains.K[::-1]]),
    }


def phase_margin(char_poly: np.ndarray, delay_s: float) -> tuple[float, float]:
    """(crossover rad/s, phase margin rad) of the loop ``L(s) = exp(-s delay) (P(s) - s^n) / s^n``, ``P`` the
    characteristic polynomial (highest power first, monic). A negative margin: unstable with that delay."""
    p = np.asarray(char_poly, dtype=float)
    n = len(p) - 1
    num = p.copy()
    num[0] = 0.0  # P(s) - s^n
    w = np.logspace(-2, 4, 60001)
    s = 1j * w
    mag = np.abs(np.polyval(num, s)) / w**n
    above = np.nonzero(mag >= 1.0)[0]
    if len(above) == 0:
        return 0.0, math.pi
    k = int(above[-1])  # the last crossing from above: the crossover
    if k + 1 < len(w):  # refine between the samples (log-linear)
        lm0, lm1 = math.log(mag[k]), math.log(mag[k + 1])
        x = lm0 / (lm0 - lm1) if lm0 != lm1 else 0.0
        wc = float(math.exp(math.log(w[k]) + x * (math.log(w[k + 1]) - math.log(w[k]))))
    else:
        wc = float(w[k])
    sc = 1j * wc
    # pi + arg L: the delay-free part's phase lies in (-pi, pi]; the delay's is subtracted unwrapped
    return wc, math.pi + float(np.angle(np.polyval(num, sc) / sc**n)) - wc * delay_s


__all__ = ["SENSOR_BUDGET_S", "gain_scale", "loop_delay", "loop_polynomials", "phase_margin"]
