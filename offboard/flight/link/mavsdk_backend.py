"""A second backend on the ``mavsdk`` package (MAVSDK 4, native binding) behind the same interface as the
pymavlink one, for users who already run MAVSDK.

How it is wired (one link, one socket):

- the socket, the tlog and the telemetry path are those of :class:`~offboard.flight.link.connection.MavConnection`
  (pymavlink parses what arrives; the estimator's measurements come from it exactly as with the default backend);
- a ``Mavsdk`` instance (component type companion computer, system id 254) is attached with MAVSDK's ``raw://``
  transport: every packet we receive is handed to it (``pass_received_raw_bytes``) and every packet it wants to
  send goes out on our socket (``subscribe_raw_bytes_to_be_sent``) and into the tlog;
- vehicle management uses MAVSDK's plugins: :class:`MavsdkManager` arms, takes off, holds and lands with
  ``Action``, and reads the flight mode / armed state with ``Telemetry``;
- setpoints are raw MAVLink (our own SET_ATTITUDE_TARGET / SET_ACTUATOR_CONTROL_TARGET encoding): MAVSDK's
  ``Offboard`` plugin only takes Euler angles in degrees and re-sends its last setpoint at 20 Hz on its own, which
  would interleave with the loop's stream, so the switch to OFFBOARD (PX4) / GUIDED (ArduPilot) is also sent as
  raw DO_SET_MODE (see ``shared/docs/mavlink-facts.md`` section 4.4).

MAVSDK's calls are used in their ``*_async`` form and awaited while this thread keeps polling the socket: MAVSDK
only sees the packets we pass it, so a blocking call would wait for an acknowledgement nobody delivers.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from typing import Any

from estimators.errors import UserError
from offboard.flight.link.connection import MavConnection, Received, SigningConfig
from offboard.flight.link.management import Manager

MAVSDK_SYSTEM_ID = 254


class MavsdkConnection(MavConnection):
    """:class:`MavConnection` with a MAVSDK instance riding on the same socket (see module docstring)."""

    #: systems whose every component is ours: MAVSDK's instance sends the commands (arm, take-off, mode), so the
    #: autopilot's answers addressed to it are answers to us, not to a foreign sender (supervision)
    own_systems: tuple[int, ...] = (MAVSDK_SYSTEM_ID,)

    def __init__(
        self,
        url: str,
        *,
        baud: int | None = None,
        tlog_path: str | os.PathLike[str] | None = None,
        signing: SigningConfig | None = None,
    ) -> None:
        super().__init__(url, baud=baud, tlog_path=tlog_path, signing=signing)
        #: MAVSDK (Python) cannot sign: with a key, its frames are re-signed here before they leave
        self._resign: Any = _Resigner(self.mav, signing) if signing is not None else None
        try:
            from mavsdk import ComponentType, Configuration, Mavsdk
        except ImportError as exc:  # pragma: no cover - mavsdk is a dependency
            raise UserError(f"--backend mavsdk needs the mavsdk package: {exc}") from None
        cfg = Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER)
        cfg.system_id = MAVSDK_SYSTEM_ID
        self.sdk = Mavsdk(cfg)
        self._out_lock = threading.Lock()
        self.sdk_bytes_out = 0
        self._sub = self.sdk.subscribe_raw_bytes_to_be_sent(self._from_sdk)
        res = self.sdk.add_any_connection("raw://")
        if int(res) != 0:
            raise UserError(f"MAVSDK refused its raw connection: {getattr(res, 'name', res)}")

    def _from_sdk(self, data: bytes) -> None:
        """Bytes MAVSDK wants to send (called from a MAVSDK thread)."""
        if self._closed:
            return
        with self._out_lock:
            if self._resign is not None:
                data = self._resign(data)
            try:
                self.conn.write(data)
            except OSError:
                return
            self.sdk_bytes_out += len(data)
            if self.tlog is not None:
                self.tlog.write(data)

    def send(self, msg: Any, log: bool = True) -> bytes:
        """As :meth:`MavConnection.send`, serialized with MAVSDK's own writes."""
        with self._out_lock:
            return super().send(msg, log)

    def log_sent(self, buf: bytes, wall_time: float) -> None:
        """As :meth:`MavConnection.log_sent`, serialized with MAVSDK's own writes (its packets go into the tlog too)."""
        with self._out_lock:
            super().log_sent(buf, wall_time)

    def poll(self) -> list[Received]:
        """As :meth:`MavConnection.poll`; every packet is also handed to MAVSDK."""
        out = super().poll()
        for r in out:
            self.sdk.pass_received_raw_bytes(bytes(r.msg.get_msgbuf()))
        return out

    def close(self) -> None:
        """Stop MAVSDK, then close the socket and the tlog."""
        if self._closed:
            return
        try:
            self.sdk.unsubscribe_raw_bytes_to_be_sent(self._sub)
            self.sdk.destroy()
        finally:
            super().close()


