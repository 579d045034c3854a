"""Control laws behind one :class:`~offboard.control.controllers.protocol.Controller` protocol.

Light on purpose: the flight path imports ``protocol`` and ``sliding_mode`` only; the baselines of
``slung compare`` / ``slung sweep`` are imported by name through :func:`offboard.control.controllers.registry.make`.
"""
