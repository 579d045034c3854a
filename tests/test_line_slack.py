"""A line gone slack in flight told as an event (issue 38; ``offboard.flight.line_slack`` in the hover throttle
learner): synthetic records of ArduPilot SITL's quad (3.0 kg with 1.2 kg on the line, hover throttle 0.51), thrust
steady, the accelerometer at 250 Hz with noise, the vertical acceleration jumping by the load's share of g."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.model.measurements import Attitude, Imu, PositionVelocity
from offboard.flight.hover_thrust_learning import HoverThrustLearner
from offboard.flight.line_slack import LineSlackWatch

G = 9.80665
SHARE = 1.2 / 4.2
HOVER = 0.51
T_JUMP = 12.0


def _fly(jump_s: float, jump: float = SHARE * G, noise: float = 0.3, seed: int = 1) -> HoverThrustLearner:
    """10 s of hover to learn the hover throttle, the watch started (the start of control), then at ``T_JUMP`` the
    vertical acceleration up by ``jump`` (m/s^2) for ``jump_s`` s, the thrust unchanged; 20 s in all."""
    rng = np.random.default_rng(seed)
    att = Attitude(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    pos = PositionVelocity(0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0)
    learner = HoverThrustLearner("ardupilot", G, 0.39, angle_boost=True)
    learner.start()
    for k in range(20 * 250):
        t = (k + 1) / 250.0
        a_up = jump if T_JUMP <= t < T_JUMP + jump_s - 1e-9 else 0.0
        learner.on_imu(Imu(t, 0.0, 0.0, G + a_up + noise * rng.standard_normal(), 0.0, 0.0, 0.0), att)
        if k % 5 == 4:  # ATTITUDE_TARGET at 50 Hz
            learner.on_thrust(t, HOVER, att, pos)
        if k == 10 * 250:
            assert learner.learned() is not None
            learner.watch_load(SHARE)
    return learner


def _kinds(learner: HoverThrustLearner) -> list[str]:
    return [kind for kind, _ in learner.line_events]


def test_a_line_slack_for_tenths_of_a_second_is_told_with_its_time_and_length() -> None:
    learner = _fly(0.3)
    assert _kinds(learner) == ["line_slack", "line_taut"], learner.line_events
    ((start, end),) = [(a, b) for a, b in learner.slack_watch.spells]
    # the times of the residuals themselves (one thrust sample, 0.02 s); the window's average crosses the
    # threshold (0.8 of the jump, below) within the window (0.1 s) and it is told SLACK_AFTER_S (0.1 s) after
    # that: within 0.3 s of the jump
    assert T_JUMP <= start <= T_JUMP + 0.021, start
    assert end is not None and 0.28 <= end - start <= 0.32, (start, end)
    assert learner.slack_watch.told[0] - T_JUMP <= 0.25, learner.slack_watch.told
    # a spell is told once the average has stayed above for SLACK_AFTER_S (0.1 s), not at the first crossing
    assert learner.slack_watch.told[0] - start >= 0.1 - 1e-9, (learner.slack_watch.told, start)
    assert f"at t={start:.2f} s" in learner.line_events[0][1]
    assert f"after {end - start:.2f} s slack" in learner.line_events[1][1]
    assert learner.load_lost is None
    assert learner.summary()["line_slack"]["spells"] == [[round(start, 3), round(end - start, 3)]]


def test_a_blip_or_noise_is_no_slack_line() -> None:
    assert _kinds(_fly(0.02)) == []
    # no jump, 2 m/s^2 of noise per sample (0.9 per fusion, the window's average 0.4: 5 sigma 2.0)
    assert _kinds(_fly(0.0, noise=2.0)) == []
    # a jump below the threshold (a third of the load's share of g: a line that still pulls two thirds) is none
    assert _kinds(_fly(0.3, jump=SHARE * G / 3.0)) == []


def test_a_line_slack_for_long_is_also_a_lost_load() -> None:
    learner = _fly(1.5)
    assert _kinds(learner) == ["line_slack", "line_taut"], learner.line_events
    assert learner.load_lost is not None and learner.t_lost is not None
    # load_lost as before this watch: its residual low-passed over 1 s crosses half the share at 0.7 s, then 1 s
    # more (told 0.24 s after this line is taut again: for the lost-load watch a 1.5 s slack is a lost load)
    assert T_JUMP + 1.5 <= learner.t_lost <= T_JUMP + 1.8, learner.t_lost
    assert _kinds(_fly(1.0)) == ["line_slack", "line_taut"] and _fly(1.0).load_lost is None


def test_the_threshold_is_half_the_loads_share_of_g_or_five_sigma_of_the_window() -> None:
    watch = LineSlackWatch(SHARE, G)
    for k in range(5):  # a full window: 5 fusions at 50 Hz
        watch.update(0.02 * k, 0.0, 1.0)
    # PX4's floor of the learned noise, 1 (m/s^2)^2 per fusion: 5 sqrt(1 / 5) = 2.24 m/s^2, above half the share
    # of g (1.40) and below a slack line's 3.9 (m g / M)
    assert watch.threshold_for(1.0) == pytest.approx(5.0 * math.sqrt(1.0 / 5.0))
    assert watch.threshold_for(0.01) == pytest.approx(0.5 * SHARE * G)
