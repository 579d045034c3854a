"""The plant: quadrotor + load on a cable, its sensors, the environment's disturbances and the autopilot's
estimate error; the linearization and the paper's angle form for cross-checks.
"""
