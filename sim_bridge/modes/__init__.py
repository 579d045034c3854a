"""The emulated autopilot's modes, arming and failsafes, and what differs between the PX4 and ArduPilot
flavours.
"""
