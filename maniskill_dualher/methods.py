"""The method registry: every method declares itself here once, and train, protocol, sweep and report
read it. A new method is one file (a ``ReplayMethod``, see ``replay/method.py``) plus one line below.

A :class:`MethodSpec` says what the rest of the project needs to know without importing the method's
code (the report runs without torch): where its class lives, its legend label, colour, line style, marker and
shade, whether it is the paper's method, whether it takes part in the transfer experiment (and its
from-scratch control), whether its R/E sampling ratio is a setting that the ratio study varies and that names
its run folders and table rows, and whose prior it can adapt from (``adopts``: an arm with a ``prior_method``
plans only that method and those that adopt it, ``registry.Experiment.arm_methods``). Each entry owns its facts:
nothing reads a method's position in the registry but the order of legends and tables, so a line appended
here restyles no other method.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Dict, List, Optional, Tuple, Union

import numpy as np

from .config import ConfigError, RunConfig, format_ratio


@dataclass(frozen=True)
class MethodSpec:
    name: str
    target: str               # "module:Class" of its ReplayMethod, imported when a run builds it
    display: str              # legend and table label
    color: str                # matplotlib colour, the same in every figure
    transfer: bool = True     # runs the transfer chain (paper Fig. 5 / Table 5) and the scratch control
    sampling_ratio: bool = False  # replay.ratio matters: the ratio study varies it; it tags folders and rows
    adopts: Tuple[str, ...] = ()  # other methods whose prior (networks and replay) it can adapt from
    linestyle: Union[str, tuple] = ":"  # matplotlib line style (a name or a dash pattern), the same in every figure (tells two methods of one arm apart)
    marker: str = "D"         # matplotlib marker, the same in every figure
    paper: bool = False       # the paper's method: listed first in the aggregate figure (P(it > each other))
    # how its line on an arm other than the paper's settings departs from that arm's colour (analysis/plots.py:
    # shade): 0 the arm's colour itself, > 0 that fraction towards contrast (a dark colour lighter, a light one
    # darker), < 0 the other way. None: the first of plots.SHADE_LEVELS no method declares, in registry order, so
    # two methods on one arm never share a colour and an appended method restyles no other
    shade: Optional[float] = None
    # joins the experiments that take every method ("all", "transfer", "sampling_ratio") and a sweep's default
    # --methods; False: only experiments that name it, so adding it leaves every default sweep (and its folder's
    # sweep.json, which a resumed sweep must match) as it was
    default: bool = True

    def tag(self, cfg: RunConfig) -> str:
        """The settings that tell this method's runs apart in folder names and table rows ('' if none)."""
        return format_ratio(cfg.replay.ratio) if self.sampling_ratio else ""

    def load(self):
        module, cls = self.target.split(":")
        return getattr(importlib.import_module(module), cls)


METHOD_SPECS: Dict[str, MethodSpec] = {s.name: s for s in (
    MethodSpec("sac", "maniskill_dualher.baselines.sac:SACReplay", "SAC (uniform replay)", "tab:gray", transfer=False,
               linestyle="-.", marker="^", shade=-0.6),
    MethodSpec("sac_her_per", "maniskill_dualher.baselines.sac_her_per:SACHerPerReplay", "SAC+HER+PER", "tab:blue",
               linestyle="--", marker="s", shade=0.45),
    MethodSpec("dual_buffer", "maniskill_dualher.dual_buffer:DualBufferReplay", "dual buffer", "tab:orange",
               sampling_ratio=True, adopts=("sac_her_per",), linestyle="-", marker="o", paper=True, shade=0.0),
    MethodSpec("mixed_batch", "maniskill_dualher.baselines.mixed_batch:MixedBatchReplay", "mixed batches (RLPD)",
               "#008b8b", adopts=("sac_her_per",), linestyle=(0, (5, 1)), marker="v", default=False, shade=-0.35),
    MethodSpec("success_bonus", "maniskill_dualher.baselines.success_bonus:SuccessBonusReplay",
               "success bonus (DDPGfD)", "#c71585", linestyle=(0, (3, 1, 1, 1)), marker="P", default=False,
               shade=0.7),
)}


def method_names() -> List[str]:
    return list(METHOD_SPECS)


def method_spec(name: str) -> MethodSpec:
    spec = METHOD_SPECS.get(name)
    if spec is None:
        raise ConfigError(f"unknown method {name!r} (known: {', '.join(METHOD_SPECS)})")
    return spec


def make_method(cfg: RunConfig, spec, rng: np.random.Generator, device: str = "cpu"):
    """Build the replay method ``cfg.method`` for an env described by ``spec`` (an EnvSpec)."""
    cls = method_spec(cfg.method).load()
    if cls.uses_goals and not getattr(spec, "goal_dim", 0):
        raise ConfigError(f"method {cfg.method!r} needs a goal environment (HER); {cfg.env_id!r} has no goals")
    if cls.uses_goals and getattr(spec, "is_maniskill", False) and cfg.reward_mode != "sparse":
        raise ConfigError(f"method {cfg.method!r} relabels goals with the sparse compute_reward; "
                          f"reward_mode={cfg.reward_mode!r} would mix two rewards (use reward_mode='sparse')")
    if cls.uses_goals and getattr(spec, "reward_fn", None) is None:
        raise ConfigError(f"method {cfg.method!r} needs the env's compute_reward; {cfg.env_id!r} gives none")
    return cls(cfg, spec, rng, device)
