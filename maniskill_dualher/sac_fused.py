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
import torch.optim.optimizer as _optimizer

if TYPE_CHECKING:  # pragma: no cover
    from .replay.base import Batch

_HALF_LOG_2PI = 0.5 * math.log(2 * math.pi)
CPP_WRAPPER = True  # SACConfig.compile's generated code is called from C++ (False: inductor's Python wrapper)


class Layers:
    """One network's affine layers in the form ``y = x @ W + b`` with E members, ReLU between layers, for a
    pack of S agents (the same network of S runs, ``sac_pack.py``) or for one (S = 1).

    Ensembles store W as (E, in, out) and b as (E, 1, out); an ``nn.Linear`` stack (actor, V) is the case E = 1
    with W = weight.T, so one forward and one backward serve every network. A pack's members are its agents'
    members in agent order (S * E); for one agent the parameters are used in place, for a pack ``refresh``
    stacks them once per update. The backward returns gradients in the parameters' own layout (stacked over
    the pack's agents), where the optimizer expects them."""

    def __init__(self, modules, low_precision: bool):
        modules = list(modules) if isinstance(modules, (list, tuple)) else [modules]
        self.linear = isinstance(modules[0], nn.Sequential)
        self.own: List[Tuple[List[torch.Tensor], List[torch.Tensor]]] = []  # per agent: (weights, biases)
        for m in modules:
            if self.linear:
                lin = [layer for layer in m if isinstance(layer, nn.Linear)]
                self.own.append(([layer.weight for layer in lin], [layer.bias for layer in lin]))
            else:  # EnsembleMLP
                self.own.append((list(m.weights), list(m.biases)))
        self.agents = len(modules)
        self.per_agent = 1 if self.linear else self.own[0][0][0].shape[0]  # members of one agent
        self.n = self.agents * self.per_agent
        # per agent, the order of backward's grads
        self.params_of = [[p for wb in zip(ws, bs) for p in wb] for ws, bs in self.own]
        self.params = self.params_of[0]
        last = len(self.own[0][0]) - 1
        # hidden-to-hidden layers (all but the first and the last) get bf16 inputs when asked
        self.bf16 = [low_precision and 0 < k < last for k in range(last + 1)]
        # the parameters' detached views, made once: Adam steps them in place, so they always read current
        self._ws = [[w.detach() for w in o[0]] for o in self.own]
        self._bs = [[b.detach() for b in o[1]] for o in self.own]
        self._build(self._ws[0], self._bs[0]) if self.agents == 1 else self.refresh()

    def refresh(self) -> None:
        """This update's weights: the parameters themselves for one agent (nothing to do), stacked copies for a
        pack."""
        if self.agents == 1:
            return
        # linear: (S, out, in) and (S, out); ensembles: (S * E, in, out) and (S * E, 1, out)
        join = torch.stack if self.linear else torch.cat
        ws, bs = self._ws, self._bs
        self._build([join([w[k] for w in ws]) for k in range(len(ws[0]))],
                    [join([b[k] for b in bs]) for k in range(len(bs[0]))])

    def _build(self, W: List[torch.Tensor], B: List[torch.Tensor]) -> None:
        """The views of W and B that the products read, made once per set of weights rather than per product:
        per layer (weight, bias) in the (E, in, out), (E, 1, out) form, the weight's transpose (input
        gradients), for one member (n = 1) their first rows (2-D products), and for a width-1 output layer its
        weight vector per member (matrix-vector products)."""
        self.W, self.B = W, B
        self.wb = []
        for w, b in zip(W, B):
            if self.linear:  # the weight's transposed view, as one agent's products read it
                if self.agents == 1:
                    w, b = w.t().unsqueeze(0), b.view(1, 1, -1)
                else:
                    w, b = w.transpose(1, 2), b.unsqueeze(1)
            self.wb.append((w, b))
        self.wt = [w.transpose(1, 2) for w, _ in self.wb]
        one = self.n == 1
        self.w0 = [w[0] if one else None for w, _ in self.wb]
        self.b0 = [b[0] if one else None for _, b in self.wb]
        self.wt0 = [w[0] if one else None for w in self.wt]
        self.cols = [w[..., 0].unbind(0) if w.shape[-1] == 1 else None for w, _ in self.wb]

    def forward(self, x: torch.Tensor) -> Tuple[torch.Tensor, List[Tuple[torch.Tensor, Optional[torch.Tensor]]]]:
        """x (B, in), shared by all members, (S, B, in), one per agent, shared by its members, or (E, B, in)
        -> (output (E, B, out), each layer's input in fp32 and, for a bf16 layer, in bf16)."""
        if x.dim() == 3 and self.per_agent > 1 and x.shape[0] == self.agents:
            if self.agents == 1:
                x = x[0]
            else:
                x = x.unsqueeze(1).expand(self.agents, self.per_agent, *x.shape[1:]).reshape(self.n, *x.shape[1:])
        if x.dim() == 2:
            x = x.unsqueeze(0).expand(self.n, *x.shape)
        inputs: List[Tuple[torch.Tensor, Optional[torch.Tensor]]] = []
        h = x
        last = len(self.W) - 1
        for k in range(last + 1):
            w, b = self.wb[k]
            if self.bf16[k]:
                hb = h.to(torch.bfloat16)
                inputs.append((h, hb))
                z = _mm(hb, w.to(torch.bfloat16)).float().add_(b)
            else:
                inputs.append((h, None))
                if self.cols[k] is not None:  # output layer of width 1: matrix-vector products, not a thin bmm
                    z = _mv(h.unbind(0), self.cols[k]).unsqueeze(-1).add_(b)
                elif self.w0[k] is not None:
                    z = torch.addmm(self.b0[k], h[0], self.w0[k]).unsqueeze(0)
                else:
                    z = torch.baddbmm(b, h, w)
            h = z.relu_() if k < last else z
        return h, inputs

    def backward(self, inputs, g: torch.Tensor, grads: Optional[List[torch.Tensor]] = None,
                 input_cols: Optional[slice] = None, grad_rows: Optional[slice] = None,
                 input_rows: Optional[slice] = None) -> Optional[torch.Tensor]:
        """g = dL/d(output) (E, B, out). Appends the gradients of ``params`` (in that order) to ``grads`` if it
        is given, from the batch rows ``grad_rows`` (None: all); returns dL/d(input)[:, input_rows, input_cols]
        (E, rows, len) if ``input_cols`` is given, else None. Rows are independent until a weight gradient sums
        them, so two losses' batches stacked as row blocks go back through one pass."""
        found: List[Tuple[torch.Tensor, torch.Tensor]] = []
        back = None
        for k in reversed(range(len(self.W))):
            x, xb = inputs[k]
            w, _ = self.wb[k]
            if xb is not None:  # bf16 layer: both products take bf16 inputs
                gb, wb = g.to(torch.bfloat16), w.to(torch.bfloat16)
                if grads is not None:
                    found.append(self._grads(_rows(xb, grad_rows), _rows(gb, grad_rows), _rows(g, grad_rows)))
                g = _mm(gb, wb.transpose(1, 2)).float()
            else:
                if grads is not None:
                    gr = _rows(g, grad_rows)
                    found.append(self._grads(_rows(x, grad_rows), gr, gr))
                if k == 0:
                    if input_cols is not None:
                        back = torch.bmm(_rows(g, input_rows), w[:, input_cols, :].transpose(1, 2))
                    break
                if w.shape[-1] == 1:
                    g = g * self.wt[k]
                elif self.wt0[k] is not None:
                    g = torch.mm(g[0], self.wt0[k]).unsqueeze(0)
                else:
                    g = torch.bmm(g, self.wt[k])
            g = torch.ops.aten.threshold_backward(g, x, 0)  # ReLU': where this layer's input is > 0
        if grads is not None:
            for gw, gbias in reversed(found):
                grads += [gw, gbias]
        return back

    def _grads(self, x: torch.Tensor, gx: torch.Tensor, g: torch.Tensor) -> Tuple[torch.Tensor, torch.Tensor]:
        """(weight, bias) gradients of a layer from its input x and the gradient g at its output (gx: g in
        x's dtype)."""
        if self.linear and self.agents == 1:  # weight (out, in): g^T x
            gw = torch.mm(gx[0].t(), x[0])
            gbias = g[0].sum(0)
        elif self.linear:  # (S, out, in)
            gw = torch.bmm(gx.transpose(1, 2), x)
            gbias = g.sum(1)
        elif g.shape[-1] == 1:  # (E, in, 1): x^T g member by member
            gw = _mv(x.transpose(1, 2).unbind(0), g[..., 0].unbind(0)).unsqueeze(-1)
            gbias = g.sum(1, keepdim=True)
        else:  # (E, in, out): x^T g
            gw = torch.bmm(x.transpose(1, 2), gx)
            gbias = g.sum(1, keepdim=True)
        return (gw if gw.dtype == torch.float32 else gw.float()), gbias


