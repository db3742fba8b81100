"""Sampling importance distribution L_pdf on the LCD (paper Sec. 3.2, Eq. 2-3).

For a surface point x with normal n and roughness r, Eq. 2 projects the GGX NDF onto the LCD:

    L'_pdf(x, y) = D(h) (h . n) (-n_l . w_i) / (4 (h . w_o) |x - y|^2),

which is the density, per unit LCD area, of w_i = reflect(w_o, h) when h is drawn from
D(h) (h . n). Eq. 3 normalises it over the LCD polygon, and L_pdf sums the normalised
distributions of all texels. We integrate each point's distribution over every *cell* with the
deterministic light + visible-normal quadrature of :mod:`mitsvbrdf.render.quadrature`, so a
near-mirror material gives a sharp but finite peak (all of a texel's mass in its mirror cell)
instead of missing it between grid points. The result is min-max normalised to [0, 1] per
material, as in the paper.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .brdf import roughness_to_alpha
from .render.quadrature import LocalDirections, QuadratureSettings, cell_kernels, chunk_size
from .checks import check_int
from .errors import MaterialError
from .svbrdf import NORMAL_TOL, RANGE_TOL
from .rig import Rig


def projected_ndf(d: LocalDirections):
    """Per-solid-angle density of w_i under half-vectors drawn from D(h)(h.n): D (h.n) / (4 h.w_o)."""
    return [], [d.ndf() * d.cos_h.clamp_min(0.0) / (4.0 * d.o_dot_h.clamp_min(1e-6))]


def texel_importance(normal: Tensor, roughness: Tensor, rig: Rig, *,
                     settings: QuadratureSettings | None = None, texel_stride: int = 1) -> Tensor:
    """Eq. 2 integrated over each cell, per texel, before the normalisation of Eq. 3.

    Args:
        normal: (3, H, W) unit normals of one material; roughness: (1, H, W).
        texel_stride: use every k-th texel in each direction (a cheaper, coarser L_pdf).
    Returns:
        (N, h * w) cell masses per texel, N = texels used; each row sums to the fraction of the
        texel's NDF mass whose mirror directions land on the LCD.
    """
    settings = settings or QuadratureSettings()
    H, W = normal.shape[-2:]
    dev, dt = normal.device, normal.dtype
    s = int(texel_stride)
    x = rig.surface_points((H, W), dev)[::s, ::s].reshape(-1, 3).to(dt)
    wo = rig.view_directions((H, W), dev)[::s, ::s].reshape(-1, 3).to(dt)
    n = normal[:, ::s, ::s].reshape(3, -1).t()
    alpha = roughness_to_alpha(roughness[0, ::s, ::s].reshape(-1))
    lcd = rig.lcd_geometry(dev, dt)
    step = chunk_size(settings, lcd.cells[0] * lcd.cells[1])
    rows = [cell_kernels(x[i:i + step], n[i:i + step], wo[i:i + step], alpha[i:i + step], lcd,
                         projected_ndf, settings)[:, 0]
            for i in range(0, x.shape[0], step)]
    return torch.cat(rows, 0)


def importance(normal: Tensor, roughness: Tensor, rig: Rig, *, normalize: bool = True,
               settings: QuadratureSettings | None = None, texel_stride: int = 1) -> Tensor:
    """L_pdf of one or a batch of materials on the LCD's cell grid.

    Args:
        normal: (B, 3, H, W) or (3, H, W) unit tangent-space normals.
        roughness: (B, 1, H, W) or (1, H, W) roughness r in [0, 1].
        rig: the capture rig (LCD geometry and camera position).
        normalize: min-max normalise each material's L_pdf to [0, 1] (paper); False returns the
            sum over texels of the per-texel normalised cell masses (Eq. 3 summed), whose total is
            the number of texels with any mass on the LCD.
        texel_stride: subsample the texel grid by this factor (cost / detail trade).
    Returns:
        (B, 1, h, w), or (1, h, w) for unbatched input. Never NaN: a texel whose NDF puts no mass on
        the LCD contributes nothing, and a material whose L_pdf is flat normalises to all ones.
    """
    batched = normal.ndim == 4
    if not batched:
        normal, roughness = normal.unsqueeze(0), roughness.unsqueeze(0)
    if normal.ndim != 4 or normal.shape[1] != 3 or roughness.shape[1] != 1 or \
            normal.shape[-2:] != roughness.shape[-2:] or normal.shape[0] != roughness.shape[0]:
        raise MaterialError(f"importance needs normal (B, 3, H, W) and roughness (B, 1, H, W), got "
                            f"{tuple(normal.shape)} and {tuple(roughness.shape)}")
    for name, t in (("normal", normal), ("roughness", roughness)):
        bad = int((~torch.isfinite(t.detach())).sum())
        if bad:  # a NaN texel would otherwise drop out and leave a silently wrong (e.g. uniform) L_pdf
            raise MaterialError(f"importance: the {name} map has {bad} NaN/Inf values")
    r = roughness.detach()
    outside = int(((r < -RANGE_TOL) | (r > 1 + RANGE_TOL)).sum())
    if outside:
        raise MaterialError(f"importance: roughness must lie in [0, 1], {outside} values do not "
                            f"(range {float(r.min()):.4g}..{float(r.max()):.4g})")
    off = int(((torch.linalg.vector_norm(normal.detach(), dim=1) - 1).abs() > NORMAL_TOL).sum())
    if off:
        raise MaterialError(f"importance: normals must be unit vectors, {off} texels are not")
    check_int("texel_stride", texel_stride, 1)
    h, w = rig.lcd_cells
    out = []
    for b in range(normal.shape[0]):
        k = texel_importance(normal[b], roughness[b], rig, settings=settings, texel_stride=texel_stride)
        mass = k.sum(1, keepdim=True)
        k = torch.where(mass > 1e-20, k / mass.clamp_min(1e-20), torch.zeros_like(k))
        lpdf = k.sum(0)
        if normalize:
            lo, hi = lpdf.min(), lpdf.max()
            span = hi - lo
            lpdf = torch.where(span > 1e-12 * hi.abs().clamp_min(1e-30),
                               (lpdf - lo) / span.clamp_min(1e-30), torch.ones_like(lpdf))
        out.append(lpdf.reshape(1, h, w))
    res = torch.stack(out, 0)
    return res if batched else res[0]
