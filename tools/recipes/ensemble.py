"""Temporal ensembling of action chunks (ACT's scheme), shared by the state and the visual
policies of ``train_policy.py``.

Each step's predicted chunk (the targets of the coming ``chunk`` steps) is added to a running
weighted sum per env; the prediction made ``j`` steps ahead of the step it is for weighs
``exp(-decay * j)``. The step's action is the weighted mean for it, less the anchor (what a
delta-joint controller's action is relative to). ``reset()`` forgets every env's predictions.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn


class TemporalEnsemble(nn.Module):
    """Running weighted sums of each env's predictions for its next ``chunk`` steps."""

    def __init__(self, chunk: int, act_dim: int, decay: float):
        super().__init__()
        self.chunk, self.act_dim = chunk, act_dim
        weights = np.exp(-decay * np.arange(chunk))
        self.register_buffer("weights", torch.as_tensor(weights, dtype=torch.float32))
        self.pending = torch.zeros(0, chunk, act_dim)
        self.pending_weight = torch.zeros(0, chunk)

    @torch.jit.export
    def reset(self) -> None:
        """Forget every env's pending predictions (an episode starts)."""
        self.pending = torch.zeros(0, self.chunk, self.act_dim)
        self.pending_weight = torch.zeros(0, self.chunk)

    def forward(self, chunk: torch.Tensor, anchor: torch.Tensor) -> torch.Tensor:
        """``chunk`` ``(B, chunk, A)`` targets, ``anchor`` ``(B, A)`` -> this step's action."""
        batch = chunk.shape[0]
        if self.pending.shape[0] != batch:  # the first step after reset(), or a new batch
            self.pending = torch.zeros_like(chunk)
            self.pending_weight = torch.zeros(batch, self.chunk, device=chunk.device)
        pending = self.pending + chunk * self.weights[None, :, None]
        weight = self.pending_weight + self.weights[None, :]
        action = pending[:, 0] / weight[:, :1] - anchor
        self.pending = torch.cat([pending[:, 1:], torch.zeros_like(pending[:, :1])], 1)
        self.pending_weight = torch.cat([weight[:, 1:], torch.zeros_like(weight[:, :1])], 1)
        return action
