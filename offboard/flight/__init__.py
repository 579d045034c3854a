"""The live flight: the MAVLink link, the flight loop, the mapping of the controller's command onto the
autopilot's setpoints, supervision and ``slung fly``.

Part of the live flight path: nothing here loads the simulation harness or ``sim_bridge``; the report is
written after the flight.
"""
