"""Flight logs and run records: tlog / ULog / DataFlash readers, what a log holds, the run log's schema and
``slung replay`` (the same estimator and controller over a log).

Part of the live flight path (the loop writes its log with these records): nothing here loads the simulation
harness or ``sim_bridge``.
"""
