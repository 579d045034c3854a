"""The emulated autopilot's position / velocity estimate error: EKF-like, wandering, with a local origin offset.

A real autopilot's estimate (PX4's EKF2 fusing GPS, baro, magnetometer and IMU) is not the truth plus white
noise: its error wanders over seconds (GPS random walk and the filter's own dynamics), the velocity error goes
with it, and the local frame's origin is where the estimator started, not the ground (PX4 SITL's SIH: the ground
sat between about -0.8 and +0.6 m local z). This module models that per axis as a small estimator of its own: a
prediction that integrates the true acceleration plus accelerometer noise and, in the horizontal, the gravity
its attitude estimate's tilt error leaks (``tilt_leak``: EKF2 rotates the measured specific force with its own
attitude, so a tilt error ``d`` reads as an acceleration ``g d``) and, in the vertical and in the air, the noise
of the accelerometer (``air_accel_sigma_v_m_s2``: SIH's is more than ten times noisier in flight than at rest),
corrected by a measurement with Gauss-Markov noise (optionally delayed) with fixed position and velocity gains:
the GPS at its rate horizontally, the height at its own rate (``height_hz``: EKF2 fuses SIH's rangefinder at
50 Hz). What comes out is the error: estimate minus truth. The height error is therefore the integral of a
wandering vertical velocity error less the fused correction, as EKF2's is: millimetres on the ground (EKF2 fuses
zero velocity there), centimetres in flight, smooth, and the autopilot's Hold, flying the velocity error, sways
the truth while the estimate follows it (docs/emulator.md, "The height").
Everything the autopilot does with its position (its own hold, take-off, landing, position setpoints) uses the
estimate, as a real one does. Its attitude loops fly an attitude estimate whose roll and pitch wander about the
truth (first-order Gauss-Markov, ``tilt_sigma_rad``: a behavioural stand-in for EKF2's tilt error, not its
mechanism; the velocity prediction leaks this same error), and (PX4) a gyro with the preset's white noise
(``gyro_sigma_rad_s``: SIH's); with both, the truth's step response jitters about its top as PX4 SITL's does
(docs/emulator.md, calibration). Not modelled: the heading error (PX4 SITL's EKF2 was off the truth by 1.4-2.3
deg of tilt and 10-16 deg of heading in hovers on a loaded machine, ``docs/model.md`` section 12.2).

The ground's local z (``ground_local_z_m``, NED, m) is drawn once, uniform in ``origin_z_range_m``; it shifts
LOCAL_POSITION_NED, ODOMETRY, HOME_POSITION and SET_POSITION_TARGET_LOCAL_NED's z and nothing else (heights
above home, GLOBAL_POSITION_INT's relative altitude, stay ground-relative). Magnitudes: ``docs/emulator.md``
(calibrated against PX4 SITL with ``bench/calibrate_emulator_px4.py``).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from estimators.model.frames import STANDARD_GRAVITY


@dataclass(frozen=True)
class EkfErrorSpec:
    """The estimator model's constants (per direction: horizontal, vertical).

    gps_sigma_m: GPS position noise (1 sigma, m), Gauss-Markov with time constant gps_tau_s (the vertical one is
    the height measurement's); gps_delay_s: how old a horizontal GPS sample and a height sample are when the
    estimator fuses them as current (an uncompensated delay, s); gps_hz: GPS rate (Hz); gain_p, gain_v: the
    estimator's correction per GPS sample (the vertical ones per height sample) of position (fraction) and velocity
    (1/s) from the position residual; accel_sigma_m_s2: white noise of the accelerometer the prediction integrates
    (1 sigma per step of the model, m/s^2, every axis, on the ground too);
    origin_z_range_m: range of the ground's local NED z (uniform); air_white_v_m: white noise on the height in the
    air (1 sigma, m, a new draw at every step of the model); reported_accuracy_m: the horizontal and vertical
    position accuracy the autopilot reports in ESTIMATOR_STATUS (1 sigma, m); gyro_sigma_rad_s: white noise of
    the gyro the autopilot's rate loop flies on (1 sigma per 250 Hz sample, rad/s, body FRD roll / pitch / yaw;
    PX4 only: the emulated rate loop otherwise sees the true rates); tilt_sigma_rad, tilt_tau_s: the attitude
    estimate's roll and pitch error in the air (1 sigma, rad; first-order Gauss-Markov with these time constants;
    on the ground it relaxes to zero with the same time constants); air_gps_sigma_h_m: the horizontal GPS noise in
    the air (1 sigma, m; 0: ``gps_sigma_m``'s on the ground and in the air alike), a behavioural stand-in for
    EKF2's horizontal error being larger in flight than at rest (PX4 SITL: 0.054-0.080 m of scatter on the ground,
    0.18-0.28 m in Hold); tilt_leak: how much of gravity the attitude estimate's tilt error puts into the velocity
    prediction (1: all of it, as in EKF2, which rotates the accelerometer's specific force with its own attitude:
    a tilt error ``d`` makes it believe in a horizontal acceleration ``g d`` the vehicle does not have, and its
    attitude loop, flying that estimate, gives the truth the opposite; 0: the prediction integrates the true
    acceleration); air_height_sigma_m: in the air, a white noise (1 sigma, m, a new draw per height sample) on the
    height measurement the estimator fuses (a barometer's, say), which the estimator's own filtering turns into a
    height error that wanders; air_accel_sigma_v_m_s2: in the air, the white noise of the vertical accelerometer the
    prediction integrates (1 sigma per 250 Hz IMU sample, m/s^2, integrated with the same power over the model's
    own step: a velocity random walk of ``sigma sqrt(dt / 250 Hz)`` per step ``dt``), SIH's in flight, which makes
    EKF2's vertical velocity error wander and its height follow; height_hz: the rate at which the height is fused
    (Hz; 0: with the GPS, at gps_hz), with its own noise generator.
    """

    gps_sigma_m: tuple[float, float]
    gps_tau_s: float
    gps_delay_s: tuple[float, float]
    gps_hz: float
    gain_p: tuple[float, float]
    gain_v: tuple[float, float]
    accel_sigma_m_s2: float
    origin_z_range_m: tuple[float, float]
    air_white_v_m: float = 0.0
    reported_accuracy_m: tuple[float, float] = (0.0, 0.0)
    gyro_sigma_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tilt_sigma_rad: tuple[float, float] = (0.0, 0.0)
    tilt_tau_s: tuple[float, float] = (1.0, 1.0)
    air_gps_sigma_h_m: float = 0.0
    tilt_leak: float = 0.0
    air_height_sigma_m: float = 0.0
    air_accel_sigma_v_m_s2: float = 0.0
    height_hz: float = 0.0


#: Presets of ``--ekf``: ``none`` reports the truth; ``px4-sih`` behaves as PX4 SITL's SIH + EKF2 did
#: (docs/emulator.md, "Calibration against PX4 SITL").
EKF_PRESETS: dict[str, EkfErrorSpec | None] = {
    "none": None,
    "px4-sih": EkfErrorSpec(
        gps_sigma_m=(0.1, 0.005),
        gps_tau_s=10.0,
        # SIH's GPS and rangefinder arrive with no delay, and EKF2 fuses them on its delayed horizon: real PX4's
        # estimate did not lag the truth in a 1 m/s move (error -0.016 x velocity) nor in the climb (0.01-0.04 s)
        gps_delay_s=(0.0, 0.0),
        gps_hz=5.0,
        # horizontally, with the tilt leak driving the velocity error, these gains give PX4's velocity error and
        # position hold (docs/emulator.md, "Calibration against PX4 SITL"); vertically, per 50 Hz height sample,
        # a position correction of 1.6 /s and a velocity one of 1.0 /s^2: EKF2's height error in Hold (its state on
        # the fusion horizon, real PX4's ULog of 6 Dec 2026) follows err' = 0.94 verr - 1.61 err, the emulated Hold's
        # err' = (0.86-0.96) verr - (1.32-1.62) err over seeds 0-3
        gain_p=(0.3, 0.032),
        gain_v=(0.16, 0.02),
        accel_sigma_m_s2=0.05,
        origin_z_range_m=(-0.8, 0.6),
        # the height: EKF2 fuses SIH's rangefinder (mm-precise, 50 Hz, EKF2_RNG_CTRL 1 below 5 m) and integrates an
        # accelerometer that SIH makes noisy in flight (vertical: 1.4 m/s^2 per 250 Hz sample, 0.07 on the ground);
        # the integrated noise is a vertical velocity error that the Hold flies, so the truth sways and the estimate
        # follows it: PX4 SITL's Hold, 6 Dec 2026, height error 0.057 m (1.5 s), vertical velocity error 0.085 m/s
        # (1.2 s), truth jitter 0.116 m, LOCAL_POSITION_NED scatter 0.078 m (docs/emulator.md, "The height")
        height_hz=50.0,
        air_accel_sigma_v_m_s2=1.4,
        reported_accuracy_m=(0.29, 0.03),  # PX4 SITL's ESTIMATOR_STATUS in hover: 0.286-0.293 m, 0.029-0.033 m
        # SIH's gyro noise in flight (its sensor model: 0.14, 0.07, 0.03 rad/s per 250 Hz sample); PX4's
        # vehicle_angular_velocity minus the truth scattered 0.083 / 0.041 / 0.017 rad/s after the 40 Hz filter
        gyro_sigma_rad_s=(0.14, 0.07, 0.03),
        # EKF2's roll / pitch minus the truth in the air, four real-PX4 flights of 4 Dec 2026 (hover 20 s, move,
        # Ctrl-C, offboard loss; 9-30 s in the air each): roll std 0.021-0.022 rad, correlation time 3.1-5 s; pitch
        # std 0.013-0.018 rad, 5.3-9 s (the earlier 14 s step flights gave pitch 0.004-0.010 over 1.5 s: too short
        # to see the wander)
        tilt_sigma_rad=(0.021, 0.016),
        tilt_tau_s=(3.5, 6.0),
        # in the air: with SIH's drag modelled (SIH_KDV) the ground's 0.1 m left the emulated Hold at 0.19-0.33 m of
        # truth jitter against PX4's 0.26-0.45 (docs/emulator.md, angular damping and drag, 4 Dec 2026)
        air_gps_sigma_h_m=0.15,
        # EKF2's tilt error is what makes its velocity wander in the air (PX4 SITL: velocity error 0.26-0.34 m/s
        # across, 0.11-0.13 along the nose, correlated over 2.4-4.5 s; 0.016-0.03 m/s on the ground; its rate of
        # change correlates 0.3-0.7 with g times the tilt error)
        tilt_leak=1.0,
    ),
}


class EkfError:
    """A per-axis estimator (prediction with the measured acceleration, correction by a delayed, noisy GPS and height);
    its error is what the autopilot believes minus the truth. Model frame (NWU), m and m/s; seeded by ``rng``.

    :meth:`step` is called with the true state and acceleration at a fixed period; :meth:`position_error` and
    :meth:`velocity_error` give the current error.
    """

    def __init__(self, spec: EkfErrorSpec, rng: np.random.Generator) -> None:
        self.spec = spec
        self.rng = rng
        lo, hi = spec.origin_z_range_m
        #: NED z of the ground in the estimator's local frame, m (the local origin is not the ground)
        self.ground_local_z_m = float(rng.uniform(lo, hi))
        sh, sv = spec.gps_sigma_m
        self.gps_sigma = (sh, sh, sv)
        self.gps_noise = [float(rng.normal(0.0, s)) for s in self.gps_sigma]  # stationary start
        self.kp = (spec.gain_p[0], spec.gain_p[0], spec.gain_p[1])
        self.kv = (spec.gain_v[0], spec.gain_v[0], spec.gain_v[1])
        self.e = [0.0, 0.0, 0.0]  # position error, m
        self.ev = [0.0, 0.0, 0.0]  # velocity error, m/s
        self._hist: deque[tuple[float, tuple[float, float, float]]] = deque()
        self._t = 0.0
        self._next_gps = 0.0
        self._white_v = 0.0  # the height's white noise now (0 on the ground)
        # each noise has its own generator, spawned whether it is used or not: the estimator's draws, and each
        # noise's, are then the same whichever of the others a spec turns on
        white, gyro, tilt, height, accel_v, height_gm = rng.spawn(6)
        self._accel_v_rng = accel_v if spec.air_accel_sigma_v_m_s2 > 0.0 else None
        self._height_gm_rng = height_gm
        self._height_dt = 1.0 / spec.height_hz if spec.height_hz > 0.0 else 0.0
        self._next_height = 0.0
        self._white_rng = white if spec.air_white_v_m > 0.0 else None
        self._gyro_rng = gyro if any(v > 0.0 for v in spec.gyro_sigma_rad_s) else None
        self._tilt_rng = tilt if any(v > 0.0 for v in spec.tilt_sigma_rad) else None
        self.tilt = [0.0, 0.0]  # the attitude estimate's roll and pitch error, rad (model frame Euler angles)
        self._height_rng = height if spec.air_height_sigma_m > 0.0 else None

    def gyro_noise_frd(self) -> tuple[float, float, float]:
        """A new draw of the gyro's white noise (body FRD, rad/s; zeros without one), one per gyro sample."""
        if self._gyro_rng is None:
            return (0.0, 0.0, 0.0)
        z = self._gyro_rng.standard_normal(3)
        s = self.spec.gyro_sigma_rad_s
        return (s[0] * float(z[0]), s[1] * float(z[1]), s[2] * float(z[2]))

    def step(self, dt: float, pos: tuple[float, float, float], on_ground: bool = False, yaw: float = 0.0) -> None:
        """Advance ``dt`` s; ``pos``: the true position now (model frame, m); ``on_ground``: landed (no height
        noise); ``yaw``: the true heading (rad, model frame), which turns the tilt error into the world frame. The
        prediction integrates the true acceleration plus accelerometer noise (in the air, the vertical one's too) and
        (``tilt_leak``) the gravity its tilt error leaks, so only these and the GPS and height corrections create
        error."""
        sp = self.spec
        if self._tilt_rng is not None:
            z = self._tilt_rng.standard_normal(2)
            for i in range(2):
                a = math.exp(-dt / sp.tilt_tau_s[i])
                drive = 0.0 if on_ground else math.sqrt(1.0 - a * a) * sp.tilt_sigma_rad[i] * float(z[i])
                self.tilt[i] = a * self.tilt[i] + drive
        if self._white_rng is not None:
            self._white_v = 0.0 if on_ground else float(self._white_rng.normal(0.0, sp.air_white_v_m))
        self._t += dt
        t = self._t
        sa = sp.accel_sigma_m_s2
        za = self.rng.standard_normal(3)
        leak = (0.0, 0.0)
        if sp.tilt_leak > 0.0:
            # the estimate's body up axis, tilted by (roll, pitch) error d about the true attitude (small angles,
            # near level: ZYX Euler, model frame FLU / NWU), gives gravity a horizontal part g (d_pitch, -d_roll),
            # turned by the heading into the world
            gl = STANDARD_GRAVITY * sp.tilt_leak
            c, s = math.cos(yaw), math.sin(yaw)
            dr, dp = self.tilt
            leak = (gl * (dp * c + dr * s), gl * (dp * s - dr * c))
        for i in range(3):
            self.ev[i] += (sa * float(za[i]) + (leak[i] if i < 2 else 0.0)) * dt
        if self._accel_v_rng is not None and not on_ground:
            # white per IMU sample, so its integral over dt is a random walk of sigma sqrt(dt / 250 Hz): the same
            # velocity error whatever the model's step
            self.ev[2] += sp.air_accel_sigma_v_m_s2 * math.sqrt(dt / 250.0) * float(self._accel_v_rng.standard_normal())
        for i in range(3):
            self.e[i] += self.ev[i] * dt
        self._hist.append((t, pos))
        dmax = max(sp.gps_delay_s)
        while self._hist and self._hist[0][0] < t - dmax - 1.0:
            self._hist.popleft()
        if self._height_dt > 0.0 and t + 1e-9 >= self._next_height:
            # the height fused on its own clock (EKF2's rangefinder at 50 Hz in SIH's Hold), with its own noise draws
            self._next_height = t + self._height_dt
            self._fuse_height(self._height_dt, self._sample_at(t, sp.gps_delay_s[1])[2], pos[2], on_ground)
        if t + 1e-9 < self._next_gps:
            return
        gdt = 1.0 / sp.gps_hz
        self._next_gps = t + gdt
        # the horizontal sample fused now was taken gps_delay_s[0] ago
        old_h = self._sample_at(t, sp.gps_delay_s[0])
        a = math.exp(-gdt / sp.gps_tau_s)
        q = math.sqrt(1.0 - a * a)
        # three draws per GPS sample whether the height is fused here or on its own clock: the horizontal draws
        # are then the same either way
        zg = self.rng.standard_normal(3)
        sigma = self.gps_sigma
        if not on_ground and sp.air_gps_sigma_h_m > 0.0:
            sigma = (sp.air_gps_sigma_h_m, sp.air_gps_sigma_h_m, sigma[2])
        for i in range(2):
            self.gps_noise[i] = a * self.gps_noise[i] + q * sigma[i] * float(zg[i])
            resid = old_h[i] + self.gps_noise[i] - (pos[i] + self.e[i])
            self.e[i] += self.kp[i] * resid
            self.ev[i] += self.kv[i] * resid
        if self._height_dt == 0.0:
            self._fuse_height(gdt, self._sample_at(t, sp.gps_delay_s[1])[2], pos[2], on_ground, float(zg[2]))

    def _sample_at(self, t: float, delay: float) -> tuple[float, float, float]:
        """The true position ``delay`` s before ``t`` (the oldest one kept if the history is shorter; m)."""
        if delay <= 0.0:
            return self._hist[-1][1]
        old = self._hist[0][1]
        for tt, pp in self._hist:
            if tt > t - delay:
                break
            old = pp
        return old

    def _fuse_height(self, hdt: float, z_meas: float, z_true: float, on_ground: bool, zg: float | None = None) -> None:
        """One height correction: the measurement ``z_meas`` (true height, possibly delayed, m) plus the vertical
        Gauss-Markov noise (advanced by ``hdt`` s with the draw ``zg``, or one of its own generator's) and, in the
        air, the white ``air_height_sigma_m``; ``z_true``: the true height now."""
        sp = self.spec
        if zg is None:
            zg = float(self._height_gm_rng.standard_normal())
        a = math.exp(-hdt / sp.gps_tau_s)
        self.gps_noise[2] = a * self.gps_noise[2] + math.sqrt(1.0 - a * a) * self.gps_sigma[2] * zg
        noise = self.gps_noise[2]
        if self._height_rng is not None and not on_ground:
            noise += sp.air_height_sigma_m * float(self._height_rng.standard_normal())
        resid = z_meas + noise - (z_true + self.e[2])
        self.e[2] += self.kp[2] * resid
        self.ev[2] += self.kv[2] * resid

    def position_error(self) -> tuple[float, float, float]:
        """Current position error (model frame NWU, m)."""
        return (self.e[0], self.e[1], self.e[2] + self._white_v)

    def tilt_error(self) -> tuple[float, float]:
        """Current roll and pitch error of the attitude estimate (model frame ZYX Euler angles, rad)."""
        return (self.tilt[0], self.tilt[1])

    def velocity_error(self) -> tuple[float, float, float]:
        """Current velocity error (model frame NWU, m/s)."""
        return (self.ev[0], self.ev[1], self.ev[2])


__all__ = ["EKF_PRESETS", "EkfError", "EkfErrorSpec"]
