"""The Kalman filters that turn measurement records into a ``ControlState``, and the factory that builds one by
name (``docs/estimation.md``).
"""
