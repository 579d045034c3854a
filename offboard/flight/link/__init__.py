"""The MAVLink side of the flight code: connection, telemetry decoding, setpoint encoding, vehicle management.

Nothing here imports ``sim_bridge``: the controller and the emulator meet only on the MAVLink wire.
All NED / FRD <-> model-frame conversions go through ``estimators.model.frames``.
"""
