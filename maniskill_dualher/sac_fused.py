"""The SAC update of ``sac.py`` with its gradients written out by hand: the same losses, the same random draws
and the same values to float rounding (``tests/test_sac_fused.py`` runs every variant and option against
autograd), in less time. ``SACConfig.update_impl = "fused"`` (the default) selects it.

Why it is faster on a CPU. At batch 256 and 256x256 networks an update is ~16 matrix products of
256x256x256 (the matmul floor ``bench/train_speed.py`` prints); autograd adds the rest: its graph, a
(2, 256, 1) batched product for the critics' output layer that MKL runs ~7x slower than two matrix-vector
products, masks and temporaries. Here each layer's backward is two products (weight and input gradient) and a
ReLU mask, the critics' output layer is a matrix-vector product per member, and only gradients that a loss
needs are formed: none for the critic weights inside the actor loss, none into the observations.

``SACConfig.matmul_precision = "bf16"`` (opt-in) also feeds the hidden-to-hidden products, which hold nearly
all FLOPs, with bfloat16 inputs (fp32 accumulation; oneDNN uses the AVX512-BF16/AMX units where the CPU has
them, ~2.3x the fp32 rate on the reference CPU). First and last layers, losses, the squashing, parameters
and Adam stay fp32. That rounds beyond fp32 level, so it has its own learning check
(``tests/test_sac_fused.py``, marked slow), not an equality test.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Dict, List, Optional, Tuple

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

if TYPE_CHECKING:  # pragma: no cover
    from .replay.base import Batch

_HALF_LOG_2PI = 0.5 * math.log(2 * math.pi)


class Layers:
    """One network's affine layers in the form ``y = x @ W + b`` with E members, ReLU between layers.

    Ensembles store W as (E, in, out) and b as (E, 1, out); an ``nn.Linear`` stack (actor, V) is the case E = 1
    with W = weight.T, so one forward and one backward serve every network. The backward returns gradients in
    the parameters' own layout, where the optimizer expects them."""

    def __init__(self, module: nn.Module, low_precision: bool):
        if isinstance(module, nn.Sequential):
            lin = [m for m in module if isinstance(m, nn.Linear)]
            self.weights = [m.weight for m in lin]
            self.biases = [m.bias for m in lin]
            self.linear = True
        else:  # EnsembleMLP
            self.weights = list(module.weights)
            self.biases = list(module.biases)
            self.linear = False
        self.params = [p for wb in zip(self.weights, self.biases) for p in wb]  # the order of backward's grads
        self.n = 1 if self.linear else self.weights[0].shape[0]
        last = len(self.weights) - 1
        # hidden-to-hidden layers (all but the first and the last) get bf16 inputs when asked
        self.bf16 = [low_precision and 0 < k < last for k in range(last + 1)]

    def _wb(self, k: int) -> Tuple[torch.Tensor, torch.Tensor]:
        w, b = self.weights[k].detach(), self.biases[k].detach()
        if self.linear:
            return w.t().unsqueeze(0), b.view(1, 1, -1)
        return w, b

    def forward(self, x: torch.Tensor) -> Tuple[torch.Tensor, List[Tuple[torch.Tensor, Optional[torch.Tensor]]]]:
        """x (B, in), shared by all members, or (E, B, in) -> (output (E, B, out), each layer's input in fp32
        and, for a bf16 layer, in bf16)."""
        if x.dim() == 2:
            x = x.unsqueeze(0).expand(self.n, *x.shape)
        inputs: List[Tuple[torch.Tensor, Optional[torch.Tensor]]] = []
        h = x
        last = len(self.weights) - 1
        for k in range(last + 1):
            w, b = self._wb(k)
            if self.bf16[k]:
                hb = h.to(torch.bfloat16)
                inputs.append((h, hb))
                z = _mm(hb, w.to(torch.bfloat16)).float().add_(b)
            else:
                inputs.append((h, None))
                if w.shape[-1] == 1:  # output layer of width 1: matrix-vector products, not a thin bmm
                    z = _mv(h, w[..., 0]).unsqueeze(-1).add_(b)
                else:
                    z = _addmm(b, h, w)
            h = z.relu_() if k < last else z
        return h, inputs

    def backward(self, inputs, g: torch.Tensor, grads: Optional[List[torch.Tensor]] = None,
                 input_cols: Optional[slice] = None) -> Optional[torch.Tensor]:
        """g = dL/d(output) (E, B, out). Appends the gradients of ``params`` (in that order) to ``grads`` if it
        is given; returns dL/d(input)[..., input_cols] (E, B, len) if ``input_cols`` is given, else None."""
        found: List[Tuple[torch.Tensor, torch.Tensor]] = []
        back = None
        for k in reversed(range(len(self.weights))):
            x, xb = inputs[k]
            w, _ = self._wb(k)
            if xb is not None:  # bf16 layer: both products take bf16 inputs
                gb, wb = g.to(torch.bfloat16), w.to(torch.bfloat16)
                if grads is not None:
                    found.append(self._grads(xb, gb, g))
                g = _mm(gb, wb.transpose(1, 2)).float()
            else:
                if grads is not None:
                    found.append(self._grads(x, g, g))
                if k == 0:
                    if input_cols is not None:
                        back = torch.bmm(g, w[:, input_cols, :].transpose(1, 2))
                    break
                g = g * w.transpose(1, 2) if w.shape[-1] == 1 else _mm(g, w.transpose(1, 2))
            g = torch.ops.aten.threshold_backward(g, x, 0)  # ReLU': where this layer's input is > 0
        if grads is not None:
            for gw, gbias in reversed(found):
                grads += [gw, gbias]
        return back

    def _grads(self, x: torch.Tensor, gx: torch.Tensor, g: torch.Tensor) -> Tuple[torch.Tensor, torch.Tensor]:
        """(weight, bias) gradients of a layer from its input x and the gradient g at its output (gx: g in
        x's dtype)."""
        if self.linear:  # weight (out, in): g^T x
            gw = torch.mm(gx[0].t(), x[0])
            gbias = g[0].sum(0)
        elif g.shape[-1] == 1:  # (E, in, 1): x^T g member by member
            gw = _mv(x.transpose(1, 2), g[..., 0]).unsqueeze(-1)
            gbias = g.sum(1, keepdim=True)
        else:  # (E, in, out): x^T g
            gw = torch.bmm(x.transpose(1, 2), gx)
            gbias = g.sum(1, keepdim=True)
        return (gw if gw.dtype == torch.float32 else gw.float()), gbias


