"""The emulator's PX4 inner loops (sim_bridge.inner.px4_inner), its EKF-like estimate (sim_bridge.plant.ekf_error) and
its API (sim_bridge.emulator_api): PX4's structure, checked against hand-derived values."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from estimators.errors import UserError
from estimators.model.frames import euler_to_quaternion
from estimators.model.vehicle import load_vehicle, named_vehicles
from sim_bridge.emulator_api import EmulatorConfig, EmulatorTruth, build_emulator
from sim_bridge.inner.px4_inner import QUAD_X, Px4Allocator, Px4AttitudeControl, Px4Motors, Px4RateControl, Px4RateGains
from sim_bridge.modes.flavors import px4_gain_scale, px4_params
from sim_bridge.plant.dynamics import make_state
from sim_bridge.plant.ekf_error import EKF_PRESETS, EkfError

SIH = load_vehicle("px4-sih")


def test_px4_sih_vehicle_is_shipped_with_the_sih_constants() -> None:
    assert "px4-sih" in named_vehicles()
    assert SIH.mass_vehicle == 1.0 and SIH.inertia == (0.025, 0.025, 0.030) and SIH.motor_thrust_max == 5.0
    assert SIH.arm_length / math.sqrt(2.0) == pytest.approx(0.2)  # SIH_L_ROLL: the perpendicular arm
    assert SIH.hover_thrust_normalized == pytest.approx(0.49, abs=0.001)
    # PX4's stock rate gains hold for SIH's vehicle; another vehicle gets them scaled to the same dynamics
    assert px4_gain_scale(SIH) == pytest.approx((1.0, 1.0))
    p = px4_params(SIH)
    assert (p["MC_ROLLRATE_P"].value, p["MC_ROLLRATE_I"].value, p["MC_ROLLRATE_D"].value) == (0.15, 0.2, 0.003)
    assert p["MC_ROLL_P"].value == 4.0 and p["MC_YAW_WEIGHT"].value == 0.4 and p["CA_ROTOR2_KM"].value == -0.05


def test_allocator_normalization_is_pxs_for_the_sih_quad() -> None:
    a = Px4Allocator(QUAD_X)
    # same scale on roll and pitch: a unit command moves each motor by 1/sqrt(2); yaw to +-1; thrust share 1
    assert [abs(v) for v in a.m_roll] == pytest.approx([1 / math.sqrt(2)] * 4)
    assert [abs(v) for v in a.m_pitch] == pytest.approx([1 / math.sqrt(2)] * 4)
    assert [abs(v) for v in a.m_yaw] == pytest.approx([1.0] * 4)
    assert a.m_thrust == pytest.approx([1.0] * 4)
    # so the unit roll torque of the physical vehicle is 2 f_max d = 2.83 N m (not the hover-margin 1.96 N m)
    m = Px4Motors(SIH, QUAD_X, 0.001)
    m.command(a.allocate((0.1, 0.0, 0.0), 0.5))
    m.f = list(m.cmd)  # the motors have reached their commands
    t, rx, ry, rz = m.wrench_frd()
    assert t == pytest.approx(10.0) and rx == pytest.approx(0.1 * 2 * 5.0 * SIH.arm_length) and ry == pytest.approx(0)
    assert rx / 0.1 == pytest.approx(2.828, abs=0.001) and rz == pytest.approx(0.0, abs=1e-9)


def test_allocator_saturation_without_and_with_airmode() -> None:
    # near full thrust, airmode off: the collective is lowered to keep the roll torque
    a = Px4Allocator(QUAD_X, airmode=0)
    u = a.allocate((0.5, 0.0, 0.0), 0.9)
    assert max(u) <= 1.0 and min(u) >= 0.0
    assert sum(u) / 4 < 0.9 and a.unallocated[0] == pytest.approx(0.0, abs=1e-9)
    # near zero thrust, airmode off: the collective is never raised, so the roll torque is cut
    u = a.allocate((0.5, 0.0, 0.0), 0.1)
    assert sum(u) / 4 <= 0.1 + 1e-9 and a.unallocated[0] > 0.1
    # with roll / pitch airmode the collective rises to deliver it
    b = Px4Allocator(QUAD_X, airmode=1)
    u = b.allocate((0.5, 0.0, 0.0), 0.1)
    assert sum(u) / 4 > 0.1 and b.unallocated[0] == pytest.approx(0.0, abs=1e-6)
    # yaw comes last: a large yaw command at hover is reduced, roll kept
    u = a.allocate((0.3, 0.0, 1.0), 0.5)
    assert a.unallocated[0] == pytest.approx(0.0, abs=1e-9) and a.unallocated[2] > 0.1


def test_attitude_control_is_reduced_attitude_with_yaw_weight() -> None:
    c = Px4AttitudeControl()
    c.set_gains(4.0, 4.0, 2.8, 0.4)
    level = euler_to_quaternion(0.0, 0.0, 0.0)
    r = c.update(level, euler_to_quaternion(0.2, 0.0, 0.0))
    assert r[0] == pytest.approx(4.0 * 2.0 * math.sin(0.1)) and r[1] == pytest.approx(0.0) and r[2] == pytest.approx(0)
    # a pure yaw error keeps MC_YAW_P (the gain is divided by the weight that scales the error)
    r = c.update(level, euler_to_quaternion(0.0, 0.0, 0.2))
    assert r[2] == pytest.approx(2.8 / 0.4 * 2.0 * math.sin(0.4 * 0.1), rel=1e-9)
    # roll + yaw: the roll part is the full reduced-attitude error, the yaw part weighted down
    both = c.update(level, euler_to_quaternion(0.2, 0.0, 0.5))
    assert abs(both[0]) > 0.7 and abs(both[2]) < 2.8 * 0.5 + 1e-9
    # rate limits
    c.rate_limit = [1.0, 1.0, 0.5]
    r = c.update(level, euler_to_quaternion(1.0, 0.0, 1.0))
    assert abs(r[0]) <= 1.0 and abs(r[2]) <= 0.5


def test_rate_control_integrator_limit_saturation_and_landed() -> None:
    rc = Px4RateControl(500.0)
    rc.set_gains(Px4RateGains(int_lim=(0.1, 0.1, 0.1)))
    for _ in range(5000):
        rc.update((1.0, 0.0, 0.0), (0.0, 0.0, 0.0), landed=False)
    assert rc.integ[0] == pytest.approx(0.1)  # held at MC_RR_INT_LIM
    rc.reset_integral()
    rc.sat_pos = [True, False, False]  # the allocator could not give more positive roll
    for _ in range(100):
        rc.update((1.0, 0.0, 0.0), (0.0, 0.0, 0.0), landed=False)
    assert rc.integ[0] == 0.0
    rc.sat_pos = [False, False, False]
    for _ in range(100):
        rc.update((1.0, 0.0, 0.0), (0.0, 0.0, 0.0), landed=True)
    assert rc.integ[0] == 0.0  # no integration on the ground
    # D acts on the measurement: a rate setpoint step gives no derivative kick, a gyro step does
    rc2 = Px4RateControl(500.0, gyro_cutoff_hz=0.0, dgyro_cutoff_hz=0.0)
    rc2.set_gains(Px4RateGains(p=(0.0, 0.0, 0.0), i=(0.0, 0.0, 0.0), d=(0.01, 0.0, 0.0)))
    rc2.update((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), True)
    assert rc2.update((5.0, 0.0, 0.0), (0.0, 0.0, 0.0), True)[0] == 0.0
    assert rc2.update((5.0, 0.0, 0.0), (0.1, 0.0, 0.0), True)[0] == pytest.approx(-0.01 * 0.1 * 500.0)


def test_ekf_error_origin_offset_and_wander_are_seeded() -> None:
    spec = EKF_PRESETS["px4-sih"]
    assert spec is not None

    def run(seed: int) -> tuple[float, np.ndarray]:
        e = EkfError(spec, np.random.default_rng(seed))
        out = []
        for _ in range(3000):  # 30 s at rest at 100 Hz
            e.step(0.01, (0.0, 0.0, 0.0))
            out.append(e.position_error())
        return e.ground_local_z_m, np.array(out)

    z0, a = run(1)
    z0b, b = run(1)
    z0c, c = run(2)
    assert z0 == z0b and np.array_equal(a, b) and z0 != z0c and not np.array_equal(a, c)
    assert -0.8 <= z0 <= 0.6 and -0.8 <= z0c <= 0.6
    h = float(np.std(a[:, 0]))
    assert 0.005 < h < 0.5  # it wanders, by centimetres to decimetres at rest
    offsets = [EkfError(spec, np.random.default_rng(s)).ground_local_z_m for s in range(200)]
    assert min(offsets) < -0.6 and max(offsets) > 0.4  # the whole documented range is used


def test_ekf_error_height_scatters_in_the_air_not_on_the_ground() -> None:
    """``air_white_v_m``, a white noise on the reported height in the air only (px4-sih's until 6 Dec 2026, now off:
    EKF2's height has none, docs/emulator.md "The height"): it has its own generator, so the wandering error is the
    same draw with and without it, and on the ground it is off."""
    preset = EKF_PRESETS["px4-sih"]
    assert preset is not None and preset.air_white_v_m == 0.0
    spec = replace(preset, air_height_sigma_m=0.0, air_white_v_m=0.05)  # the fused height's noise: the next test
    quiet = replace(spec, air_white_v_m=0.0)

    ground, air, air_quiet = _heights(spec, True), _heights(spec, False), _heights(quiet, False)
    assert np.array_equal(ground, _heights(quiet, True))  # on the ground the white noise is off, same draws
    assert float(np.std(ground)) < 0.02
    assert float(np.std(air - air_quiet)) == pytest.approx(spec.air_white_v_m, rel=0.1)


def _heights(s, on_ground: bool, n: int = 2000, seed: int = 3) -> np.ndarray:
    """The height error (m) of an estimator of spec ``s`` at rest 2 m up, every 10 ms for ``n`` steps."""
    e = EkfError(s, np.random.default_rng(seed))
    out = []
    for _ in range(n):
        e.step(0.01, (0.0, 0.0, 2.0), on_ground)
        out.append(e.position_error()[2])
    return np.array(out)


def test_ekf_error_fused_height_noise_wanders_in_the_air_only() -> None:
    """``air_height_sigma_m``, a white noise on the fused height in the air (a barometer's; px4-sih's 4 Dec model:
    0.1 m per 5 Hz sample with vertical gains 0.1 / 0.2, now off, docs/emulator.md "The height"): the estimator's
    filtering makes it a height error that wanders over about a second; on the ground it is off and the draws are
    those without it."""
    preset = EKF_PRESETS["px4-sih"]
    assert preset is not None and preset.air_height_sigma_m == 0.0
    spec = replace(  # the 4 Dec vertical model, the accelerometer's noise (the next test) quiet
        preset,
        air_white_v_m=0.0,
        air_height_sigma_m=0.1,
        air_accel_sigma_v_m_s2=0.0,
        height_hz=0.0,
        gain_p=(preset.gain_p[0], 0.1),
        gain_v=(preset.gain_v[0], 0.2),
    )
    quiet = replace(spec, air_height_sigma_m=0.0)
    assert np.array_equal(_heights(spec, True, 20000), _heights(quiet, True, 20000))
    air, air_quiet = _heights(spec, False, 20000), _heights(quiet, False, 20000)
    fused = air - air_quiet  # what the fused noise adds (the estimator is linear in its inputs)
    assert 0.03 < float(np.std(fused)) < 0.08 and float(np.std(air_quiet)) < 0.02
    r = fused - fused.mean()
    lag = 50  # 0.5 s: far beyond one GPS sample (0.2 s), so the correlation is the filter's, not the noise's
    assert float(np.corrcoef(r[:-lag], r[lag:])[0, 1]) > 0.4


def test_ekf_error_height_error_is_the_wandering_vertical_velocity_error_it_integrates() -> None:
    """px4-sih's height (docs/emulator.md, "The height"): EKF2 integrates SIH's noisy accelerometer (vertical 1.4 m/s^2
    per 250 Hz sample in flight) and corrects with the rangefinder at 50 Hz, so its height error is the integral of
    a wandering vertical velocity error less a position correction of about 1.6 /s (its ULog in Hold: err' = 0.94
    verr - 1.61 err; 0.057 m and 0.085 m/s, correlated over 1.5 and 1.2 s), smooth (no white noise: PX4's height
    error has 1-2 mm above 2 Hz), and on the ground, with the noise off, millimetres. The noise has its own
    generator: the horizontal error is the same draw with and without it."""
    spec = EKF_PRESETS["px4-sih"]
    assert spec is not None and spec.air_accel_sigma_v_m_s2 == 1.4 and spec.height_hz == 50.0
    dt = 0.01

    def run(s, on_ground: bool, n: int = 10000) -> tuple[np.ndarray, np.ndarray]:
        e = EkfError(s, np.random.default_rng(11))
        pos, vel = [], []
        for _ in range(n):  # 100 s at 100 Hz, at rest 2 m up
            e.step(dt, (0.0, 0.0, 2.0), on_ground)
            pos.append(e.position_error())
            vel.append(e.velocity_error())
        return np.array(pos), np.array(vel)

    pos, vel = run(spec, False)
    ez, vz = pos[:, 2], vel[:, 2]
    assert 0.03 < float(np.std(ez)) < 0.07 and 0.06 < float(np.std(vz)) < 0.12
    # the height follows the velocity error: de/dt = c1 verr + c2 err with c1 = 1 (it is its integral) and c2 the
    # fused correction's rate, -ln(1 - gain_p) height_hz; a noise on the measurement or the report would break both
    de = np.diff(ez) / dt
    c1, c2 = np.linalg.lstsq(np.column_stack([vz[1:], ez[:-1]]), de, rcond=None)[0]
    assert c1 == pytest.approx(1.0, abs=0.05)
    assert -c2 == pytest.approx(-math.log(1.0 - spec.gain_p[1]) * spec.height_hz, rel=0.15)
    assert float(np.std(np.diff(ez))) < 0.003  # smooth: no white noise on the height
    for x, lo, hi in ((ez, 0.8, 3.5), (vz, 0.6, 2.5)):  # correlation times, s (PX4: 1.5 and 1.2)
        r = x - x.mean()
        ac = np.array([float(np.dot(r[:-k], r[k:])) for k in range(1, 400)]) / float(np.dot(r, r))
        assert lo < (int(np.argmax(ac < math.exp(-1.0))) + 1) * dt < hi
    ground_pos, ground_vel = run(spec, True, 2000)
    assert float(np.std(ground_pos[:, 2])) < 0.01 and float(np.std(ground_vel[:, 2])) < 0.01
    quiet_pos, _ = run(replace(spec, air_accel_sigma_v_m_s2=0.0), False, 2000)
    assert np.array_equal(pos[:2000, :2], quiet_pos[:, :2]) and float(np.std(quiet_pos[:, 2])) < 0.01


def test_ekf_error_fuses_each_direction_with_its_own_delay() -> None:
    """gps_delay_s is per direction: with the truth moving at 1 m/s along x and z and no noise anywhere, the direction
    fused without delay keeps no error, the delayed one lags (its error pulls back toward where the truth was)."""
    quiet = replace(
        EKF_PRESETS["px4-sih"],  # type: ignore[arg-type]
        gps_sigma_m=(0.0, 0.0),
        air_gps_sigma_h_m=0.0,
        accel_sigma_m_s2=0.0,
        air_accel_sigma_v_m_s2=0.0,
        tilt_sigma_rad=(0.0, 0.0),
    )
    for delays, lagging in (((0.0, 0.3), 2), ((0.3, 0.0), 0)):
        e = EkfError(replace(quiet, gps_delay_s=delays), np.random.default_rng(2))
        for k in range(1, 1001):  # 10 s, the truth at (t, 0, 2 + t) m
            t = 0.01 * k
            e.step(0.01, (t, 0.0, 2.0 + t), False)
        err = e.position_error()
        assert abs(err[2 - lagging]) < 1e-9 and err[lagging] < -0.05


def test_ekf_error_horizontal_gps_noise_is_larger_in_the_air() -> None:
    """px4-sih's ``air_gps_sigma_h_m`` (0.15 m against the ground's 0.1): the same draws, landed and airborne,
    give a horizontal GPS noise 1.5x larger in the air once the start has decayed (its Gauss-Markov process is
    linear in its drive), the vertical one alike; PX4 SITL scattered 0.054-0.080 m on the ground, 0.18-0.28 m in
    Hold, and with SIH's drag modelled the ground's noise alone left the emulated Hold a third too calm."""
    spec = EKF_PRESETS["px4-sih"]
    assert spec is not None and spec.air_gps_sigma_h_m == 0.15 and spec.gps_sigma_m[0] == 0.1

    def noise(on_ground: bool) -> list[float]:
        e = EkfError(spec, np.random.default_rng(7))
        for _ in range(10_000):  # 100 s at 100 Hz: the start's share decays as exp(-100 / 10)
            e.step(0.01, (0.0, 0.0, 2.0), on_ground)
        return e.gps_noise

    ground, air = noise(True), noise(False)
    assert air[0] / ground[0] == pytest.approx(1.5, rel=1e-3) and air[1] / ground[1] == pytest.approx(1.5, rel=1e-3)
    assert air[2] == pytest.approx(ground[2], rel=1e-3)


def test_config_validates_and_truth_is_a_typed_copy() -> None:
    with pytest.raises(UserError, match="--ekf"):
        EmulatorConfig(ekf="kalman").validate()
    with pytest.raises(UserError, match="flavor"):
        EmulatorConfig(flavor="betaflight").validate()
    emu, ap, link = build_emulator(EmulatorConfig(vehicle="px4-sih", mavlink=("udpout:127.0.0.1:9",), ekf="px4-sih"))
    try:
        emu.step(50)
        tr = emu.truth()
        assert isinstance(tr, EmulatorTruth) and tr.time_s == pytest.approx(0.05)
        assert tr.on_ground and tr.position_m == (0.0, 0.0, 0.0) and len(tr.state) == 18
        assert ap.ekf is not None and -0.8 <= ap.ekf.ground_local_z_m <= 0.6
        # the autopilot's belief is the estimate, the truth stays the truth
        assert list(ap.x_true[:3]) == [0.0, 0.0, 0.0] and ap.x[:3] != [0.0, 0.0, 0.0]
    finally:
        link.close()


def test_ekf_error_tilt_wanders_in_the_air_gyro_noise_is_sihs_and_position_draws_are_unchanged() -> None:
    """The px4-sih preset's attitude estimate error (roll / pitch Gauss-Markov, in the air) and gyro noise (SIH's,
    per sample) have their own generators: with the tilt's leak into the velocity off (tested on its own below),
    the position error is the same draw with and without them."""
    preset = EKF_PRESETS["px4-sih"]
    assert preset is not None and preset.tilt_sigma_rad[0] > 0.0 and preset.gyro_sigma_rad_s == (0.14, 0.07, 0.03)
    assert preset.tilt_leak == 1.0
    spec = replace(preset, tilt_leak=0.0)
    quiet = replace(spec, tilt_sigma_rad=(0.0, 0.0), gyro_sigma_rad_s=(0.0, 0.0, 0.0))

    def run(s, on_ground: bool, n: int = 20000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        e = EkfError(s, np.random.default_rng(5))
        tilt, pos, gyro = [], [], []
        for _ in range(n):  # 200 s at 100 Hz
            e.step(0.01, (0.0, 0.0, 2.0), on_ground)
            tilt.append(e.tilt_error())
            pos.append(e.position_error())
            gyro.append(e.gyro_noise_frd())
        return np.array(tilt), np.array(pos), np.array(gyro)

    tilt, pos, gyro = run(spec, False)
    _, pos_quiet, gyro_quiet = run(quiet, False)
    assert np.array_equal(pos, pos_quiet)
    assert not gyro_quiet.any() and np.std(gyro, axis=0) == pytest.approx(spec.gyro_sigma_rad_s, rel=0.05)
    assert np.std(tilt, axis=0) == pytest.approx(spec.tilt_sigma_rad, rel=0.35)
    # it wanders (correlated over its time constant), it is not white
    r = tilt[:, 0] - tilt[:, 0].mean()
    lag = int(0.5 * spec.tilt_tau_s[0] / 0.01)
    assert float(np.corrcoef(r[:-lag], r[lag:])[0, 1]) > 0.3
    ground, _, _ = run(spec, True, 1000)
    assert not ground.any()  # no driving noise on the ground (it relaxes from zero to zero)


def test_ekf_error_tilt_leaks_gravity_into_the_velocity_in_the_world_axis_the_heading_gives() -> None:
    """``tilt_leak`` 1: a held roll / pitch estimate error ``d`` makes the velocity error grow as ``g d`` (EKF2
    rotates the measured specific force with its own attitude), in the world axis the heading turns it to (model
    frame NWU: pitch error (nose down, +) leaks along the nose, roll error (right side down, +) to the right); 0:
    none. The GPS (the height with it) is made far away in time and the vertical accelerometer quiet, so the first
    second is the leak alone."""
    spec = replace(
        EKF_PRESETS["px4-sih"],  # type: ignore[arg-type]
        tilt_sigma_rad=(0.0, 0.0),
        accel_sigma_m_s2=0.0,
        gps_hz=1e-3,
        tilt_leak=1.0,
        height_hz=0.0,
        air_accel_sigma_v_m_s2=0.0,
    )
    g, d = 9.80665, 0.02

    def velocity_after_1s(s, tilt: tuple[float, float], yaw: float) -> tuple[float, float, float]:
        e = EkfError(s, np.random.default_rng(1))
        e.step(0.01, (0.0, 0.0, 2.0), False, yaw=yaw)  # the first step fuses the one GPS sample
        e.ev = [0.0, 0.0, 0.0]
        e.tilt = list(tilt)
        for _ in range(100):
            e.step(0.01, (0.0, 0.0, 2.0), False, yaw=yaw)
        return e.velocity_error()

    # pitch error at yaw 0: along +x (north, the nose); at yaw 90 deg (nose west, +y)
    assert velocity_after_1s(spec, (0.0, d), 0.0) == pytest.approx((g * d, 0.0, 0.0), abs=1e-9)
    assert velocity_after_1s(spec, (0.0, d), math.pi / 2) == pytest.approx((0.0, g * d, 0.0), abs=1e-9)
    # roll error at yaw 0: toward -y (the right side, east); at yaw 90 deg toward +x (north)
    assert velocity_after_1s(spec, (d, 0.0), 0.0) == pytest.approx((0.0, -g * d, 0.0), abs=1e-9)
    assert velocity_after_1s(spec, (d, 0.0), math.pi / 2) == pytest.approx((g * d, 0.0, 0.0), abs=1e-9)
    assert velocity_after_1s(replace(spec, tilt_leak=0.0), (d, d), 0.3) == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)


def test_the_px4_autopilot_flies_and_reports_the_estimated_tilt() -> None:
    _, ap, link = build_emulator(EmulatorConfig(vehicle="px4-sih", mavlink=("udpout:127.0.0.1:9",), ekf="px4-sih"))
    try:
        ap.ekf.tilt = [0.03, -0.01]
        xe = ap._believed([0.0] * 18)
        assert xe[6] == pytest.approx(0.03) and xe[7] == pytest.approx(-0.01)
        snap = ap.tel.snapshot(1000, [0.0] * 18, [0.0] * 13, False)
        assert snap.roll == pytest.approx(0.03, abs=0.02)  # ATTITUDE carries the estimate (plus the preset's noise)
    finally:
        link.close()


def test_sih_linear_drag_slows_the_vehicle_as_sihs_does() -> None:
    """px4-sih's ``linear_drag_n_s_m`` (SIH_KDV 1 N per m/s on 1 kg; real PX4's ULog truth fits 0.99): unpowered, in
    the air, the horizontal velocity decays as exp(-k t / M); the disturbance log keeps the disturbance alone."""
    emu, _, link = build_emulator(EmulatorConfig(vehicle="px4-sih", mavlink=("udpout:127.0.0.1:9",)))
    try:
        assert emu.drag == 1.0
        emu.input_log = []
        emu.x = make_state((0.0, 0.0, 50.0), velocity=(2.0, -1.0, 0.0))
        emu.on_ground = False
        emu.step(500)  # 0.5 s, disarmed: no thrust
        tr = emu.truth()
        decay = math.exp(-0.5 * 1.0 / 1.0)  # the drag is held over each 1 ms step: (1 - 0.001)^500, 2.5e-4 less
        assert tr.velocity_m_s[0] == pytest.approx(2.0 * decay, rel=5e-4)
        assert tr.velocity_m_s[1] == pytest.approx(-1.0 * decay, rel=5e-4)
        assert tr.disturbance[:3] == pytest.approx((-2.0 * decay, 1.0 * decay, -tr.velocity_m_s[2]), rel=2e-3)
        assert all(v == (0.0,) * 9 for _, v in emu.input_log)
    finally:
        link.close()
    emu, _, link = build_emulator(EmulatorConfig(mavlink=("udpout:127.0.0.1:9",)))  # the paper's vehicle: no drag
    try:
        emu.x = make_state((0.0, 0.0, 50.0), velocity=(2.0, 0.0, 0.0))
        emu.on_ground = False
        emu.step(100)
        assert emu.drag == 0.0 and emu.truth().velocity_m_s[0] == 2.0
    finally:
        link.close()


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_sih_angular_damping_slows_the_rotation_as_sihs_does(axis: int) -> None:
    """px4-sih's ``angular_drag_n_m_s_rad`` (SIH_KDW 0.025 N m per rad/s): unpowered and level, a body rate decays
    as exp(-k t / I) about its own axis (inertia 0.025 / 0.025 / 0.030 kg m^2); the paper's vehicle has none."""
    emu, _, link = build_emulator(EmulatorConfig(vehicle="px4-sih", mavlink=("udpout:127.0.0.1:9",)))
    try:
        assert emu.angular_drag == 0.025
        rate = [0.0, 0.0, 0.0]
        rate[axis] = 1.0  # level: the Euler rate is the body rate
        emu.x = make_state((0.0, 0.0, 50.0), euler_rate=rate)
        emu.on_ground = False
        emu.step(400)  # 0.4 s, disarmed: no thrust, no torque but the damping
        inertia = (0.025, 0.025, 0.030)[axis]
        got = emu.x[9 + axis]
        # held over each 1 ms step: (1 - 0.001 k / I)^400 against exp(-0.4 k / I), 2e-4 apart
        assert got == pytest.approx(math.exp(-0.4 * 0.025 / inertia), rel=1e-3)
    finally:
        link.close()
    emu, _, link = build_emulator(EmulatorConfig(mavlink=("udpout:127.0.0.1:9",)))
    try:
        emu.x = make_state((0.0, 0.0, 50.0), euler_rate=(0.0, 0.0, 1.0))
        emu.on_ground = False
        emu.step(100)
        assert emu.angular_drag == 0.0 and emu.x[11] == 1.0
    finally:
        link.close()


