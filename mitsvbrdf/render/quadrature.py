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

from ..brdf import ggx_ndf, sample_vndf_local, smith_ggx_g1, tangent_frame
from ..errors import MitsvbrdfError
from ..rig import DisplayModel, LcdGeometry


@dataclass(frozen=True)
class LocalDirections:
    """Cosines of a light direction w_i in the shading frame, as integrands need them.

    All fields broadcast to one shape (pixels x points); n is the shading normal and
    h = normalize(w_i + w_o). ``sin2_h = |n x h|^2`` is computed from tangent-plane components,
    without the cancellation of ``1 - cos^2`` for tiny alpha.
    """

    cos_i: Tensor  # n . w_i
    cos_o: Tensor  # n . w_o
    cos_h: Tensor  # n . h
    sin2_h: Tensor  # |n x h|^2
    o_dot_h: Tensor  # w_o . h
    alpha: Tensor  # GGX alpha

    @classmethod
    def from_local(cls, wi: tuple[Tensor, Tensor, Tensor], wo: tuple[Tensor, Tensor, Tensor],
                   alpha: Tensor) -> "LocalDirections":
        hx, hy, hz = wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]
        inv = torch.rsqrt((hx * hx + hy * hy + hz * hz).clamp_min(1e-24))
        hx, hy, hz = hx * inv, hy * inv, hz * inv
        return cls(cos_i=wi[2], cos_o=wo[2], cos_h=hz, sin2_h=hx * hx + hy * hy,
                   o_dot_h=wo[0] * hx + wo[1] * hy + wo[2] * hz, alpha=alpha)

    def ndf(self) -> Tensor:
        """GGX D(h)."""
        return ggx_ndf(self.alpha, self.cos_h, self.sin2_h)


#: Integrand: LocalDirections -> (smooth channels, peaked channels), lists of tensors shaped like
#: ``cos_i``. Smooth channels use the light rule only; peaked channels both rules.
Integrand = Callable[[LocalDirections], tuple[list[Tensor], list[Tensor]]]


@dataclass(frozen=True)
class QuadratureSettings:
    """Accuracy knobs of the deterministic LCD integration.

    Attributes:
        cell_order: q, Gauss-Legendre points per cell along each axis (q^2 per cell).
        lobe_grid: m, visible-normal samples per pixel along each axis (m^2 per pixel);
            0 switches the lobe rule off.
        window: radius, in light-point spacings, of the region around a lobe's peak that the
            lobe rule integrates (see :func:`lobe_share`).
        max_elements: bound on pixels x points evaluated at once (memory vs. overhead).
    """

    cell_order: int = 2
    lobe_grid: int = 32
    window: float = 2.0
    max_elements: int = 1 << 21

    def __post_init__(self):
        if self.cell_order < 1 or self.lobe_grid < 0 or not self.window > 0 or self.max_elements < 1:
            raise MitsvbrdfError(f"need cell_order >= 1, lobe_grid >= 0, window > 0, max_elements >= 1, got {self}")

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


def vndf_pdf(d: LocalDirections, ndf: Tensor) -> Tensor:
    """Solid-angle density of the lobe rule's directions: G1_smith(w_o) D(h) / (4 n.w_o)."""
    pdf = smith_ggx_g1(d.cos_o, d.alpha) * ndf / (4.0 * d.cos_o.clamp_min(1e-12))
    return torch.where(d.cos_o > 0, pdf, torch.zeros_like(pdf))