def _mm(x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    return torch.mm(x[0], w[0]).unsqueeze(0) if x.shape[0] == 1 else torch.bmm(x, w)


def _addmm(b: torch.Tensor, x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    return torch.addmm(b[0], x[0], w[0]).unsqueeze(0) if x.shape[0] == 1 else torch.baddbmm(b, x, w)


def _mv(x: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """(E, B, n) @ (E, n) -> (E, B), one matrix-vector product per member."""
    return torch.stack([torch.mv(x[e], v[e]) for e in range(x.shape[0])])


class FusedUpdate:
    """``SAC._update`` with hand-written gradients; built once per agent (it holds views of its parameters).

    ``compute`` is pure: tensors in, gradients and outputs out (no ``.grad`` written, no optimizer), so that
    ``SACConfig.compile`` can hand it to ``torch.compile``; ``__call__`` applies its result."""

    def __init__(self, sac: nn.Module):  # a sac.SAC (not imported: sac.py imports this module)
        self.sac = sac
        self.log_std_range = sac.actor.log_std_range
        low = sac.cfg.matmul_precision == "bf16"
        self.actor = Layers(sac.actor.net, low)
        self.q = Layers(sac.q, low)
        if sac.paper:
            self.v = Layers(sac.v, low)
            self.v_target = Layers(sac.v_target, low)
        else:
            self.q_target = Layers(sac.q_target, low)
        # the parameters compute() returns gradients for, in its order
        self.params = self.q.params + self.actor.params + (self.v.params if sac.paper else [])
        if sac.learn_alpha:
            self.params.append(sac.log_alpha)
        self.compute = self._compute
        if sac.cfg.compile:
            import torch._inductor.config as inductor_config
            inductor_config.fallback_random = True  # the same random draws as eager (and as autograd's path)
            self.compute = torch.compile(self._compute, dynamic=False)

    def policy(self, obs: torch.Tensor, keep: bool):
        """The actor's reparameterised sample (as ``Actor.forward``, same random draw) and what its backward needs."""
        out, inputs = self.actor.forward(obs)
        mu, raw_log_std = out[0].chunk(2, dim=-1)
        log_std = torch.clamp(raw_log_std, *self.log_std_range)
        eps = torch.randn_like(mu)
        std = log_std.exp()
        u = mu + std * eps
        a = torch.tanh(u)
        logp = (-0.5 * eps.pow(2) - log_std - _HALF_LOG_2PI).sum(-1)
        logp = logp - (2.0 * (math.log(2.0) - u - F.softplus(-2.0 * u))).sum(-1)
        saved = (inputs, raw_log_std, eps, std, a) if keep else None
        return a, logp, saved

    def policy_backward(self, saved, g_a: torch.Tensor, g_logp: torch.Tensor, grads: List[torch.Tensor]) -> None:
        """Gradients of the actor from dL/da and dL/dlog pi (a = tanh(mu + std eps); dlog pi/du = 2 tanh u)."""
        inputs, raw_log_std, eps, std, a = saved
        g_logp = g_logp.unsqueeze(-1)
        g_u = g_a * (1.0 - a * a) + g_logp * (2.0 * a)
        lo, hi = self.log_std_range
        g_log_std = (g_u * std * eps - g_logp) * ((raw_log_std >= lo) & (raw_log_std <= hi))
        self.actor.backward(inputs, torch.cat([g_u, g_log_std], -1).unsqueeze(0), grads)

    def _compute(self, obs, act, rew, next_obs, done, w, pi_obs, log_alpha):
        """-> (gradients of self.params, |TD| summed over critics, the loss terms for the logs). ``pi_obs``: the
        actor's own batch, or None for the critic batch."""
        sac, cfg = self.sac, self.sac.cfg
        alpha = log_alpha.exp()
        n_critic, d_obs = obs.shape
        grads: List[torch.Tensor] = []
        separate_actor_batch = pi_obs is not None  # the actor trains on its own batch
        pi_obs = obs if pi_obs is None else pi_obs

        # --- policy at s, and the critics there (their weights are constants in the actor loss)
        n_pi = pi_obs.shape[0]
        a_pi, logp_pi, saved_pi = self.policy(pi_obs, keep=True)
        q_pi_all, q_pi_inputs = self.q.forward(torch.cat([pi_obs, a_pi], -1))
        q_pi, q_pi_arg = q_pi_all.squeeze(-1).min(0)
        actor_w = w if (w is not None and not separate_actor_batch and not cfg.is_weights_critic_only) else None

        # --- critic targets
        if sac.paper:
            next_v = self.v_target.forward(next_obs)[0][0].squeeze(-1)
        else:
            a_next, logp_next, _ = self.policy(next_obs, keep=False)
            q_next = self.q_target.forward(torch.cat([next_obs, a_next], -1))[0].min(0).values.squeeze(-1)
            next_v = q_next - alpha * logp_next
        y = rew + cfg.gamma * (1.0 - done) * next_v

        q_sa, q_sa_inputs = self.q.forward(torch.cat([obs, act], -1))
        q_sa = q_sa.squeeze(-1)  # (E, B)
        td = q_sa - y

        # --- critic loss mean_b w_b 0.5 sum_e td^2: dL/dQ_e(s, a) = w td / B
        g_q = td * (w / n_critic) if w is not None else td / n_critic
        self.q.backward(q_sa_inputs, g_q.unsqueeze(-1), grads)

        # --- actor loss mean_b w_b (alpha log pi - min_e Q_e(s, a_pi)): through the argmin member into a_pi
        coef = actor_w / n_pi if actor_w is not None else torch.full_like(logp_pi, 1.0 / n_pi)
        g_q_pi = torch.zeros_like(q_pi_all.squeeze(-1)).scatter_(0, q_pi_arg.unsqueeze(0), -coef.unsqueeze(0))
        g_a = self.q.backward(q_pi_inputs, g_q_pi.unsqueeze(-1), input_cols=slice(d_obs, None)).sum(0)
        self.policy_backward(saved_pi, g_a, alpha * coef, grads)

        sq = 0.5 * td.pow(2).sum(0)
        actor_terms = alpha * logp_pi - q_pi
        terms = {
            "losses/qf_loss": (w * sq).mean() if w is not None else sq.mean(),
            "losses/actor_loss": (actor_w * actor_terms).mean() if actor_w is not None else actor_terms.mean(),
            "losses/alpha": alpha,
            "losses/entropy": -logp_pi.mean(),
            "losses/qf_values": q_sa.mean(),
        }
        if sac.paper:  # V(s) <- min_e Q_e(s, a~pi) - alpha log pi(a|s) (Eq. 4)
            v_target = q_pi - alpha * logp_pi
            if separate_actor_batch:  # V trains on the critic batch; a fresh action there
                a2, lp2, _ = self.policy(obs, keep=False)
                v_target = self.q.forward(torch.cat([obs, a2], -1))[0].min(0).values.squeeze(-1) - alpha * lp2
            v_pred, v_inputs = self.v.forward(obs)
            v_err = v_pred[0].squeeze(-1) - v_target
            g_v = v_err * (w / n_critic) if w is not None else v_err / n_critic
            self.v.backward(v_inputs, g_v.view(1, -1, 1), grads)
            v_sq = 0.5 * v_err.pow(2)
            terms["losses/v_loss"] = (w * v_sq).mean() if w is not None else v_sq.mean()
        if sac.learn_alpha:  # alpha loss -mean(log alpha (log pi + target entropy))
            grads.append(-(logp_pi + sac.target_entropy).mean())
            terms["losses/alpha_loss"] = -(log_alpha * (logp_pi + sac.target_entropy)).mean()
        return grads, td.abs().sum(0), terms

    @torch.no_grad()
    def __call__(self, batch: "Batch", actor_batch: Optional["Batch"],
                 want_logs: bool) -> Tuple[np.ndarray, Dict[str, float]]:
        sac = self.sac
        pi_obs = None if actor_batch is None else actor_batch.obs
        grads, td_abs, terms = self.compute(batch.obs, batch.action, batch.reward, batch.next_obs, batch.done,
                                            batch.weights, pi_obs, sac.log_alpha.detach())
        for p, g in zip(self.params, grads):
            p.grad = g
        sac.optimizer.step()
        torch._foreach_lerp_(sac._target_params, sac._online_params, sac.cfg.tau)
        sac._n_updates += 1
        logs = {k: float(v) for k, v in terms.items()} if want_logs else {}
        return td_abs.cpu().numpy(), logs
