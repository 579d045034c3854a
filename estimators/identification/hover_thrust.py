"""PX4's hover thrust estimator (``mc_hover_thrust_estimator``'s ``ZeroOrderHoverThrustEkf``): the normalized
thrust that holds a hover, learned from the vertical acceleration and the vertical thrust command. One filter, two
users: the emulator's PX4 flavour runs it as PX4 does (``sim_bridge.inner.px4_hover_thrust``), and ``slung fly``
learns the hover throttle of the vehicle it flies, with whatever load hangs below it
(``offboard.flight.hover_thrust_learning``): ArduPilot learns MOT_THST_HOVER only under its own altitude controller
(ArduPilot SITL kept its bare 0.39 with a load that needs 0.51, issue 38), and a vehicle file's hover throttle is
only as right as its load values (issue 34).

The filter (modelled from PX4's source, ``zero_order_hover_thrust_ekf.cpp``, not copied): the state ``h`` (hover
thrust, 0..1) is constant with process noise ``HTE_HT_NOISE`` (per s; the variance grows by ``noise^2 dt^2`` per
step, as PX4's does); the measurement is the vertical acceleration ``a = g T / h - g`` (up, m/s^2) for the vertical
thrust ``T`` (normalized, up), whose Jacobian is ``-g T / h^2``; innovations beyond ``HTE_ACC_GATE`` standard
deviations are refused, and a run of refusals (a low-passed signed test ratio above 0.2) inflates the state variance
by ``1e3 noise^2 dt`` so the filter can follow a sudden change; the acceleration noise is learned from the residuals
less their low-passed bias (2 s time constant, kept within 1..400 (m/s^2)^2), scaled up above ``HTE_VZ_THR`` /
``HTE_VXY_THR`` of speed (PX4's module); ``h`` is kept within ``hover_param +- HTE_THR_RANGE`` (PX4's module). The
estimate is valid once its variance is below 0.001 and its test ratio below 1, continuously for 2 s.

With a load on a taut cable the vertical motion is the vehicle's and the load's together, so ``h`` is the hover
thrust of both (what a hover needs); a slack line breaks the model and shows as refused innovations.
"""

from __future__ import annotations

import math

#: PX4's defaults of the HTE_* parameters (``hover_thrust_estimator_params.yaml``)
HTE_DEFAULTS = {
    "HTE_HT_NOISE": 0.0036,
    "HTE_ACC_GATE": 3.0,
    "HTE_HT_ERR_INIT": 0.1,
    "HTE_VXY_THR": 10.0,
    "HTE_VZ_THR": 2.0,
    "HTE_THR_RANGE": 0.2,
}
#: time constants (s) of the residual's low-pass and of the noise learning; the validity hysteresis (s)
RESIDUAL_LPF_S = 1.0
NOISE_LEARNING_S = 2.0
VALID_AFTER_S = 2.0
#: the estimate is trusted below this variance (normalized thrust^2)
VALID_VARIANCE = 0.001


class HoverThrustEstimator:
    """The hover thrust estimate of one PX4 vehicle; ``gravity`` in m/s^2, thrusts normalized 0..1."""

    def __init__(self, gravity: float, hover_param: float, params: dict[str, float] | None = None) -> None:
        self.g = gravity
        self.p = dict(HTE_DEFAULTS if params is None else params)
        self.reset(hover_param)

    def reset(self, hover_param: float) -> None:
        """Back to MPC_THR_HOVER (``hover_param``) with the initial uncertainty (PX4 does this while disarmed)."""
        self.hover_param = hover_param
        rng = self.p["HTE_THR_RANGE"]
        self.h_min = min(max(hover_param - rng, 0.0), 0.8)
        self.h_max = min(max(hover_param + rng, 0.2), 0.9)
        self.h = min(max(hover_param, 0.1), 0.9)
        self.var = self.p["HTE_HT_ERR_INIT"] ** 2
        self.acc_var = 5.0
        self.residual_lpf = 0.0
        self.ratio_lpf = 0.0
        self.test_ratio = 0.0
        self.valid = False
        self._valid_for = 0.0
        #: the user's in-air flag (PX4 fuses only in the air); the filter itself does not read it
        self.in_air = False

    def update(self, dt: float, acc_up: float, thrust_up: float, speed_xy: float, speed_z: float) -> None:
        """One fusion: ``dt`` s since the last, the measured vertical acceleration ``acc_up`` (m/s^2, up), the
        position controller's vertical thrust ``thrust_up`` (normalized, up), the horizontal and vertical speeds
        (m/s) that scale the noise."""
        if not (dt > 0.001 and dt < 1.0 and math.isfinite(acc_up) and math.isfinite(thrust_up)):
            return
        g = self.g
        self.var += self.p["HTE_HT_NOISE"] ** 2 * dt * dt
        scale = max(abs(speed_z) - self.p["HTE_VZ_THR"] + 1.0, speed_xy - self.p["HTE_VXY_THR"] + 1.0, 1.0)
        acc_var = self.acc_var * scale * scale
        H = -g * thrust_up / (self.h * self.h)
        innov_var = max(H * self.var * H + acc_var, acc_var)
        innov = self.model_residual(acc_up, thrust_up)
        gate = self.p["HTE_ACC_GATE"]
        self.test_ratio = innov * innov / (gate * gate * innov_var)
        residual = innov
        if self.test_ratio < 1.0:
            k = self.var * H / innov_var
            self.h = min(max(self.h + k * innov, self.h_min), self.h_max)
            self.var = min(max((1.0 - k * H) * self.var, 1e-10), 1.0)
            residual = self.model_residual(acc_up, thrust_up)
        elif abs(self.ratio_lpf) > 0.2:  # refused for a while: the hover thrust moved, let the filter follow
            self.var += 1e3 * self.p["HTE_HT_NOISE"] ** 2 * dt
        a = dt / (RESIDUAL_LPF_S + dt)
        self.residual_lpf = (1.0 - a) * self.residual_lpf + a * residual
        signed = math.copysign(min(self.test_ratio, 1.0), innov)
        self.ratio_lpf = (1.0 - a) * self.ratio_lpf + a * signed
        b = dt / (NOISE_LEARNING_S + dt)
        r = residual - self.residual_lpf
        self.acc_var = min(max((1.0 - b) * self.acc_var + b * (r * r + H * self.var * H), 1.0), 400.0)
        ok = self.var < VALID_VARIANCE and (self.valid or self.test_ratio < 1.0)
        self._valid_for = self._valid_for + dt if ok else 0.0
        self.valid = self._valid_for >= VALID_AFTER_S if not self.valid else ok

    def model_residual(self, acc_up: float, thrust_up: float) -> float:
        """The measured vertical acceleration ``acc_up`` (m/s^2, up) less what the vertical thrust ``thrust_up``
        (normalized) explains with the current hover thrust: ``g T / h - g`` (the filter's innovation before an
        update, its residual after)."""
        return acc_up - (self.g * thrust_up / self.h - self.g)

    @property
    def sigma(self) -> float:
        """The estimate's standard deviation (normalized thrust)."""
        return math.sqrt(max(self.var, 0.0))


__all__ = ["HTE_DEFAULTS", "HoverThrustEstimator"]
