"""Training losses (paper Sec. 3.5, Eq. 6-8).

* :func:`map_l1`: L_r, L1 between encoded maps (B, 10, H, W), optionally weighted per map.
* :func:`inverse_importance_loss`: L_inv, L1 of G_l's inverse head against the true normal and
  roughness.
* :func:`importance_consistency_loss`: L_c = 1 - MS-SSIM_cs(grey(L_0 + sum_i L_i) / P, L_pdf),
  Eq. 7, keeping only the contrast-structure term at every scale: the mean level (luminance) and
  the colours of the patterns stay free, their spatial structure and contrast follow L_pdf.

MS-SSIM on a 32 x 32 LCD grid: 3 scales (32, 16, 8 cells) with a 5-tap Gaussian window
(sigma 1.0, the 11-tap / 1.5 window of the image metric would not fit the coarsest scale), equal
exponents 1/3, constants C2 = (0.03)^2 for data in [0, 1] (the pattern sum is divided by the
number of patterns; L_pdf is min-max normalised by construction). The inputs are not normalised
further: C2 is what makes a nearly flat pattern sum score low against a structured L_pdf. A
constant map (e.g. black patterns) has cs = C2 / (var + C2) against a map of variance var:
finite, with finite gradients.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

C2 = 0.03 ** 2


#: Per-map weights of :func:`map_l1` in the order of the encoded channels; all ones is the paper's L1.
PLAIN_MAP_WEIGHTS = (1.0, 1.0, 1.0, 1.0)


def map_weight_channels(weights, device=None, dtype=torch.float32) -> Tensor:
    """(normal, diffuse, roughness, specular) weights -> (10,) per encoded channel (3, 3, 1, 3)."""
    if len(weights) != 4 or any(not math.isfinite(w) or w < 0 for w in weights) or sum(weights) <= 0:
        raise ValueError(f"map weights must be 4 finite numbers >= 0 (normal, diffuse, roughness, specular), "
                         f"not all 0; got {list(weights)}")
    n, d, r, s = (float(w) for w in weights)
    return torch.tensor([n] * 3 + [d] * 3 + [r] + [s] * 3, device=device, dtype=dtype)


def map_l1(pred: Tensor, gt: Tensor, weights=PLAIN_MAP_WEIGHTS) -> Tensor:
    """Mean absolute difference of encoded maps (B, 10, H, W), each map's channels scaled by its
    weight in ``weights`` (normal, diffuse, roughness, specular).

    The weighted loss is ``mean_c(w_c |pred_c - gt_c|)``: all ones is the paper's L_r, and raising
    one weight raises that map's gradient without lowering the others' (no renormalisation, so the
    learning rate keeps its meaning for the unweighted maps). Why weight at all: at the step
    counts a CPU affords, plain L1 leaves the normal map flat for hundreds of steps, because a
    flat normal is already within a few hundredths of most maps (train/README.md).
    """
    diff = (pred - gt).abs()
    if tuple(weights) == PLAIN_MAP_WEIGHTS:
        return diff.mean()
    w = map_weight_channels(weights, diff.device, diff.dtype)
    return (diff * w[:, None, None]).mean()


def inverse_importance_loss(normal: Tensor, roughness: Tensor, gt_normal: Tensor, gt_roughness: Tensor) -> Tensor:
    """L1 of predicted normal (B, 3, H, W) and roughness (B, 1, H, W) against the truth."""
    return (normal - gt_normal).abs().mean() + (roughness - gt_roughness).abs().mean()


def _window(size: int = 5, sigma: float = 1.0, device=None, dtype=torch.float32) -> Tensor:
    x = torch.arange(size, device=device, dtype=dtype) - (size - 1) / 2
    g = torch.exp(-x * x / (2 * sigma * sigma))
    g = g / g.sum()
    return (g[:, None] * g[None, :])[None, None]


def ssim_cs(x: Tensor, y: Tensor, window: Tensor) -> Tensor:
    """Mean contrast-structure term (2 s_xy + C2) / (s_x^2 + s_y^2 + C2) per map: (B, 1, h, w) -> (B,)."""
    mu_x, mu_y = F.conv2d(x, window), F.conv2d(y, window)
    sxx = F.conv2d(x * x, window) - mu_x * mu_x
    syy = F.conv2d(y * y, window) - mu_y * mu_y
    sxy = F.conv2d(x * y, window) - mu_x * mu_y
    return ((2 * sxy + C2) / (sxx + syy + C2)).mean((1, 2, 3))


def ms_ssim_cs(x: Tensor, y: Tensor, scales: int = 3) -> Tensor:
    """Product over scales of the cs terms, each to the power 1 / scales: (B, 1, h, w) x 2 -> (B,).

    Negative cs (anti-correlated structure) is clamped to a small positive value before the
    fractional power, which is what keeps the product differentiable.
    """
    if x.shape != y.shape or x.ndim != 4 or x.shape[1] != 1:
        raise ValueError(f"ms_ssim_cs needs two (B, 1, h, w) maps of one shape, got {tuple(x.shape)}, {tuple(y.shape)}")
    w = _window(device=x.device, dtype=x.dtype)
    if min(x.shape[-2:]) < 5 * 2 ** (scales - 1):
        raise ValueError(f"{scales} scales need maps of at least {5 * 2 ** (scales - 1)} cells, got {tuple(x.shape[-2:])}")
    out = torch.ones(x.shape[0], device=x.device, dtype=x.dtype)
    for s in range(scales):
        if s:
            x, y = F.avg_pool2d(x, 2), F.avg_pool2d(y, 2)
        out = out * ssim_cs(x, y, w).clamp_min(1e-4) ** (1.0 / scales)
    return out


def importance_consistency_loss(l0: Tensor, patterns: Tensor, lpdf: Tensor) -> Tensor:
    """Eq. 7 as a loss: 1 - MS-SSIM_cs between the grey mean of all P patterns and L_pdf.

    Args:
        l0: (3, h, w) or (B, 3, h, w) first pattern; patterns: (B, P-1, 3, h, w) adaptive patterns;
        lpdf: (B, 1, h, w).
    """
    total = (patterns.sum(1) + (l0 if l0.ndim == 4 else l0[None])) / (patterns.shape[1] + 1)
    return (1.0 - ms_ssim_cs(total.mean(1, keepdim=True), lpdf)).mean()
