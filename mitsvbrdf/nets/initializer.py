"""The bootstrap of the acquisition (paper Sec. 3.2 "Discussion of bootstrapping"): a learned first
pattern L_0 and a single-image network that estimates the maps from I_0. Trained jointly, they
are also the single-pattern baseline ("LPL")."""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from .nafnet import NAFNet, diffuse_ratio, normalize_images


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
    """Single-image NAFNet: I_0 (B, 3, H, W) -> (B, 10, H, W) encoded maps in [0, 1].

    Args:
        width, enc_blocks, middle_blocks: the NAFNet's (default 16, (1, 1, 1), 1).
        diffuse_ratio: besides I_0, take I_0 over L_0's flat-Lambertian irradiance L_0^d
            (:func:`~mitsvbrdf.nets.nafnet.diffuse_ratio`, as G_sc's option of the same name), so
            the shading a normal adds is not buried under the position-dependent ramp of L_0's
            light; the forward pass then needs ``irradiance`` (B or 1, 3, H, W). Default False
            (the paper's input, and every export before the option). Not in the paper.
    """

    #: the convolution that takes the inputs (:func:`~mitsvbrdf.nets.nafnet.with_diffuse_ratio`)
    RATIO_INTRO = "net.encoder.intro.weight"

    def __init__(self, width: int = 16, enc_blocks: tuple[int, ...] = (1, 1, 1), middle_blocks: int = 1,
                 diffuse_ratio: bool = False):
        super().__init__()
        self.config = dict(width=width, enc_blocks=tuple(enc_blocks), middle_blocks=middle_blocks)
        if diffuse_ratio:  # kept out of config otherwise, so older files load unchanged
            self.config["diffuse_ratio"] = True
        self.diffuse_ratio = bool(diffuse_ratio)
        self.net = NAFNet(6 if diffuse_ratio else 3, 10, width, enc_blocks, middle_blocks)

    def forward(self, i0: Tensor, irradiance: Tensor | None = None) -> Tensor:
        x = normalize_images(i0)
        if self.diffuse_ratio:
            if irradiance is None:
                raise ValueError("this Initializer was built with diffuse_ratio=True and needs L_0's irradiance L^d")
            x = torch.cat([x, diffuse_ratio(i0, irradiance.expand_as(i0))], 1)
        return torch.sigmoid(self.net(x))


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
