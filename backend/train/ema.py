"""Exponential moving average of the trained weights (kept in float32 beside the model)."""

from __future__ import annotations

import contextlib

import torch


class EMA:
    """shadow ← d·shadow + (1 − d)·param after every optimiser step, with d = min(decay, (1 + n)/(10 + n)) at
    update n (so early updates follow the weights instead of freezing the initialisation)."""

    def __init__(self, params: dict, decay: float):
        self.decay = decay
        self.updates = 0
        self.shadow = {k: p.detach().float().clone() for k, p in params.items()}

    def rate(self) -> float:
        return min(self.decay, (1 + self.updates) / (10 + self.updates))

    @torch.no_grad()
    def update(self, params: dict) -> None:
        d = self.rate()
        for k, p in params.items():
            self.shadow[k].lerp_(p.detach().float(), 1.0 - d)
        self.updates += 1

    @contextlib.contextmanager
    @torch.no_grad()
    def applied(self, params: dict):
        """Temporarily copy the EMA weights into ``params`` (for samples), restoring the raw weights after."""
        saved = {k: p.detach().clone() for k, p in params.items()}
        for k, p in params.items():
            p.copy_(self.shadow[k].to(p.dtype))
        try:
            yield
        finally:
            for k, p in params.items():
                p.copy_(saved[k])
