"""Typed configs: the one place for defaults.

Defaults follow the paper's Table 3 where it gives a value (learning rate 1e-4,
replay memory 10^7, batch 256, discount 0.99, SAC temperature 0.005, 150 steps
per episode, prioritization exponent 0.5). Values the paper does not state are
marked "not in the paper" and chosen so a run learns on a 2-core CPU.

Naming, to avoid the usual confusion: the paper's "prioritization exponent β"
is what PER libraries (Schaul et al., cpprb, TorchRL) call ``alpha``. Here it is
``priority_exponent``. The importance-sampling exponent (PER libraries' ``beta``)
is ``is_exponent``; the paper does not use importance weights.
"""
from __future__ import annotations

import dataclasses
import json
import math
import shutil
from dataclasses import dataclass, field
from typing import Any, Optional, Tuple


MATMUL_PRECISIONS = ("highest", "high", "medium", "bf16")
UPDATE_IMPLS = ("fused", "autograd")
SAC_VARIANTS = ("paper", "modern")
HER_STRATEGIES = ("future", "final", "episode")
DUAL_MODES = ("choose", "split")
UPDATE_SCHEDULES = ("step", "episode")
SUCCESS_BUFFER_MODES = ("transitions", "episodes")
SIM_BACKENDS = ("physx_cpu", "physx_cuda")
# The catalog of our tasks (a new task: its file in tasks/, its import in tasks/__init__.py, its id here). The
# sweep's --tasks and budgets, the tables' and plots' task order read it; the paper's transfer chain is
# experiment data (experiment/registry.py: PAPER_CHAIN), so a task added here joins no chain. A list: a task
# registered at run time is appended (tests/test_registry.py).
TASKS = ["ReachTarget-v1", "CloseBox-v1", "CloseMicrowave-v1"]


def check_device(device: str, what: Optional[str] = None) -> None:
    """A torch device string that exists on this machine, or one ConfigError line naming it."""
    if device == "cpu":  # always there; the grid (and the report's hyperparameters.csv through it) loads no torch
        return
    import torch
    what = what or f"device {device!r}"
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise ConfigError(f"unknown device {device!r} (e.g. cpu, cuda, cuda:0)") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ConfigError(f"{what} needs a CUDA GPU, but torch finds none on this machine")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ConfigError(f"device {device!r}: this machine has {torch.cuda.device_count()} CUDA devices")
    elif dev.type not in ("cpu", "cuda"):
        raise ConfigError(f"unsupported device {device!r} (use cpu or cuda)")


# How an update is computed, not what it computes (fused and autograd, compiled or not, agree to float
# rounding: tests/test_sac_fused.py; so do torch's fp32 precision settings: tests/test_sac.py). A run may
# resume under other values of these; its config.json then records the current ones.
IMPLEMENTATION_ONLY = ("update_impl", "compile")
FP32_LEVEL_PRECISIONS = ("highest", "high", "medium")


# (section or "", key, default) of settings added after run folders were first named (RunConfig.to_dict)
ADDED_LATER = (("replay", "e_batches", "full"), ("replay", "carry_rows", True))
E_BATCHES = ("full", "critic")


def run_identity(cfg: dict) -> dict:
    """A RunConfig dict (as in a run's config.json) without the settings that do not change its results."""
    out = json.loads(json.dumps(cfg))
    out.pop("gpu_memory_scale", None)  # GPU buffer sizes: how a run is simulated, not what (runs made before it)
    sac = out.get("sac", {})
    for k in IMPLEMENTATION_ONLY:
        sac.pop(k, None)
    if sac.get("matmul_precision") in FP32_LEVEL_PRECISIONS:
        sac["matmul_precision"] = "fp32"
    return out


class ConfigError(ValueError):
    """A bad configuration value; the message is one line naming it."""