def lobe_share(d: LocalDirections, omega: Tensor, window: float) -> Tensor:
    """Weight w_H in [0, 1] of the lobe rule at w_i; the light rule gets 1 - w_H.

    The light rule resolves the integrand where it varies slowly on the scale of its point
    spacing. Near its peak GGX varies on the scale l = sqrt(alpha^2 + sin^2 theta_h) (core width,
    then power-law tails), while light points are ``sqrt(omega_h)`` apart in half-vector angle,
    omega_h = omega / (4 w_o.h) with ``omega`` the solid angle per light point. The lobe rule
    takes the region within ``window`` spacings of the peak:

        w_H = 1 / (1 + (l^2 / (window^2 omega_h))^2).

    For rough lobes l >> spacing everywhere and w_H ~ 0; for near-mirror lobes the lobe rule owns
    the unresolvable core and the light rule the smooth tails.

    It is evaluated as ``s^2 / (s^2 + l^4)``, s = window^2 omega_h, which is the same number but
    has no division by ``omega``: directions that miss the LCD have omega = 0, and the quotient
    form overflowed there (1 / clamp(0) squared), which made the backward pass NaN although the
    forward value was masked out. The denominator is at least alpha^4 >= ALPHA_MIN^4, so the
    gradient is finite everywhere, and exactly 0 where omega = 0.
    """
    omega_h = omega / (4.0 * d.o_dot_h.clamp_min(1e-6))
    s = window * window * omega_h
    l2 = d.alpha * d.alpha + d.sin2_h
    s2 = s * s
    return s2 / (s2 + l2 * l2)


class _Frame:
    """Per-pixel shading frames (t, b, n) and the view direction in them; all (N, 3) / (N,)."""

    def __init__(self, x: Tensor, n: Tensor, wo: Tensor):
        self.x, self.n = x, n
        self.t, self.b = tangent_frame(n)
        self.m = torch.stack([self.t, self.b, n], 1)  # (N, 3, 3) rows = frame axes
        self.wo = tuple((self.m @ wo[:, :, None])[:, k, 0] for k in range(3))
        self.front = self.wo[2] > 0


def cell_kernels(
    x: Tensor,
    n: Tensor,
    wo: Tensor,
    alpha: Tensor,
    lcd: LcdGeometry,
    integrand: Integrand,
    settings: QuadratureSettings,
    display: DisplayModel | None = None,
) -> Tensor:
    """Per-cell integrals of ``integrand`` for N surface points.

    Args:
        x, n, wo: (N, 3) positions (metres), unit shading normals, unit view directions.
        alpha: (N,) GGX alpha (>= ALPHA_MIN).
        lcd: the light; display: its display model (only the decay is used here), or None.
        integrand: see :data:`Integrand`.
        settings: quadrature orders.
    Returns:
        (N, K, C) kernels, K = smooth then peaked channels, C = h * w cells in row-major order.
    """
    N = x.shape[0]
    q2 = settings.cell_order ** 2
    uv, area = light_points(lcd, settings.cell_order)  # (C, q2, 2), (C, q2)
    C = uv.shape[0]
    y = lcd.point(uv).reshape(C * q2, 3)
    a_cell = lcd.area / C
    fr = _Frame(x, n, wo)

    # Light rule: every direction from the frame projections of y - x (matmuls, no (N, M, 3) tensors).
    proj = torch.einsum("mk,nak->nam", y, fr.m) - (fr.m @ x[:, :, None])  # (N, 3, M)
    inv = torch.rsqrt((proj * proj).sum(1).clamp_min(1e-24))  # 1 / distance, (N, M)
    wi = (proj[:, 0] * inv, proj[:, 1] * inv, proj[:, 2] * inv)
    cos_e = ((x @ lcd.normal)[:, None] - y @ lcd.normal) * inv  # -(n_l . w_i)
    jac = cos_e.clamp_min(0.0) * inv * inv  # solid angle per unit LCD area
    wo_e = tuple(c[:, None] for c in fr.wo)
    dirs = LocalDirections.from_local(wi, wo_e, alpha[:, None])
    weight = jac
    if display is not None:
        decay = display.decay(uv.reshape(1, C * q2, 2), cos_e)
        if decay is not None:
            weight = jac * decay
    smooth, peaked = integrand(dirs)
    use_lobe = bool(peaked) and settings.lobe_grid > 0
    if use_lobe:
        w_light = weight * (1.0 - lobe_share(dirs, a_cell * jac / q2, settings.window))
    channels = [g * weight for g in smooth] + [g * (w_light if use_lobe else weight) for g in peaked]
    kernels = torch.stack([torch.einsum("ncq,cq->nc", g.reshape(N, C, q2), area) for g in channels], 1)
    if not use_lobe:
        return kernels
    lobe = _lobe_rule(fr, alpha, lcd, integrand, settings, display, a_cell, q2)
    ks = len(smooth)
    return torch.cat([kernels[:, :ks], kernels[:, ks:] + lobe], dim=1)


