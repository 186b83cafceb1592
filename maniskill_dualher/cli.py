"""Command lines: the plumbing shared by train, sweep and report (one-line errors, exit code 2), and
``python -m maniskill_dualher.train``'s flags and how they become a RunConfig (every RunConfig field, --config,
--preset, --set KEY=VALUE); ``train.main`` runs them."""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

from .cmdline import OneLineParser  # noqa: F401 (train's parser; evaluate imports it from here)
from .config import (DUAL_MODES, E_BATCHES, HER_STRATEGIES, MATMUL_PRECISIONS, SAC_VARIANTS, SIM_BACKENDS, SUCCESS_BUFFER_MODES,
                     UPDATE_IMPLS, UPDATE_SCHEDULES, ConfigError, ReplayConfig, RunConfig, SACConfig, field_docs,
                     format_ratio)

# --------------------------------------------------------------------------- python -m maniskill_dualher.train
_SECTIONS = {"sac": SACConfig, "replay": ReplayConfig}
# --- issue 31 (one CLI vocabulary): the sweep's spellings are the main names (--task as sweep's --tasks;
# --total-steps, since sweep's --steps is a source-stage budget); the old spellings stay as aliases.
_ALIASES = {"env_id": "task", "total_steps": "total-steps"}
_OLD_SPELLINGS = {"env_id": ("--env",), "total_steps": ("--steps",)}
# every enumerated field lists its choices in --help and refuses others in one line (argparse choices)
_CHOICES = {"variant": SAC_VARIANTS, "her_strategy": HER_STRATEGIES, "dual_mode": DUAL_MODES,
            "update_schedule": UPDATE_SCHEDULES, "matmul_precision": MATMUL_PRECISIONS, "update_impl": UPDATE_IMPLS,
            "success_buffer": SUCCESS_BUFFER_MODES, "sim_backend": SIM_BACKENDS, "e_batches": E_BATCHES}
# --- end issue 31


def _field_flags(parser: argparse.ArgumentParser) -> None:
    """Every config field becomes a flag (--lr, --her-k, --ratio 0.6/0.4, --hidden 256,256, ...)."""
    groups = [("run", RunConfig)] + list(_SECTIONS.items())
    for section, cls in groups:
        g = parser.add_argument_group(f"{section} options ({cls.__name__} in maniskill_dualher/config.py)")
        docs = field_docs(cls)
        for f in dataclasses.fields(cls):
            if f.name in _SECTIONS:
                continue
            name = _ALIASES.get(f.name, f.name).replace("_", "-")
            dest = f"{section}.{f.name}"
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore
            shown = (format_ratio(default) if f.name == "ratio" else ",".join(map(str, default))) \
                if isinstance(default, tuple) else default
            help_ = f"{docs.get(f.name, '')} [default: {shown}]".replace("%", "%%")
            flags = (f"--{name}",) + _OLD_SPELLINGS.get(f.name, ())
            if isinstance(default, bool) or f.name in ("learn_alpha",):
                g.add_argument(*flags, dest=dest, action=argparse.BooleanOptionalAction, default=None, help=help_)
            elif f.name in _CHOICES:
                g.add_argument(*flags, dest=dest, default=None, choices=_CHOICES[f.name], help=help_)
            else:
                g.add_argument(*flags, dest=dest, default=None, metavar=f.name.upper(), help=help_)


def train_config(args: argparse.Namespace) -> RunConfig:
    """--config file, then --preset (its settings and this task's single-task budget), then the flags given,
    then --set KEY=VALUE: every value typed by one parser (experiment/overrides.py)."""
    from .experiment import overrides
    base = RunConfig()
    if args.config:
        p = Path(args.config)
        if not p.is_file():
            raise ConfigError(f"config file not found: {p}")
        try:
            base = RunConfig.from_dict(json.loads(p.read_text()))
        except json.JSONDecodeError as e:
            raise ConfigError(f"config file {p} is not valid JSON (line {e.lineno})") from None
        except TypeError as e:
            raise ConfigError(f"config file {p}: {e}") from None
    items = []
    for key, raw in vars(args).items():
        if "." not in key or raw is None:
            continue
        section, name = key.split(".", 1)
        path = name if section == "run" else f"{section}.{name}"
        try:
            value = raw if isinstance(raw, bool) else overrides.coerce(path, raw)
        except ConfigError as e:
            if not str(e).startswith("bad value for"):  # a message that already names the value (ratios)
                raise
            raise ConfigError(f"--{_ALIASES.get(name, name).replace('_', '-')}: bad value {raw!r}") from None
        items.append(overrides.Override(path, value))
    if args.preset:
        from .experiment.presets import preset
        given = {o.path: o.value for o in items}
        base = preset(args.preset).single_config(given.get("method", base.method), given.get("seed", base.seed),
                                                 given.get("env_id", base.env_id))
    items += [overrides.parse(i) for i in (args.set or [])]
    if any(o.stage for o in items):
        raise ConfigError("train runs one stage: --set takes KEY=VALUE without a stage prefix (adapt., source.)")
    return overrides.apply(base, items).validate()


def train_parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="python -m maniskill_dualher.train",
        description="Train one SAC run (sac | sac_her_per | dual_buffer) on a ManiSkill task or any gymnasium "
                    "env with a Box action space. Running again on the same --out resumes.")
    p.add_argument("--out", required=True, help="run folder (created; resumed if it holds a checkpoint)")
    p.add_argument("--config", help="JSON file with a RunConfig (flags override it)")
    from .experiment.presets import PRESETS  # issue 31: --preset lists its choices
    p.add_argument("--preset", choices=list(PRESETS), help="start from a sweep preset's settings and this task's single-task budget "
                                    "(quick: settings that learn in minutes; without it the defaults are the "
                                    "paper's Table 3, which learned nothing in 20k env steps on ReachTarget)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="any RunConfig setting, dotted (sac.lr=3e-4, replay.ratio=1/0); repeatable")
    p.add_argument("--init-from", help="a finished run folder whose networks start this run (transfer)")
    p.add_argument("--carry-replay", action="store_true", help="with --init-from: also carry its replay buffers")
    p.add_argument("--keep-replay", action="store_true",
                   help="keep the replay buffers in the finished run's checkpoint (for a later --carry-replay)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    _field_flags(p)
    return p
