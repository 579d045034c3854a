"""The emulated autopilot's inner control: PX4's and ArduPilot's attitude / rate loops, the allocator, the
mixer and motors.
"""
