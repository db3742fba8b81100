"""Specular appearance separation (paper Sec. 3.4, Eq. 4-5).

For a Lambertian surface with a *flat* normal the diffuse image under pattern i is
``I_i^d = kd L_i^d`` with the pattern's irradiance term

    L_i^d(x) = integral over the LCD of L_i(w_i) e(y, w_i) (z . w_i) / pi dw_i     (Eq. 4),

which depends only on the rig, the pattern and the display model (with its decay, when the scene
has one), not on the material. For two images the combination

    I^spec_(x, y) = I_x L_y^d - I_y L_x^d                                            (Eq. 5)

cancels the diffuse albedo exactly for flat Lambertian texels and leaves specular-related
appearance. L^d uses the same cell quadrature as the reference renderer's diffuse lobe, so the
cancellation holds to float precision.
"""

from __future__ import annotations

import itertools
import weakref

import torch
from torch import Tensor

from .render.quadrature import QuadratureSettings, cell_kernels, chunk_size
from .render.reference import diffuse_integrand
from .errors import ImageError
from .rig import Rig, per_texel

_KERNEL_CACHE: "weakref.WeakKeyDictionary[Rig, dict]" = weakref.WeakKeyDictionary()


def flat_diffuse_kernel(rig: Rig, resolution: tuple[int, int], *, device=None,
                        settings: QuadratureSettings | None = None) -> Tensor:
    """(H*W, h*w) kernel K with L^d = K @ radiance: per texel and cell, the integral of
    e (z . w_i) / pi over the cell. Cached per rig, resolution, device and cell order; a window's
    (:meth:`Rig.window`) is its rows of the whole grid's (:func:`mitsvbrdf.rig.per_texel`)."""
    settings = settings or QuadratureSettings()
    return per_texel(rig, resolution, lambda r, res: _flat_diffuse_kernel(r, res, device, settings), 0)


def _flat_diffuse_kernel(rig: Rig, resolution: tuple[int, int], device, settings: QuadratureSettings) -> Tensor:
    H, W = resolution
    key = (H, W, str(device), settings.cell_order)
    cache = _KERNEL_CACHE.setdefault(rig, {})
    if key not in cache:
        x = rig.surface_points((H, W), device).reshape(-1, 3)
        wo = rig.view_directions((H, W), device).reshape(-1, 3)
        n = torch.zeros_like(x)
        n[:, 2] = 1.0
        alpha = torch.ones(x.shape[0], device=device)
        lcd = rig.lcd_geometry(device)
        display = rig.display if rig.display.has_decay else None
        step = chunk_size(settings, lcd.cells[0] * lcd.cells[1])
        with torch.no_grad():
            k = torch.cat([cell_kernels(x[i:i + step], n[i:i + step], wo[i:i + step], alpha[i:i + step],
                                        lcd, diffuse_integrand, settings, display)[:, 0]
                           for i in range(0, x.shape[0], step)], 0)
        if len(cache) >= 4:
            cache.pop(next(iter(cache)))
        cache[key] = k
    return cache[key]


def diffuse_irradiance(patterns: Tensor, rig: Rig, resolution: tuple[int, int] | int, *,
                       settings: QuadratureSettings | None = None) -> Tensor:
    """L_i^d of Eq. 4 for patterns (..., P, 3, h, w) -> (..., P, 3, H, W), differentiable in patterns."""
    res = (resolution, resolution) if isinstance(resolution, int) else tuple(resolution)
    radiance = rig.display_radiance(patterns)
    k = flat_diffuse_kernel(rig, res, device=patterns.device, settings=settings).to(radiance.dtype)
    lead = radiance.shape[:-2]
    ld = radiance.reshape(*lead, -1) @ k.t()  # (..., P, 3, H*W)
    return ld.reshape(*lead, *res)


def pair_indices(p: int) -> list[tuple[int, int]]:
    """The P(P-1)/2 image pairs (i, j), i < j, in the order of the separation's output channels."""
    return list(itertools.combinations(range(p), 2))


def separate_specular(images: Tensor, patterns: Tensor, rig: Rig, *,
                      settings: QuadratureSettings | None = None, irradiance: Tensor | None = None) -> Tensor:
    """I^spec of Eq. 5 for every pair of images.

    Args:
        images: (B, P, 3, H, W) or (P, 3, H, W) linear renders/captures under ``patterns``.
        patterns: (P, 3, h, w) or (B, P, 3, h, w) drive values.
        irradiance: their L^d (:func:`diffuse_irradiance`) when the caller has it already.
    Returns:
        (B, P(P-1)/2, 3, H, W) (or without B), pairs ordered as :func:`pair_indices`.
    """
    batched = images.ndim == 5
    imgs = images if batched else images.unsqueeze(0)
    if imgs.ndim != 5 or imgs.shape[2] != 3:
        raise ImageError(f"images must be (B, P, 3, H, W) or (P, 3, H, W), got {tuple(images.shape)}")
    P = imgs.shape[1]
    if patterns.shape[-4] != P:
        raise ImageError(f"{P} images but {patterns.shape[-4]} patterns")
    bad = int((~torch.isfinite(imgs.detach())).sum())
    if bad:  # Eq. 5 would carry them into every pair's I^spec
        raise ImageError(f"separate_specular: the images have {bad} NaN/Inf values")
    ld = irradiance if irradiance is not None else \
        diffuse_irradiance(patterns.to(imgs.device, imgs.dtype), rig, imgs.shape[-2:], settings=settings)
    if ld.ndim == 4:
        ld = ld.unsqueeze(0)
    i, j = map(list, zip(*pair_indices(P))) if P > 1 else ([], [])
    spec = imgs[:, i] * ld[:, j] - imgs[:, j] * ld[:, i]
    return spec if batched else spec[0]

