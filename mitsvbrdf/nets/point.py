"""G_p, the per-point BRDF predictor (paper Sec. 3.3): a SIREN applied to each pixel alone.

Its input at a pixel is what was observed there and what it needs to know of the patterns: the P
observations (normalised), the diffuse irradiance L^d of each pattern at that pixel (Eq. 4), and a
per-material embedding of the patterns (a linear projection of the downsampled patterns,
broadcast to every pixel). Everything is 1x1, so no spatial context reaches a pixel: shuffling
the pixels shuffles the outputs the same way.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .nafnet import normalize_images


class Sine(nn.Module):
    """A 1x1 convolution followed by sin(w0 x), with SIREN's initialisation."""

    def __init__(self, cin: int, cout: int, w0: float, first: bool):
        super().__init__()
        self.w0 = w0
        self.conv = nn.Conv2d(cin, cout, 1)
        bound = 1.0 / cin if first else math.sqrt(6.0 / cin) / w0
        nn.init.uniform_(self.conv.weight, -bound, bound)

    def forward(self, x: Tensor) -> Tensor:
        return torch.sin(self.w0 * self.conv(x))


class PointPredictor(nn.Module):
    """SIREN per pixel -> (B, 10, H, W) encoded maps in [0, 1].

    Args:
        num_images: P observations per pixel.
        cells: LCD grid of the patterns (h, w).
        hidden: width of the hidden layers; layers: number of sine layers.
        embed: size of the per-material pattern embedding.
        w0: SIREN frequency of the first layer.
    """

    def __init__(self, num_images: int = 5, cells: tuple[int, int] = (32, 32), hidden: int = 64,
                 layers: int = 3, embed: int = 16, w0: float = 30.0):
        super().__init__()
        self.config = dict(num_images=num_images, cells=tuple(cells), hidden=hidden, layers=layers,
                           embed=embed, w0=w0)
        self.embed = nn.Linear(num_images * 3 * 8 * 8, embed)
        cin = 6 * num_images + embed
        mods = [Sine(cin, hidden, w0, first=True)] + [Sine(hidden, hidden, 1.0, first=False) for _ in range(layers - 1)]
        self.body = nn.Sequential(*mods)
        self.out = nn.Conv2d(hidden, 10, 1)

    def forward(self, images: Tensor, irradiance: Tensor, patterns: Tensor) -> Tensor:
        """images, irradiance (B, P, 3, H, W) linear; patterns (B, P, 3, h, w) drive values."""
        b, p, _, h, w = images.shape
        code = self.embed(F.adaptive_avg_pool2d(patterns.flatten(1, 2), 8).flatten(1))
        # Observations relative to the diffuse irradiance carry the albedo; both are given.
        x = torch.cat([normalize_images(images).flatten(1, 2), normalize_images(irradiance).flatten(1, 2),
                       code[:, :, None, None].expand(b, code.shape[1], h, w)], 1)
        return torch.sigmoid(self.out(self.body(x)))