class _Resigner:
    """MAVSDK's outgoing bytes with every frame signed with the link's key (``mavsdk`` for Python exposes no
    signing): each frame is parsed and packed again with its own system, component and sequence number, signed
    (its stream is MAVSDK's system id, so its timestamps never collide with the loop's own stream)."""

    def __init__(self, mav: Any, signing: SigningConfig) -> None:
        from pymavlink.dialects.v20 import ardupilotmega

        self._parser = ardupilotmega.MAVLink(None)
        self._parser.robust_parsing = True
        s = ardupilotmega.MAVLink(None)
        s.signing.secret_key = signing.key
        s.signing.sign_outgoing = True
        s.signing.link_id = signing.link_id
        s.signing.timestamp = mav.signing.timestamp
        self._signer = s

    def __call__(self, data: bytes) -> bytes:
        out = bytearray()
        s = self._signer
        for m in self._parser.parse_buffer(data) or []:
            if m.get_type() == "BAD_DATA":
                continue
            s.srcSystem, s.srcComponent, s.seq = m.get_srcSystem(), m.get_srcComponent(), m.get_seq()
            out += m.pack(s)
        return bytes(out)


class MavsdkManager(Manager):
    """:class:`Manager` whose arming, take-off, hold and landing go through MAVSDK's Action plugin."""

    def __init__(self, conn: MavsdkConnection) -> None:
        super().__init__(conn)
        self.sdk_conn = conn
        self._action: Any = None
        self._telemetry: Any = None

    # ------------------------------------------------------------------------------------------ plumbing ---
    def _plugins(self, idle: Callable[[], None] | None = None, timeout: float = 10.0) -> tuple[Any, Any]:
        if self._action is not None:
            return self._action, self._telemetry
        from mavsdk.plugins.action import Action
        from mavsdk.plugins.telemetry import Telemetry

        sdk = self.sdk_conn.sdk
        found: list[Any] = []

        def ready() -> bool:
            found[:] = [s for s in sdk.get_systems() if s.has_autopilot()]
            return bool(found)

        if not self.wait_for(ready, timeout, idle):
            raise UserError("MAVSDK did not discover the autopilot")
        self._action, self._telemetry = Action(found[0]), Telemetry(found[0])
        self.note("mavsdk", "MAVSDK discovered the autopilot")
        return self._action, self._telemetry

    def _await(
        self,
        what: str,
        start: Callable[[Callable[..., None]], None],
        idle: Callable[[], None] | None,
        timeout: float = 10.0,
    ) -> Any:
        """Start an ``*_async`` MAVSDK call and poll the link until its callback reports; the result.

        The call is started on a short-lived thread: some of MAVSDK's ``*_async`` calls block their caller until
        the answer arrives (``Action.set_takeoff_altitude_async`` runs a blocking parameter set), and on the
        ``raw://`` transport the answer only arrives while this thread keeps passing it the received bytes."""
        box: list[Any] = []
        starter = threading.Thread(
            target=start, args=(lambda result, _ud=None: box.append(result),), name=f"mavsdk-{what}", daemon=True
        )
        starter.start()
        if not self.wait_for(lambda: bool(box), timeout, idle):
            raise UserError(f"MAVSDK {what}: no answer within {timeout:g} s")
        starter.join(1.0)
        self.note(f"mavsdk_{what}", str(box[0]))
        return box[0]

    @staticmethod
    def _ok(result: Any) -> bool:
        return getattr(result, "name", str(result)).upper() == "SUCCESS"

    # --------------------------------------------------------------------------------------- overrides ---
    def arm(self, idle: Callable[[], None] | None = None, timeout: float = 10.0) -> None:
        """Arm with Action.arm (retried while refused, e.g. before the position estimate is ready)."""
        action, _ = self._plugins(idle)
        t_end = time.monotonic() + timeout
        res: Any = None
        while time.monotonic() < t_end:
            res = self._await("arm", action.arm_async, idle)
            if self._ok(res):
                self.armed_here = True
                return
            self.wait_for(lambda: False, 0.25, idle)
        raise UserError(f"MAVSDK could not arm: {res}")

    def takeoff(
        self,
        height: float,
        home_alt_amsl: float | None,
        height_now: Callable[[], float | None],
        idle: Callable[[], None] | None = None,
        timeout: float = 60.0,
    ) -> None:
        """Action.set_takeoff_altitude + arm + Action.takeoff, then wait for the height."""
        action, _ = self._plugins(idle)
        res = self._await("set_takeoff_altitude", lambda cb: action.set_takeoff_altitude_async(height, cb), idle)
        if not self._ok(res):
            self.warnings.append(f"MAVSDK set_takeoff_altitude: {res}")
        self.arm(idle)
        res = self._await("takeoff", action.takeoff_async, idle)
        if not self._ok(res):
            raise UserError(f"MAVSDK take-off refused: {res}")
        self.wait_for_takeoff(height, height_now, timeout, idle)

    def set_mode(self, role: str, idle: Callable[[], None] | None = None, retries: int = 3) -> bool:
        """hold / land through Action; offboard as raw DO_SET_MODE (module docstring)."""
        if role == "offboard":
            return super().set_mode(role, idle, retries)
        action, _ = self._plugins(idle)
        fn = action.hold_async if role == "hold" else action.land_async
        return self._ok(self._await(role, fn, idle))

    def send_mode_no_wait(self, role: str) -> None:
        """hold / land without waiting (Action's async call; its answer arrives while the loop polls)."""
        if role == "offboard" or self._action is None:
            super().send_mode_no_wait(role)
            return
        fn = self._action.hold_async if role == "hold" else self._action.land_async
        fn(lambda result, _ud=None: self.note(f"mavsdk_{role}", str(result)))


__all__ = ["MAVSDK_SYSTEM_ID", "MavsdkConnection", "MavsdkManager"]
