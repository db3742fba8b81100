"""A camera sensor's noise on rendered images, so that training sees capture-like inputs.

For linear radiance x (any shape) and a sensor whose white level corresponds to radiance
``white``: signal s = x / white; shot noise with variance ``shot * s`` (``shot`` = 1 / photons
at the white level; Gaussian approximation of Poisson), Gaussian read noise of standard
deviation ``read``, clipping to [0, 1] (saturation), and quantisation to ``bits`` bits; the
result is returned in radiance units again. Gradients pass straight through the noise, the
clipping's inside and the rounding (straight-through estimator), so rendering stays trainable.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass(frozen=True)
class SensorNoise:
    shot: float = 0.0
    read: float = 0.0
    bits: int = 0
    white: float = 1.0

    def __post_init__(self):
        if self.shot < 0 or self.read < 0 or self.bits < 0 or self.white <= 0:
            raise ValueError(f"sensor noise needs shot, read, bits >= 0 and white > 0, got {self}")

    @property
    def active(self) -> bool:
        return self.shot > 0 or self.read > 0 or self.bits > 0

    def __call__(self, images: Tensor, generator: torch.Generator | None = None) -> Tensor:
        s = images / self.white
        # noise is an additive term computed without gradient: d(out)/d(in) = 1 (straight-through)
        with torch.no_grad():
            sd = torch.sqrt(self.shot * s.clamp_min(0.0) + self.read ** 2)
            noise = sd * torch.randn(s.shape, generator=generator, device=s.device, dtype=s.dtype)
        y = s + noise
        y = y - (y - y.clamp(0.0, 1.0)).detach()  # saturation; gradient passes
        if self.bits:
            levels = 2 ** self.bits - 1
            y = y + (torch.round(y * levels) / levels - y).detach()
        return y * self.white