@dataclass
class SACConfig:
    # SAC variant: "paper" = twin Q + state value V with a Polyak target V-bar and a fixed temperature
    # (the paper's Fig. 1); "modern" = twin Q with target critics, no V, learned temperature (SAC v2, SB3/CleanRL)
    variant: str = "paper"
    lr: float = 1e-4                      # Adam learning rate of every network (> 0; paper Table 3: 1e-4)
    gamma: float = 0.99                   # discount factor in (0, 1] (paper Table 3: 0.99)
    alpha: float = 0.005                  # entropy temperature, fixed, or the initial value when learned (Table 3)
    learn_alpha: Optional[bool] = None    # learn the temperature (default: False for "paper", True for "modern")
    target_entropy: Optional[float] = None  # entropy target of the learned temperature (default: -action width)
    hidden: Tuple[int, ...] = (256, 256)  # hidden layer widths of every network, e.g. 64,64 (not in the paper)
    tau: float = 0.005                    # Polyak rate of the target networks in (0, 1] (not in the paper)
    batch_size: int = 256                 # mini-batch size, transitions per update (paper Table 3: 256)
    # when gradient updates happen: "step" = updates_per_step per env step (UTD; SB3, CleanRL); "episode" =
    # updates_per_episode each time an episode ends (the paper's Algorithm 1: one update per episode loop)
    update_schedule: str = "step"
    updates_per_step: float = 1.0         # gradient updates per env step, summed over parallel envs (schedule "step")
    updates_per_episode: float = 1.0      # gradient updates per finished episode (schedule "episode"; Alg. 1: 1)
    log_every: int = 100                  # write losses, alpha, entropy and Q to TensorBoard every this many updates
    random_steps: int = 5_000             # env steps of uniform random actions before the policy acts (paper: 100k)
    learning_starts: int = 1_000          # env steps before the first gradient update (not in the paper)
    # importance weights on the critic loss only, never the actor's (against PER's harm to actor-critic, LA3P)
    is_weights_critic_only: bool = False
    actor_uniform_batch: bool = False     # train the actor on its own uniform batch (LAP/PAL-style option)
    # matmul precision of updates and acting: "highest" = strict fp32 (on CPUs also the fastest fp32 choice for
    # the fused update); "high"/"medium" = torch's setting (oneDNN/cuBLAS may use TF32/bf16 kernels: fp32-level
    # results on AVX512-BF16 CPUs, tests/test_sac.py, but within ~0.5% only on CPUs with AMX); "bf16" = the fused update's hidden-to-hidden products take bfloat16 inputs
    # (rounds beyond fp32, its own learning check; ~2x their fp32 rate on CPUs with AVX512-BF16 or AMX)
    matmul_precision: str = "highest"
    # how the update gets its gradients: "fused" = written out by hand (sac_fused.py; autograd's values to
    # float rounding, tests/test_sac_fused.py; faster); "autograd" = torch autograd over sac.py's losses
    update_impl: str = "fused"
    # hand the fused update to torch.compile (inductor; needs a C++ compiler on CPU): ~25% faster updates
    # after a one-off compilation of 15-40 s per process (cached on disk after); float-rounding-level changes
    compile: bool = False

    def resolved_learn_alpha(self) -> bool:
        return (self.variant == "modern") if self.learn_alpha is None else bool(self.learn_alpha)


@dataclass
class ReplayConfig:
    capacity: int = 10_000_000            # transitions per buffer, FIFO (paper Table 3: 1e7; memory grows as it fills)
    priority_exponent: float = 0.5        # PER priority exponent: the paper's "beta" (Table 3: 0.5), PER libraries' alpha
    is_weights: bool = False              # importance-sampling weights on prioritized batches (the paper uses none)
    is_exponent: float = 0.4              # PER libraries' beta: importance-sampling exponent, annealed to 1 over the run
    priority_eps: float = 1e-6            # added to |TD| so no transition has zero priority (paper Eq. 9)
    her_strategy: str = "future"          # hindsight goal selection: future, final or episode
    her_k: int = 4                        # hindsight goals per real transition (paper: 4 single-task, 8 multi-task)
    ratio: Tuple[float, float] = (0.6, 0.4)  # dual buffer: P(batch from R)/P(batch from E), sums to 1 (paper's best)
    dual_mode: str = "choose"             # dual buffer: "choose" = whole batch from R or E (Alg. 1); "split" = r:e rows
    solver_demos: int = 0                 # seed E with this many successful scripted-solver episodes (not in the paper)
    # dual buffer: what enters E. "transitions" (Algorithm 1: "if r_t = 1 then store in E"): real reward-1
    # transitions, one per successful episode when success ends it; "episodes" (section 4.2: E "only contains
    # successful trajectories"): every real transition of a successful episode
    success_buffer: str = "transitions"
    # dual buffer, transfer: keep E's rows from the source stages when a stage starts from another run's replay
    # (off: E starts empty, so it holds only this task's successes; R is carried either way)
    carry_success_buffer: bool = True
    # transfer: start from the previous stage's replay rows (R, and E) where the chain carries replay (a sweep's
    # default); off: from its networks only, every buffer empty (results/paper_regime_critics: the carried rows
    # and a critic that leaves its bound)
    carry_rows: bool = True
    # dual buffer, "choose" mode: what a whole batch from E trains. "full" (Algorithm 1): critics, actor and
    # alpha; "critic": the critics (and V) only, no actor or alpha step (the mechanism ablation, issue 30)
    e_batches: str = "full"


