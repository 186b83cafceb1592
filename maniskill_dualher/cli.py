"""Command lines: the plumbing shared by train, sweep and report (one-line errors, exit code 2), and
``python -m maniskill_dualher.train``'s flags and how they become a RunConfig (every RunConfig field, --config,
--preset, --set KEY=VALUE); ``train.main`` runs them."""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from .cmdline import OneLineParser, did_you_mean, old_flag  # noqa: F401 (train's parser; evaluate imports it here)
from .config import (DUAL_MODES, E_BATCHES, HER_STRATEGIES, MATMUL_PRECISIONS, SAC_VARIANTS, SIM_BACKENDS, TASKS,
                     SUCCESS_BUFFER_MODES, UPDATE_IMPLS, UPDATE_SCHEDULES, ConfigError, ReplayConfig, RunConfig,
                     SACConfig, config_yaml, field_docs, format_ratio, read_config_file)
from .methods import METHOD_SPECS

# --------------------------------------------------------------------------- python -m maniskill_dualher.train
_SECTIONS = {"sac": SACConfig, "replay": ReplayConfig}
# One word, one meaning across train, sweep and evaluate (issues 31, 43): --task as sweep's --tasks (--env, the
# same thing, stays); the whole run is --total-steps (sweep's budgets are --source-steps and --adapt-steps), so
# --steps is no flag anywhere: it answers with the new spelling.
_ALIASES = {"env_id": "task", "total_steps": "total-steps"}
_OLD_SPELLINGS = {"env_id": ("--env",)}
# every enumerated field lists its choices in --help and refuses others in one line (argparse choices)
_CHOICES = {"variant": SAC_VARIANTS, "her_strategy": HER_STRATEGIES, "dual_mode": DUAL_MODES,
            "update_schedule": UPDATE_SCHEDULES, "matmul_precision": MATMUL_PRECISIONS, "update_impl": UPDATE_IMPLS,
            "success_buffer": SUCCESS_BUFFER_MODES, "sim_backend": SIM_BACKENDS, "e_batches": E_BATCHES}
NO_PRESET_NOTE = ("note: no --preset or --config: the paper's Table 3 settings (RunConfig's defaults), which "
                  "learned nothing in 20k env steps on ReachTarget here; --preset quick has settings that learn in "
                  "minutes")


def flag_of(name: str) -> str:
    """A config field's train flag: total_steps -> --total-steps, env_id -> --task."""
    return "--" + _ALIASES.get(name, name).replace("_", "-")


def _field_names():
    return [f.name for cls in (RunConfig, SACConfig, ReplayConfig) for f in dataclasses.fields(cls)
            if f.name not in _SECTIONS]


def name_flags(message: str, keep=()) -> str:
    """A validation message in the words the user typed: a field name becomes its flag (``total_steps must
    be > 0`` -> ``--total-steps must be > 0``), except those in ``keep`` (given through --set KEY=VALUE)."""
    import re
    for name in sorted(_field_names(), key=len, reverse=True):
        if name in keep:
            continue
        if "_" in name:
            message = re.sub(rf"(?<![\w.'\"-]){name}(?![\w'\"])", flag_of(name), message)
        else:  # a plain word (seed, lr, hidden) only where it is the subject
            message = re.sub(rf"^{name}(?= must|=|,| and )", flag_of(name), message)
    return message


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
            elif f.name in _CHOICES or f.name == "method":
                # methods: the registry as the parser is built (a method registered at run time is in)
                choices = list(METHOD_SPECS) if f.name == "method" else _CHOICES[f.name]
                g.add_argument(*flags, dest=dest, default=None, choices=choices, help=help_)
            else:
                g.add_argument(*flags, dest=dest, default=None, metavar=f.name.upper(), help=help_)


def train_config(args: argparse.Namespace) -> RunConfig:
    """--config file, then --preset (its settings and this task's single-task budget), then the flags given,
    then --set KEY=VALUE: every value typed by one parser (experiment/overrides.py)."""
    from .experiment import overrides
    base = RunConfig()
    if args.config:
        p = Path(args.config)
        try:
            base = RunConfig.from_dict(read_config_file(p))
        except ConfigError as e:
            raise ConfigError(e if str(e).startswith("config file") else f"config file {p}: {e}") from None
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
                raise ConfigError(name_flags(str(e))) from None
            raise ConfigError(f"{flag_of(name)}: bad value {raw!r}") from None
        items.append(overrides.Override(path, value))
    if args.preset:
        from .experiment.presets import preset
        given = {o.path: o.value for o in items}
        base = preset(args.preset).single_config(given.get("method", base.method), given.get("seed", base.seed),
                                                 given.get("env_id", base.env_id))
    given_by_set = [overrides.parse(i) for i in (args.set or [])]
    items += given_by_set
    if any(o.stage for o in items):
        raise ConfigError("train runs one stage: --set takes KEY=VALUE without a stage prefix (adapt., source.)")
    try:
        cfg = overrides.apply(base, items).validate()
    except ConfigError as e:
        raise ConfigError(name_flags(str(e), keep={o.path.split(".")[-1] for o in given_by_set})) from None
    if cfg.env_id not in TASKS and did_you_mean(cfg.env_id, TASKS):  # a typo of ours, not another env
        import gymnasium as gym
        import maniskill_dualher.tasks  # noqa: F401  (registers our tasks)
        if cfg.env_id not in gym.registry:
            raise ConfigError(f"--task: unknown environment {cfg.env_id!r}{did_you_mean(cfg.env_id, TASKS)}")
    return cfg


