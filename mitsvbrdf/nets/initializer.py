"""The bootstrap of the acquisition (paper Sec. 3.2 "Discussion of bootstrapping"): a learned first
pattern L_0 and a single-image network that estimates the maps from I_0. Trained jointly, they
are also the single-pattern baseline ("LPL")."""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from .nafnet import NAFNet, normalize_images


class LearnedPattern(nn.Module):
    """One RGB pattern (1, 3, h, w) in [0, 1], parameterised through a sigmoid.

    ``init``: "uniform" (drive 0.9 everywhere), "grey" (0.5) or a (3, h, w) tensor in (0, 1).
    """

    def __init__(self, cells: tuple[int, int] = (32, 32), init: str | Tensor = "uniform"):
        super().__init__()
        self.config = dict(cells=tuple(cells))
        if isinstance(init, Tensor):
            start = init.clamp(1e-3, 1 - 1e-3)
        else:
            value = {"uniform": 0.9, "grey": 0.5}.get(init)
            if value is None:
                raise ValueError(f"init must be 'uniform', 'grey' or a tensor, got {init!r}")
            start = torch.full((3, *cells), value)
        self.logits = nn.Parameter(torch.log(start / (1 - start)))

    def forward(self) -> Tensor:
        return torch.sigmoid(self.logits)[None]


class Initializer(nn.Module):
    """Single-image NAFNet: I_0 (B, 3, H, W) -> (B, 10, H, W) encoded maps in [0, 1]."""

    def __init__(self, width: int = 16, enc_blocks: tuple[int, ...] = (1, 1, 1), middle_blocks: int = 1):
        super().__init__()
        self.config = dict(width=width, enc_blocks=tuple(enc_blocks), middle_blocks=middle_blocks)
        self.net = NAFNet(3, 10, width, enc_blocks, middle_blocks)

    def forward(self, i0: Tensor) -> Tensor:
        return torch.sigmoid(self.net(normalize_images(i0)))


class PatternSet(nn.Module):
    """A group of patterns (n, 3, h, w) in [0, 1] kept with a network file: fixed (the pattern
    baselines; a buffer) or ``learnable`` (the optimized-pattern baselines LPL and LPL+:
    parameterised through a sigmoid like :class:`LearnedPattern`).

    Call :meth:`set` to give the patterns their values (a learnable set keeps them inside
    [0.02, 0.98], where the sigmoid still passes gradients).
    """

    def __init__(self, count: int = 5, cells: tuple[int, int] = (32, 32), learnable: bool = False):
        super().__init__()
        self.config = dict(count=count, cells=tuple(cells))
        if learnable:  # the key stays out of config for fixed sets, so older files load unchanged
            self.config["learnable"] = True
            self.logits = nn.Parameter(torch.zeros(count, 3, *cells))
        else:
            self.register_buffer("patterns", torch.zeros(count, 3, *cells))

    @property
    def learnable(self) -> bool:
        return "logits" in self._parameters

    @torch.no_grad()
    def set(self, patterns: Tensor) -> None:
        """Give the set its values: (n, 3, h, w) drive values in [0, 1]."""
        want = (self.config["count"], 3, *self.config["cells"])
        if tuple(patterns.shape) != want:
            raise ValueError(f"patterns must be {want}, got {tuple(patterns.shape)}")
        if self.learnable:
            p = patterns.clamp(0.02, 0.98)
            self.logits.copy_(torch.log(p / (1 - p)))
        else:
            self.patterns.copy_(patterns)

    def forward(self) -> Tensor:
        return torch.sigmoid(self.logits) if self.learnable else self.patterns
