"""Episodes of N parallel envs that end on their own: each env's clock, the episode rules, and assembly of the
steps into preallocated (T, N, ...) arrays.

The training loop owns one :class:`EnvEpisodes`; evaluation and demonstrations own another, with its own clock
and arrays, so that they never read or overwrite the training episodes' state. Both drive the same simulator
(an evaluation resets it, so the training loop restarts its envs afterwards): a second simulator would change
the physics state that every later training episode starts from, and PhysX's CPU simulation is not
bit-reproducible across different reset histories once contact happened (``../shared/notes/facts.md``).

Episode rules (the paper, section 4.1): an episode ends on success when ``terminate_on_success`` and the env's
``terminated`` means success (ManiSkill; other envs say so with ``terminate_on_success = True`` on the class),
on ``truncated``, or at ``max_episode_steps``. With ``terminate_on_success`` off, success is not terminal
(fixed-length episodes).
"""
from __future__ import annotations

from typing import Callable, Dict, Generator, List, NamedTuple, Optional, Sequence

import numpy as np

from .envs import BatchEnv
from .replay.base import Episode

KEYS = ("flat", "action", "reward", "next_flat", "terminated", "success")


class EnvEpisodes:
    def __init__(self, env: BatchEnv, terminate_on_success: bool):
        self.env, self.spec = env, env.spec
        self.n_envs, self.max_steps = int(self.spec.num_envs), int(self.spec.max_episode_steps)
        # envs whose ``terminated`` means success (ManiSkill; others say so with a class attribute)
        self.success_terminates = bool(self.spec.is_maniskill or getattr(env.unwrapped, "terminate_on_success", False))
        self.terminate_on_success = bool(terminate_on_success)
        # relabeled transitions are terminal where their goal is reached iff real success ends an episode
        self.goal_terminal = bool(terminate_on_success and self.success_terminates and self.spec.goal_dim)
        self.t = np.zeros(self.n_envs, np.int64)        # each env's clock: steps since its last reset
        self.length = np.zeros(self.n_envs, np.int64)   # steps assembled of each env's episode in flight
        self.pending = np.ones(self.n_envs, bool)       # envs to reset before the next step
        self.flat = np.zeros((self.n_envs, self.spec.flat_dim), np.float32)  # the envs' current observations
        self._arrays: Optional[Dict[str, np.ndarray]] = None  # (T, N, ...) per key, allocated at the first step

    # ------------------------------------------------------------------ resets
    def reset(self, idx: np.ndarray, seeds: Sequence[int]) -> None:
        """Start new episodes in envs ``idx`` with one seed each."""
        self.flat = self.flat.copy()  # the last step's observations may be the simulator's own memory
        self.flat[idx] = self.env.reset_envs(idx, seeds)
        self.t[idx] = 0
        self.length[idx] = 0
        self.pending[idx] = False

    def reset_all(self, seed: int) -> None:
        """Every env starts an episode; env i gets seed ``seed + i``."""
        self.flat = self.env.reset(seed)
        self.t[:] = 0
        self.length[:] = 0
        self.pending[:] = False

    def restart(self) -> None:
        """Forget the episodes in flight (someone else reset the simulator): every env starts anew."""
        self.length[:] = 0
        self.pending[:] = True

    # ------------------------------------------------------------------ steps
    def _env_step(self, action: np.ndarray):
        """One env step under the episode rules -> (next flat, reward, terminated, success, ended), all (N, ...)."""
        nxt, rew, term, trunc, succ = self.env.step(action)
        succ = succ if succ is not None else np.zeros(self.n_envs, bool)
        if self.success_terminates and not self.terminate_on_success:
            term = np.zeros_like(term)  # fixed-length episodes: success is not terminal
        self.t += 1
        return nxt, rew, term, succ, term | trunc | (self.t >= self.max_steps)

    def step(self, action: np.ndarray, record: Optional[np.ndarray] = None) -> np.ndarray:
        """One env step under the episode rules; stores it; returns which envs' episodes ended (N,) bool.
        ``record``: envs whose step is stored (default: all)."""
        nxt, rew, term, succ, ended = self._env_step(action)
        self._store_step(dict(flat=self.flat, action=action, reward=rew, next_flat=nxt, terminated=term,
                              success=succ), np.arange(self.n_envs) if record is None else np.flatnonzero(record))
        self.flat = nxt
        self.pending |= ended
        return ended

    def _store_step(self, step: Dict[str, np.ndarray], idx: np.ndarray) -> None:
        if self._arrays is None:
            self._arrays = {k: np.zeros((self.max_steps, self.n_envs) + np.shape(step[k])[1:], np.asarray(step[k]).dtype)
                            for k in KEYS}
        rows = self.length[idx]  # < max_steps: an episode ends at its max_steps-th step and restarts before the next
        for k in KEYS:
            self._arrays[k][rows, idx] = np.asarray(step[k])[idx]
        self.length[idx] += 1

    # ------------------------------------------------------------------ episodes out
    def pop(self, i: int) -> Episode:
        """Env i's assembled steps as a one-env Episode (T, 1, ...); its assembly starts over."""
        L = int(self.length[i])
        arr = {k: v[:L, i:i + 1].copy() for k, v in self._arrays.items()}
        self.length[i] = 0
        o, ag, dg = self.env.split(arr["flat"])
        no, nag, _ = self.env.split(arr["next_flat"])
        return Episode(obs=o, action=arr["action"], reward=arr["reward"], next_obs=no,
                       terminated=arr["terminated"], achieved_goal=ag, next_achieved_goal=nag,
                       desired_goal=dg, success=arr["success"], goal_terminal=self.goal_terminal)

    def finished(self, ended: np.ndarray) -> List[Episode]:
        return [self.pop(i) for i in np.flatnonzero(ended)]

    def cut_in_flight(self) -> List[Episode]:
        """The episodes still running (their steps so far, stored as time-limit truncations); those envs
        restart before the next step, so a checkpoint or an evaluation never holds half an episode."""
        cut = [i for i in range(self.n_envs) if not self.pending[i] and self.length[i] > 0]
        self.pending[cut] = True
        return [self.pop(i) for i in cut]

    def rollout(self, seed: int, policy: Callable[[np.ndarray], np.ndarray]) -> List[Episode]:
        """Whole episodes of all N envs from one reset (evaluation, demonstrations); each ends on its own,
        the others keep stepping (unrecorded) until the last one ends."""
        self.reset_all(seed)
        out: List[Optional[Episode]] = [None] * self.n_envs
        while any(e is None for e in out):
            open_ = np.array([e is None for e in out])
            ended = self.step(policy(self.env.policy_input(self.flat)), record=open_)
            for i in np.flatnonzero(ended & open_):
                out[i] = self.pop(i)
        self.pending[:] = True
        return out  # type: ignore[return-value]

    def scores(self, seed: int) -> Generator[np.ndarray, np.ndarray, List[Score]]:
        """``rollout`` for an evaluation: the same resets and env steps, keeping per episode only what its metrics
        read (``Score``) instead of its arrays. A generator, so that several runs' evaluations can step side by
        side (``train.evaluate_runs``): it yields the policy input (N, input) float32, a buffer rewritten at
        every step, is sent the actions (N, A), and returns one Score per env."""
        self.reset_all(seed)
        n, env = self.n_envs, self.env
        x = np.empty((n, self.spec.input_dim), np.float32)
        open_ = np.ones(n, bool)
        rewards: Optional[np.ndarray] = None  # (T, N) as the env returns them: a return sums them as pop's arrays do
        success = np.zeros(n, bool)
        last = np.zeros(n, bool)
        out: List[Optional[Score]] = [None] * n
        while True:
            action = yield env.policy_input(self.flat, out=x)
            nxt, rew, _, succ, ended = self._env_step(action)
            if rewards is None:
                rewards = np.zeros((self.max_steps, n), np.asarray(rew).dtype)
            if n == 1:  # training's case: no fancy indexing
                rewards[self.length[0], 0] = rew[0]
                success[0] |= succ[0]
                last[0] = succ[0]
                self.length[0] += 1
            else:
                idx = np.flatnonzero(open_)
                rewards[self.length[idx], idx] = rew[idx]
                success[idx] |= succ[idx]
                last[idx] = succ[idx]
                self.length[idx] += 1
            self.flat = nxt
            self.pending |= ended
            done = ended & open_
            if done.any():
                for i in np.flatnonzero(done):
                    L = int(self.length[i])
                    out[i] = Score(rewards[:L, i:i + 1].copy().sum(), bool(success[i]), bool(last[i]), L)
                open_ &= ~done
                if not open_.any():
                    break
        self.pending[:] = True
        return out  # type: ignore[return-value]


class Score(NamedTuple):
    """What an evaluation's metrics read of one episode: the sum of its rewards (numpy's sum of the episode's
    (T, 1) reward array, as ``Episode.reward.sum()``), whether it succeeded at any step, at its last step, its length."""
    ret: np.floating
    success: bool
    success_at_end: bool
    length: int
