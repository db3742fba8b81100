"""LTC renderer (Heitz et al. 2016): the fast baseline, in torch, with exact LCD-cell partition.

The specular lobe at a point is approximated by a linearly transformed cosine: a distribution D_o
with ``integral over P of D_o = form factor of (M^-1 P)``, so each LCD cell's specular kernel is
one clipped polygon integral after transforming the cell's corners by M^-1 (fitted per roughness
and view angle by :mod:`mitsvbrdf.render.ltc_fit`), scaled by the lobe's directional albedo. The
diffuse kernel is the exact form factor of the cell. Frames: the local frame at a point has +z
along the shading normal and the view direction in its xz-plane (x towards the view).

    I = kd (1 - ks) sum_c E_c L_c + sum_c E'_c L_c (ks (A_1 - A_S) + A_S)

E_c: exact cell form factor; E'_c: the LTC integral over cell c; A_1, A_S: the lobe's directional
albedo with F = 1 and with F = S (Schlick weight), so the Fresnel term of DESIGN.md is exact in
the albedo (not in its angular distribution). Emission decay, when the scene has one, is applied
at the cell centres (an approximation the benchmark measures).
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..rig import Rig
from .polygon import clipped_polygon_form_factor, lcd_cell_form_factors


def view_frame(n: Tensor, wo: Tensor) -> tuple[Tensor, Tensor]:
    """(N, 3, 3) frames (rows x, y, z = n) with w_o in the xz-plane, and cos(theta_v) (N,)."""
    cos_v = (n * wo).sum(-1)
    x = wo - cos_v[:, None] * n
    norm = torch.linalg.vector_norm(x, dim=-1, keepdim=True)
    # Normal incidence: any tangent will do.
    fallback = torch.linalg.cross(n, torch.tensor([0.0, 1.0, 0.0], dtype=n.dtype, device=n.device).expand_as(n), dim=-1)
    fallback = torch.where(torch.linalg.vector_norm(fallback, dim=-1, keepdim=True) > 1e-6, fallback,
                           torch.tensor([1.0, 0.0, 0.0], dtype=n.dtype, device=n.device).expand_as(n))
    x = torch.where(norm > 1e-7, x / norm.clamp_min(1e-12), torch.nn.functional.normalize(fallback, dim=-1))
    y = torch.linalg.cross(n, x, dim=-1)
    return torch.stack([x, y, n], 1), cos_v


def ltc_cell_integrals(x: Tensor, n: Tensor, wo: Tensor, m_inv: Tensor, cell_corners: Tensor) -> Tensor:
    """Integral of each point's LTC distribution over every cell: (N, C).

    Args:
        x, n, wo: (N, 3) positions, unit normals, unit view directions (world).
        m_inv: (N, 3, 3) inverse LTC matrices in the view frame of :func:`view_frame`.
        cell_corners: (C, 4, 3) cell corners (world).
    """
    frame, cos_v = view_frame(n, wo)
    rel = cell_corners[None] - x[:, None, None]  # (N, C, 4, 3)
    local = torch.einsum("nak,ncvk->ncva", frame, rel)
    warped = torch.einsum("nab,ncvb->ncva", m_inv, local)
    e = clipped_polygon_form_factor(warped)
    return torch.where((cos_v > 0)[:, None], e, torch.zeros_like(e))


def render_ltc(svbrdf, patterns: Tensor, rig: Rig, table, *, lobes: str = "both") -> Tensor:
    """Render B materials under P patterns with the LTC approximation; (B, P, 3, H, W).

    ``table`` provides ``lookup(roughness (N,), cos_theta_v (N,)) -> (m_inv (N, 3, 3), a_one (N,),
    a_schlick (N,))`` (see :mod:`mitsvbrdf.render.ltc_fit`).
    """
    rig.check_patterns(patterns)
    B = svbrdf.batch_size
    H, W = svbrdf.resolution
    dev, dt = svbrdf.normal.device, svbrdf.normal.dtype
    rad = rig.display.radiance(patterns.to(dev, dt))
    if rad.ndim == 4:
        rad = rad.unsqueeze(0).expand(B, *rad.shape)
    P = rad.shape[1]
    rad = rad.reshape(B, P, 3, -1)
    corners = rig.lcd_cell_corners(dev).reshape(-1, 4, 3).to(dt)
    x = rig.surface_points((H, W), dev).reshape(-1, 3).to(dt)
    wo = rig.view_directions((H, W), dev).reshape(-1, 3).to(dt)
    decay = None
    if rig.display.has_decay:
        centres = corners.mean(1)
        d = centres[None] - x[:, None]
        lcd = rig.lcd_geometry(dev, dt)
        cos_e = -(torch.nn.functional.normalize(d, dim=-1) @ lcd.normal)
        h, w = rig.lcd_cells
        v, u = torch.meshgrid((torch.arange(h, device=dev, dtype=dt) + 0.5) / h,
                              (torch.arange(w, device=dev, dtype=dt) + 0.5) / w, indexing="ij")
        decay = rig.display.decay(torch.stack([u, v], -1).reshape(1, -1, 2), cos_e)
    step = max(1, (1 << 20) // corners.shape[0])  # pixels per chunk: ~1M polygon integrals
    out = []
    for b in range(B):
        maps = [m[b].reshape(m.shape[1], -1).t() for m in (svbrdf.normal, svbrdf.diffuse, svbrdf.specular,
                                                             svbrdf.roughness)]
        rows = []
        for s in range(0, x.shape[0], step):
            n, kd, ks, r = (m[s:s + step] for m in maps)
            xs, ws = x[s:s + step], wo[s:s + step]
            dec = None if decay is None else decay[s:s + step]
            img = torch.zeros(xs.shape[0], P, 3, dtype=dt, device=dev)
            if lobes != "specular":
                e = lcd_cell_form_factors(xs, n, ws, corners)
                e = e if dec is None else e * dec
                img = img + (kd * (1 - ks))[:, None] * torch.einsum("nc,pjc->npj", e, rad[b])
            if lobes != "diffuse":
                m_inv, a_one, a_s = table.lookup(r[:, 0], (n * ws).sum(-1))
                e = ltc_cell_integrals(xs, n, ws, m_inv, corners)
                e = e if dec is None else e * dec
                scale = ks * (a_one - a_s)[:, None] + a_s[:, None]
                img = img + scale[:, None] * torch.einsum("nc,pjc->npj", e, rad[b])
            rows.append(img)
        out.append(torch.cat(rows, 0).permute(1, 2, 0).reshape(P, 3, H, W))
    return torch.stack(out, 0)
