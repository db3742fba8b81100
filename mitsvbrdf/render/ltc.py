"""LTC renderer (Heitz et al. 2016): the fast baseline, in torch, with exact LCD-cell partition.

The specular lobe at a point is approximated by a linearly transformed cosine: a distribution D_o
with ``integral over P of D_o = form factor of (M^-1 P)``, so each LCD cell's specular kernel is
one clipped polygon integral after transforming the cell's corners by M^-1 (fitted per roughness
and view angle by :mod:`mitsvbrdf.render.ltc_fit`), scaled by the lobe's directional albedo. The
diffuse kernel is the exact form factor of the cell. Frames: the local frame at a point has +z
along the shading normal and the view direction in its xz-plane (x towards the view).

    I = kd (1 - ks) sum_c E_c L_c + sum_c E'_c L_c (ks (A_1 - A_S) + A_S)

E_c: exact cell form factor; E'_c: the LTC integral over cell c; A_1, A_S: the lobe's directional
albedo with F = 1 and with F = S (Schlick weight), so the Fresnel term of mitsvbrdf.brdf is exact
in the albedo (not in its angular distribution). Emission decay, when the scene has one, is applied
at the cell centres (an approximation the benchmark measures).
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..rig import Rig
from .polygon import clipped_polygon_form_factor, clipped_polygon_vector_form_factor, lcd_cell_form_factors


def view_frame(n: Tensor, wo: Tensor) -> tuple[Tensor, Tensor]:
    """(N, 3, 3) frames (rows x, y, z = n) with w_o in the xz-plane, and cos(theta_v) (N,)."""
    cos_v = (n * wo).sum(-1)
    x = wo - cos_v[:, None] * n
    norm = torch.linalg.vector_norm(x, dim=-1, keepdim=True)
    # Normal incidence: any tangent will do.
    fallback = torch.linalg.cross(n, torch.tensor([0.0, 1.0, 0.0], dtype=n.dtype, device=n.device).expand_as(n), dim=-1)
    fallback = torch.where(torch.linalg.vector_norm(fallback, dim=-1, keepdim=True) > 1e-6, fallback,
                           torch.tensor([1.0, 0.0, 0.0], dtype=n.dtype, device=n.device).expand_as(n))
    # Below ~1e-4 the tangential part of w_o is rounding noise: use the fallback tangent there.
    x = torch.where(norm > 1e-4, x / norm.clamp_min(1e-12), fallback)
    x = torch.nn.functional.normalize(x - (x * n).sum(-1, keepdim=True) * n, dim=-1)  # re-orthogonalise
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


def pattern_pyramid(radiance: Tensor) -> list[Tensor]:
    """Box-filtered mip levels of per-cell radiance (..., 3, h, w), finest first, down to 1 x 1."""
    lead = radiance.shape[:-3]
    x = radiance.reshape(-1, 3, *radiance.shape[-2:])
    levels = [x]
    while max(levels[-1].shape[-2:]) > 1:
        levels.append(torch.nn.functional.avg_pool2d(levels[-1], 2, ceil_mode=True))
    return [lv.reshape(*lead, 3, *lv.shape[-2:]) for lv in levels]


def sample_pyramid(levels: list[Tensor], uv: Tensor, lod: Tensor) -> Tensor:
    """Trilinear lookup: levels of (P, 3, h_k, w_k), uv (N, 2) in [0, 1] (u along columns),
    lod (N,) in [0, len(levels) - 1]; returns (N, P, 3)."""
    grid = (2.0 * uv - 1.0).view(1, -1, 1, 2)
    samples = []
    for lv in levels:
        img = lv.reshape(1, -1, *lv.shape[-2:])
        s = torch.nn.functional.grid_sample(img, grid, mode="bilinear", padding_mode="border", align_corners=False)
        samples.append(s.view(lv.shape[0], 3, -1).permute(2, 0, 1))
    stack = torch.stack(samples, 0)  # (L, N, P, 3)
    lod = lod.clamp(0, len(levels) - 1)
    lo = lod.floor().long().clamp(max=len(levels) - 1)
    hi = (lo + 1).clamp(max=len(levels) - 1)
    f = (lod - lo.to(lod.dtype))[:, None, None]
    idx = torch.arange(uv.shape[0], device=uv.device)
    return stack[lo, idx] * (1 - f) + stack[hi, idx] * f


def prefiltered_lookup(x: Tensor, n: Tensor, wo: Tensor, m_inv: Tensor, spread: Tensor, rig: Rig,
                       levels: list[Tensor]) -> tuple[Tensor, Tensor]:
    """One LTC polygon integral over the whole LCD and one prefiltered radiance fetch per point.

    The fetch point is where the LTC's average direction (its vector form factor, mapped back by
    M) meets the LCD; the level of detail matches a footprint of half-angle ``spread`` (radians)
    at that distance. Returns (E (N,), radiance (N, P, 3)).
    """
    lcd = rig.lcd_geometry(x.device, x.dtype)
    corners = rig.lcd_corners.to(x.device, x.dtype)
    frame, cos_v = view_frame(n, wo)
    local = torch.einsum("nak,vk->nva", frame, corners) - torch.einsum("nak,nk->na", frame, x)[:, None]
    f = clipped_polygon_vector_form_factor(torch.einsum("nab,nvb->nva", m_inv, local))
    e = torch.where(cos_v > 0, f[:, 2].abs(), torch.zeros_like(cos_v))
    f = f * torch.where(f[:, 2:] < 0, -1.0, 1.0)
    d = torch.linalg.solve(m_inv, f.unsqueeze(-1)).squeeze(-1)
    d = torch.nn.functional.normalize(torch.einsum("nak,na->nk", frame, d), dim=-1)
    uv, dist, _ = lcd.hit(x, d)
    uv = uv.clamp(0, 1)
    h, w = rig.lcd_cells
    cell = torch.sqrt(lcd.area / (h * w))
    footprint = 2.0 * dist.abs() * torch.tan(spread.clamp(1e-4, 1.4))
    lod = torch.log2((footprint / cell).clamp_min(1.0))
    return e, sample_pyramid(levels, uv, lod)


def render_ltc(svbrdf, patterns: Tensor, rig: Rig, table, *, lobes: str = "both",
               mode: str = "exact") -> Tensor:
    """Render B materials under P patterns with the LTC approximation; (B, P, 3, H, W).

    ``table`` provides ``lookup(roughness (N,), cos_theta_v (N,)) -> (m_inv (N, 3, 3), a_one (N,),
    a_schlick (N,))`` (see :mod:`mitsvbrdf.render.ltc_fit`). ``mode``: "exact" sums the polygon
    integral over every LCD cell; "prefiltered" integrates the whole LCD once and multiplies by a
    fetch from a box-filtered pattern pyramid (the textured-light LTC of Heitz et al. 2016, and of
    the paper's training renderer), with the cosine lobe for the diffuse term.
    """
    if mode not in ("exact", "prefiltered"):
        raise ValueError(f"mode must be 'exact' or 'prefiltered', got {mode!r}")
    B = svbrdf.batch_size
    H, W = svbrdf.resolution
    dev, dt = svbrdf.normal.device, svbrdf.normal.dtype
    rad = rig.material_radiance(patterns, B, dev, dt)  # (B, P, 3, C)
    P = rad.shape[1]
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
    if mode == "prefiltered":
        if decay is not None:
            raise ValueError("mode='prefiltered' does not model emission decay; use mode='exact'")
        h, w = rig.lcd_cells
        levels = [pattern_pyramid(rad[b].reshape(P, 3, h, w)) for b in range(B)]
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
            if mode == "prefiltered":
                eye = torch.eye(3, dtype=dt, device=dev).expand(xs.shape[0], 3, 3)
                if lobes != "specular":
                    # 0.3 rad: the footprint that fitted MonoGrad + random patterns best in a sweep.
                    e, lr = prefiltered_lookup(xs, n, ws, eye, torch.full_like(r[:, 0], 0.3), rig, levels[b])
                    img = img + (kd * (1 - ks))[:, None] * e[:, None, None] * lr
                if lobes != "diffuse":
                    m_inv, a_one, a_s = table.lookup(r[:, 0], (n * ws).sum(-1))
                    spread = 2.0 * torch.atan((r[:, 0] ** 2).clamp_min(1e-4))
                    e, lr = prefiltered_lookup(xs, n, ws, m_inv, spread, rig, levels[b])
                    scale = ks * (a_one - a_s)[:, None] + a_s[:, None]
                    img = img + scale[:, None] * e[:, None, None] * lr
                rows.append(img)
                continue
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
