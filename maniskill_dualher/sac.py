"""Soft actor-critic, readable top to bottom (in the spirit of CleanRL's sac_continuous_action.py).

Two variants behind one switch (``SACConfig.variant``):

* ``"paper"`` (Haarnoja et al. 2018a, the paper's Fig. 1 / Eqs. 2-8): tanh-Gaussian policy, twin soft Q
  critics, a state-value network V and its Polyak-averaged target V̄, fixed temperature α.
      y      = r + γ (1 - d) V̄(s')
      V(s)  <- E_a~π[min_i Q_i(s, a) - α log π(a|s)]
* ``"modern"`` (Haarnoja et al. 2018b, as in SB3/CleanRL): twin critics with Polyak targets, no V,
  learned α towards a target entropy of -|A|.
      y      = r + γ (1 - d) (min_i Q̄_i(s', a') - α log π(a'|s')),  a' ~ π(s')

This file is the reference: the losses, back-propagated by autograd (``SACConfig.update_impl="autograd"``).
The default, ``"fused"``, is sac_fused.py: the same update with hand-written gradients (equal to this one
to float rounding, tests/test_sac_fused.py), faster. Both: the two critics are one ensemble evaluated with
batched matmuls, all losses are summed (they touch disjoint parameters because the actor loss reads
detached critic weights), one fused Adam steps every parameter, and the Polyak update is one foreach lerp.

The update knows nothing about replay: it takes a Batch and returns one |TD| per sample,
summed over both critics (the paper's Eq. 9), for whoever wants priorities.
"""
from __future__ import annotations

import contextlib
import math
from typing import Callable, Dict, List, Optional, Tuple

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from .config import SACConfig
from .replay.base import Batch
from .sac_fused import FusedUpdate

LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0


def precision_setting(precision: str) -> str:
    """SACConfig.matmul_precision -> torch's float32 matmul setting ("bf16" is the fused update's own)."""
    return "highest" if precision == "bf16" else precision


@contextlib.contextmanager
def matmul_precision(precision: str):
    """torch.set_float32_matmul_precision for a block, restored after (it is process-global). "bf16" (the
    fused update's own bf16 products, sac_fused.py) runs every other product in strict fp32."""
    precision = precision_setting(precision)
    old = torch.get_float32_matmul_precision()
    if old == precision:
        yield
        return
    torch.set_float32_matmul_precision(precision)
    try:
        yield
    finally:
        torch.set_float32_matmul_precision(old)


def linear(in_dim: int, out_dim: int, generator: Optional[torch.Generator] = None) -> nn.Linear:
    """``nn.Linear(in_dim, out_dim)`` with its default initialisation drawn from ``generator`` (None: torch's
    global one): the same draws, in the same order, as ``nn.Linear.reset_parameters``."""
    layer = torch.nn.utils.skip_init(nn.Linear, in_dim, out_dim)
    nn.init.kaiming_uniform_(layer.weight, a=math.sqrt(5), generator=generator)
    bound = 1.0 / math.sqrt(in_dim) if in_dim > 0 else 0.0
    nn.init.uniform_(layer.bias, -bound, bound, generator=generator)
    return layer


def normal(like: torch.Tensor, generator: Optional[torch.Generator]) -> torch.Tensor:
    """Standard-normal draws of ``like``'s shape from ``generator`` (None: torch's global one)."""
    return torch.randn(like.shape, dtype=like.dtype, device=like.device, generator=generator)


def mlp(in_dim: int, hidden: Tuple[int, ...], out_dim: int, generator: Optional[torch.Generator] = None
        ) -> nn.Sequential:
    layers: List[nn.Module] = []
    d = in_dim
    for h in hidden:
        layers += [linear(d, h, generator), nn.ReLU()]
        d = h
    layers.append(linear(d, out_dim, generator))
    return nn.Sequential(*layers)


class EnsembleMLP(nn.Module):
    """E independent MLPs evaluated together with batched matmuls (one kernel per layer, not E)."""

    def __init__(self, n: int, in_dim: int, hidden: Tuple[int, ...], out_dim: int,
                 generator: Optional[torch.Generator] = None):
        super().__init__()
        dims = [in_dim, *hidden, out_dim]
        self.n = n
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for i, o in zip(dims[:-1], dims[1:]):
            bound = 1.0 / math.sqrt(i)  # nn.Linear's default initialisation, per member
            self.weights.append(nn.Parameter(torch.empty(n, i, o).uniform_(-bound, bound, generator=generator)))
            self.biases.append(nn.Parameter(torch.empty(n, 1, o).uniform_(-bound, bound, generator=generator)))

    def forward(self, x: torch.Tensor, detach: bool = False) -> torch.Tensor:
        """x (B, in) -> (E, B, out). ``detach``: gradients reach x but not the weights."""
        h = x.unsqueeze(0).expand(self.n, *x.shape)
        last = len(self.weights) - 1
        for k, (w, b) in enumerate(zip(self.weights, self.biases)):
            if detach:
                w, b = w.detach(), b.detach()
            h = torch.baddbmm(b, h, w)
            if k < last:
                h = F.relu(h)
        return h


