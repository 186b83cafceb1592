"""Analysis: loading runs, statistics, claims, plots; no torch, no simulator."""
