"""Pointwise pieces of the ``importance`` integrator's control variate (Dr.Jit).

The control variate itself (what it is, its closed-form integral, the per-texel coefficients) is
:mod:`mitsvbrdf.render.control_variate`; the integrator receives those coefficients and
evaluates g_p in each sampled direction with the helpers below, so known part and residual use
the same numbers.

Frames: "local" is the sample's geometric frame at the shading point (Mitsuba's ``si.to_local``);
the view frame has +z along the shading normal n and the view direction in its xz-plane (x towards
the view), as :func:`mitsvbrdf.render.ltc.view_frame` defines it for the LTC table.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

from mitsvbrdf.render.ltc_fit import MAX_VIEW_ANGLE

_TINY = 1e-24
#: sqrt(1 - cos(MAX_VIEW_ANGLE)) of :mod:`mitsvbrdf.render.ltc_fit`: the table's last column
_MAX_VIEW_X = math.sqrt(1.0 - math.cos(MAX_VIEW_ANGLE))


class ViewFrame:
    """Per-lane view frame (x towards the view, z = shading normal n), in the local frame; the same
    construction as :func:`mitsvbrdf.render.ltc.view_frame`, fallback tangent included."""

    def __init__(self, n, wi):
        self.n = n
        cos_v = dr.dot(n, wi)
        t = wi - cos_v * n
        # Normal incidence (|t| <= 1e-4): the lobe is isotropic there, any tangent will do.
        alt = dr.cross(n, mi.Vector3f(0.0, 1.0, 0.0))
        alt = dr.select(dr.squared_norm(alt) > 1e-12, alt, mi.Vector3f(1.0, 0.0, 0.0))
        x = dr.select(dr.squared_norm(t) > 1e-8, t, alt)
        x = x - dr.dot(x, n) * n
        self.x = x * dr.rsqrt(dr.maximum(dr.squared_norm(x), _TINY))
        self.y = dr.cross(n, self.x)
        self.cos_v = cos_v

    @classmethod
    def of_axes(cls, x, n):
        """The frame of the unit axes x and n (local) a :class:`ViewFrame` computed before (its
        ``cos_v`` is not kept)."""
        frame = cls.__new__(cls)
        frame.x, frame.n, frame.y, frame.cos_v = x, n, dr.cross(n, x), None
        return frame

    def to_view(self, v):
        return mi.Vector3f(dr.dot(self.x, v), dr.dot(self.y, v), dr.dot(self.n, v))


def ltc_density(m, w):
    """D_ltc(w) (1/sr) for the unit view-frame direction w and M^-1 = [[a, 0, b], [0, c, 0],
    [d, 0, 1]] given as m = (a, b, c, d): ``(z')^+ / pi |det M^-1| / |M^-1 w|^3`` with
    ``z' = (M^-1 w)_z / |M^-1 w|``."""
    a, b, c, d = m
    wp = warp(m, w)
    len2 = dr.maximum(dr.squared_norm(wp), _TINY)
    return dr.maximum(wp.z, 0.0) * dr.abs(c * (a - b * d)) / (dr.pi * len2 * len2)


def ltc_lookup(table, size: int, roughness, cos_v):
    """The LTC table's lookup, as :meth:`mitsvbrdf.render.ltc_fit.LtcTable.lookup` does it (bilinear
    in (r, sqrt(1 - cos theta_v)), albedos divided by the hemisphere mass), for the flat
    (size, size, 6) ``table`` (M^-1 entries a, b, c, d, then A_1, A_S per entry): returns
    ``((a, b, c, d), A_1, A_S)``, differentiable in roughness and cos theta_v."""
    n = size - 1
    fr = dr.clip(roughness, 0.0, 1.0) * n
    x = dr.sqrt(dr.maximum(1.0 - dr.clip(cos_v, 0.0, 1.0), 0.0) + 1e-12)
    fv = dr.minimum(x, _MAX_VIEW_X) * n
    i0 = dr.clip(mi.Int32(dr.floor(dr.detach(fr))), 0, n - 1)
    j0 = dr.clip(mi.Int32(dr.floor(dr.detach(fv))), 0, n - 1)
    tr, tv = fr - mi.Float(i0), fv - mi.Float(j0)
    at = mi.UInt32(i0 * size + j0) * 6

    def entry(k):
        v00, v01 = (dr.gather(mi.Float, table, at + o + k) for o in (0, 6))
        v10, v11 = (dr.gather(mi.Float, table, at + o + k) for o in (size * 6, size * 6 + 6))
        return dr.lerp(dr.lerp(v00, v01, tv), dr.lerp(v10, v11, tv), tr)

    a, b, c, d, a_one, a_s = (entry(k) for k in range(6))
    # the hemisphere mass (1 + cos phi) / 2 of :func:`mitsvbrdf.render.ltc_fit.hemisphere_mass`
    mass = dr.maximum(0.5 * (1.0 + dr.sign(a - b * d) * a * dr.rsqrt(dr.maximum(a * a + d * d, _TINY))), 1e-3)
    return (a, b, c, d), a_one / mass, a_s / mass


def warp(m, w):
    """M^-1 w for the view-frame vector w and M^-1 given as m = (a, b, c, d) (:func:`ltc_density`)."""
    a, b, c, d = m
    return mi.Vector3f(a * w.x + b * w.z, c * w.y, d * w.x + w.z)


def _unit_edge_z(p, q):
    """The z component of theta (p x q) / |p x q| for unit vectors p, q (Lambert's formula's edge
    term), as :func:`mitsvbrdf.render.polygon._unit_edge_z`: |p x q| = sqrt(1 - (p . q)^2), theta
    from the same sine, so theta / |p x q| stays ~1 and finite (safe_sqrt: no infinite derivative)
    as the edge shrinks."""
    cos = dr.dot(p, q)
    sin = dr.safe_sqrt(1.0 - cos * cos)
    ratio = dr.select(sin > 1e-12, dr.atan2(sin, cos) / dr.maximum(sin, 1e-12), 1.0)
    return ratio * (p.x * q.y - p.y * q.x)


def grid_cell_form_factors(corners) -> list:
    """Form factors (unclipped) of the m x n quads of a grid of corner vectors (rows of Vector3f,
    (m + 1) x (n + 1), any length), as :func:`mitsvbrdf.render.polygon.grid_cell_form_factors`:
    rows of Floats, m x n; neighbouring quads share their edge terms."""
    c = [[v * dr.rsqrt(dr.maximum(dr.squared_norm(v), _TINY)) for v in row] for row in corners]
    m, n = len(c) - 1, len(c[0]) - 1
    across = [[_unit_edge_z(c[i][j], c[i][j + 1]) for j in range(n)] for i in range(m + 1)]
    down = [[_unit_edge_z(c[i][j], c[i + 1][j]) for j in range(n + 1)] for i in range(m)]
    return [[dr.abs(across[i][j] + down[i][j + 1] - across[i + 1][j] - down[i][j]) / (2.0 * dr.pi)
             for j in range(n)] for i in range(m)]
