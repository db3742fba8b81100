"""Reference renderer: deterministic quadrature of paper Eq. 1 over the LCD, in torch.

    I(x) = sum over cells c of L_c * integral over c of f(w_i, w_o) (n . w_i) e(y, w_i) dw_i

evaluated on the sample's texel grid (pixel (i, j) = texel (i, j), view direction towards the
camera's centre of projection), one bounce, no pixel filter. The per-cell integrals come from
:func:`mitsvbrdf.render.quadrature.cell_kernels` (light rule + visible-normal rule with MIS), so
the result converges at every roughness, including the mirror limit. Because the specular term is
linear in ks (F = ks (1 - S) + S), three pattern-independent kernels per pixel and cell suffice:

    I = kd (1 - ks) K_d L + ks K_a L + K_b L,
    K_d = int (n.w_i)^+ / pi,   K_a = int f_s' (1 - S),   K_b = int f_s' S,

with f_s' = D G / (4 n.l n.v) (n.l). The image is exactly linear in the patterns and
differentiable w.r.t. patterns and all four maps (see the quadrature module for the one caveat on
normal/roughness gradients at cell edges).
"""

from __future__ import annotations

import math

import torch
import torch.utils.checkpoint
from torch import Tensor

from ..brdf import roughness_to_alpha, schlick_weight
from ..rig import Rig
from .quadrature import LocalDirections, QuadratureSettings, cell_kernels, chunk_size

LOBES = ("both", "diffuse", "specular")


def diffuse_integrand(d: LocalDirections):
    """(n.w_i)^+ / pi where both directions are above the shading horizon (one smooth channel)."""
    g = torch.where((d.cos_i > 0) & (d.cos_o > 0), d.cos_i / math.pi, torch.zeros_like(d.cos_i))
    return [g], []


def specular_cosine(d: LocalDirections) -> Tensor:
    """D G / (4 n.l n.v) (n.l) in the stable form D (n.l) / (4 (n.l(1-k)+k)(n.v(1-k)+k)); the
    same algebra as :func:`mitsvbrdf.brdf.specular_terms`."""
    k = 0.5 * d.alpha
    nl, nv = d.cos_i.clamp_min(0.0), d.cos_o.clamp_min(0.0)
    f = d.ndf() * nl / (4.0 * (nl * (1.0 - k) + k) * (nv * (1.0 - k) + k))
    return torch.where((d.cos_i > 0) & (d.cos_o > 0), f, torch.zeros_like(f))


def make_brdf_integrand(lobes: str):
    """Integrand for :func:`cell_kernels`: smooth = [K_d], peaked = [K_a, K_b] as ``lobes`` asks."""
    if lobes not in LOBES:
        raise ValueError(f"lobes must be one of {LOBES}, got {lobes!r}")

    def integrand(d: LocalDirections):
        smooth = diffuse_integrand(d)[0] if lobes != "specular" else []
        peaked = []
        if lobes != "diffuse":
            f = specular_cosine(d)
            s = schlick_weight(d.o_dot_h)
            peaked = [f * (1.0 - s), f * s]
        return smooth, peaked

    return integrand


def _pixels(t: Tensor) -> Tensor:
    """(C, H, W) -> (H*W, C)."""
    return t.reshape(t.shape[0], -1).transpose(0, 1)


def render_reference(
    svbrdf,
    patterns: Tensor,
    rig: Rig,
    *,
    lobes: str = "both",
    settings: QuadratureSettings | None = None,
    progress=None,
) -> Tensor:
    """Render B materials under P patterns.

    Args:
        svbrdf: :class:`mitsvbrdf.SVBRDF` with maps (B, C, H, W).
        patterns: drive values (P, 3, h, w) shared by all materials or (B, P, 3, h, w) per material.
        rig: geometry and display model.
        lobes: "both", "diffuse" or "specular".
        settings: quadrature orders (default :class:`QuadratureSettings()`).
        progress: optional callable(n_done_pixels) for progress bars.
    Returns:
        (B, P, 3, H, W) linear radiance, float32, on the maps' device.
    """
    settings = settings or QuadratureSettings()
    integrand = make_brdf_integrand(lobes)
    B = svbrdf.batch_size
    H, W = svbrdf.resolution
    dev, dt = svbrdf.normal.device, svbrdf.normal.dtype
    radiance = rig.material_radiance(patterns, B, dev, dt)  # (B, P, 3, C)
    P = radiance.shape[1]
    lcd = rig.lcd_geometry(dev, dt)
    x_all = rig.surface_points((H, W), dev).reshape(-1, 3).to(dt)
    wo_all = rig.view_directions((H, W), dev).reshape(-1, 3).to(dt)
    display = rig.display if rig.display.has_decay else None
    step = chunk_size(settings, lcd.cells[0] * lcd.cells[1])

    def shade(x, wo, n, rough, kd, ks, rad):
        alpha = roughness_to_alpha(rough[:, 0])
        k = cell_kernels(x, n, wo, alpha, lcd, integrand, settings, display)
        kl = torch.einsum("nkc,pjc->nkpj", k, rad)  # (N, K, P, 3)
        out = torch.zeros_like(kl[:, 0])
        i = 0
        if lobes != "specular":
            out = out + (kd * (1.0 - ks))[:, None] * kl[:, 0]
            i = 1
        if lobes != "diffuse":
            out = out + ks[:, None] * kl[:, i] + kl[:, i + 1]
        return out  # (N, P, 3)

    need_grad = torch.is_grad_enabled() and any(
        t.requires_grad for t in (svbrdf.normal, svbrdf.diffuse, svbrdf.roughness, svbrdf.specular, radiance))
    images = []
    for b in range(B):
        maps = [_pixels(m[b]) for m in (svbrdf.normal, svbrdf.roughness, svbrdf.diffuse, svbrdf.specular)]
        rows = []
        for s in range(0, H * W, step):
            args = (x_all[s:s + step], wo_all[s:s + step], *(m[s:s + step] for m in maps), radiance[b])
            if need_grad:
                rows.append(torch.utils.checkpoint.checkpoint(shade, *args, use_reentrant=False))
            else:
                rows.append(shade(*args))
            if progress is not None:
                progress(min(step, H * W - s))
        img = torch.cat(rows, 0)  # (H*W, P, 3)
        images.append(img.permute(1, 2, 0).reshape(P, 3, H, W))
    return torch.stack(images, 0)