@dataclass
class RunConfig:
    env_id: str = "ReachTarget-v1"        # a task (ReachTarget-v1, CloseBox-v1, CloseMicrowave-v1) or any gymnasium id
    method: str = "dual_buffer"           # replay method, a name in the registry (maniskill_dualher/methods.py)
    seed: int = 0                         # run seed (>= 0): networks, exploration, replay sampling, episode resets
    total_steps: int = 30_000             # training budget in env steps, summed over parallel envs
    max_episode_steps: Optional[int] = None  # time limit of an episode in env steps (default: the task's, 150 = Table 3)
    # end an episode on success, its last transition terminal (paper 4.1: "an episode terminated either when
    # the maximum timestep was reached or the task was completed"); off: fixed-length episodes (Fetch/HER)
    terminate_on_success: bool = True
    control_mode: Optional[str] = None    # Panda controller (default: the task's, pd_joint_delta_pos)
    sim_backend: str = "physx_cpu"        # physx_cpu (one env per process) or physx_cuda (GPU, num_envs > 1)
    reward_mode: str = "sparse"           # ManiSkill reward mode; HER methods need sparse (the paper's +1 on success)
    num_envs: int = 1                     # parallel envs (CPU simulation: 1)
    # GPU simulation (physx_cuda) only: multiply every PhysX GPU buffer size in ManiSkill's GPUMemoryConfig
    # (rigid contacts and patches, found/lost pairs, heap, temp buffer, collision stack), each rounded up to a
    # power of two, by this factor (> 0); raise it (2, 4) when PhysX prints a buffer overflow on many envs
    gpu_memory_scale: float = 1.0
    eval_every: int = 5_000               # env steps between evaluations
    eval_episodes: int = 10               # evaluation episodes, fixed seeds shared by every run, deterministic policy
    checkpoint_every: int = 5_000         # env steps between checkpoints (also at the end; resume granularity)
    # evaluate once before any training (env step 0): the prior's zero-shot score in a transfer stage
    eval_at_start: bool = False
    torch_threads: int = 1                # torch intra-op threads of this run
    device: str = "cpu"                   # torch device of networks and batches (cpu, cuda, cuda:0)
    sac: SACConfig = field(default_factory=SACConfig)
    replay: ReplayConfig = field(default_factory=ReplayConfig)

    # ----------------------------------------------------------------- helpers
    def to_dict(self) -> dict:
        """Every setting, except those added after run folders were first named while they keep their
        default: a config's dict, folder hash and identity stay what they were before the setting existed."""
        d = dataclasses.asdict(self)
        for section, key, default in ADDED_LATER:
            if (d.get(section, d) if section else d).get(key) == default:
                (d[section] if section else d).pop(key)
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)

    @classmethod
    def from_dict(cls, d: dict) -> "RunConfig":
        return _from_dict(cls, d, "")

    def validate(self) -> "RunConfig":
        s, r = self.sac, self.replay
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0, got {self.seed}")
        if self.total_steps <= 0:
            raise ConfigError(f"total_steps must be > 0, got {self.total_steps}")
        if self.num_envs < 1:
            raise ConfigError(f"num_envs must be >= 1, got {self.num_envs}")
        g = self.gpu_memory_scale
        if not isinstance(g, (int, float)) or isinstance(g, bool) or not math.isfinite(g) or g <= 0:
            raise ConfigError(f"gpu_memory_scale must be a finite number > 0, got {g!r}")
        for name, v in (("lr", s.lr), ("gamma", s.gamma), ("alpha", s.alpha), ("tau", s.tau),
                        ("updates_per_step", s.updates_per_step), ("updates_per_episode", s.updates_per_episode),
                        ("priority_exponent", r.priority_exponent), ("is_exponent", r.is_exponent),
                        ("priority_eps", r.priority_eps)):
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                raise ConfigError(f"{name} must be a finite number, got {v!r}")
        if s.target_entropy is not None and not math.isfinite(s.target_entropy):
            raise ConfigError(f"target_entropy must be a finite number, got {s.target_entropy!r}")
        for name, value, choices in (("SAC variant", s.variant, SAC_VARIANTS),
                                     ("matmul_precision", s.matmul_precision, MATMUL_PRECISIONS),
                                     ("update_impl", s.update_impl, UPDATE_IMPLS),
                                     ("HER strategy", r.her_strategy, HER_STRATEGIES),
                                     ("dual_mode", r.dual_mode, DUAL_MODES),
                                     ("update_schedule", s.update_schedule, UPDATE_SCHEDULES),
                                     ("success_buffer", r.success_buffer, SUCCESS_BUFFER_MODES),
                                     ("e_batches", r.e_batches, E_BATCHES),
                                     ("sim_backend", self.sim_backend, SIM_BACKENDS)):
            if value not in choices:
                raise ConfigError(f"unknown {name} {value!r} (choose {', '.join(choices)})")
        if r.e_batches != "full" and r.dual_mode != "choose":
            raise ConfigError(f"e_batches={r.e_batches!r} needs dual_mode 'choose' (split batches mix R and E rows)")
        if s.compile and s.update_impl != "fused":
            raise ConfigError("compile needs update_impl 'fused' (it compiles the fused update)")
        if s.compile and self.device == "cpu" and not any(shutil.which(c) for c in ("c++", "g++", "clang++")):
            raise ConfigError("compile on the CPU needs a C++ compiler (c++, g++ or clang++ on PATH); none found")
        if s.matmul_precision == "bf16" and s.update_impl != "fused":
            raise ConfigError("matmul_precision 'bf16' needs update_impl 'fused' (autograd runs fp32 matmuls)")
        if len(r.ratio) != 2 or min(r.ratio) < 0 or abs(sum(r.ratio) - 1.0) > 1e-6:
            raise ConfigError(f"ratio must be two non-negative numbers summing to 1, got {format_ratio(r.ratio)}")
        for name, v in (("lr", s.lr), ("batch_size", s.batch_size), ("capacity", r.capacity)):
            if v <= 0:
                raise ConfigError(f"{name} must be > 0, got {v}")
        if not 0 < s.gamma <= 1:
            raise ConfigError(f"gamma must be in (0, 1], got {s.gamma}")
        if r.her_k < 0:
            raise ConfigError(f"her_k must be >= 0, got {r.her_k}")
        if s.updates_per_step <= 0 or s.updates_per_episode <= 0:
            raise ConfigError(f"updates_per_step and updates_per_episode must be > 0, got "
                              f"{s.updates_per_step}, {s.updates_per_episode}")
        if not 0 < s.tau <= 1:
            raise ConfigError(f"tau must be in (0, 1], got {s.tau}")
        if s.log_every < 1:
            raise ConfigError(f"log_every must be >= 1, got {s.log_every}")
        if self.max_episode_steps is not None and self.max_episode_steps < 1:
            raise ConfigError(f"max_episode_steps must be >= 1, got {self.max_episode_steps}")
        if not s.hidden or min(s.hidden) < 1:
            raise ConfigError(f"hidden must be positive layer sizes, got {s.hidden}")
        if self.eval_every < 1 or self.eval_episodes < 1 or self.checkpoint_every < 1:
            raise ConfigError(f"eval_every, eval_episodes and checkpoint_every must be >= 1, got "
                              f"{self.eval_every}, {self.eval_episodes}, {self.checkpoint_every}")
        if self.torch_threads < 1:
            raise ConfigError(f"torch_threads must be >= 1, got {self.torch_threads}")
        if self.sim_backend == "physx_cpu" and self.num_envs != 1 and self.env_id in TASKS:
            raise ConfigError(f"num_envs={self.num_envs} needs sim_backend='physx_cuda'; "
                              "ManiSkill's CPU simulation runs one env per process")
        check_device(self.device)
        if self.sim_backend == "physx_cuda":
            check_device("cuda", what="sim_backend='physx_cuda'")
        return self


