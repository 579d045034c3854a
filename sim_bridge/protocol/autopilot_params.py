"""The emulated autopilot's parameter protocol: PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET answered
with PARAM_VALUE as each autopilot encodes it (PX4 integers bytewise in the float, ArduPilot's C cast), and
:meth:`ParameterProtocol.set_param`, the one way a value changes (a PARAM_SET, or ``slung emulate --param``
before the start), with the parameter's range checked and the value pushed into the inner loops.

A mixin: it works on the attributes :class:`sim_bridge.autopilot.Autopilot` sets up (``params``,
``param_names``, ``fl``, ``mav``, ``counters``, ``statustext``, ``_apply_params``); it is not used on its own.
"""

from __future__ import annotations

import math
import struct
from typing import Any

from sim_bridge.autopilot_constants import WARNING
from sim_bridge.modes.flavors import INT8, INT16, INT32


class ParameterProtocol:
    """Parameters of :class:`sim_bridge.autopilot.Autopilot`."""

    params: dict[str, Any]
    param_names: list[str]
    fl: Any
    mav: Any
    counters: dict[str, int]

    def _param_wire(self, name: str) -> float:
        """A parameter's value as it travels in PARAM_VALUE.param_value (PX4 ints bytewise, ArduPilot C cast)."""
        p = self.params[name]
        if p.ptype in (INT8, INT16, INT32) and self.fl.is_px4:
            return struct.unpack("<f", struct.pack("<i", int(p.value)))[0]
        return float(p.value)

    def _send_param(self, name: str) -> None:
        p = self.params[name]
        self.mav.send(
            self.mav.param_value_encode(
                name.encode(), self._param_wire(name), p.ptype, len(self.param_names), self.param_names.index(name)
            )
        )

    def _on_param_request_list(self, msg: Any) -> int:
        for name in self.param_names:
            self._send_param(name)
        return 0

    def _on_param_request_read(self, msg: Any) -> int:
        if msg.param_index >= 0:
            if msg.param_index < len(self.param_names):
                self._send_param(self.param_names[msg.param_index])
            return 0
        name = _param_id(msg.param_id)
        if name in self.params:
            self._send_param(name)
        return 0

    def _on_param_set(self, msg: Any) -> int:
        name = _param_id(msg.param_id)
        p = self.params.get(name)
        if p is None:
            return 0
        if p.ptype in (INT8, INT16, INT32):
            if self.fl.is_px4:
                v: float = struct.unpack("<i", struct.pack("<f", msg.param_value))[0]
            else:
                v = float(round(msg.param_value)) if math.isfinite(msg.param_value) else float("nan")
        else:
            v = msg.param_value
        refused = self.set_param(name, v)
        if refused is not None and not p.readonly:
            self.statustext(WARNING, refused)
        self._send_param(name)
        return 0

    def set_param(self, name: str, value: float) -> str | None:
        """Set a parameter as PARAM_SET does (an integer type rounds to its integer) and push it into the inner
        loops; None when set, else why not (unknown, read-only, not finite, out of the parameter's range)."""
        p = self.params.get(name)
        if p is None:
            return f"param {name}: no such parameter"
        if p.readonly or not math.isfinite(value) or not (p.lo <= value <= p.hi):
            return (
                f"param {name}: read-only"
                if p.readonly
                else f"param {name}: {value:g} out of range [{p.lo:g}, {p.hi:g}]"
            )
        p.value = int(value) if p.ptype in (INT8, INT16, INT32) else float(value)
        self.counters["param_sets"] += 1
        self._apply_params(name)
        return None


def _param_id(raw: Any) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return str(raw).split("\x00", 1)[0]
