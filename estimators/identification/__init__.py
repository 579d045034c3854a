"""Identification of what the vehicle carries, from what an autopilot reports (no cable-angle sensor needed)."""