def field_docs(cls) -> dict:
    """Field name -> its one-line doc: the comment on the field's line and the comment block just above it.

    The comments in this file are the fields' documentation; ``--help`` is generated from them, so the
    two cannot drift (the same idea as tyro's field docstrings)."""
    import inspect
    import io
    import tokenize

    src = inspect.getsource(cls)
    comments = {}
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        if tok.type == tokenize.COMMENT:
            comments[tok.start[0]] = tok.string.lstrip("#").strip()
    lines = src.splitlines()
    out = {}
    for f in dataclasses.fields(cls):
        i = next((n for n, ln in enumerate(lines, 1) if ln.strip().startswith(f"{f.name}:")), None)
        if i is None:
            continue
        above, j = [], i - 1
        while j in comments and lines[j - 1].strip().startswith("#"):
            above.insert(0, comments[j])
            j -= 1
        parts = above + ([comments[i]] if i in comments else [])
        out[f.name] = " ".join(parts)
    return out


def format_ratio(ratio) -> str:
    try:
        return "/".join(f"{float(x):g}" for x in ratio)
    except (TypeError, ValueError):
        return repr(ratio)


def parse_ratio(text: str) -> Tuple[float, float]:
    """'0.6/0.4' (or '0.6,0.4') -> (0.6, 0.4); raises ConfigError naming the bad value."""
    parts = str(text).replace(",", "/").split("/")
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        raise ConfigError(f"ratio must look like 0.6/0.4, got {text!r}") from None
    if len(vals) != 2 or min(vals) < 0 or abs(sum(vals) - 1.0) > 1e-6:
        raise ConfigError(f"ratio must be two non-negative numbers summing to 1, got {text!r}")
    return vals  # type: ignore[return-value]


