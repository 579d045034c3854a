"""estimators/model/frames.py: NED/FRD <-> model NWU/FLU conversions are inverse pairs, mutually consistent,
and physically right (checked against rotation matrices built here from first principles)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.model import frames

P = np.diag([1.0, -1.0, -1.0])


def _rot_zyx(phi: float, theta: float, psi: float) -> np.ndarray:
    """Body-to-world R = Rz(psi) Ry(theta) Rx(phi), built from elementary rotations."""
    cx, sx = math.cos(phi), math.sin(phi)
    cy, sy = math.cos(theta), math.sin(theta)
    cz, sz = math.cos(psi), math.sin(psi)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def _rot_quat(q: tuple[float, float, float, float]) -> np.ndarray:
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _random_euler(rng: np.random.Generator) -> tuple[float, float, float]:
    return (rng.uniform(-3.0, 3.0), rng.uniform(-1.5, 1.5), rng.uniform(-3.1, 3.1))


def _same_angle(a: float, b: float, tol: float = 1e-12) -> bool:
    return abs(frames.wrap_angle(a - b)) < tol


def test_vector_conversions_are_inverse_pairs() -> None:
    rng = np.random.default_rng(1)
    for _ in range(100):
        v = tuple(rng.normal(size=3))
        assert frames.ned_to_model_vector(*frames.model_to_ned_vector(*v)) == pytest.approx(v, abs=0)
        assert frames.model_to_ned_vector(*frames.ned_to_model_vector(*v)) == pytest.approx(v, abs=0)
        assert frames.frd_to_model_body(*frames.model_body_to_frd(*v)) == pytest.approx(v, abs=0)
        assert frames.model_body_to_frd(*frames.frd_to_model_body(*v)) == pytest.approx(v, abs=0)
    # and they are not the identity: north stays, up becomes -down, west becomes -east
    assert frames.model_to_ned_vector(1.0, 2.0, 3.0) == (1.0, -2.0, -3.0)


def test_euler_and_quaternion_conversions_are_inverse_pairs() -> None:
    rng = np.random.default_rng(2)
    for _ in range(200):
        e = _random_euler(rng)
        back = frames.ned_euler_to_model(*frames.model_euler_to_ned(*e))
        assert back[0] == pytest.approx(e[0], abs=1e-15)
        assert back[1] == pytest.approx(e[1], abs=1e-15)
        assert _same_angle(back[2], e[2])
        q = frames.euler_to_quaternion(*e)
        assert frames.ned_quaternion_to_model(*frames.model_quaternion_to_ned(*q)) == pytest.approx(q, abs=0)
        e2 = frames.quaternion_to_euler(*q)
        assert all(_same_angle(a, b, 1e-10) for a, b in zip(e, e2))


def test_quaternion_and_euler_paths_agree() -> None:
    """Quaternion of the NED Euler angles == converted model quaternion (up to the sign of q)."""
    rng = np.random.default_rng(3)
    for _ in range(200):
        e = _random_euler(rng)
        q_via_euler = np.array(frames.euler_to_quaternion(*frames.model_euler_to_ned(*e)))
        q_via_quat = np.array(frames.model_quaternion_to_ned(*frames.euler_to_quaternion(*e)))
        assert min(np.abs(q_via_euler - q_via_quat).max(), np.abs(q_via_euler + q_via_quat).max()) < 1e-12
        # and the NED quaternion decodes to the NED Euler angles
        ned = frames.model_euler_to_ned(*e)
        dec = frames.quaternion_to_euler(*q_via_quat)
        assert all(_same_angle(a, b, 1e-10) for a, b in zip(ned, dec))


def test_rotation_matrices_satisfy_p_r_p() -> None:
    """R_ned = P R_model P, P = diag(1, -1, -1), both from Euler angles and from quaternions."""
    rng = np.random.default_rng(4)
    for _ in range(100):
        e = _random_euler(rng)
        r_model = _rot_zyx(*e)
        r_ned = _rot_zyx(*frames.model_euler_to_ned(*e))
        np.testing.assert_allclose(r_ned, P @ r_model @ P, atol=1e-13)
        np.testing.assert_allclose(_rot_quat(frames.euler_to_quaternion(*e)), r_model, atol=1e-13)
        q_ned = frames.model_quaternion_to_ned(*frames.euler_to_quaternion(*e))
        np.testing.assert_allclose(_rot_quat(q_ned), r_ned, atol=1e-13)


def test_positive_model_pitch_is_negative_mavlink_pitch_and_tilts_thrust_north() -> None:
    theta = 0.1
    r_model = _rot_zyx(0.0, theta, 0.0)
    thrust_model = r_model @ [0.0, 0.0, 1.0]  # body +z (FLU) is the thrust direction
    assert thrust_model[0] > 0.09  # toward +x = north
    roll, pitch, yaw = frames.model_euler_to_ned(0.0, theta, 0.0)
    assert (roll, pitch, yaw) == pytest.approx((0.0, -0.1, 0.0), abs=1e-15)
    r_ned = _rot_zyx(roll, pitch, yaw)
    thrust_ned = r_ned @ [0.0, 0.0, -1.0]  # thrust is along -z in FRD
    assert thrust_ned[0] > 0.09  # north, same physical direction
    nose_ned = r_ned @ [1.0, 0.0, 0.0]
    assert nose_ned[2] > 0.09  # +z in NED is down: the nose points down (negative pitch in FRD)
    np.testing.assert_allclose(frames.model_to_ned_vector(*thrust_model), thrust_ned, atol=1e-15)


def test_yaw_toward_west_is_negative_ned_yaw() -> None:
    psi = 0.3  # model: nose rotates from north toward +y = west
    nose_model = _rot_zyx(0.0, 0.0, psi) @ [1.0, 0.0, 0.0]
    assert nose_model[1] > 0.29  # west
    roll, pitch, yaw = frames.model_euler_to_ned(0.0, 0.0, psi)
    assert yaw == pytest.approx(-0.3, abs=1e-15)
    nose_ned = _rot_zyx(roll, pitch, yaw) @ [1.0, 0.0, 0.0]
    assert nose_ned[1] < -0.29  # east component negative: west
    # MAVLink yaw 350 deg (= -10 deg, slightly west of north) is +10 deg in the model
    assert frames.ned_euler_to_model(0.0, 0.0, math.radians(350.0))[2] == pytest.approx(math.radians(10.0))


def test_roll_is_unchanged_and_tilts_thrust_the_same_way() -> None:
    phi = 0.2
    thrust_model = _rot_zyx(phi, 0.0, 0.0) @ [0.0, 0.0, 1.0]
    assert thrust_model[1] < -0.19  # -y model = east (errata C2: +phi tilts thrust toward -y)
    ned = frames.model_euler_to_ned(phi, 0.0, 0.0)
    assert ned[0] == phi
    thrust_ned = _rot_zyx(*ned) @ [0.0, 0.0, -1.0]
    assert thrust_ned[1] > 0.19  # east


def test_wrap_and_bad_quaternion() -> None:
    for a in (-7.0, -math.pi, 0.0, 1.0, math.pi, 4.0, 100.0):
        w = frames.wrap_angle(a)
        assert -math.pi < w <= math.pi
        assert math.sin(w) == pytest.approx(math.sin(a), abs=1e-12)
        assert math.cos(w) == pytest.approx(math.cos(a), abs=1e-12)
    with pytest.raises(ValueError):
        frames.quaternion_to_euler(0.0, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError):
        frames.quaternion_to_euler(math.nan, 0.0, 0.0, 0.0)


def test_milli_g_conversions_are_inverse_and_one_g_is_standard_gravity() -> None:
    """MAVLink's SCALED_IMU / RAW_IMU accelerations are milli-g: 1000 mG is 9.80665 m/s^2, both ways."""
    assert frames.milli_g_to_m_s2(1000.0) == pytest.approx(9.80665, abs=1e-12)
    assert frames.m_s2_to_milli_g(9.80665) == pytest.approx(1000.0, abs=1e-9)
    for v in (-32768.0, -1.0, 0.0, 0.5, 981.0, 32767.0):
        assert frames.m_s2_to_milli_g(frames.milli_g_to_m_s2(v)) == pytest.approx(v, abs=1e-9)