def printed_config(args: argparse.Namespace, argv) -> str:
    """``train ARGV`` with --print-config: the config the flags give, as the YAML file ``--config`` reads back."""
    if args.continue_run is not None:
        raise ConfigError(f"--print-config prints a new run's config; --continue {args.continue_run} keeps its own: "
                          f"{Path(args.continue_run) / 'config.json'}")
    cfg = train_config(args)
    import shlex
    typed = shlex.join([a for a in argv if a != "--print-config"] + ["--print-config"])
    return config_yaml(cfg, "RunConfig for python -m maniskill_dualher.train --config FILE (maniskill_dualher/"
                            f"config.py documents each key)\nwritten by: python -m maniskill_dualher.train {typed}")


def continue_request(args: argparse.Namespace):
    """``--continue RUN --total-steps N`` -> (RUN, N); None without --continue. The run keeps its own config,
    so no other setting goes with it; without --continue, --out is needed."""
    from .experiment import overrides
    if args.continue_run is None:
        if not args.out:
            raise ConfigError("--out is required (or --continue RUN --total-steps N)")
        return None
    others = [flag_of(key.split(".", 1)[1]) for key, v in sorted(vars(args).items())
              if "." in key and v is not None and key != "run.total_steps"]
    others += [f"--{k.replace('_', '-')}" for k in ("out", "config", "preset", "set", "init_from", "carry_replay",
                                                    "keep_replay") if getattr(args, k)]
    if others:
        raise ConfigError(f"--continue {args.continue_run} takes the run's own config: only --total-steps goes "
                          f"with it, not {others[0]}")
    raw = vars(args)["run.total_steps"]
    if raw is None:
        raise ConfigError(f"--continue {args.continue_run} needs --total-steps N (more than the run has done)")
    try:
        return args.continue_run, overrides.coerce("total_steps", raw)
    except ConfigError:
        raise ConfigError(f"--total-steps: bad value {raw!r}") from None


def train_parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="python -m maniskill_dualher.train",
        description="Train one SAC run (sac | sac_her_per | dual_buffer) on a ManiSkill task or any gymnasium "
                    "env with a Box action space. Running again on the same --out resumes.")
    p.add_argument("--out", help="run folder (created; resumed if it holds a checkpoint)")
    p.add_argument("--continue", dest="continue_run", metavar="RUN",
                   help="carry the finished run in folder RUN on to --total-steps N (more than it has done), from "
                        "its final checkpoint, with its own config (it needs its replay: trained with "
                        "--keep-replay)")
    p.add_argument("--config", metavar="FILE",
                   help="a RunConfig, or part of one, as YAML (.yaml, .yml) or JSON (flags override it); "
                        "--print-config writes one")
    p.add_argument("--print-config", action="store_true",
                   help="print the config these flags give as YAML and exit (nothing trained, no --out): saved to a "
                        "file, --config FILE gives the same config, e.g. --preset quick --task CloseBox-v1 "
                        "--print-config > quick.yaml")
    from .experiment.presets import PRESETS  # issue 31: --preset lists its choices
    p.add_argument("--preset", choices=list(PRESETS),
                   help="start from a sweep preset's settings and this task's single-task budget (quick: settings "
                        "that learn in minutes; without it the defaults are the paper's Table 3, which learned "
                        "nothing in 20k env steps on ReachTarget: the run says so in one line)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="any RunConfig setting, dotted (sac.lr=3e-4, replay.ratio=1/0); repeatable")
    p.add_argument("--init-from", help="a finished run folder whose networks start this run (transfer)")
    p.add_argument("--carry-replay", action="store_true", help="with --init-from: also carry its replay buffers")
    p.add_argument("--keep-replay", action="store_true",
                   help="keep the replay buffers in the finished run's checkpoint (for a later --carry-replay)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    _field_flags(p)
    old_flag(p, "--steps", "the whole run is --total-steps N (sweep's budgets: --source-steps, --adapt-steps)")
    return p
