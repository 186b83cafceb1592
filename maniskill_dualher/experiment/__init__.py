"""Experiments as data: the registry of experiments and arms, presets, overrides, the grid, the transfer
protocol, cost estimates and the backends that run it all (``python -m maniskill_dualher.sweep``)."""
