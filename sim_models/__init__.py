"""Pure-Python models of the CANopen master's environment.

Nothing in this package imports cocotb at module level except the explicitly named
cocotb adapters, so every model can be unit-tested without a simulator.
All times are integer picoseconds (``t_ps``) on one shared :class:`~sim_models.sim_time.Scheduler`.
"""
