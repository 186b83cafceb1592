"""Replay: ring storage, samplers (uniform, prioritized on a sum tree), buffers, HER relabeling."""
