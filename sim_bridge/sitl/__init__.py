"""Real PX4 SITL: start / stop it, and read its ULog's ground truth (test and benchmark harness)."""
