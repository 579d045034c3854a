"""The control side: the sliding-mode laws and the controllers behind one protocol, references with exact
derivatives, named scenarios, feasibility checks and the one controller tick every driver calls.

Part of the live flight path: nothing here loads the simulation harness, the reports or ``sim_bridge``.
"""
