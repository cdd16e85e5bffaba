"""An exponential moving average of a network's weights, for the weights a run saves.

Why: on the CPU the generator is fine-tuned at a learning rate high enough that consecutive
checkpoints 250 steps apart differ by more than a whole run gains. Mid-run, generator v8a
scored a median input-depth AbsRel of 0.150 at step 2250 and 0.200 at step 2500
(BENCHMARKS, "Generator v8"). Which checkpoint the schedule happens to end on is then a
lottery; an average over the last few hundred steps is not.

The average starts as a copy of the weights and moves toward them after each optimiser step:
``avg = d·avg + (1 - d)·w`` with ``d = min(decay, (1 + n) / (10 + n))`` after ``n`` updates,
so a fresh average follows the weights quickly instead of remembering its starting copy for
``1 / (1 - decay)`` steps: it spans about the last tenth of its updates until the decay takes
over (0.998, a span of 500 steps, after ~4,500 updates). Every floating-point tensor of the state dict is averaged
(parameters and float buffers); integer buffers are copied.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor, nn


class WeightAverage:
    """EMA of ``model``'s state dict, kept in float32 on the model's device.

    >>> avg = WeightAverage(model, decay=0.998)
    >>> opt.step(); avg.update(model)
    >>> save(avg.state_dict())            # the averaged weights
    >>> resume: avg.load_state_dict(saved, updates=n)
    """

    def __init__(self, model: nn.Module, decay: float) -> None:
        if not 0 < decay < 1:
            raise ValueError(f"the weight average's decay must be in (0, 1), got {decay}")
        self.decay = float(decay)
        self.updates = 0
        self._avg: dict[str, Tensor] = {
            k: v.detach().clone().float() if v.is_floating_point() else v.detach().clone()
            for k, v in model.state_dict().items()
        }

    def current_decay(self) -> float:
        """The decay of the next update: warmed up over the first updates (see the module)."""
        return min(self.decay, (1 + self.updates) / (10 + self.updates))

    @torch.no_grad()
    def update(self, model: nn.Module) -> None:
        """Move the average toward ``model``'s weights (call after each optimiser step)."""
        d = self.current_decay()
        for k, v in model.state_dict().items():
            avg = self._avg[k]
            if avg.is_floating_point():
                avg.mul_(d).add_(v.detach().float(), alpha=1 - d)
            else:
                avg.copy_(v)
        self.updates += 1

    def state_dict(self, like: nn.Module | None = None) -> dict[str, Tensor]:
        """The averaged weights; with ``like``, in that model's dtypes (to load or save as it)."""
        if like is None:
            return dict(self._avg)
        ref = like.state_dict()
        return {k: v.to(ref[k].dtype) for k, v in self._avg.items()}

    def load_state_dict(self, weights: Mapping[str, Tensor], updates: int) -> None:
        """Restore a saved average (a resumed run) and its update count."""
        missing = sorted(set(self._avg) - set(weights))
        extra = sorted(set(weights) - set(self._avg))
        if missing or extra:
            raise KeyError(
                f"the saved weight average does not fit: missing {missing}, extra {extra}"
            )
        for k, v in weights.items():
            self._avg[k].copy_(v.to(self._avg[k].dtype))
        self.updates = int(updates)