class Actor(nn.Module):
    """Tanh-squashed Gaussian policy with actions in [-1, 1]^A. ``generator``: where its sampling noise comes
    from (None: torch's global generator); ``init_generator``: its initial weights' draws."""
    log_std_range = (LOG_STD_MIN, LOG_STD_MAX)  # the clamp of log std (read by sac_fused.py too)

    def __init__(self, obs_dim: int, act_dim: int, hidden: Tuple[int, ...],
                 generator: Optional[torch.Generator] = None, init_generator: Optional[torch.Generator] = None):
        super().__init__()
        self.generator = generator
        self.net = mlp(obs_dim, hidden, 2 * act_dim, init_generator)

    def forward(self, obs: torch.Tensor) -> Tuple[torch.Tensor, torch.Tensor]:
        """Reparameterised sample and its log-probability (with the tanh correction)."""
        mu, log_std = self.net(obs).chunk(2, dim=-1)
        log_std = torch.clamp(log_std, LOG_STD_MIN, LOG_STD_MAX)
        eps = normal(mu, self.generator)
        u = mu + log_std.exp() * eps
        a = torch.tanh(u)
        # log N(u; mu, std) - sum log(1 - tanh(u)^2), the latter in a numerically stable form
        logp = (-0.5 * eps.pow(2) - log_std - 0.5 * math.log(2 * math.pi)).sum(-1)
        logp = logp - (2.0 * (math.log(2.0) - u - F.softplus(-2.0 * u))).sum(-1)
        return a, logp

    def sample(self, obs: torch.Tensor) -> torch.Tensor:
        """The action of ``forward`` (same random draw, same value) without its log-probability: acting is per env step."""
        mu, log_std = self.net(obs).chunk(2, dim=-1)
        log_std = torch.clamp(log_std, LOG_STD_MIN, LOG_STD_MAX)
        return torch.tanh(mu + log_std.exp() * normal(mu, self.generator))

    def mean_action(self, obs: torch.Tensor) -> torch.Tensor:
        mu, _ = self.net(obs).chunk(2, dim=-1)
        return torch.tanh(mu)

    def bare_sample(self) -> Callable[[torch.Tensor], torch.Tensor]:
        """``sample`` as a plain function over this actor's weights (acting in the training loop, once per env
        step): the same ops and the same draw from ``generator`` on detached views of the parameters, so no
        module call and no autograd graph, bit for bit (tests/test_sac.py)."""
        layers = self._bare_layers()
        *hidden, (w_out, b_out) = layers
        linear, relu_, tanh, clamp, gen = F.linear, torch.relu_, torch.tanh, torch.clamp, self.generator

        def sample(x: torch.Tensor) -> torch.Tensor:
            for w, b in hidden:
                x = relu_(linear(x, w, b))
            mu, log_std = linear(x, w_out, b_out).chunk(2, dim=-1)
            log_std = clamp(log_std, LOG_STD_MIN, LOG_STD_MAX)
            return tanh(mu + log_std.exp() * normal(mu, gen))
        return sample

    def _bare_layers(self):
        layers = [(m.weight.detach(), m.bias.detach()) for m in self.net if isinstance(m, nn.Linear)]
        if len(layers) != sum(1 for m in self.net if not isinstance(m, nn.ReLU)):
            raise TypeError("the bare actor knows Linear and ReLU layers only")  # mlp() builds no others
        return layers

    def bare_mean_action(self) -> Callable[[torch.Tensor], torch.Tensor]:
        """``mean_action`` as a plain function over this actor's weights, for loops that act many times between
        updates (evaluation): the same ops (``F.linear``, ReLU, tanh of the mean half) on detached views of the
        same parameters, so no module call, no distribution and nothing recorded for autograd, bit for bit
        (tests/test_sac.py). The views share the parameters' memory: an in-place update shows through."""
        layers = self._bare_layers()
        *hidden, (w_out, b_out) = layers
        n_act = w_out.shape[0] // 2
        linear, relu_, tanh = F.linear, torch.relu_, torch.tanh

        def act(x: torch.Tensor) -> torch.Tensor:
            for w, b in hidden:
                x = relu_(linear(x, w, b))
            return tanh(linear(x, w_out, b_out)[..., :n_act])  # chunk(2)'s first half: the same view
        return act


