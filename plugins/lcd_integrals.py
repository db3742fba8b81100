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

import drjit as dr
import mitsuba as mi

_TINY = 1e-24


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

    def to_view(self, v):
        return mi.Vector3f(dr.dot(self.x, v), dr.dot(self.y, v), dr.dot(self.n, v))


def ltc_density(m, w):
    """D_ltc(w) (1/sr) for the unit view-frame direction w and M^-1 = [[a, 0, b], [0, c, 0],
    [d, 0, 1]] given as m = (a, b, c, d): ``(z')^+ / pi |det M^-1| / |M^-1 w|^3`` with
    ``z' = (M^-1 w)_z / |M^-1 w|``."""
    a, b, c, d = m
    wp = mi.Vector3f(a * w.x + b * w.z, c * w.y, d * w.x + w.z)
    len2 = dr.maximum(dr.squared_norm(wp), _TINY)
    return dr.maximum(wp.z, 0.0) * dr.abs(c * (a - b * d)) / (dr.pi * len2 * len2)