def test_the_in_process_attitude_path_tracks_a_tilt_step_as_px4s_attitude_loop() -> None:
    """``Px4AttitudePath`` (what ``slung compare`` flies the attitude-level law through in process): a 0.1 rad roll
    setpoint on SIH's vehicle at hover thrust is reached as a first-order attitude P loop with MC_ROLL_P = 4 and a
    fast rate loop reaches it (63 % within 0.15-0.5 s, 1 / MC_ROLL_P being 0.25 s; within 3 % after 1.5 s), with no
    pitch or yaw, and the motors' collective thrust settles on the setpoint's; a non-finite thrust is no thrust."""
    from sim_bridge.inner.px4_attitude_path import Px4AttitudePath
    from sim_bridge.plant import dynamics

    v, dt = SIH, 0.001
    p = dynamics.plant_params(v)
    path = Px4AttitudePath(v, dt)
    hover = v.total_mass * v.gravity
    path.reset(hover / 4.0)
    thrust = hover / math.cos(0.1)
    path.set_setpoint(0.1, 0.0, 0.0, thrust)
    x = dynamics.make_state((0.0, 0.0, 10.0))
    t63 = None
    for k in range(1500):
        w = path.step(x)
        x = dynamics.rk4_step(x, [*w, *(0.0,) * 9], p, dt, k * dt)
        if t63 is None and x[6] >= 0.063:
            t63 = (k + 1) * dt
    assert t63 is not None and 0.15 <= t63 <= 0.5, t63
    assert x[6] == pytest.approx(0.1, abs=0.003)
    assert abs(x[7]) < 0.003 and abs(x[8]) < 0.003
    assert path.wrench()[0] == pytest.approx(thrust, rel=0.01)
    path.set_setpoint(0.0, 0.0, 0.0, math.nan)
    assert path.thrust_sp == 0.0