def _from_dict(cls, d: Any, prefix: str):
    if not isinstance(d, dict):
        raise ConfigError(f"config section {prefix or '<root>'!r} must be a mapping, got {type(d).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kwargs = {}
    for k, v in d.items():
        if k not in fields:
            raise ConfigError(f"unknown config key {prefix + k!r}")
        f = fields[k]
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default  # type: ignore
        if dataclasses.is_dataclass(default):
            kwargs[k] = _from_dict(type(default), v, prefix + k + ".")
        elif isinstance(default, tuple) and isinstance(v, (list, tuple)):
            kwargs[k] = tuple(v)
        else:
            kwargs[k] = v
    return cls(**kwargs)


# --------------------------------------------------------------------------- hyperparameters as files
YAML_SUFFIXES = (".yaml", ".yml")


def _yaml_loader():
    """PyYAML's safe loader, with YAML 1.2's floats: ``lr: 1e-3`` is a number (YAML 1.1 reads it as a string)."""
    import re
    import yaml

    class Loader(yaml.SafeLoader):
        pass
    Loader.add_implicit_resolver("tag:yaml.org,2002:float", re.compile(
        r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"), list("-+0123456789"))
    return Loader


def read_config_file(path) -> dict:
    """A (nested) settings mapping from a JSON or YAML file: ``.yaml``/``.yml`` as YAML, anything else as JSON.
    ConfigError (one line) where the file is missing, unreadable or not a mapping."""
    from pathlib import Path
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"config file not found: {p}")
    text = p.read_text()
    if p.suffix.lower() in YAML_SUFFIXES:
        import yaml
        try:
            d = yaml.load(text, Loader=_yaml_loader())  # noqa: S506 (a safe loader)
        except yaml.YAMLError as e:
            mark = getattr(e, "problem_mark", None)
            raise ConfigError(f"config file {p} is not valid YAML"
                              + (f" (line {mark.line + 1})" if mark is not None else "")) from None
    else:
        try:
            d = json.loads(text)
        except json.JSONDecodeError as e:
            raise ConfigError(f"config file {p} is not valid JSON (line {e.lineno}; a .yaml or .yml file is read "
                              f"as YAML)") from None
    if not isinstance(d, dict):
        raise ConfigError(f"config file {p} must hold a mapping of settings, got {type(d).__name__}")
    return d


def config_yaml(cfg: "RunConfig", comment: str = "") -> str:
    """``cfg`` as a YAML file (every setting, in RunConfig's order) that ``read_config_file`` and
    ``RunConfig.from_dict`` read back to ``cfg`` exactly; ``comment``: lines put first, each as a # comment."""
    import yaml
    head = "".join(f"# {line}\n" if line else "#\n" for line in comment.splitlines())
    return head + yaml.safe_dump(json.loads(json.dumps(dataclasses.asdict(cfg))), sort_keys=False,
                                 default_flow_style=None, width=1000)
