"""The experiment registry: every experiment the sweep can run, as data.

An experiment says which runs it makes (``kind``: single-task runs, transfer chains, or the from-scratch
control), for which methods, and its **arms**: a name plus dotted ``RunConfig`` settings, for every stage
or one (``adapt.sac.random_steps=0``; see ``overrides.py``). The grid (``grid.py``) turns an experiment
into run folders; runs that come out identical (same config, same parent) are shared between arms and
experiments, so an ablation that changes only the adaptation stage reuses the source stages, and its
unchanged arm *is* the transfer experiment's run. Every run folder records its cells (experiment, arm,
task, chain, method, ...) in ``cell.json``; the analysis groups by them and infers nothing.

Add an experiment: one ``Experiment(...)`` entry in ``EXPERIMENTS`` below; claims about it go in
``analysis/claims.py``. What it feeds (``feeds``: tables and figures by file name, ``FEEDS``) is declared
here and nowhere inferred; an ablation feeds ``ablations.csv`` and its own figure, ``fig6<letter>_<name>.png``
(``fig6_file``), by default. Every arm has a ``display`` name, the figures' legends (``arm_display``). Its
seeds in the reference preset are the ones ``results/reference`` holds (none until it is run there), and
the experiment table of ``docs/experiments.md`` is printed from here (``python -m
maniskill_dualher.experiment.registry --markdown``).

The paper's transfer chain (``PAPER_CHAIN``) is experiment data too: the order of a chain's tasks unless a
sweep says otherwise, and its last task, the paper's target. ``config.TASKS`` is the catalog of tasks; a
task added there joins no chain.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Iterable, Optional, Tuple, Union

from ..config import ConfigError
from ..methods import METHOD_SPECS

KINDS = ("single", "chain", "scratch")
PAPER_ARM = "paper"
# The paper's transfer chain (section 3.1): ReachTarget -> CloseBox -> CloseMicrowave. The protocol's
# TRANSFER_ORDER, the sweep's --task-order default, the paper's target and its chain in the tables read it.
PAPER_CHAIN: Tuple[str, ...] = ("ReachTarget-v1", "CloseBox-v1", "CloseMicrowave-v1")
PAPER_TARGET = PAPER_CHAIN[-1]


def chain_name(tasks: Iterable[str]) -> str:
    """A chain as its cells name it (``cell.json``'s, ``scores.csv``'s and the tables' ``chain`` column):
    its tasks joined by " > ", e.g. ``chain_name(PAPER_CHAIN)``; a scratch run's chain is its one task."""
    return " > ".join(tasks)

# What an experiment or arm can feed: the report's tables and figures (file names), and the panel of one.
SINGLE_TASK_CSV, TABLE4_CSV, TABLE5_CSV, ABLATIONS_CSV, BUDGET_CSV = (
    "single_task.csv", "table4_sampling_ratio.csv", "table5_multitask.csv", "ablations.csv", "budget.csv")
FIG4, FIG5, FIG5_RATIOS, FIG6, FIG7 = (
    "fig4_single_task.png", "fig5_multitask.png", "fig5_multitask.png:ratio", "fig6<letter>_<experiment>.png",
    "fig7_aggregate.png")
FEEDS = {
    SINGLE_TASK_CSV: "single-task runs: one row per task, method and metric",
    TABLE4_CSV: "the paper's Table 4: successful adaptation episodes per R/E sampling ratio, the paper's beside",
    TABLE5_CSV: "the paper's Table 5: adaptation metrics per method, transfer and from scratch, the paper's beside",
    ABLATIONS_CSV: "adaptation metrics of the ablations",
    BUDGET_CSV: "the budget curve (and fig8_budget.png): an arm's adaptation at Arm.adapt_steps_factor times "
                "the budget",
    FIG4: "the paper's Fig. 4: single-task curves per task",
    FIG5: "the paper's Fig. 5: adaptation curves on the target, transfer and from scratch",
    FIG5_RATIOS: "Fig. 5's sampling-ratio panel",
    FIG6: "one figure per ablation experiment (fig6a_e_share.png, ...: fig6_file)",
    FIG7: "rliable-style aggregates of single-task runs",
}
ABLATION_FEEDS = (ABLATIONS_CSV, FIG6)
SINGLE_FEEDS = (SINGLE_TASK_CSV, FIG4, FIG7)   # these hold single-task rows; every other feed adaptation rows


def _check_feeds(what: str, feeds: Tuple[str, ...]) -> None:
    unknown = [f for f in feeds if f not in FEEDS]
    if unknown or isinstance(feeds, str):
        raise ConfigError(f"{what} feeds {unknown[0] if unknown else feeds!r}: not a tuple of {', '.join(FEEDS)}")


@dataclass(frozen=True)
class Arm:
    name: str
    settings: Tuple[str, ...] = ()            # dotted overrides, optionally per stage (adapt., source., stageN.)
    methods: Optional[Tuple[str, ...]] = None  # only these of the experiment's methods (None: all of them)
    doc: str = ""
    max_seeds: Optional[int] = None            # only the first n of the experiment's seeds (second-tier arms)
    adapt_steps_factor: float = 1.0            # the adaptation stage's budget times this (a longer regime)
    prior_method: Optional[str] = None         # source stages trained by this method (one prior for all)
    feeds: Tuple[str, ...] = ()                # tables/figures (FEEDS) it feeds beyond its experiment's
    # the legend name in every figure (arm_display); arms of one colour share it. Empty: the paper arm's
    # "paper's settings" where it changes nothing, else the name (tests hold every registry arm to a display)
    display: str = ""
    # a declared colour (any matplotlib colour): outside the palette, so an arm added with one restyles no other;
    # empty: the next palette colour in registry order
    colour: str = ""
    # (experiment, arm, method) whose algorithm this arm's runs repeat bit for bit: a figure that draws that cell
    # draws this arm once, as it, with a note (two lines of one algorithm on different seeds read as a difference)
    identical_to: Tuple[str, str, str] = ()

    def __post_init__(self):
        _check_feeds(f"arm {self.name!r}", self.feeds)
        if self.identical_to and len(self.identical_to) != 3:
            raise ConfigError(f"arm {self.name!r}: identical_to is (experiment, arm, method), "
                              f"not {self.identical_to!r}")


@dataclass(frozen=True)
class Experiment:
    name: str
    title: str
    kind: str                                  # "single", "chain" (the transfer chain) or "scratch"
    arms: Tuple[Arm, ...] = (Arm(PAPER_ARM),)
    # "all", "transfer" (MethodSpec.transfer), "sampling_ratio" (MethodSpec.sampling_ratio) or method names
    methods: Union[str, Tuple[str, ...]] = "all"
    default: bool = False                      # run when --experiments is not given
    max_seeds: Optional[int] = None            # use only the first n of the preset's seeds (costly arms)
    paper: str = ""                            # the paper's figure/table it reproduces, if any
    # the tables and figures its rows feed (FEEDS: file names, "fig5_multitask.png:ratio" a panel); the
    # analysis selects on these, and on nothing else about the experiment. Default: an ablation's; a
    # single-task experiment feeds only SINGLE_FEEDS, a chain or scratch one only the others (checked)
    feeds: Tuple[str, ...] = ABLATION_FEEDS
    doc: str = ""                              # the question it answers, beyond its title (docs/experiments.md)

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ConfigError(f"experiment {self.name!r}: kind {self.kind!r} is not one of {', '.join(KINDS)}")
        _check_feeds(f"experiment {self.name!r}", self.feeds)
        for what, feeds in ((f"experiment {self.name!r}", self.feeds),
                            *((f"arm {self.name}:{a.name}", a.feeds) for a in self.arms)):
            fits = [f for f in FEEDS if (f in SINGLE_FEEDS) == (self.kind == "single")]
            wrong = [f for f in feeds if f not in fits]
            if wrong:
                rows = "adaptation" if self.kind == "single" else "single-task"
                raise ConfigError(f"{what} ({self.kind}) feeds {wrong[0]}, which holds {rows} rows: give its "
                                  f"feeds=(...) from {', '.join(fits)}")

    def method_names(self) -> Tuple[str, ...]:
        """The experiment's methods: those it names, or the registry's that join a group (``MethodSpec.default``)."""
        if self.methods == "all":
            return tuple(m for m, s in METHOD_SPECS.items() if s.default)
        if self.methods == "transfer":
            return tuple(m for m, s in METHOD_SPECS.items() if s.transfer and s.default)
        if self.methods == "sampling_ratio":
            return tuple(m for m, s in METHOD_SPECS.items() if s.sampling_ratio and s.default)
        return tuple(m for m in self.methods if m in METHOD_SPECS)

    def arm_methods(self, arm: Arm) -> Tuple[str, ...]:
        """The methods one arm plans, in registry order: the experiment's (``method_names``) that the arm does not
        leave out (``Arm.methods``); for an arm with a ``prior_method``, only that method and those whose
        ``MethodSpec.adopts`` names it (a method can adapt only from a prior it adopts; ``protocol.validate_chain``
        is the guard). So a method appended to the registry joins no shared-prior arm it cannot adapt in."""
        return tuple(m for m in self.method_names() if (arm.methods is None or m in arm.methods)
                     and (arm.prior_method is None or m == arm.prior_method
                          or arm.prior_method in METHOD_SPECS[m].adopts))

    def arm(self, name: str) -> Arm:
        for a in self.arms:
            if a.name == name:
                return a
        raise ConfigError(f"experiment {self.name!r} has no arm {name!r}")


# Display names shared by arms of one treatment (an adaptation arm and its from-scratch twin: one colour;
# arm_display adds ", from scratch" to a scratch experiment's arms), or by two arms of the same runs.
PAPER_DISPLAY = "paper's settings"
E_OFF = "E off (ratio 1/0)"
R_MATCHED = "R's updates matched (1/0.6 per env step)"
R_STARVED = "E off, 0.6 updates per env step"
E_CRITIC = "E's batches train the critics only"
E_OFF_MATCHED = "E off, 1/0.6 updates per env step"
X4 = "4× adaptation budget"

# Arms run both after transfer (e_mechanism) and from scratch (mechanism): one definition each.
R_STARVED_ARM = Arm("r_starved", ("adapt.replay.ratio=1/0", "adapt.sac.updates_per_step=0.6"),
                    doc="E off at 0.6 updates per env step: R's share of the paper arm's updates, no E batches",
                    display=R_STARVED)
E_CRITIC_ARM = Arm("e_critic", ("adapt.replay.e_batches=critic",),
                   doc="E's batches train the critics only: no actor or alpha step on them", display=E_CRITIC)
E_OFF_MATCHED_ARM = Arm("e_off_matched", ("adapt.replay.ratio=1/0", "adapt.sac.updates_per_step=1/0.6"),
                        doc="E off at 1/0.6 updates per env step: r_matched's update count, every update from R",
                        display=E_OFF_MATCHED)


def _ratio_arm(r: str) -> Arm:
    return Arm(r, (f"adapt.replay.ratio={r}",), doc=f"adaptation stage samples R/E at {r}", display=r)


# The paper's own regime (issue 41): Table 3's settings in the adaptation stage, on a prior that keeps the
# preset's (rl-zoo-like) source stages. What cannot be Table 3's there: the networks (variant, width, tau) are
# the prior's, so they stay the preset's (modern SAC, 64x64, tau 0.05); the temperature is fixed at 0.005
# (train.Trainer._init_from sets it whatever the prior learned). Replay capacity 10^7 in every stage, so R
# carries whole (it does not bind in the source stages: 12k env steps x 9 rows).
PAPER_REGIME_SETTINGS = (
    "replay.capacity=10000000", "replay.priority_exponent=0.5", "replay.her_k=8",
    "adapt.total_steps=3600000",          # Table 3: 120 epochs x 200 episodes x 150 steps
    "adapt.max_episode_steps=150", "adapt.terminate_on_success=true",
    "adapt.sac.lr=1e-4", "adapt.sac.gamma=0.99", "adapt.sac.alpha=0.005", "adapt.sac.learn_alpha=false",
    "adapt.sac.batch_size=256", "adapt.sac.random_steps=100000", "adapt.sac.learning_starts=100000",
    # evaluation once per paper epoch (30,000 env steps): 10 episodes of <= 150 steps, <= 5% of the env steps
    "adapt.eval_every=30000", "adapt.eval_episodes=10",
    "adapt.checkpoint_every=300000",      # resume granularity: 10 epochs (~5 min of a run on CPU B)
)

# the dual buffer, SAC+HER+PER and the two relatives (registered with default=False: only experiments naming them)
RELATIVES = ("sac_her_per", "dual_buffer", "mixed_batch", "success_bonus")

EXPERIMENTS: Dict[str, Experiment] = {e.name: e for e in (
    # ------------------------------------------------------------------ the paper's experiments
    Experiment("single", "Single-task learning", "single", default=True, paper="Fig. 4",
               feeds=(SINGLE_TASK_CSV, FIG4, FIG7)),
    Experiment("transfer", "Transfer chain, adaptation on the last task", "chain", methods="transfer",
               arms=(Arm(PAPER_ARM, feeds=(BUDGET_CSV,), doc="the paper's chain, replay carried, HER k = 8"),),
               default=True, paper="Fig. 5, Table 5", feeds=(TABLE5_CSV, FIG5),
               doc="ReachTarget -> CloseBox -> CloseMicrowave, HER k = 8, replay carried"),
    Experiment("ratios", "Dual buffer R/E sampling ratio in the adaptation stage", "chain",
               arms=tuple(_ratio_arm(r) for r in ("0.5/0.5", "0.6/0.4", "0.7/0.3")), methods="sampling_ratio",
               default=True, paper="Table 4", feeds=(TABLE4_CSV, FIG5_RATIOS)),
    Experiment("scratch", "The last task from scratch, adaptation budget and settings (control)", "scratch",
               methods="transfer", arms=(Arm(PAPER_ARM, display="from scratch"),), default=True,
               paper="not in the paper (tests section 3.1's premise)",
               feeds=(TABLE5_CSV, FIG5), doc="the control the paper never ran: does pretraining help?"),
    # ------------------------------------------------------------------ why the dual buffer loses (ablations)
    # Each changes the adaptation stage only, so every arm adapts the same prior (the source stages are shared).
    Experiment("e_share", "How much of the dual buffer's updates E takes", "chain", methods=("dual_buffer",),
               doc="and what E's own batches do", arms=(
        Arm(PAPER_ARM, doc="Algorithm 1: whole batch from E with probability 0.4"),
        Arm("e_off", ("adapt.replay.ratio=1/0",), doc="same prior, E never sampled in adaptation",
            display=E_OFF),
        Arm("split", ("adapt.replay.dual_mode=split",), doc="E's 40% inside every batch", max_seeds=8,
            display="E's 40% inside every batch"),
        Arm("r_matched", ("adapt.sac.updates_per_step=1/0.6",),
            doc="1/0.6 updates per env step: as many updates from R as SAC+HER+PER", display=R_MATCHED),
        R_STARVED_ARM,
        E_CRITIC_ARM,
        E_OFF_MATCHED_ARM,
    )),
    # The same contrasts with no prior at all: the last task from scratch (adaptation budget and settings).
    Experiment("mechanism", "Where E's cost comes from, without transfer: R's lost updates vs E's own batches",
               "scratch", methods=("dual_buffer",),
               doc="total updates vs R's share (e_off_matched); E off is SAC+HER+PER bit for bit, so the claims read "
                   "SAC+HER+PER's own from-scratch runs for it and e_off is the identity check (scratch_e_off: "
                   "exactly 0)", arms=(
        Arm("e_off", ("adapt.replay.ratio=1/0",),
            doc="E never sampled: SAC+HER+PER bit for bit (an identity check of the code; claims use "
                "SAC+HER+PER's runs)",
            display=E_OFF, identical_to=("scratch", PAPER_ARM, "sac_her_per")),
        Arm("r_matched", ("adapt.sac.updates_per_step=1/0.6",),
            doc="1/0.6 updates per env step: R gets SAC+HER+PER's updates, E's batches on top", display=R_MATCHED),
        R_STARVED_ARM,
        E_CRITIC_ARM,
        E_OFF_MATCHED_ARM,
    )),
    Experiment("matched_chain", "R's updates matched in every stage: does the dual buffer's prior catch up?",
               "chain", methods=("dual_buffer",),
               doc="does it close the gap (claims matched_prior, matched_a; its own gain: matched_gain)?", arms=(
        Arm("r_matched_all", ("sac.updates_per_step=1/0.6",),
            doc="1/0.6 updates per env step in every stage (source stages too)",
            display="R's updates matched in every stage"),
    )),
    Experiment("budget", "A longer adaptation budget: multiples of the paper arm's", "chain",
               methods="transfer", doc="does the order of the methods change with the budget?", arms=(
        Arm("x2", doc="2x the adaptation budget", adapt_steps_factor=2.0, feeds=(BUDGET_CSV,),
            display="2× adaptation budget"),
        Arm("x4", doc="4x the adaptation budget (the regime experiment's long arm)", adapt_steps_factor=4.0,
            feeds=(BUDGET_CSV,), display=X4),
        Arm("x8", doc="8x the adaptation budget", adapt_steps_factor=8.0, max_seeds=8, feeds=(BUDGET_CSV,),
            display="8× adaptation budget"),
    )),
    Experiment("shared_prior", "One prior for both methods: SAC+HER+PER's source stages", "chain",
               methods="transfer", doc="is the gap the prior or the adaptation?", arms=(
        Arm("shared", prior_method="sac_her_per",
            doc="both adapt from SAC+HER+PER's prior (networks and R); the dual buffer's E starts from R's real "
                "reward-1 rows", display="one shared prior (SAC+HER+PER's)"),
    )),
    Experiment("e_content", "What the dual buffer's E holds in adaptation", "chain", methods=("dual_buffer",), arms=(
        Arm("e_target_only", ("adapt.replay.carry_success_buffer=false",),
            doc="E starts empty in adaptation: only the target task's successes", max_seeds=8,
            display="E of the target task's successes only"),
        Arm("e_episodes", ("adapt.replay.success_buffer=episodes",),
            doc="section 4.2: every real transition of a successful episode enters E", max_seeds=8,
            display="E of whole successful episodes"),
    )),
    Experiment("warm_start", "Fine-tuning collapse: the prior acts from the first step", "chain", methods="transfer",
               arms=(
        Arm(PAPER_ARM, doc="1000 uniform-random steps first, lr 1e-3"),
        Arm("warm", ("adapt.sac.random_steps=0", "adapt.sac.learning_starts=0"),
            doc="no random steps: the prior acts and learns from step 0 on its carried replay",
            display="warm start (no random steps)"),
        Arm("warm_low_lr", ("adapt.sac.random_steps=0", "adapt.sac.learning_starts=0", "adapt.sac.lr=3e-4"),
            doc="warm, and a lower adaptation learning rate", max_seeds=8, display="warm start, lr 3e-4"),
    )),
    Experiment("her_episode", "Algorithm 1's hindsight goals: k random states of the episode", "chain",
               methods="transfer", arms=(
        Arm(PAPER_ARM, doc="HER 'future'"),
        Arm("her_episode", ("replay.her_strategy=episode",), doc="HER 'episode' in every stage (changes the prior)",
            display="HER goals from the whole episode"),
    ), max_seeds=8),
    Experiment("paper_regime", "The paper's own regime: Table 3's settings, 3.6M adaptation env steps, one shared "
               "SAC+HER+PER prior", "chain", methods="transfer",
               doc="Table 3's settings in the adaptation stage (lr 1e-4, gamma 0.99, alpha 0.005 fixed, batch 256, "
                   "replay 10^7, PER exponent 0.5, HER k = 8, 150-step episodes ending on success, 100k random "
                   "steps) on the reference preset's source stages; results/paper_regime/", arms=(
        Arm("episode", PAPER_REGIME_SETTINGS + ("adapt.sac.update_schedule=episode", "adapt.sac.updates_per_episode=1"),
            prior_method="sac_her_per",
            doc="Algorithm 1: one update per finished episode (the pilot, results/paper_regime)",
            display="Table 3's settings, one update per episode"),
        # the compiled fused update (results/paper_regime/AMENDMENT.md, second section): declared before any run;
        # ~3.5M updates a run (one per env step after the 100k random ones) make the update most of a run's time
        Arm("step", PAPER_REGIME_SETTINGS + ("adapt.sac.update_schedule=step", "adapt.sac.updates_per_step=1",
                                             "adapt.sac.compile=true"),
            prior_method="sac_her_per",
            doc="one update per env step, compiled (the confirmatory study's second schedule; ~3.5M updates a run)",
            display="Table 3's settings, one update per env step"),
        # results/paper_regime/AMENDMENT.md, third section: defined before any of its runs. The `step` arm's settings,
        # adapting the same prior (one folder: the chain still carries, this stage takes none of the rows), with R
        # and E starting empty: do the `step` arm's critics leave their bound because of the 108,000 rows carried
        # from the source tasks (results/paper_regime_critics), and does the dual buffer help a learner without them?
        Arm("step_empty", PAPER_REGIME_SETTINGS + ("adapt.sac.update_schedule=step", "adapt.sac.updates_per_step=1",
                                                   "adapt.sac.compile=true", "adapt.replay.carry_rows=false"),
            prior_method="sac_her_per",
            doc="one update per env step, compiled, the buffers starting empty: the prior's networks, none of its "
                "replay rows (Amendment 3; the follow-up of results/paper_regime_critics)",
            display="Table 3's settings, one update per env step, buffers start empty", colour="#e6ab02"),
        # the count uniform-random actions give under the same episode rules, budget and prior (its R is carried
        # and filled as in the other arms; no update is ever made, so the prior's actor is only evaluated)
        Arm("random", PAPER_REGIME_SETTINGS + ("adapt.sac.random_steps=3600000", "adapt.sac.learning_starts=3600000"),
            methods=("sac_her_per",), prior_method="sac_her_per",
            doc="uniform-random actions for all 3.6M env steps, no updates: the count chance gives (the baseline "
                "beside every count of this experiment)",
            display="uniform-random actions, no updates", colour="#252525"),
    )),
    Experiment("regime", "A longer adaptation (4x), with updates per env step or per episode", "chain",
               methods="transfer", doc="do scarce updates decide the sign?", arms=(
        Arm("long", doc="4x the adaptation budget (the same runs as budget's x4)", adapt_steps_factor=4.0,
            feeds=(BUDGET_CSV,), display=X4),
        Arm("long_episode", ("adapt.sac.update_schedule=episode",), adapt_steps_factor=4.0,
            doc="4x the adaptation budget and Algorithm 1's schedule: one update per finished episode",
            display="4× adaptation budget, one update per episode"),
    ), max_seeds=6),

    # ------------------------------------------------------------------ the dual buffer's relatives
    # Defined, with the `relatives` claims family, before any of their runs. All four methods run in one sweep on
    # one CPU kind, so from-scratch sides pair by seed and no side carries another machine's physics.
    Experiment("relatives", "The dual buffer's relatives in adaptation: mixed batches (RLPD), a success bonus in "
               "one prioritized R (DDPGfD)", "chain", methods=RELATIVES,
               doc="does per-batch mixing, or a success bonus inside one buffer, keep what E was meant to give "
                   "without starving R? each method adapts after its own chain", arms=(
        Arm(PAPER_ARM, doc="the paper's chain, replay carried, HER k = 8, as transfer's"),)),
    Experiment("relatives_scratch", "The dual buffer's relatives from scratch", "scratch", methods=RELATIVES,
               doc="the same four methods on the last task from scratch (adaptation budget and settings)", arms=(
        Arm(PAPER_ARM, display="from scratch"),)),
)}


def experiment(name: str) -> Experiment:
    if name not in EXPERIMENTS:
        raise ConfigError(f"unknown experiment {name!r} (choose from {', '.join(EXPERIMENTS)})")
    return EXPERIMENTS[name]


def feeds_of(experiment: str, arm: str) -> Tuple[str, ...]:
    """What a cell of (experiment, arm) feeds: its experiment's feeds and its arm's (none for an experiment or
    arm the registry does not have)."""
    e = EXPERIMENTS.get(experiment)
    a = next((x for x in e.arms if x.name == arm), None) if e is not None else None
    return () if a is None else tuple(dict.fromkeys(e.feeds + a.feeds))


def experiments_feeding(feed: str) -> Tuple[str, ...]:
    """The experiments (in registry order) whose own feeds name ``feed``."""
    return tuple(n for n, e in EXPERIMENTS.items() if feed in e.feeds)


def arms_feeding(feed: str) -> Tuple[Tuple[str, str], ...]:
    """(experiment, arm) of every cell that feeds ``feed``, by its experiment or by itself, in registry order."""
    return tuple((e.name, a.name) for e in EXPERIMENTS.values() for a in e.arms if feed in feeds_of(e.name, a.name))


def default_experiments() -> Tuple[str, ...]:
    return tuple(n for n, e in EXPERIMENTS.items() if e.default)


def ablation_experiments() -> Tuple[str, ...]:
    return tuple(n for n, e in EXPERIMENTS.items() if not e.default)


def is_paper_treatment(experiment: str, arm: str) -> bool:
    """An arm of a single-task or chain experiment whose settings leave every stage as the paper arm's (the
    plots draw it as the paper's settings, in one colour)."""
    e = EXPERIMENTS.get(experiment)
    return e is not None and e.kind != "scratch" and _changes_nothing(experiment, arm)


def is_scratch_control(experiment: str, arm: str) -> bool:
    """An arm of a scratch experiment whose settings change nothing: the paper treatment's from-scratch twin
    (the plots draw it in its method's colour, darkened)."""
    e = EXPERIMENTS.get(experiment)
    return e is not None and e.kind == "scratch" and _changes_nothing(experiment, arm)


def _changes_nothing(experiment: str, arm: str) -> bool:
    from . import overrides  # plain config code: no torch, no simulator
    from ..config import RunConfig
    e = EXPERIMENTS.get(experiment)
    a = next((x for x in e.arms if x.name == arm), None) if e is not None else None
    if a is None or a.adapt_steps_factor != 1.0 or a.prior_method is not None:
        return False
    base = RunConfig()
    for stage in range(3):
        if overrides.apply(base, overrides.parse_all(a.settings), stage, 3).to_dict() != base.to_dict():
            return False
    return True


def _arm(experiment: str, arm: str) -> Tuple[Optional[Experiment], Optional[Arm]]:
    e = EXPERIMENTS.get(experiment)
    return e, (next((x for x in e.arms if x.name == arm), None) if e is not None else None)


def arm_display(experiment: str, arm: str) -> str:
    """An arm's name in every legend: its ``display``; the paper's settings for an arm that changes nothing; a
    scratch experiment's arm says "from scratch". An arm the registry does not have, or one without a display
    (registered at run time), is its name with spaces."""
    e, a = _arm(experiment, arm)
    if a is not None and a.display:
        name = a.display
    elif is_paper_treatment(experiment, arm):
        return PAPER_DISPLAY
    else:
        name = arm.replace("_", " ")
    if e is not None and e.kind == "scratch" and not name.endswith("from scratch"):
        name += ", from scratch"
    return name


def colour_key(experiment: str, arm: str) -> str:
    """What an arm's colour is keyed on: its display as declared, so an adaptation arm and its from-scratch twin,
    or two arms of the same runs, share one colour."""
    _, a = _arm(experiment, arm)
    return a.display if a is not None and a.display else f"{experiment}:{arm}"


def fig6_file(experiment: str) -> str:
    """The figure of one ablation experiment: ``fig6<letter>_<name>.png``, the letter its place among the
    experiments that feed FIG6 in registry order (fixed, whichever of them a folder holds)."""
    names = experiments_feeding(FIG6)
    i = names.index(experiment) if experiment in names else len(names)
    letter = "abcdefghijklmnopqrstuvwxyz"[i] if i < 26 else f"z{i}"
    return f"fig6{letter}_{experiment}.png"


# --------------------------------------------------------------------------- the table of docs/experiments.md
def _md(text: str) -> str:
    return text.replace("|", "\\|")


def markdown_table() -> str:
    """The experiment table of ``docs/experiments.md``, from the registry (tests/test_registry.py holds the
    file to it): one row per experiment, its arms with their docs and seed caps, what it feeds."""
    lines = ["| experiment | kind | arms | question | feeds |", "|---|---|---|---|---|"]
    for e in EXPERIMENTS.values():
        kind = e.kind + (", default" if e.default else "") + (f", {e.max_seeds} seeds" if e.max_seeds else "")
        methods = e.methods if isinstance(e.methods, str) else "+".join(e.methods)
        arms = "; ".join(
            f"`{a.name}`" + (f" \"{a.display}\"" if a.display not in ("", a.name) else "")
            + (f" ({a.max_seeds} seeds)" if a.max_seeds else "")
            + (f": {a.doc}" if a.doc else (": as the preset" if not a.settings else f": {', '.join(a.settings)}"))
            + (f" [+ {', '.join(f'`{f}`' for f in a.feeds)}]" if a.feeds else "")
            for a in e.arms)
        question = e.title + (f" [{e.paper}]" if e.paper else "") + (f": {e.doc}" if e.doc else "")
        feeds = ", ".join(f"`{fig6_file(e.name) if f == FIG6 else f}`" for f in e.feeds) or "nothing"
        lines.append(f"| `{e.name}` | {kind}; methods: {methods} | {_md(arms)} | {_md(question)} | {feeds} |")
    return "\n".join(lines) + "\n"


DOCS_BEGIN = "<!-- experiments: generated from experiment/registry.py"
DOCS_END = "<!-- end of experiments -->"


def docs_with_table(text: str) -> str:
    """``text`` (docs/experiments.md) with the block between its markers replaced by ``markdown_table()``."""
    i, j = text.index(DOCS_BEGIN), text.index(DOCS_END)
    head = text[i:text.index("\n", i) + 1]
    return text[:i] + head + markdown_table() + text[j:]


def main(argv=None) -> int:
    import argparse
    from pathlib import Path
    p = argparse.ArgumentParser(prog="python -m maniskill_dualher.experiment.registry",
                                description="Print the experiment registry.")
    p.add_argument("--markdown", action="store_true",
                   help="print the experiment table of docs/experiments.md (between its generated-table markers)")
    p.add_argument("--update-docs", metavar="FILE",
                   help="write the table into FILE (docs/experiments.md) between its markers")
    a = p.parse_args(argv)
    if a.update_docs:
        path = Path(a.update_docs)
        path.write_text(docs_with_table(path.read_text()))
    elif a.markdown:
        print(markdown_table(), end="")
    else:
        for e in EXPERIMENTS.values():
            print(f"{e.name}: {e.kind}, arms {', '.join(x.name for x in e.arms)}; feeds {', '.join(e.feeds)}")
    return 0


if __name__ == "__main__":
    import sys
    sys.exit(main())
