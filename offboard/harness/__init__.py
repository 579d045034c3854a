"""The simulation harness: ``slung sim`` (plant in process), ``slung demo`` (against the emulator),
``slung bench``, ``slung sweep`` and ``slung compare``. The only part of ``offboard`` that loads ``sim_bridge``.
"""
