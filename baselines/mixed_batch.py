"""Mixed batches (RLPD's "symmetric sampling", Ball et al., ICML 2023) on the dual buffer's two buffers.

The dual buffer of Algorithm 1 draws *whole* batches from E with probability e, so R (every real and hindsight
transition) is sampled in only a share r of the updates. Here every batch takes round(B r) rows from R
(prioritized, as the dual buffer's R) and the rest from E (uniform, real reward-1 transitions, as its E), so R is
sampled in every update and E's successes are in every batch. HER, PER and E's contents are the dual buffer's;
while E is empty the batch is all R. Its ratio is the dual buffer's setting (``replay.ratio``, e.g. 0.6/0.4 for
154 + 102 of 256 rows). RLPD's second ingredient, a LayerNorm critic, is not a setting of this learner and is
not part of this method.

It is the dual buffer with ``dual_mode`` fixed to "split", as a method of its own so that it can be compared with
the dual buffer in one experiment (the ``relatives`` family) and adopt SAC+HER+PER's prior as the dual buffer does.
"""
from __future__ import annotations

from maniskill_dualher.dual_buffer import DualBufferReplay


class MixedBatchReplay(DualBufferReplay):
    def __init__(self, cfg, spec, rng, device="cpu"):
        super().__init__(cfg, spec, rng, device)
        self.mode = "split"   # every batch mixes R and E by the ratio, whatever replay.dual_mode says
