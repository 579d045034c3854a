"""The live loop's identification hover (mixed into :class:`offboard.flight.loop.FlightLoop`, whose state it reads
and writes): the load identified in flight before control (``offboard.flight.load_identification``), and the law,
the filter, the mapping and the feasibility check rebuilt for it when it is confident. Off unless
``LoopConfig.identify_load_s`` (``slung fly --identify-load``).

Hooks in the loop: :meth:`_identification_hover` after the hold at the reference's start, before the hover
throttle is chosen and the filter initialized; every decoded record of the autopilot to :attr:`load_id` while it
buffers (``loop_link``).
"""

from __future__ import annotations

import threading
from typing import Any

from estimators.model.flatness import flat_constants
from estimators.model.vehicle import Vehicle
from offboard.control import smc_attitude
from offboard.flight.attitude_mapping import inner_loop_of
from offboard.flight.load_identification import InFlightLoadId, decide
from offboard.flight.loop_link import FlightAbortError

#: the identification hover's excitation: the held point moved this far (m) along x for its first half
EXCITATION_M = 0.3


class LoadIdentificationPhase:
    """The identification hover of :class:`~offboard.flight.loop.FlightLoop` (a mixin: the state is the loop's)."""

    def _identification_hover(self) -> None:
        """At the reference's start, settled: the identification hover (``cfg.identify_load_s``), the autopilot's
        hold with a gentle excitation (the held point moved :data:`EXCITATION_M` along x for the first half, so the
        vehicle's own accelerations separate the load's mass from its length; a still hover ties them along the
        coupled mode), the load identified in another process while the hold goes on, the identified load flown if
        confident (else the priors), and the start reached again."""
        if self.cfg.identify_load_s <= 0.0 or self.goal is None:
            return
        lid = self.load_id = InFlightLoadId(self.vehicle, self.cfg.identify_load_s)
        lid.start()
        goal = self.goal
        start = self._now_vehicle()
        limit = lid.hover_s + 5.0  # the records come with the hover; a stream that stops must not hold forever
        while not lid.ready() and self._now_vehicle() - start < limit:
            moved = lid.span_s() < 0.5 * lid.hover_s
            self.goal = (goal[0] + EXCITATION_M, *goal[1:]) if moved else goal
            self.stream_hover()
            if self._signal is not None:
                raise FlightAbortError("signal", f"signal {self._signal} before the flight", self.cfg.signal_action)
        self.goal = goal
        span = lid.span_s()
        lid.run_in_background()
        t_id = self._now_vehicle()
        while not lid.done():
            self.stream_hover()
            if self._signal is not None:
                raise FlightAbortError("signal", f"signal {self._signal} before the flight", self.cfg.signal_action)
        flown, block = decide(lid.result, self.vehicle, lid.error)
        block["hover_s"] = round(span, 3)
        block["compute_s"] = round(self._now_vehicle() - t_id, 3)
        self.load_block = block
        self.event("load_identification", f"after {span:.1f} s of hover: {block['why']}")
        if flown is not None:
            self._adopt_vehicle(flown)
        else:
            self.mgr.warnings.append(f"load identification: {block['why']}")
        block["flown"] = {"mass_kg": self.vehicle.mass_load, "cable_m": self.vehicle.cable_length}
        self._approach()  # back at the start, settled, before control

    def _adopt_vehicle(self, vehicle: Vehicle) -> None:
        """Fly ``vehicle`` (the identified load) from now on: the law's parameters and the filter rebuilt for it by
        ``rebuild_for`` (``slung fly``: as it built them for the file, with the feasibility check, whose refusal
        ends the flight in the autopilot's hold), the mapping for its weight, the flat-output constants."""
        if self.rebuild_for is None:
            self.event("load_identification", "no rebuild given: the law and the filter keep the vehicle file's load")
            return
        attitude = isinstance(self.params, smc_attitude.AttitudeParams)
        rebuild = self.rebuild_for
        box: dict[str, Any] = {}

        def work() -> None:
            try:
                params, factory = rebuild(vehicle, attitude)
                if isinstance(params, smc_attitude.AttitudeParams):  # its gains follow the autopilot's loops (run())
                    tilt_max = min(params.tilt_max, self.mapper.config.max_tilt)
                    params = params.with_inner(inner_loop_of(self.mapper.autopilot), tilt_max=tilt_max)
                self._warm_up(self._now_vehicle(), factory=factory)
                box["built"] = (params, factory)
            except BaseException as exc:  # raised again in the loop's thread
                box["error"] = exc

        # the gains' design, the feasibility check and the new filter's warm-up take a second or more on a loaded
        # machine: the hold's setpoints go on meanwhile (PX4 leaves offboard after COM_OF_LOSS_T without them: a
        # PX4 HIL flight went to AUTO.LOITER, 2026-12-07)
        worker = threading.Thread(target=work, name="slung-rebuild", daemon=True)
        worker.start()
        while worker.is_alive():
            self.stream_hover()
        worker.join()
        if "error" in box:
            raise box["error"]
        params, factory = box["built"]
        old = self.mapper
        mapper: Any = type(old)(vehicle, old.config, old.autopilot)
        mapper.events = old.events
        self.mapper = mapper
        self.vehicle = vehicle
        self.k = flat_constants(vehicle)
        self.params = params
        self.estimator_factory = factory
        self.estimator = factory()


__all__ = ["LoadIdentificationPhase"]
