"""The budget curve (``budget.csv`` rows): the dual/HER ratio of successful adaptation episodes and the
difference in final evaluation success, each with its 95% interval, against the adaptation budget (log x)."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

from .plots import _plt, save_figure


def plot_budget(rows: Sequence[dict], path: Path) -> bool:
    """Two panels, one point per budget; False (nothing written) without any budget row."""
    if not rows:
        return False
    plt = _plt()
    fig, (ax_r, ax_d) = plt.subplots(1, 2, figsize=(11, 4))
    fig.subplots_adjust(wspace=0.35)
    x = [float(r["budget_factor"]) for r in rows]
    for ax, key, ref, ylabel, title in (
            (ax_r, "ratio", 1.0, "dual buffer / SAC+HER+PER", "successful adaptation episodes: ratio of means"),
            (ax_d, "final_success_diff", 0.0, "dual buffer - SAC+HER+PER", "final evaluation success: difference")):
        pts = [(xi, float(r[key]), float(r[key + "_ci95_low"] if key == "final_success_diff" else r["ratio_ci95_low"]),
                float(r[key + "_ci95_high"] if key == "final_success_diff" else r["ratio_ci95_high"]),
                r["n_dual"], r["n_her"]) for xi, r in zip(x, rows) if r.get(key) not in (None, "")]
        pts = [p for p in pts if not math.isnan(p[1])]
        for xi, y, lo, hi, nd, nh in pts:
            lo_err = y - lo if math.isfinite(lo) else 0.0
            hi_err = hi - y if math.isfinite(hi) else 0.0
            # black: a contrast of two methods, in neither's colour
            ax.errorbar([xi], [y], yerr=[[lo_err], [hi_err]], fmt="o", color="black", capsize=4)
            ax.annotate(f"n={nd}, {nh}", (xi, y), textcoords="offset points", xytext=(6, 4), fontsize=7)
        if len(pts) > 1:
            ax.plot([p[0] for p in pts], [p[1] for p in pts], color="black", alpha=0.5)
        ax.axhline(ref, color="black", lw=0.8, ls="--")
        ax.set_xscale("log", base=2)
        ax.set_xticks(x)
        ax.set_xticklabels([f"{xi:g}x" for xi in x])
        ax.set_xlabel("adaptation budget (x the adaptation stage's env steps)")
        ax.set_ylabel(ylabel)
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
        if not pts:
            ax.text(0.5, 0.5, "not measured", ha="center", va="center", transform=ax.transAxes)
    fig.suptitle("The adaptation budget (95% intervals; n = dual buffer, SAC+HER+PER seeds)", fontsize=10)
    save_figure(fig, path)
    plt.close(fig)
    return True
