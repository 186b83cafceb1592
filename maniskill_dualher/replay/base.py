"""The contract between the training loop, the replay methods and the SAC update.

The train loop hands a finished :class:`Episode` to ``method.add_episode``; the update
draws a :class:`Batch` with ``method.sample`` and returns one |TD| per sample to
``method.update_priorities``. Nothing else crosses these lines.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Dict, Optional, Protocol

import numpy as np
import torch

# compute_reward(achieved_goal (M, G), desired_goal (M, G), info) -> reward (M,) float32 numpy
RewardFn = Callable[[np.ndarray, np.ndarray, Optional[dict]], np.ndarray]


@dataclass
class Episode:
    """One episode of N parallel envs, time-major arrays of shape (T, N, ...), all numpy.

    ``obs``/``next_obs`` hold the network input part of the observation: for goal
    environments the ``observation`` slice only (no goals); for plain environments
    the whole observation. ``achieved_goal``/``desired_goal`` (+ ``next_achieved_goal``)
    are None for plain environments.
    """
    obs: np.ndarray                 # (T, N, O)
    action: np.ndarray              # (T, N, A)
    reward: np.ndarray              # (T, N)
    next_obs: np.ndarray            # (T, N, O)
    terminated: np.ndarray          # (T, N) bool: true terminal (no bootstrap)
    achieved_goal: Optional[np.ndarray] = None       # (T, N, G) at s_t
    next_achieved_goal: Optional[np.ndarray] = None  # (T, N, G) at s_{t+1}
    desired_goal: Optional[np.ndarray] = None        # (T, N, G)
    success: Optional[np.ndarray] = None             # (T, N) bool, env's own success flag
    info: Dict[str, Any] = field(default_factory=dict)
    # True when reaching the goal ends an episode (terminate_on_success): then a relabeled transition is
    # terminal exactly where its relabeled reward says the relabeled goal was reached.
    goal_terminal: bool = False

    @property
    def is_goal(self) -> bool:
        return self.desired_goal is not None

    @property
    def length(self) -> int:
        return int(self.obs.shape[0])


@dataclass
class Batch:
    """A mini-batch as float32 torch tensors; ``obs`` already includes the goal for goal envs."""
    obs: torch.Tensor        # (B, D)
    action: torch.Tensor     # (B, A)
    reward: torch.Tensor     # (B,)
    next_obs: torch.Tensor   # (B, D)
    done: torch.Tensor       # (B,) 1.0 where terminal
    weights: Optional[torch.Tensor] = None  # (B,) importance-sampling weights, or None
    handle: Any = None       # opaque: what update_priorities needs (indices, source buffer)
    critic_only: bool = False  # train the critics (and V) only: no actor or alpha step on this batch


class ReplayMethod(Protocol):
    """What the training loop knows about a method."""

    uses_goals: bool  # True if the method needs a goal-conditioned environment (HER)

    def add_episode(self, ep: Episode) -> None: ...
    def sample(self, batch_size: int) -> Batch: ...
    def sample_uniform(self, batch_size: int) -> Batch: ...  # for the actor-on-uniform-batch option
    def update_priorities(self, batch: Batch, td_abs: np.ndarray) -> None: ...
    def set_progress(self, fraction: float) -> None: ...  # anneals the IS exponent; no-op if unused
    def state_dict(self) -> dict: ...
    def load_state_dict(self, state: dict) -> None: ...
    def stats(self) -> Dict[str, float]: ...  # logged each evaluation (sizes, share of batches from R, ...)
    def has_data(self) -> bool: ...  # whether sample() can serve a batch (updates wait until then)
    accepts_demos: bool  # whether add_demo_episode seeds a buffer (the dual buffer's E)
    def add_demo_episode(self, ep: Episode) -> None: ...  # scripted-solver episode; no-op default
    def reseed(self, rng: np.random.Generator) -> None: ...  # new sampling stream after loading another run's replay
    # (a classmethod) per buffer: (most rows one env step adds, prioritized, the method's own bytes per row), for
    # the sweep's memory plan (experiment/cost.py); replay/method.py's BufferMethod gives one uniform buffer
    def replay_layout(cls, cfg) -> Dict[str, Any]: ...
    # (optional classmethod) per buffer, rows per env step a typical run adds where far below the layout's most
    def replay_typical(cls, cfg) -> Dict[str, float]: ...


def goal_input(obs: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """Network input of a goal-conditioned policy: observation ‖ desired goal."""
    return np.concatenate([obs, goal], axis=-1)