def _lobe_rule(fr: _Frame, alpha: Tensor, lcd: LcdGeometry, integrand: Integrand,
               settings: QuadratureSettings, display: DisplayModel | None, a_cell: Tensor,
               q2: int) -> Tensor:
    N = fr.x.shape[0]
    h, w = lcd.cells
    m2 = settings.lobe_grid ** 2
    dt, dev = fr.x.dtype, fr.x.device
    # The warp needs a view above the shading horizon; elsewhere the BRDF is zero anyway.
    wo_l = torch.stack(fr.wo, -1)
    wo_safe = torch.where(fr.front[:, None], wo_l, torch.tensor([0.0, 0.0, 1.0], dtype=dt, device=dev))
    u1, u2 = lobe_grid(settings.lobe_grid, dev, dt)
    hl = sample_vndf_local(wo_safe[:, None, :], alpha[:, None], u1[None], u2[None])  # (N, S, 3)
    wil = 2.0 * (wo_safe[:, None] * hl).sum(-1, keepdim=True) * hl - wo_safe[:, None]
    wil = wil * torch.rsqrt((wil * wil).sum(-1, keepdim=True).clamp_min(1e-24))
    wi = wil @ fr.m  # local -> world, (N, S, 3)

    # Ray x + s wi against the LCD plane (its normal faces the sample: denom < 0 on approach).
    denom = wi @ lcd.normal
    towards = denom < -1e-9
    dist = ((lcd.origin - fr.x) @ lcd.normal)[:, None] / torch.where(towards, denom, -torch.ones_like(denom))
    rel = fr.x[:, None] + dist[..., None] * wi - lcd.origin
    u = rel @ lcd.edge_u / (lcd.edge_u @ lcd.edge_u)
    v = rel @ lcd.edge_v / (lcd.edge_v @ lcd.edge_v)
    inside = towards & (dist > 0) & (u >= 0) & (u < 1) & (v >= 0) & (v < 1) & fr.front[:, None]
    cell = (v.clamp(0, 1 - 1e-7) * h).long() * w + (u.clamp(0, 1 - 1e-7) * w).long()
    cos_e = -denom
    jac = cos_e.clamp_min(0.0) / (dist * dist).clamp_min(1e-24)

    wo_e = tuple(c[:, None] for c in fr.wo)
    dirs = LocalDirections.from_local((wil[..., 0], wil[..., 1], wil[..., 2]), wo_e, alpha[:, None])
    _, peaked = integrand(dirs)
    share = lobe_share(dirs, a_cell * jac / q2, settings.window)
    scale = share / (m2 * vndf_pdf(dirs, dirs.ndf())).clamp_min(1e-30)
    if display is not None:
        decay = display.decay(torch.stack([u, v], -1), cos_e)
        if decay is not None:
            scale = scale * decay
    scale = torch.where(inside, scale, torch.zeros_like(scale))
    contrib = torch.stack([g * scale for g in peaked], 1)  # (N, Kp, S)
    out = torch.zeros(N, len(peaked), h * w, dtype=dt, device=dev)
    idx = torch.where(inside, cell, torch.zeros_like(cell))
    out.scatter_add_(2, idx[:, None, :].expand(-1, len(peaked), -1), contrib)
    return out


def chunk_size(settings: QuadratureSettings, cells: int) -> int:
    """Pixels per chunk so that pixels x light points stays below ``settings.max_elements``.
    Raises MitsvbrdfError when a single pixel's points exceed it (the memory bound cannot hold)."""
    pts = cells * settings.cell_order ** 2 + settings.lobe_grid ** 2
    if pts > settings.max_elements:
        raise MitsvbrdfError(f"the reference quadrature needs {pts} points per texel ({cells} cells x cell_order "
                             f"{settings.cell_order}^2 + lobe_grid {settings.lobe_grid}^2), more than max_elements = "
                             f"{settings.max_elements}: lower cell_order or lobe_grid")
    return max(1, settings.max_elements // pts)
