"""G_l, the lighting predictor (paper Sec. 3.3, 3.5): I_0 and L_pdf -> 4 adaptive RGB patterns,
plus the inverse head (normal and roughness) that the inverse importance loss supervises."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .blocks import NAFBlock
from .nafnet import NAFDecoder, NAFEncoder, normalize_images


@dataclass
class LightingOutput:
    """patterns (B, P-1, 3, h, w) drive values in [0, 1]; normal (B, 3, H, W) unit vectors with
    z > 0; roughness (B, 1, H, W) in [0, 1]."""

    patterns: Tensor
    normal: Tensor
    roughness: Tensor


class LightingPredictor(nn.Module):
    """Shallow NAFNet: image encoder, L_pdf fused at the bottom, a pattern trunk on the LCD grid
    with one head per adaptive pattern, and a decoder for the inverse head.

    Args:
        num_patterns: adaptive patterns to predict (4 in the paper).
        cells: LCD grid (h, w).
        width: channels of the first encoder level (12 in the paper).
        enc_blocks: NAFBlocks per encoder level (its length sets the downsampling, 2^levels).
        trunk_blocks: NAFBlocks of the pattern trunk at LCD resolution.
    """

    def __init__(self, num_patterns: int = 4, cells: tuple[int, int] = (32, 32), width: int = 12,
                 enc_blocks: tuple[int, ...] = (1, 1, 1), trunk_blocks: int = 2):
        super().__init__()
        self.config = dict(num_patterns=num_patterns, cells=tuple(cells), width=width,
                           enc_blocks=tuple(enc_blocks), trunk_blocks=trunk_blocks)
        self.num_patterns, self.cells = num_patterns, tuple(cells)
        self.encoder = NAFEncoder(3, width, enc_blocks)
        c = self.encoder.out_channels
        self.fuse = nn.Conv2d(c + 1, c, 1)
        self.trunk = nn.Sequential(nn.Conv2d(c + 1, 2 * width, 1), *[NAFBlock(2 * width) for _ in range(trunk_blocks)])
        self.heads = nn.ModuleList([nn.Conv2d(2 * width, 3, 3, padding=1) for _ in range(num_patterns)])
        self.decoder = NAFDecoder(4, width, enc_blocks)

    def forward(self, i0: Tensor, lpdf: Tensor) -> LightingOutput:
        """i0 (B, 3, H, W) linear radiance, lpdf (B, 1, h, w) in [0, 1]."""
        bottom, skips = self.encoder(normalize_images(i0))
        lp_small = F.adaptive_avg_pool2d(lpdf, bottom.shape[-2:])
        bottom = self.fuse(torch.cat([bottom, lp_small], 1))
        feat = F.interpolate(bottom, size=self.cells, mode="bilinear", align_corners=False)
        feat = self.trunk(torch.cat([feat, lpdf], 1))
        patterns = torch.stack([torch.sigmoid(h(feat)) for h in self.heads], 1)
        inv = self.decoder(bottom, skips)
        xy = torch.tanh(inv[:, :2])
        z = torch.sqrt((1.0 - xy.square().sum(1, keepdim=True)).clamp_min(0.0) + 1e-3)
        normal = torch.cat([xy, z], 1)
        normal = normal / normal.norm(dim=1, keepdim=True)
        return LightingOutput(patterns, normal, torch.sigmoid(inv[:, 3:4]))
