"""A compact NAFNet U-Net: encoder levels of NAFBlocks with stride-2 downsampling, a middle
stack, and a decoder with pixel-shuffle upsampling and additive skips. Input H and W must be
multiples of 2^levels."""

from __future__ import annotations

from typing import Sequence

import torch
from torch import Tensor, nn

from .blocks import NAFBlock


def _stack(c: int, n: int) -> nn.Sequential:
    return nn.Sequential(*[NAFBlock(c) for _ in range(n)])


class NAFEncoder(nn.Module):
    """(B, in_ch, H, W) -> (bottom features (B, width 2^L, H / 2^L, W / 2^L), skips finest first)."""

    def __init__(self, in_ch: int, width: int, blocks: Sequence[int] = (1, 1, 1)):
        super().__init__()
        self.intro = nn.Conv2d(in_ch, width, 3, padding=1)
        self.levels = nn.ModuleList()
        self.downs = nn.ModuleList()
        c = width
        for n in blocks:
            self.levels.append(_stack(c, n))
            self.downs.append(nn.Conv2d(c, 2 * c, 2, stride=2))
            c *= 2
        self.out_channels = c
        self.factor = 2 ** len(blocks)

    def forward(self, x: Tensor) -> tuple[Tensor, list[Tensor]]:
        if x.shape[-1] % self.factor or x.shape[-2] % self.factor:
            raise ValueError(f"input of {x.shape[-2]}x{x.shape[-1]} px: H and W must be multiples of {self.factor}")
        x = self.intro(x)
        skips = []
        for level, down in zip(self.levels, self.downs):
            x = level(x)
            skips.append(x)
            x = down(x)
        return x, skips


class NAFDecoder(nn.Module):
    """(bottom features, skips) -> (B, out_ch, H, W); mirrors :class:`NAFEncoder`."""

    def __init__(self, out_ch: int, width: int, blocks: Sequence[int] = (1, 1, 1)):
        super().__init__()
        c = width * 2 ** len(blocks)
        self.ups = nn.ModuleList()
        self.levels = nn.ModuleList()
        for n in reversed(blocks):
            self.ups.append(nn.Sequential(nn.Conv2d(c, 2 * c, 1, bias=False), nn.PixelShuffle(2)))
            c //= 2
            self.levels.append(_stack(c, n))
        self.ending = nn.Conv2d(width, out_ch, 3, padding=1)

    def forward(self, x: Tensor, skips: list[Tensor]) -> Tensor:
        for up, level, skip in zip(self.ups, self.levels, reversed(skips)):
            x = level(up(x) + skip)
        return self.ending(x)


class NAFNet(nn.Module):
    """Image-to-image NAFNet: (B, in_ch, H, W) -> (B, out_ch, H, W)."""

    def __init__(self, in_ch: int, out_ch: int, width: int = 16, enc_blocks: Sequence[int] = (1, 1, 1),
                 middle_blocks: int = 1, dec_blocks: Sequence[int] | None = None):
        super().__init__()
        self.encoder = NAFEncoder(in_ch, width, enc_blocks)
        self.middle = _stack(self.encoder.out_channels, middle_blocks)
        self.decoder = NAFDecoder(out_ch, width, dec_blocks or enc_blocks)

    def forward(self, x: Tensor) -> Tensor:
        bottom, skips = self.encoder(x)
        return self.decoder(self.middle(bottom), skips)


def normalize_images(x: Tensor, scale: float = 0.05) -> Tensor:
    """Network input from linear radiance: log1p(x / scale). ``scale`` ~ a grey diffuse texel
    under one white pattern, so typical values land near 1 while highlights 100x brighter stay
    below 7 (and gradients stay finite at 0: log1p is smooth there)."""
    return torch.log1p(x.clamp_min(0.0) / scale)


#: linear radiance added to image and irradiance in :func:`diffuse_ratio`: about 1e-4 of a grey
#: texel under a white pattern (L^d ~ 0.05-0.16 in the default rig), so that the ratio's bias
#: f / (kd L^d) stays below 0.1% where a pattern lights a texel; 1e-3 biased it by a few per cent,
#: as much as the normal signal it is there to expose.
RATIO_FLOOR = 1e-5


def diffuse_ratio(images: Tensor, irradiance: Tensor, floor: float = RATIO_FLOOR) -> Tensor:
    """Network input log((I + f) / (L^d + f)): each image over its pattern's flat-Lambertian
    irradiance L^d (Eq. 4), both (B, P, 3, H, W) (L^d may lack B). For a Lambertian texel with a
    flat normal this is log kd wherever it is lit, whatever its position under the LCD, so the
    differences between patterns that a linear layer forms are the normal's (and the specular
    lobe's) doing. The raw images put that few-per-cent signal on top of a position-dependent
    ramp the network would have to learn first. ``floor`` keeps unlit texels finite: where both
    are ~0 the ratio is ~0, and it is bounded by log(1 / floor) ~ 11.5 in magnitude for values <= 1."""
    return torch.log((images.clamp_min(0.0) + floor) / (irradiance.clamp_min(0.0) + floor))


def with_diffuse_ratio(net: nn.Module) -> nn.Module:
    """A copy of ``net`` (an :class:`~mitsvbrdf.nets.svbrdf_net.SVBRDFPredictor` or an
    :class:`~mitsvbrdf.nets.initializer.Initializer`) that also takes the diffuse-ratio inputs
    and, at first, ignores them: the new input channels of its intro convolution (the
    ``RATIO_INTRO`` weight, appended after the images' channels) start at zero, so the copy
    computes exactly what ``net`` computes and training can continue from it (an export trained
    without the option). ``net`` itself when it already takes them."""
    if net.diffuse_ratio:
        return net
    wide = type(net)(**{**net.config, "diffuse_ratio": True})
    state = dict(net.state_dict())
    w = state[net.RATIO_INTRO]
    state[net.RATIO_INTRO] = torch.cat([w, torch.zeros_like(w)], 1)
    wide.load_state_dict(state)
    return wide.to(w.device)
