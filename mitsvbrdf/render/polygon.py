"""Closed-form integral of a clamped cosine over a spherical polygon, with horizon clipping.

For directions expressed in a local frame whose +z is the normal, the cosine-weighted solid angle
of the polygon with vertices p_0..p_{K-1} (vectors from the shading point, any length), clipped
to the upper hemisphere, is

    E = (1 / 2 pi) | sum_k theta_k (p_k x p_{k+1})_z / |p_k x p_{k+1}| |,

theta_k the angle between p_k and p_{k+1} (Lambert's formula). ``E`` is the form factor of the
polygon: (1 / pi) times the integral of (z . w)^+ over it, so a polygon covering the hemisphere
gives 1. This is exact, which is what the LTC renderer builds on (Heitz et al. 2016): the diffuse
lobe uses it directly, the specular lobe after a linear transform of the vertices.

Clipping works for convex polygons (LCD cells and the LCD itself): each edge keeps its visible
part, and when the polygon crosses the horizon one closing edge runs along it from the exit to
the entry point. Everything is vectorised over leading dimensions; no Python loop over polygons.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ..brdf import tangent_frame


def _unit(p: Tensor) -> Tensor:
    return p / torch.linalg.vector_norm(p, dim=-1, keepdim=True).clamp_min(1e-20)


def _angle_over_sine(s: Tensor, c: Tensor) -> Tensor:
    """theta / sin(theta) of the angle with sine s >= 0 and cosine c; -> 1 as the edge shrinks
    (the clamp only guards the division)."""
    return torch.where(s > 1e-12, torch.atan2(s, c) / s.clamp_min(1e-12), torch.ones_like(s))


def _edge_vector(p: Tensor, q: Tensor) -> Tensor:
    """theta (p x q) / |p x q| for edges p -> q (..., 3); finite and differentiable when p ~ q."""
    pn, qn = _unit(p), _unit(q)
    cross = torch.linalg.cross(pn, qn, dim=-1)
    s = torch.linalg.vector_norm(cross, dim=-1, keepdim=True)
    return _angle_over_sine(s, (pn * qn).sum(-1, keepdim=True)) * cross


def _unit_edge_z(pn: Tensor, qn: Tensor) -> Tensor:
    """The z component of :func:`_edge_vector` for unit vectors, without the full cross product:
    |p x q| = sqrt(1 - (p . q)^2). Where that loses precision (p ~ q), theta comes from the same
    |p x q|, so theta / |p x q| stays ~1 and the term stays accurate."""
    c = (pn * qn).sum(-1)
    s = (1.0 - c * c).clamp_min(0.0).sqrt()
    return _angle_over_sine(s, c) * (pn[..., 0] * qn[..., 1] - pn[..., 1] * qn[..., 0])


def polygon_vector_form_factor(vertices: Tensor) -> Tensor:
    """Vector form factor (1 / 2 pi) sum_k theta_k (p_k x p_{k+1}) / |p_k x p_{k+1}| of polygons
    (..., K, 3), unclipped and frame-free: for a polygon wholly above the horizon of a unit
    normal n, ``|n . result|`` is its form factor; (..., 3)."""
    b = torch.roll(vertices, shifts=-1, dims=-2)
    return _edge_vector(vertices, b).sum(-2) / (2.0 * math.pi)


def grid_cell_form_factors(corners: Tensor) -> Tensor:
    """Form factors of the m x n quads of a grid of corners (..., m + 1, n + 1, 3), unclipped (a
    quad wholly above the horizon z = 0 gets its form factor; only there is it one), (..., m, n).
    Neighbouring quads share their edges, so the grid costs 2 m n + m + n edge terms instead of
    4 m n: quad (i, j) runs (i, j) -> (i, j + 1) -> (i + 1, j + 1) -> (i + 1, j)."""
    c = _unit(corners)  # each corner normalised once, not once per edge
    across = _unit_edge_z(c[..., :, :-1, :], c[..., :, 1:, :])  # (..., m + 1, n)
    down = _unit_edge_z(c[..., :-1, :, :], c[..., 1:, :, :])  # (..., m, n + 1)
    total = across[..., :-1, :] + down[..., :, 1:] - across[..., 1:, :] - down[..., :, :-1]
    return total.abs() / (2.0 * math.pi)


def clipped_polygon_vector_form_factor(vertices: Tensor) -> Tensor:
    """Vector form factor (1 / 2 pi) sum_k theta_k (p_k x p_{k+1}) / |p_k x p_{k+1}| of convex
    polygons clipped to z >= 0, signed by the polygon's orientation; (..., 3).

    Its z component is the (signed) form factor; its direction is the polygon's average
    cosine-weighted direction (used to look up prefiltered textures).
    """
    a = vertices
    b = torch.roll(vertices, shifts=-1, dims=-2)
    za, zb = a[..., 2], b[..., 2]
    a_up, b_up = za > 0, zb > 0
    # Point where the edge crosses z = 0 (only used where it does).
    t = (za / torch.where(a_up != b_up, za - zb, torch.ones_like(za))).unsqueeze(-1)
    cross_pt = a + t * (b - a)
    start = torch.where(a_up.unsqueeze(-1), a, cross_pt)
    end = torch.where(b_up.unsqueeze(-1), b, cross_pt)
    visible = (a_up | b_up).unsqueeze(-1)
    total = torch.where(visible, _edge_vector(start, end), torch.zeros_like(a)).sum(-2)
    # Closing edge along the horizon from the exit point (up -> down) to the entry (down -> up).
    exits = (a_up & ~b_up).unsqueeze(-1)
    entries = (~a_up & b_up).unsqueeze(-1)
    exit_pt = torch.where(exits, cross_pt, torch.zeros_like(cross_pt)).sum(-2)
    entry_pt = torch.where(entries, cross_pt, torch.zeros_like(cross_pt)).sum(-2)
    crosses = (exits.any(-2) & entries.any(-2))
    total = total + torch.where(crosses, _edge_vector(exit_pt, entry_pt), torch.zeros_like(total))
    return total / (2.0 * math.pi)


def clipped_polygon_form_factor(vertices: Tensor) -> Tensor:
    """Form factor of convex polygons clipped to z >= 0.

    Args:
        vertices: (..., K, 3) polygon vertices relative to the shading point, in the local frame
            (+z = normal), in order around the polygon (either orientation).
    Returns:
        (...) form factors in [0, 1].
    """
    return clipped_polygon_vector_form_factor(vertices)[..., 2].abs()


def lcd_cell_form_factors(x: Tensor, n: Tensor, wo: Tensor, cell_corners: Tensor) -> Tensor:
    """Exact per-cell diffuse kernels: the form factor of every LCD cell seen from each point.

    ``K[x, c] = (1 / pi) * integral over cell c of (n . w_i)^+ dw_i``, zero where the view is
    below the shading horizon (n . w_o <= 0), i.e. the quantity the reference renderer integrates
    by quadrature for the diffuse lobe without emission decay.

    Args:
        x, n, wo: (N, 3) positions (metres), unit shading normals, unit view directions.
        cell_corners: (C, 4, 3) cell corners in order (e.g. ``Rig.lcd_cell_corners().reshape(-1, 4, 3)``).
    Returns:
        (N, C) form factors.
    """
    t, b = tangent_frame(n)
    frame = torch.stack([t, b, n], 1)  # (N, 3, 3), rows = local axes
    rel = cell_corners[None] - x[:, None, None]  # (N, C, 4, 3)
    local = torch.einsum("nak,ncvk->ncva", frame, rel)
    ff = clipped_polygon_form_factor(local)
    return torch.where(((n * wo).sum(-1) > 0)[:, None], ff, torch.zeros_like(ff))
