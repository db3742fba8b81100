"""Deterministic integration over the LCD's cells that stays accurate at every roughness.

Everything the torch side integrates over the LCD has the form

    K[x, c] = integral over cell c of  g(x, w_i) e(y, w_i) dw_i,     dw_i = cos(theta_emit) dA / d^2,

with g a per-solid-angle integrand at surface point x (a cosine-weighted BRDF term, or the
projected NDF of Eq. 2) and e the display's emission decay. Images and L_pdf are then
contractions of these per-cell kernels with per-cell radiance, which keeps them exactly linear in
the patterns and makes a black cell cost nothing special.

A fixed grid on the light alone misses narrow GGX lobes (at alpha = 1e-4 the lobe is ~0.02 mm
wide on the LCD, cells are 2.8 mm), and a grid on the lobe alone converges slowly for rough
materials where the cell edges cut the lobe. We combine two deterministic rules:

* light quadrature: a q x q Gauss-Legendre rule inside every cell (exact cell partition, so the
  piecewise-constant pattern is integrated without edge error);
* lobe quadrature: m^2 points of a low-discrepancy lattice pushed through the GGX visible-normal
  warp (Dupuy & Benyoub 2023) and reflected; each point lands in the cell its ray hits (rays that
  miss the LCD carry nothing).

A weight w_H(w_i) in [0, 1] (:func:`lobe_share`) splits the integrand: the lobe rule integrates
w_H g, the light rule (1 - w_H) g. Any such split sums to the exact integral, so the weight only
decides which rule sees which part: the lobe rule takes the neighbourhood of a GGX peak that is
narrower than the light points' spacing, the light rule everything that is smooth on that scale.
(The balance heuristic, w_H = p_H / (p_L + p_H), was tried first: it leaves the light rule a
sub-grid bump at the crossover and converged only as ~N^-1/4 for near-mirror lobes.)
Smooth integrands (the diffuse lobe) use the light rule alone. ``benchmarks/reference_accuracy.py``
measures the error of the default settings against a 4x denser rule per roughness.

Known limitation: lobe points move with normal and roughness, and the cell they land in is
piecewise constant, so gradients w.r.t. normal/roughness omit the terms from points crossing a
cell edge; they are exact w.r.t. patterns, albedos, and for the light-rule part.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch
from torch import Tensor

from ..brdf import sample_vndf_local, tangent_frame
from ..rig import DisplayModel, LcdGeometry

#: Integrand signature: (n, wi, wo, alpha) with xyz in the last dim (alpha with a trailing 1)
#: -> (smooth, peaked): tensors (..., Ks) and (..., Kp) or None. Smooth channels use the light
#: rule only; peaked channels use both rules with MIS.
Integrand = Callable[[Tensor, Tensor, Tensor, Tensor], tuple[Tensor | None, Tensor | None]]


@dataclass(frozen=True)
class QuadratureSettings:
    """Accuracy knobs of the deterministic LCD integration.

    Attributes:
        cell_order: q, Gauss-Legendre points per cell along each axis (q^2 per cell).
        lobe_grid: m, visible-normal samples per pixel along each axis (m^2 per pixel).
        window: radius, in light-point spacings, of the region around a lobe's peak that the
            lobe rule integrates (see :func:`lobe_share`).
        max_elements: bound on pixels x points evaluated at once (memory vs. overhead).
    """

    cell_order: int = 2
    lobe_grid: int = 32
    window: float = 2.0
    max_elements: int = 1 << 21

    def __post_init__(self):
        if self.cell_order < 1 or self.lobe_grid < 0:
            raise ValueError(f"need cell_order >= 1 and lobe_grid >= 0, got {self}")

    def denser(self) -> "QuadratureSettings":
        """4x the points of both rules (2x per axis): the convergence check of the benchmark."""
        return QuadratureSettings(2 * self.cell_order, 2 * self.lobe_grid, self.window, self.max_elements)


def light_points(lcd: LcdGeometry, order: int) -> tuple[Tensor, Tensor]:
    """Gauss-Legendre points of every cell: uv (C, q^2, 2) in [0,1]^2 and area weights (C, q^2)
    in m^2 (each cell's weights sum to its area). Cells are ordered row-major (c = row * w + col)."""
    h, w = lcd.cells
    x, wt = np.polynomial.legendre.leggauss(order)
    x, wt = (x + 1) / 2, wt / 2
    dev, dt = lcd.origin.device, lcd.origin.dtype
    sub_v, sub_u = np.meshgrid(x, x, indexing="ij")
    sub_w = np.outer(wt, wt).reshape(-1)
    rows, cols = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    u = (cols.reshape(-1, 1) + sub_u.reshape(1, -1)) / w
    v = (rows.reshape(-1, 1) + sub_v.reshape(1, -1)) / h
    uv = torch.tensor(np.stack([u, v], -1), dtype=dt, device=dev)
    area = lcd.area / (h * w) * torch.tensor(sub_w, dtype=dt, device=dev)
    return uv, area.expand(h * w, -1)


def lobe_grid(m: int, device=None, dtype=torch.float32) -> tuple[Tensor, Tensor]:
    """m^2 points of a golden-ratio (Fibonacci) lattice on [0,1)^2 as (u1, u2), each (m^2,).

    Its low discrepancy matters here: the integrand jumps where a cell edge cuts the lobe, and a
    lattice resolves an edge of any orientation with error ~ log(N)/N instead of a product grid's
    ~ 1/sqrt(N). u1 (the azimuth of the warp) is the periodic coordinate."""
    n = m * m
    k = torch.arange(n, dtype=torch.float64, device=device)
    u1 = torch.remainder(k * 0.6180339887498949 + 0.5 / n, 1.0)
    u2 = (k + 0.5) / n
    return u1.to(dtype), u2.to(dtype)


def lobe_share(n: Tensor, wi: Tensor, wo: Tensor, alpha: Tensor, omega: Tensor, window: float) -> Tensor:
    """Weight w_H in [0, 1] of the lobe rule at w_i; the light rule gets 1 - w_H.

    The light rule resolves the integrand where it varies slowly on the scale of its point
    spacing. Near its peak GGX varies on the scale l = sqrt(alpha^2 + sin^2 theta_h) (core width,
    then power-law tails), while light points are ``sqrt(omega_h)`` apart in half-vector angle,
    omega_h = omega / (4 w_o.h) with ``omega`` the solid angle per light point. The lobe rule
    takes the region within ``window`` spacings of the peak:

        w_H = 1 / (1 + (l^2 / (window^2 omega_h))^2).

    For rough lobes l >> spacing everywhere and w_H ~ 0; for near-mirror lobes the lobe rule owns
    the unresolvable core and the light rule the smooth tails.
    """
    h = wi + wo
    h = h / torch.linalg.vector_norm(h, dim=-1, keepdim=True).clamp_min(1e-12)
    sin2 = torch.linalg.vector_norm(torch.linalg.cross(n, h, dim=-1), dim=-1, keepdim=True) ** 2
    omega_h = omega / (4.0 * (wo * h).sum(-1, keepdim=True).clamp_min(1e-6))
    ratio = (alpha * alpha + sin2) / (window * window * omega_h).clamp_min(1e-30)
    return 1.0 / (1.0 + ratio * ratio)


def _emission(lcd: LcdGeometry, display: DisplayModel | None, x: Tensor, y: Tensor,
              uv: Tensor) -> tuple[Tensor, Tensor, Tensor | None]:
    """Direction x -> y (..., 3), the area-to-solid-angle factor J = cos(theta_emit) / d^2
    (..., 1), and the emission decay (..., 1) or None when the scene has none."""
    d = y - x
    dist2 = (d * d).sum(-1, keepdim=True)
    wi = d / dist2.sqrt()
    cos_e = (-(wi * lcd.normal).sum(-1, keepdim=True)).clamp_min(0.0)
    decay = display.decay(uv, cos_e[..., 0]) if display is not None else None
    return wi, cos_e / dist2, None if decay is None else decay.unsqueeze(-1)


def cell_kernels(
    x: Tensor,
    n: Tensor,
    wo: Tensor,
    alpha: Tensor,
    lcd: LcdGeometry,
    integrand: Integrand,
    pdf: Callable[[Tensor, Tensor, Tensor, Tensor], Tensor] | None,
    settings: QuadratureSettings,
    display: DisplayModel | None = None,
) -> Tensor:
    """Per-cell integrals of ``integrand`` for N surface points.

    Args:
        x, n, wo: (N, 3) positions (metres), unit shading normals, unit view directions.
        alpha: (N,) GGX alpha (>= ALPHA_MIN).
        lcd: the light; display: its display model (only the decay is used here), or None.
        integrand: see :data:`Integrand`.
        pdf: solid-angle density of the lobe rule, ``pdf(n, wi, wo, alpha) -> (..., 1)`` matching
            the visible-normal warp; None disables the lobe rule (light rule only).
        settings: quadrature orders.
    Returns:
        (N, Ks + Kp, C) kernels, C = h * w cells in row-major order.
    """
    q2 = settings.cell_order ** 2
    uv, area = light_points(lcd, settings.cell_order)  # (C, q2, 2), (C, q2)
    C = uv.shape[0]
    y = lcd.point(uv).reshape(1, C * q2, 3)
    uvf = uv.reshape(1, C * q2, 2)
    a_cell = lcd.area / C
    xe, ne, woe, ae = x[:, None], n[:, None], wo[:, None], alpha[:, None, None]

    # Light rule.
    wi, jac, decay = _emission(lcd, display, xe, y, uvf)
    weight = jac if decay is None else jac * decay
    smooth, peaked = integrand(ne, wi, woe, ae)
    parts = []
    if smooth is not None:
        parts.append(smooth * weight)
    if peaked is not None:
        if pdf is not None and settings.lobe_grid > 0:
            w_l = 1.0 - lobe_share(ne, wi, woe, ae, a_cell * jac / q2, settings.window)
            parts.append(peaked * (weight * w_l))
        else:
            parts.append(peaked * weight)
    k = torch.cat(parts, dim=-1)  # (N, C*q2, K)
    kernels = (k.reshape(x.shape[0], C, q2, -1) * area[None, :, :, None]).sum(2).transpose(1, 2)

    if peaked is None or pdf is None or settings.lobe_grid == 0:
        return kernels.contiguous()
    lobe = _lobe_rule(x, n, wo, alpha, lcd, integrand, pdf, settings, display, a_cell, q2)
    ks = 0 if smooth is None else smooth.shape[-1]
    return torch.cat([kernels[:, :ks], kernels[:, ks:] + lobe], dim=1)


def _lobe_rule(x, n, wo, alpha, lcd, integrand, pdf, settings, display, a_cell, q2) -> Tensor:
    N = x.shape[0]
    h, w = lcd.cells
    m2 = settings.lobe_grid ** 2
    t, b = tangent_frame(n)
    wo_l = torch.stack([(wo * t).sum(-1), (wo * b).sum(-1), (wo * n).sum(-1)], -1)
    front = wo_l[:, 2] > 0
    # The warp needs a view above the shading horizon; elsewhere the BRDF is zero anyway.
    wo_safe = torch.where(front[:, None], wo_l, torch.tensor([0.0, 0.0, 1.0], dtype=x.dtype, device=x.device))
    u1, u2 = lobe_grid(settings.lobe_grid, x.device, x.dtype)
    hl = sample_vndf_local(wo_safe[:, None, :], alpha[:, None], u1[None], u2[None])  # (N, S, 3)
    wil = 2.0 * (wo_safe[:, None] * hl).sum(-1, keepdim=True) * hl - wo_safe[:, None]
    wi = wil[..., :1] * t[:, None] + wil[..., 1:2] * b[:, None] + wil[..., 2:] * n[:, None]
    wi = wi / torch.linalg.vector_norm(wi, dim=-1, keepdim=True).clamp_min(1e-12)

    # Ray x + s wi against the LCD plane.
    nl_ = lcd.normal
    denom = (wi * nl_).sum(-1)  # < 0 when heading towards the emitting side
    dist = ((lcd.origin - x) * nl_).sum(-1, keepdim=True) / torch.where(denom < -1e-9, denom, -torch.ones_like(denom))
    hit = x[:, None] + dist[..., None] * wi
    rel = hit - lcd.origin
    u = (rel * lcd.edge_u).sum(-1) / (lcd.edge_u * lcd.edge_u).sum()
    v = (rel * lcd.edge_v).sum(-1) / (lcd.edge_v * lcd.edge_v).sum()
    inside = (denom < -1e-9) & (dist > 0) & (u >= 0) & (u < 1) & (v >= 0) & (v < 1) & front[:, None]
    cell = (v.clamp(0, 1 - 1e-7) * h).long() * w + (u.clamp(0, 1 - 1e-7) * w).long()

    _, jac, decay = _emission(lcd, display, x[:, None], hit, torch.stack([u, v], -1))
    ne, woe, ae = n[:, None].expand_as(wi), wo[:, None].expand_as(wi), alpha[:, None, None]
    _, peaked = integrand(ne, wi, woe, ae)
    w_h = lobe_share(ne, wi, woe, ae, a_cell * jac / q2, settings.window)
    contrib = peaked * (w_h / (m2 * pdf(ne, wi, woe, ae)).clamp_min(1e-30))
    if decay is not None:
        contrib = contrib * decay
    contrib = torch.where(inside[..., None], contrib, torch.zeros_like(contrib))
    out = torch.zeros(N, peaked.shape[-1], h * w, dtype=x.dtype, device=x.device)
    idx = torch.where(inside, cell, torch.zeros_like(cell))
    out.scatter_add_(2, idx[:, None, :].expand(-1, peaked.shape[-1], -1), contrib.transpose(1, 2))
    return out


def chunk_size(settings: QuadratureSettings, cells: int) -> int:
    """Pixels per chunk so that pixels x light points stays below ``settings.max_elements``."""
    pts = cells * settings.cell_order ** 2 + settings.lobe_grid ** 2
    return max(1, settings.max_elements // pts)