def _rows(t: torch.Tensor, rows: Optional[slice]) -> torch.Tensor:
    """The batch rows ``rows`` of an (E, B, ...) tensor (a view); None: all of it."""
    return t if rows is None else t[:, rows]


def _mm(x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    return torch.mm(x[0], w[0]).unsqueeze(0) if x.shape[0] == 1 else torch.bmm(x, w)


def _mv(xs, vs) -> torch.Tensor:
    """E matrices (B, n) and E vectors (n,) -> (E, B), one matrix-vector product per member."""
    return torch.stack([torch.mv(x, v) for x, v in zip(xs, vs)])


def _stack(ts: List[torch.Tensor]) -> torch.Tensor:
    """``torch.stack(ts)``; for one contiguous tensor the same layout as a view, without the copy."""
    if len(ts) == 1 and ts[0].is_contiguous():
        return ts[0].unsqueeze(0)
    return torch.stack(ts)


class FusedUpdate:
    """``SAC._update`` with hand-written gradients; built once per agent, or once per pack of agents with equal
    networks and settings (``sac_pack.py``); it holds views of their parameters.

    ``compute`` is pure: tensors in, gradients and outputs out (no ``.grad`` written, no optimizer), so that
    ``SACConfig.compile`` can hand it to ``torch.compile``; ``__call__`` (one agent) and ``step_pack`` (a pack)
    apply its result. Every tensor carries the pack's agents first: (S, B, ...)."""

    def __init__(self, sacs):  # a sac.SAC or a list of them (not imported: sac.py imports this module)
        self.sacs = list(sacs) if isinstance(sacs, (list, tuple)) else [sacs]
        sac = self.sac = self.sacs[0]
        self.log_std_range = sac.actor.log_std_range
        low = sac.cfg.matmul_precision == "bf16"
        self.actor = Layers([s.actor.net for s in self.sacs], low)
        self.q = Layers([s.q for s in self.sacs], low)
        self.nets = [self.q, self.actor]
        if sac.paper:
            self.v = Layers([s.v for s in self.sacs], low)
            self.v_target = Layers([s.v_target for s in self.sacs], low)
            self.nets += [self.v, self.v_target]
        else:
            self.q_target = Layers([s.q_target for s in self.sacs], low)
            self.nets.append(self.q_target)
        # per agent, the parameters compute() returns gradients for, in its order; and how many of a stacked
        # gradient's leading rows belong to one agent (0: a scalar per agent, log alpha)
        self.params_of = [self.q.params_of[i] + self.actor.params_of[i] + (self.v.params_of[i] if sac.paper else [])
                          for i in range(len(self.sacs))]
        self.rows = [self.q.per_agent] * len(self.q.params) + [1] * len(self.actor.params) \
            + ([1] * len(self.v.params) if sac.paper else [])
        if sac.learn_alpha:
            for i, s in enumerate(self.sacs):
                self.params_of[i].append(s.log_alpha)
            self.rows.append(0)
        self.params = self.params_of[0]
        # per agent, which of its parameters a critic-only batch leaves without a step (actor, log alpha)
        self.policy_ids = [{id(p) for p in s.policy_parameters()} for s in self.sacs]
        self._plans: List[Optional[tuple]] = [None] * len(self.sacs)  # per agent, _adam_plan's cache
        # per agent and batch kind (critic-only or not): which of params_of[i] Adam steps; and _adam_lists' cache
        self._moves = [{False: [True] * len(ps), True: [id(p) not in pol for p in ps]}
                       for ps, pol in zip(self.params_of, self.policy_ids)]
        self._lists: Dict[tuple, tuple] = {}
        self.row_blocks = len(self.sacs) == 1  # _compute: one agent's passes share their layers (row blocks)
        self.compute = self._compute
        if sac.cfg.compile:  # compute draws nothing (``draws`` are made outside it): nothing random to compile
            # inductor's C++ wrapper calls the same generated kernels as its Python wrapper (bit for bit the same
            # updates: tests/test_sac_fused.py) without a Python call per kernel: at 64x64 networks that was
            # ~0.2 ms of a 1.3 ms update (bench/step_budget.py at the paper regime's step arm)
            self.compute = torch.compile(self._compute, dynamic=False, options={"cpp_wrapper": CPP_WRAPPER})

    def draw_shapes(self, n_critic: int, n_pi: int, act_dim: int, separate: bool) -> List[Tuple[int, int]]:
        """The standard-normal draws of one update, in the order one agent's update makes them (a pack draws
        them per agent from that agent's own generator and passes them to ``compute``). ``separate``: the
        actor has its own batch."""
        shapes = [(n_pi, act_dim)]                      # the policy at s (actor loss)
        if not self.sac.paper or separate:              # a' at s' (critic target), or V's target's fresh action
            shapes.append((n_critic, act_dim))
        return shapes

    def policy(self, obs: torch.Tensor, keep: bool, eps: torch.Tensor):
        """The actor's reparameterised sample (as ``Actor.forward``, same random draw) and what its backward
        needs; ``eps``: the standard-normal draw (``draws``)."""
        out, inputs = self.actor.forward(obs)
        mu, raw_log_std = out.chunk(2, dim=-1)
        log_std = torch.clamp(raw_log_std, *self.log_std_range)
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
        self.actor.backward(inputs, torch.cat([g_u, g_log_std], -1), grads)

    def _min_critic(self, q: torch.Tensor):
        """(S * 2, B, 1) critic outputs -> min over each agent's two critics: (values (S, B), member (S, B))."""
        return q.view(-1, self.q.per_agent, q.shape[1]).min(1)

    def _compute(self, obs, act, rew, next_obs, done, w, pi_obs, log_alpha, eps, want_terms: bool = True):
        """-> (gradients of self.params stacked over the pack, |TD| summed over critics (S, B), the loss terms
        (S,) for the logs). ``pi_obs``: the actor's own batch, or None for the critic batch; ``eps``: the
        update's standard-normal draws (``draw_shapes``), stacked over the pack, or None to draw them here;
        ``want_terms``: compute the loss terms (only read when a run logs: ~15 small ops an update saved
        otherwise; the gradients do not depend on them)."""
        sac, cfg = self.sac, self.sac.cfg
        for net in self.nets:
            net.refresh()
        draws = iter(eps)
        alpha = log_alpha.exp().unsqueeze(-1)  # (S, 1)
        n_critic, d_obs = obs.shape[1:]
        grads: List[torch.Tensor] = []
        separate_actor_batch = pi_obs is not None  # the actor trains on its own batch
        pi_obs = obs if pi_obs is None else pi_obs

        # --- the policy at s (actor loss) and, for the modern variant, at s' (critic target). One agent: in one
        # pass, the batches as row blocks, each row's numbers what its own pass gives (row-independent products
        # and elementwise ops; bench/golden.py holds the bits). A pack keeps the passes apart: its joined
        # tensors are S times larger and leave the cache (bench/update_overhead.py: slower at S = 8)
        n_pi = pi_obs.shape[1]
        rows = self.row_blocks
        if sac.paper or not rows:
            a_pi, logp_pi, saved_pi = self.policy(pi_obs, keep=True, eps=next(draws))
            if not sac.paper:
                a_next, logp_next, _ = self.policy(next_obs, keep=False, eps=next(draws))
        else:
            eps_pi = next(draws)
            a_all, logp_all, saved_all = self.policy(torch.cat([pi_obs, next_obs], 1), keep=True,
                                                     eps=torch.cat([eps_pi, next(draws)], 1))
            a_pi, logp_pi, a_next, logp_next = (a_all[:, :n_pi], logp_all[:, :n_pi], a_all[:, n_pi:],
                                                logp_all[:, n_pi:])
            inputs, raw_log_std, _, std, a = saved_all
            saved_pi = ([(x[:, :n_pi], None if xb is None else xb[:, :n_pi]) for x, xb in inputs],
                        raw_log_std[:, :n_pi], eps_pi, std[:, :n_pi], a_pi)
        actor_w = w if (w is not None and not separate_actor_batch and not cfg.is_weights_critic_only) else None

        # --- critic targets
        if sac.paper:
            next_v = self.v_target.forward(next_obs)[0].squeeze(-1)
        else:
            q_next = self._min_critic(self.q_target.forward(torch.cat([next_obs, a_next], -1))[0]).values
            next_v = q_next - alpha * logp_next
        y = rew + cfg.gamma * (1.0 - done) * next_v

        # --- the critics at (s, a_pi) (actor loss; their weights constants there) and at (s, a) (critic loss):
        # one agent in one pass, row blocks [pi rows; critic rows]
        per = self.q.per_agent
        if rows:
            q_all, q_inputs = self.q.forward(torch.cat([torch.cat([pi_obs, a_pi], -1), torch.cat([obs, act], -1)],
                                                       1))
            q_all = q_all.view(-1, per, n_pi + n_critic)  # (S, 2, rows)
            q_pi, q_pi_arg = q_all[:, :, :n_pi].min(1)
            q_sa = q_all[:, :, n_pi:]
        else:
            q_pi_all, q_pi_inputs = self.q.forward(torch.cat([pi_obs, a_pi], -1))
            q_pi, q_pi_arg = self._min_critic(q_pi_all)
            q_sa, q_sa_inputs = self.q.forward(torch.cat([obs, act], -1))
            q_sa = q_sa.view(-1, per, n_critic)
        td = q_sa - y.unsqueeze(1)  # (S, 2, B)

        # --- critic loss mean_b w_b 0.5 sum_e td^2: dL/dQ_e(s, a) = w td / B; actor loss mean_b w_b (alpha log pi
        # - min_e Q_e(s, a_pi)): through the argmin member into a_pi (row blocks: one backward, the critic rows'
        # weight gradients and the pi rows' input gradient)
        g_q = td * (w / n_critic).unsqueeze(1) if w is not None else td / n_critic
        coef = actor_w / n_pi if actor_w is not None else torch.full_like(logp_pi, 1.0 / n_pi)
        g_q_pi = torch.zeros(q_pi_arg.shape[0], per, n_pi).scatter_(1, q_pi_arg.unsqueeze(1), -coef.unsqueeze(1))
        if rows:
            g_a = self.q.backward(q_inputs, torch.cat([g_q_pi, g_q], 2).view(-1, n_pi + n_critic, 1), grads,
                                  input_cols=slice(d_obs, None), grad_rows=slice(n_pi, None),
                                  input_rows=slice(0, n_pi))
        else:
            self.q.backward(q_sa_inputs, g_q.view(-1, n_critic, 1), grads)
            g_a = self.q.backward(q_pi_inputs, g_q_pi.view(-1, n_pi, 1), input_cols=slice(d_obs, None))
        g_a = g_a.view(-1, per, n_pi, g_a.shape[-1]).sum(1)
        self.policy_backward(saved_pi, g_a, alpha * coef, grads)

        terms: Dict[str, torch.Tensor] = {}
        if want_terms:
            sq = 0.5 * td.pow(2).sum(1)
            actor_terms = alpha * logp_pi - q_pi
            terms = {
                "losses/qf_loss": (w * sq).mean(-1) if w is not None else sq.mean(-1),
                "losses/actor_loss": (actor_w * actor_terms).mean(-1) if actor_w is not None
                else actor_terms.mean(-1),
                "losses/alpha": alpha[:, 0],
                "losses/entropy": -logp_pi.mean(-1),
                "losses/qf_values": q_sa.reshape(len(sq), -1).mean(-1),
            }
        if sac.paper:  # V(s) <- min_e Q_e(s, a~pi) - alpha log pi (Eq. 4)
            v_target = q_pi - alpha * logp_pi
            if separate_actor_batch:  # V trains on the critic batch; a fresh action there
                a2, lp2, _ = self.policy(obs, keep=False, eps=next(draws))
                v_target = self._min_critic(self.q.forward(torch.cat([obs, a2], -1))[0]).values - alpha * lp2
            v_pred, v_inputs = self.v.forward(obs)
            v_err = v_pred.squeeze(-1) - v_target
            g_v = v_err * (w / n_critic) if w is not None else v_err / n_critic
            self.v.backward(v_inputs, g_v.unsqueeze(-1), grads)
            if want_terms:
                v_sq = 0.5 * v_err.pow(2)
                terms["losses/v_loss"] = (w * v_sq).mean(-1) if w is not None else v_sq.mean(-1)
        if sac.learn_alpha:  # alpha loss -mean(log alpha (log pi + target entropy))
            g_alpha = -(logp_pi + sac.target_entropy).mean(-1)
            grads.append(g_alpha[0] if len(g_alpha) == 1 else g_alpha)
            if want_terms:
                terms["losses/alpha_loss"] = -(log_alpha.unsqueeze(-1) * (logp_pi + sac.target_entropy)).mean(-1)
        return grads, td.abs().sum(1), terms

    def _apply(self, grads: List[torch.Tensor], critic_only: List[bool]) -> None:
        """Each agent's share of the stacked gradients into its parameters (``.grad``), then every agent's Adam
        step and Polyak average, as ``optimizer.step()`` and one ``_foreach_lerp_`` per agent would make them.

        Why not ``optimizer.step()``: its Python (hooks, ``_init_group``'s per-parameter state walk, grouping)
        cost more than the fused kernel itself at 64x64. Here each agent's optimizer state is looked up once
        (``_adam_plan``) and the whole pack's parameters go through one ``_fused_adam_`` call per distinct set
        of hyperparameters (``tests/test_sac_fused.py``: bit for bit the same as ``optimizer.step()``);
        anything the plan does not cover (first steps, hooks, other optimizer settings) takes that path."""
        n = len(self.sacs)
        if n == 1:
            per_agent = [grads]
        else:  # one split per parameter, not one slice per parameter and agent
            cols = [g.unbind(0) if rows <= 1 else g.split(rows) for g, rows in zip(grads, self.rows)]
            per_agent = [[c[i] for c in cols] for i in range(n)]
        fused: Dict[tuple, List[List[torch.Tensor]]] = {}
        polyak: Dict[float, Tuple[List[torch.Tensor], List[torch.Tensor]]] = {}
        for i, sac in enumerate(self.sacs):
            params = self.params_of[i]
            # Adam skips a parameter without a gradient: a critic-only batch moves no actor or alpha
            moves = self._moves[i][bool(critic_only[i])]
            for p, g, m in zip(params, per_agent[i], moves):
                p.grad = g if m else None
            plan = self._adam_plan(i)
            if plan is None:
                sac.optimizer.step()
            else:
                key, state, counters = plan
                counters[bool(critic_only[i])].add_(1)  # the moving parameters' steps, as _fused_adam's
                lists = fused.setdefault(key, [[], [], [], [], []])  # _foreach_add_(steps, 1) makes them
                idx, ps, ms, vs, steps = self._adam_lists(i, bool(critic_only[i]), state)
                grads_i = per_agent[i]
                lists[0] += ps
                lists[1] += [grads_i[j] for j in idx]
                lists[2] += ms
                lists[3] += vs
                lists[4] += steps
            tgt, onl = polyak.setdefault(sac.cfg.tau, ([], []))
            tgt += sac._target_params
            onl += sac._online_params
            sac._n_updates += 1
        for (lr, beta1, beta2, weight_decay, eps, maximize), (ps, gs, ms, vs, steps) in fused.items():
            torch._fused_adam_(ps, gs, ms, vs, [], steps, amsgrad=False, lr=lr, beta1=beta1, beta2=beta2,
                               weight_decay=weight_decay, eps=eps, maximize=maximize, grad_scale=None,
                               found_inf=None)
        for tau, (tgt, onl) in polyak.items():
            torch._foreach_lerp_(tgt, onl, tau)

    def _adam_lists(self, i: int, critic_only: bool, state: List[dict]):
        """(indices, parameters, exp_avg, exp_avg_sq, step) of agent i's moving parameters, in order, for
        one ``_fused_adam_`` call: built once per state list (``_adam_plan``'s cache) and batch kind, not per
        update (the tensors are stepped in place, so the lists stay valid)."""
        key = (i, critic_only)
        hit = self._lists.get(key)
        if hit is None or hit[0] is not state:
            idx = [j for j, m in enumerate(self._moves[i][critic_only]) if m]
            params = self.params_of[i]
            hit = self._lists[key] = (state, idx, [params[j] for j in idx], [state[j]["exp_avg"] for j in idx],
                                      [state[j]["exp_avg_sq"] for j in idx], [state[j]["step"] for j in idx])
        return hit[1:]

    def _adam_plan(self, i: int) -> Optional[Tuple[tuple, List[dict], Dict[bool, torch.Tensor]]]:
        """(hyperparameters, state of each of ``params_of[i]``, its step counters: ``_step_counters``) when agent
        i's optimizer step is exactly one ``_fused_adam_`` call over them, else None. The state list is cached per optimizer and state dict
        (``load_state_dict`` replaces the latter); the settings are read at every step."""
        opt = self.sacs[i].optimizer
        if (len(opt.param_groups) != 1 or opt._optimizer_step_pre_hooks or opt._optimizer_step_post_hooks
                or _optimizer._global_optimizer_pre_hooks or _optimizer._global_optimizer_post_hooks
                or getattr(opt, "grad_scale", None) is not None or getattr(opt, "found_inf", None) is not None):
            return None
        group = opt.param_groups[0]
        if (type(opt) is not torch.optim.Adam or not group.get("fused") or group["amsgrad"]
                or group["capturable"] or group["differentiable"] or group.get("decoupled_weight_decay", False)
                or isinstance(group["lr"], torch.Tensor)):
            return None
        cached = self._plans[i]
        if cached is None or cached[0] is not opt or cached[1] is not opt.state:
            self._plans[i] = None
            if len(group["params"]) != len(self.params_of[i]) \
                    or {id(p) for p in group["params"]} != {id(p) for p in self.params_of[i]}:
                return None
            state = [opt.state.get(p) for p in self.params_of[i]]
            if any(not st or not {"step", "exp_avg", "exp_avg_sq"} <= st.keys() for st in state):
                return None  # not stepped yet: optimizer.step() makes the state
            if any(st["step"].shape or st["step"].dtype != torch.float32 for st in state):
                return None
            cached = self._plans[i] = (opt, opt.state, state, self._step_counters(i, state))
        beta1, beta2 = group["betas"]
        return ((group["lr"], beta1, beta2, group["weight_decay"], group["eps"], group["maximize"]), cached[2],
                cached[3])

    def _step_counters(self, i: int, state: List[dict]) -> Dict[bool, torch.Tensor]:
        """Agent i's Adam step counters as views of one tensor, the parameters a critic-only batch moves first:
        one ``add_`` steps every moving counter (``_foreach_add_`` over 0-dim tensors takes a per-tensor slow
        path, ~20 us an update at 64x64). -> {critic_only: the counters that batch kind steps}. The values and
        the state dict's entries stay what they were (0-dim float32 tensors, saved and loaded as before)."""
        moves = self._moves[i][True]
        order = [j for j, m in enumerate(moves) if m] + [j for j, m in enumerate(moves) if not m]
        flat = torch.stack([state[j]["step"] for j in order])
        for pos, j in enumerate(order):
            state[j]["step"] = flat[pos]
        return {False: flat, True: flat[:sum(moves)]}

    def draw(self, i: int, shapes: List[Tuple[int, int]]) -> List[torch.Tensor]:
        """Agent i's standard-normal draws of these shapes, from its own generator (``SAC.generator``)."""
        sac = self.sacs[i]
        return [torch.randn(s, generator=sac.generator, device=sac.device) for s in shapes]

    def draws(self, n_critic: int, n_pi: int, separate: bool) -> List[torch.Tensor]:
        """Every agent's draws for one update, stacked over the pack: (S, n, act_dim) per shape. Made here,
        outside ``compute``, so a compiled ``compute`` draws nothing (the same numbers as drawing inside)."""
        shapes = self.draw_shapes(n_critic, n_pi, self.sac.act_dim, separate)
        per_agent = [self.draw(i, shapes) for i in range(len(self.sacs))]
        return [_stack([d[j] for d in per_agent]) for j in range(len(shapes))]

    @torch.no_grad()
    def __call__(self, batch: "Batch", actor_batch: Optional["Batch"],
                 want_logs: bool) -> Tuple[np.ndarray, Dict[str, float]]:
        """One agent's update (a pack of one)."""
        tds, logs = self.step_pack([batch], [actor_batch], want_logs)
        return tds[0], logs[0]

    @torch.no_grad()
    def step_pack(self, batches: List["Batch"], actor_batches: List[Optional["Batch"]], want_logs: bool = True
                  ) -> Tuple[List[np.ndarray], List[Dict[str, float]]]:
        """One update of every agent of the pack, agent i on ``batches[i]`` with draws from its own generator
        (a run's draws do not depend on its pack). -> (|TD| per agent, loss terms per agent ({} unless
        ``want_logs``: reading them syncs the device))."""
        stack = lambda name, bs: _stack([getattr(b, name) for b in bs])  # noqa: E731
        separate = actor_batches[0] is not None
        pi_obs = stack("obs", actor_batches) if separate else None
        w = None if batches[0].weights is None else stack("weights", batches)
        obs = stack("obs", batches)
        n_pi = obs.shape[1] if pi_obs is None else pi_obs.shape[1]
        eps = self.draws(obs.shape[1], n_pi, separate)
        log_alpha = _stack([s.log_alpha.detach() for s in self.sacs])
        grads, td_abs, terms = self.compute(obs, stack("action", batches), stack("reward", batches),
                                            stack("next_obs", batches), stack("done", batches), w, pi_obs,
                                            log_alpha, eps, want_logs)
        self._apply(grads, [b.critic_only for b in batches])
        td = td_abs.cpu().numpy()
        n = len(self.sacs)
        if not want_logs:
            return [td[i] for i in range(n)], [{} for _ in range(n)]
        values = {k: v.tolist() for k, v in terms.items()}  # one read per term, not per term and agent
        return [td[i] for i in range(n)], [{k: v[i] for k, v in values.items()} for i in range(n)]