class SAC(nn.Module):
    """The agent. ``generator`` (on ``device``): the random stream of its actions and updates;
    ``init_generator`` (CPU): its initial weights' (the networks are built on the CPU). None: torch's global
    generator. A training run passes its own (train.Trainer), so its numbers never depend on other runs."""

    def __init__(self, obs_dim: int, act_dim: int, cfg: SACConfig, device: str = "cpu",
                 generator: Optional[torch.Generator] = None, init_generator: Optional[torch.Generator] = None):
        super().__init__()
        self.cfg = cfg
        self.obs_dim, self.act_dim = obs_dim, act_dim
        self.paper = cfg.variant == "paper"
        self.generator = generator
        g = init_generator
        self.actor = Actor(obs_dim, act_dim, cfg.hidden, generator=generator, init_generator=g)
        self.q = EnsembleMLP(2, obs_dim + act_dim, cfg.hidden, 1, g)
        # every network draws its initial weights, targets too (then overwritten): the stream's order
        if self.paper:
            self.v = mlp(obs_dim, cfg.hidden, 1, g)
            self.v_target = mlp(obs_dim, cfg.hidden, 1, g)
            self.v_target.load_state_dict(self.v.state_dict())
            self._online, self._target = self.v, self.v_target
        else:
            self.q_target = EnsembleMLP(2, obs_dim + act_dim, cfg.hidden, 1, g)
            self.q_target.load_state_dict(self.q.state_dict())
            self._online, self._target = self.q, self.q_target
        self._target.requires_grad_(False)
        self.learn_alpha = cfg.resolved_learn_alpha()
        self.log_alpha = nn.Parameter(torch.tensor(math.log(cfg.alpha)), requires_grad=self.learn_alpha)
        self.target_entropy = -float(act_dim) if cfg.target_entropy is None else float(cfg.target_entropy)
        self.to(device)
        self.device = torch.device(device)
        self.optimizer = self.make_optimizer()
        self._online_params = list(self._online.parameters())
        self._target_params = list(self._target.parameters())
        self._fused = None  # sac_fused.FusedUpdate, built at the first fused update

    # ------------------------------------------------------------------ acting
    def make_optimizer(self) -> torch.optim.Optimizer:
        params = [p for p in self.parameters() if p.requires_grad]
        try:
            return torch.optim.Adam(params, lr=self.cfg.lr, fused=True)
        except (RuntimeError, TypeError):  # fused Adam unavailable on this build/device
            return torch.optim.Adam(params, lr=self.cfg.lr, foreach=True)

    @torch.no_grad()
    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        x = torch.as_tensor(obs, dtype=torch.float32, device=self.device)
        with matmul_precision(self.cfg.matmul_precision):
            a = self.actor.mean_action(x) if deterministic else self.actor.sample(x)
        return a.cpu().numpy()

    def stochastic_actor(self) -> Callable[[np.ndarray], np.ndarray]:
        """``act(x)`` (a sampled action) for float32 numpy input without its per-call wrapping, bit for bit and
        with the same draw from the agent's generator: the training loop's acting."""
        f = self._numpy_fn(self.actor.bare_sample())
        return lambda x: f(np.asarray(x, np.float32))  # act's float32 cast (a gymnasium env may give float64)

    def deterministic_actor(self) -> Callable[[np.ndarray], np.ndarray]:
        """``act(x, deterministic=True)`` for float32 numpy input without its per-call wrapping (module calls,
        no_grad), bit for bit: for evaluation loops. The precision switch is made per call only if this
        agent's precision is not torch's current one (the global setting, as ``act`` would leave it)."""
        return self._numpy_fn(self.actor.bare_mean_action())

    def _numpy_fn(self, f: Callable[[torch.Tensor], torch.Tensor]) -> Callable[[np.ndarray], np.ndarray]:
        if self.device.type == "cpu":
            g = lambda x: f(torch.from_numpy(x)).numpy()  # noqa: E731
        else:
            dev = self.device
            g = lambda x: f(torch.as_tensor(x, dtype=torch.float32, device=dev)).cpu().numpy()  # noqa: E731
        precision = self.cfg.matmul_precision
        if precision_setting(precision) == torch.get_float32_matmul_precision():
            return g

        def switched(x: np.ndarray) -> np.ndarray:
            with matmul_precision(precision):
                return g(x)
        return switched

    def policy_parameters(self) -> List[torch.Tensor]:
        """The actor's parameters and log alpha: what a critic-only batch leaves alone."""
        return list(self.actor.parameters()) + [self.log_alpha]

    @property
    def alpha(self) -> torch.Tensor:
        return self.log_alpha.exp()

    # ------------------------------------------------------------------ update
    def update(self, batch: Batch, actor_batch: Optional[Batch] = None,
               want_logs: bool = False) -> Tuple[np.ndarray, Dict[str, float]]:
        """One gradient step on every network. Returns (|TD| summed over critics per sample, logs).

        ``logs`` (losses, alpha, entropy, Q) is filled only when ``want_logs``: reading them forces a
        device sync, so the training loop asks on its own schedule (``SACConfig.log_every``)."""
        with matmul_precision(self.cfg.matmul_precision):
            if self.cfg.update_impl == "fused":
                if self._fused is None:
                    self._fused = FusedUpdate(self)
                return self._fused(batch, actor_batch, want_logs)
            return self._update(batch, actor_batch, want_logs)

    def _update(self, batch: Batch, actor_batch: Optional[Batch],
                want_logs: bool = False) -> Tuple[np.ndarray, Dict[str, float]]:
        obs, act, rew, next_obs, done = batch.obs, batch.action, batch.reward, batch.next_obs, batch.done
        alpha = self.log_alpha.exp().detach()
        w = batch.weights  # importance-sampling weights or None

        # --- policy at s (for the actor loss, and V's target in the paper variant)
        pi_obs = obs if actor_batch is None else actor_batch.obs
        a_pi, logp_pi = self.actor(pi_obs)
        q_pi = self.q(torch.cat([pi_obs, a_pi], -1), detach=True).min(0).values.squeeze(-1)
        actor_terms = alpha * logp_pi - q_pi
        if w is not None and actor_batch is None and not self.cfg.is_weights_critic_only:
            actor_loss = (w * actor_terms).mean()
        else:
            actor_loss = actor_terms.mean()

        # --- critic targets
        with torch.no_grad():
            if self.paper:
                next_v = self.v_target(next_obs).squeeze(-1)
            else:
                a_next, logp_next = self.actor(next_obs)
                q_next = self.q_target(torch.cat([next_obs, a_next], -1)).min(0).values.squeeze(-1)
                next_v = q_next - alpha * logp_next
            y = rew + self.cfg.gamma * (1.0 - done) * next_v

        q_sa = self.q(torch.cat([obs, act], -1)).squeeze(-1)  # (2, B)
        td = q_sa - y  # (2, B)
        sq = 0.5 * td.pow(2).sum(0)
        critic_loss = (w * sq).mean() if w is not None else sq.mean()

        loss = actor_loss + critic_loss
        logs: Dict[str, float] = {}
        if self.paper:
            # V(s) <- min_i Q_i(s, a~π) - α log π(a|s), using the same policy sample (Eq. 4)
            v_target = (q_pi - alpha * logp_pi).detach()
            if actor_batch is not None:  # V trains on the critic batch; draw a fresh action there
                with torch.no_grad():
                    a2, lp2 = self.actor(obs)
                    v_target = self.q(torch.cat([obs, a2], -1)).min(0).values.squeeze(-1) - alpha * lp2
            v_sq = 0.5 * (self.v(obs).squeeze(-1) - v_target).pow(2)
            v_loss = (w * v_sq).mean() if w is not None else v_sq.mean()
            loss = loss + v_loss
        if self.learn_alpha:
            alpha_loss = -(self.log_alpha * (logp_pi.detach() + self.target_entropy)).mean()
            loss = loss + alpha_loss

        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if batch.critic_only:  # Adam skips parameters without a gradient: no actor or alpha step
            for p in self.policy_parameters():
                p.grad = None
        self.optimizer.step()
        with torch.no_grad():
            torch._foreach_lerp_(self._target_params, self._online_params, self.cfg.tau)

        td_abs = td.detach().abs().sum(0).cpu().numpy()
        self._n_updates += 1
        if want_logs:  # names as in CleanRL's SAC
            logs = {
                "losses/qf_loss": float(critic_loss.detach()),
                "losses/actor_loss": float(actor_loss.detach()),
                "losses/alpha": float(alpha),
                "losses/entropy": float(-logp_pi.detach().mean()),
                "losses/qf_values": float(q_sa.detach().mean()),
            }
            if self.paper:
                logs["losses/v_loss"] = float(v_loss.detach())
            if self.learn_alpha:
                logs["losses/alpha_loss"] = float(alpha_loss.detach())
        return td_abs, logs

    _n_updates = 0

    # ------------------------------------------------------------- checkpoint
    def full_state(self) -> dict:
        return {"networks": self.state_dict(), "optimizer": self.optimizer.state_dict(), "n_updates": self._n_updates}

    def load_full_state(self, state: dict, networks_only: bool = False) -> None:
        self.load_state_dict(state["networks"])
        if not networks_only:
            self.optimizer.load_state_dict(state["optimizer"])
            self._n_updates = int(state.get("n_updates", 0))
