"""The exponential moving average of a network's weights (validated and predicted with)."""
from __future__ import annotations

import torch


class EMA:
    """Exponential moving average of a model's parameters; buffers are copied.

    ``update`` uses ``max(decay, 1 / (updates + 1))`` so the first steps average uniformly.
    """

    def __init__(self, model: torch.nn.Module, decay: float):
        self.decay, self.updates = decay, 0
        self.state = {k: v.detach().clone() for k, v in model.state_dict().items()}
        self.param_names = {k for k, _ in model.named_parameters()}

    @torch.no_grad()
    def update(self, model: torch.nn.Module) -> None:
        self.updates += 1
        rate = max(self.decay, 1.0 / (self.updates + 1))
        for k, v in model.state_dict().items():
            if k in self.param_names and v.dtype.is_floating_point:
                self.state[k].lerp_(v.detach(), rate)
            else:
                self.state[k].copy_(v)
