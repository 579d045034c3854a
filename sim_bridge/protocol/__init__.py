"""The emulated autopilot's MAVLink side: the link (sockets, faults, framing), telemetry generation, the
outgoing streams and the incoming setpoint messages.
"""
