"""Adam for the Gaussians with torch's fused kernel (one pass over each parameter tensor).

nerfstudio's ``AdamOptimizerConfig`` builds ``torch.optim.Adam`` with its defaults, which on a CPU
is the per-tensor loop implementation: about ten elementwise passes over the parameters, their
gradients and both moments. The fused kernel computes the same update in one pass. Measured on
this 2-core machine (stealth-ns bench train's shapes: 70k Gaussians, 6 groups, 4.1M values):
14.5 ms per step for the loop, 6.6 ms with ``foreach``, 2.3 ms fused. The optimizer state is
Adam's (``exp_avg``, ``exp_avg_sq``, a ``step`` tensor), so gsplat's densification and checkpoints
handle it as before; checkpoints of the loop implementation load into it.
"""

from __future__ import annotations

from dataclasses import dataclass

from nerfstudio.engine.optimizers import AdamOptimizerConfig


@dataclass
class FusedAdamOptimizerConfig(AdamOptimizerConfig):
    """nerfstudio's Adam config with ``fused`` passed to ``torch.optim.Adam`` (CPU and CUDA)."""

    fused: bool = True
    """torch's fused Adam kernel (the same update, one pass over each tensor; 6x faster on a CPU here)."""
