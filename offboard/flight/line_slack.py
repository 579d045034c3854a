"""A line that goes slack in flight, told as an event (issue 38): the short version of the hover throttle learner's
``load_lost`` watch (``offboard.flight.hover_thrust_learning``).

On a taut line the load moves vertically with the vehicle, and the thrust ``T`` that holds both explains the
vehicle's vertical acceleration: ``a = g T / h - g`` (PX4's hover thrust model, ``h`` the learned hover throttle).
The vehicle's own balance is ``M a = F - M g - T_z`` (``F`` the rotors' vertical force, ``T_z`` the line's vertical
pull): with the pull ``m (g + a)`` of a taut line the residual ``a_measured - a_model`` is 0; with a slack line
(pull 0) it is ``m (g + a) / M``, about ``m g / M`` (ArduPilot SITL's 1.2 kg under 3.0 kg: 3.9 m/s^2), at least the
load's share of g, ``m / (M + m) g`` (2.8 m/s^2). A line partly slack pulls less, and shows as part of that.

The residual is each of the learner's fusions (one per thrust sample, 50 Hz), averaged over :data:`WINDOW_S`. The
line counts as slack when that average stays above the threshold for :data:`SLACK_AFTER_S` (``line_slack``, told
with the time of the window's first residual above it), and taut again when it stays below it as long
(``line_taut``, from the first residual after the window's last above it, with how long it was slack).
The threshold is half the load's share of g (halfway from a taut line to the smallest slack one), raised
to :data:`NOISE_SIGMAS` standard deviations of the window's average when the learner's accelerometer noise (its
``acc_var``, learned from the residuals, at least 1 (m/s^2)^2 as PX4's) says the average is noisier than that; it
is frozen while the line is slack (the noise learning sees the slack's residual too).
"""

from __future__ import annotations

import math
from collections import deque

#: the residual is averaged over this long (s): a few thrust samples, short against a slack spell of tenths of a s
WINDOW_S = 0.1
#: how long (s) the average must stay above (below) the threshold before the line counts as slack (taut again)
SLACK_AFTER_S = 0.1
#: the threshold is at least this many standard deviations of the window's average
NOISE_SIGMAS = 5.0


class LineSlackWatch:
    """Slack / taut from the thrust model's residual. ``share``: the load's share of the weight, ``m / (M + m)``;
    ``gravity`` m/s^2. :meth:`update` returns ``(kind, reason)`` for an event, else None."""

    def __init__(self, share: float, gravity: float) -> None:
        self.share = share
        self.g = gravity
        self._window: deque[tuple[float, float]] = deque()
        self.slack = False
        #: when the average first crossed (the current spell), and when it stopped
        self._crossed: float | None = None
        self._threshold_held: float | None = None
        self.t_slack: float | None = None
        #: when each ``line_slack`` was told (vehicle s)
        self.told: list[float] = []
        #: every slack spell: (start, end or None while slack), vehicle s
        self.spells: list[tuple[float, float | None]] = []
        self.threshold = 0.5 * share * gravity
        #: the largest window average seen (m/s^2): how close a flight came to the threshold
        self.peak = -math.inf

    def threshold_for(self, acc_var: float) -> float:
        """The detection threshold (m/s^2) for the learner's accelerometer noise ``acc_var`` ((m/s^2)^2 per
        fusion) over a window of ``n`` fusions."""
        n = max(len(self._window), 1)
        return max(0.5 * self.share * self.g, NOISE_SIGMAS * math.sqrt(max(acc_var, 0.0) / n))

    def update(self, t: float, residual: float, acc_var: float) -> tuple[str, str] | None:
        """One fusion at vehicle time ``t`` (s): the measured vertical acceleration less the thrust model's
        (m/s^2, up), and the learner's accelerometer noise variance."""
        if not (math.isfinite(residual) and math.isfinite(t)):
            return None
        w = self._window
        w.append((t, residual))
        while w and w[0][0] <= t - WINDOW_S:
            w.popleft()
        mean = sum(r for _, r in w) / len(w)
        self.peak = max(self.peak, mean)
        if self._threshold_held is None:
            self.threshold = self.threshold_for(acc_var)
        above = mean > self.threshold
        if above == self.slack:  # as it is: no crossing pending
            self._crossed = None
            if not self.slack:
                self._threshold_held = None
            return None
        if self._crossed is None:
            # when it happened: the average lags by up to a window, the samples in it do not (the first above the
            # threshold; or the one after the last above it)
            thr = self.threshold
            if above:
                self._crossed = next((ti for ti, r in w if r > thr), t)
                self._threshold_held = thr  # keep it while the slack's residual enters the noise
            else:
                last = max((i for i, (_, r) in enumerate(w) if r > thr), default=-1)
                self._crossed = w[min(last + 1, len(w) - 1)][0]
        if t - self._crossed < SLACK_AFTER_S:
            return None
        since, self._crossed = self._crossed, None
        if above:
            full = self.share / (1.0 - self.share) * self.g
            self.slack, self.t_slack = True, since
            self.spells.append((since, None))
            self.told.append(t)
            return (
                "line_slack",
                f"the line went slack at t={since:.2f} s: {mean:.2f} m/s^2 of climb the thrust does not explain "
                f"(threshold {self.threshold:.2f}; a slack line's is about {full:.1f}"
                "): the swing estimate's cable-pull model does not hold while it is",
            )
        start = self.t_slack if self.t_slack is not None else since
        self.slack, self._threshold_held = False, None
        self.spells[-1] = (start, since)
        return "line_taut", f"the line is taut again at t={since:.2f} s after {since - start:.2f} s slack"

    def summary(self) -> dict[str, object]:
        """``metrics.json``'s ``config.hover_thrust_learning.line_slack``: the threshold and the largest window
        average (m/s^2), the spells (start, s)."""
        return {
            "threshold": round(self.threshold, 3),
            "peak": round(self.peak, 3) if math.isfinite(self.peak) else None,
            "spells": [[round(a, 3), None if b is None else round(b - a, 3)] for a, b in self.spells],
        }


__all__ = ["LineSlackWatch"]
