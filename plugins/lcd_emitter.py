"""``lcd``: an LCD panel showing patterns, as a Mitsuba 3 area emitter on a rectangle.

Parameters (the display model of mitsvbrdf.rig.DisplayModel; optional parts compiled in only
when the scene sets them):
    cells_x, cells_y   pattern grid w, h (default 32 x 32)
    intensity          float or rgb: radiance of a cell driven at 1.0
    gamma              optional response exponent, radiance ~ drive^gamma
    color_matrix       optional 9 numbers (row-major 3x3) mixing drive RGB
    decay_cos_power    optional angular decay cos(theta_emit)^k
    decay_gradient     optional (gx, gy): ramp max(0, 1 + gx (u - 1/2) + gy (v - 1/2))
    data               optional (P, 3, h, w) tensor of drive values in [0, 1] (default: 1 white)

Cell (row, col) covers uv in [col/w, (col+1)/w) x [row/h, (row+1)/h) of the rectangle, so cell
(0, 0) sits at its local corner (-1, -1), as in mitsvbrdf.rig. ``eval``/``sample_direction`` use
pattern 0 (so ``mi.render`` works); :meth:`radiance_all` returns all P patterns at the same points,
which the ``importance`` integrator uses to render every pattern from one set of light samples.
Sampling is uniform in area, independent of the patterns, so black cells still receive
gradients. ``traverse`` exposes ``data`` as differentiable.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi


def _floats(v, n: int, name: str) -> list[float]:
    if isinstance(v, str):
        vals = [float(t) for t in v.replace(",", " ").split()]
    elif isinstance(v, (int, float)):
        vals = [float(v)]
    else:
        vals = [float(v[i]) for i in range(len(v))]
    if len(vals) == 1 and n == 3:
        vals = vals * 3
    if len(vals) != n:
        raise ValueError(f"lcd: '{name}' needs {n} numbers, got {len(vals)}")
    return vals


class LCDEmitter(mi.Emitter):
    """A pixelated planar emitter with a display model (see the module docstring)."""

    def __init__(self, props: mi.Properties):
        mi.Emitter.__init__(self, props)
        self.m_flags = mi.EmitterFlags.Surface | mi.EmitterFlags.SpatiallyVarying
        self.w = int(props.get("cells_x", 32))
        self.h = int(props.get("cells_y", 32))
        if self.w < 1 or self.h < 1:
            raise ValueError(f"lcd: needs at least one cell, got {self.h} x {self.w}")
        self.intensity = mi.ScalarColor3f(_floats(props.get("intensity", 1.0), 3, "intensity"))
        self.gamma = float(props["gamma"]) if "gamma" in props else None
        self.matrix = _floats(props["color_matrix"], 9, "color_matrix") if "color_matrix" in props else None
        self.cos_power = float(props["decay_cos_power"]) if "decay_cos_power" in props else None
        self.gradient = _floats(props["decay_gradient"], 3, "decay_gradient")[:2] if "decay_gradient" in props else None
        # The display model's contract (mitsvbrdf.rig.DisplayModel), for scenes loaded without the Rig.
        if not all(math.isfinite(v) and v > 0 for v in self.intensity):
            raise ValueError(f"lcd: 'intensity' must be finite and > 0 per channel, got {list(self.intensity)}")
        if self.gamma is not None and not (math.isfinite(self.gamma) and self.gamma > 0):
            raise ValueError(f"lcd: 'gamma' must be finite and > 0, got {self.gamma}")
        if self.matrix is not None and not all(math.isfinite(v) for v in self.matrix):
            raise ValueError(f"lcd: 'color_matrix' must be finite, got {self.matrix}")
        if self.cos_power is not None and not (math.isfinite(self.cos_power) and self.cos_power >= 0):
            raise ValueError(f"lcd: 'decay_cos_power' must be finite and >= 0, got {self.cos_power}")
        if self.gradient is not None and not all(math.isfinite(v) for v in self.gradient):
            raise ValueError(f"lcd: 'decay_gradient' must be finite, got {self.gradient}")
        if "data" in props:
            self.data = props["data"]
        else:
            self.data = mi.TensorXf(dr.full(mi.Float, 1.0, 3 * self.h * self.w), shape=(1, 3, self.h, self.w))
        self._check_data()

    def _check_data(self):
        s = tuple(self.data.shape)
        if len(s) != 4 or s[1:] != (3, self.h, self.w):
            raise ValueError(f"lcd: data must be (P, 3, {self.h}, {self.w}) drive values, got {s}")

    @property
    def pattern_count(self) -> int:
        return int(self.data.shape[0])

    # ---- display model ------------------------------------------------------------------------

    def _cell(self, uv):
        col = dr.clip(mi.Int32(dr.floor(uv.x * self.w)), 0, self.w - 1)
        row = dr.clip(mi.Int32(dr.floor(uv.y * self.h)), 0, self.h - 1)
        return mi.UInt32(row * self.w + col)

    def _factor(self, uv, cos_emit):
        """Emission decay (1 when the scene models none) times validity of the emitting side."""
        f = dr.select(cos_emit > 0, mi.Float(1.0), 0.0)
        if self.cos_power is not None:
            f *= dr.power(dr.maximum(cos_emit, 0.0), self.cos_power)
        if self.gradient is not None:
            gx, gy = self.gradient
            f *= dr.maximum(1.0 + gx * (uv.x - 0.5) + gy * (uv.y - 0.5), 0.0)
        return f

    def _drive_to_radiance(self, rgb):
        r, g, b = rgb
        if self.gamma is not None:
            r, g, b = (dr.power(dr.maximum(c, 1e-12), self.gamma) for c in (r, g, b))
        if self.matrix is not None:
            m = self.matrix
            r, g, b = (m[0] * r + m[1] * g + m[2] * b, m[3] * r + m[4] * g + m[5] * b,
                       m[6] * r + m[7] * g + m[8] * b)
        return mi.Color3f(r, g, b) * self.intensity

    def cell_radiance(self, uv, pattern=0, active=True):
        """The radiance of the cell that holds LCD uv under pattern ``pattern`` (an int or a
        per-lane UInt32 index into ``data``), before decay."""
        cells = self.h * self.w
        base = self._cell(uv) + mi.UInt32(pattern) * (3 * cells)
        rgb = [dr.gather(mi.Float, self.data.array, base + c * cells, active) for c in range(3)]
        return self._drive_to_radiance(rgb)

    def radiance(self, uv, cos_emit, pattern=0, active=True):
        """Emitted radiance of pattern ``pattern`` (an int or a per-lane UInt32 index into
        ``data``) at LCD uv towards a direction with cosine ``cos_emit``."""
        return self.cell_radiance(uv, pattern, active) * self._factor(uv, cos_emit)

    def radiance_all(self, uv, cos_emit, active=True, first=0, count=None) -> list:
        """``radiance`` of patterns first .. first + count - 1 (default: all) at the same points:
        a list of Color3f. ``first`` may be per lane, for batches of materials that each have
        their own patterns stacked in ``data``."""
        count = self.pattern_count if count is None else count
        return [self.radiance(uv, cos_emit, first + p, active) for p in range(count)]

    @property
    def has_decay(self) -> bool:
        return self.cos_power is not None or self.gradient is not None

    def to_world(self) -> mi.ScalarTransform4f:
        """The LCD rectangle's placement: local (-1, -1) is cell (0, 0)'s corner, +x the columns."""
        m = mi.traverse(self.get_shape())["to_world"].matrix
        return mi.ScalarTransform4f([[float(m[i][j][0]) for j in range(4)] for i in range(4)])

    def normal(self) -> mi.Vector3f:
        """The LCD's unit normal in world space (the side it emits into, towards the sample)."""
        return mi.Vector3f(dr.normalize(mi.ScalarVector3f(self.to_world() @ mi.ScalarNormal3f(0.0, 0.0, 1.0))))

    # ---- Mitsuba emitter interface ------------------------------------------------------------

    def eval(self, si, active=True):
        return dr.select(active, self.radiance(si.uv, mi.Frame3f.cos_theta(si.wi), 0, active), 0.0)

    def _direction(self, it, ps, active):
        ds = mi.DirectionSample3f(ps)
        ds.d = ps.p - it.p
        dist2 = dr.squared_norm(ds.d)
        ds.dist = dr.sqrt(dist2)
        ds.d = ds.d / ds.dist
        cos_emit = -dr.dot(ds.d, ps.n)
        active &= cos_emit > 0
        ds.pdf = dr.select(active, ps.pdf * dist2 / dr.maximum(cos_emit, 1e-12), 0.0)
        ds.emitter = mi.EmitterPtr(self)
        return ds, cos_emit, active

    def sample_direction(self, it, sample, active=True):
        ps = self.get_shape().sample_position(it.time, sample, active)
        ds, cos_emit, active = self._direction(it, ps, active)
        value = self.radiance(ps.uv, cos_emit, 0, active) / dr.maximum(ds.pdf, 1e-30)
        return ds, dr.select(active, value, 0.0)

    def pdf_direction(self, it, ds, active=True):
        cos_emit = -dr.dot(ds.d, ds.n)
        pdf = self.get_shape().pdf_position(ds, active) * ds.dist * ds.dist / dr.maximum(cos_emit, 1e-12)
        return dr.select(active & (cos_emit > 0), pdf, 0.0)

    def eval_direction(self, it, ds, active=True):
        return dr.select(active, self.radiance(ds.uv, -dr.dot(ds.d, ds.n), 0, active), 0.0)

    def sample_position(self, time, sample, active=True):
        ps = self.get_shape().sample_position(time, sample, active)
        return ps, dr.select(active, 1.0 / dr.maximum(ps.pdf, 1e-30), 0.0)

    def sample_ray(self, time, wavelength_sample, sample2, sample3, active=True):
        ps = self.get_shape().sample_position(time, sample2, active)
        local = mi.warp.square_to_cosine_hemisphere(sample3)
        d = mi.Frame3f(ps.n).to_world(local)
        value = self.radiance(ps.uv, mi.Frame3f.cos_theta(local), 0, active) * dr.pi / dr.maximum(ps.pdf, 1e-30)
        return mi.Ray3f(ps.p, d, time), dr.select(active, value, 0.0)

    def bbox(self):
        return self.get_shape().bbox()

    def traverse(self, cb):
        cb.put("data", self.data, mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys):
        self._check_data()

    def to_string(self):
        return f"LCDEmitter[{self.h}x{self.w} cells, {self.pattern_count} pattern(s)]"
