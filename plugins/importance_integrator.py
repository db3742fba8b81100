"""``importance``: one-bounce direct illumination from the LCD, every pattern in one pass.

A flat sample under a planar light has no inter-reflection, so one bounce is the whole light
transport. Each sample combines one LCD sample (uniform area, pattern independent) and one BSDF
sample with multiple importance sampling (power heuristic); both directions are evaluated for all
P patterns the ``lcd`` emitter holds, so P images cost one set of rays.

Parameters:
    hide_emitters   (bool, default true) camera rays that hit the LCD return black.

Two entry points:
    * ``sample``: the standard SamplingIntegrator interface (``mi.render`` through the scene's
      perspective sensor, as a real photo would see the sample); renders pattern 0.
    * :meth:`render_texels`: the texel-grid image of mitsvbrdf (pixel (i, j) = texel (i, j) of the
      sample, seen from the camera's centre of projection), (P, 3, H, W), used by
      ``mitsvbrdf.render(..., method="mitsuba")``.

For gradients w.r.t. the maps, BSDF-sampled directions are detached and the BSDF re-evaluated
(detached sampling), and MIS weights are detached; patterns enter linearly through the emitter's
``data`` tensor.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi


class _LaneSampler:
    """One PCG32 stream per lane whose state and sequence come from TEA(key, lane), as Mitsuba's
    independent sampler seeds its streams (adjacent raw PCG32 sequence ids are correlated). The
    numbers are a pure function of (key, lane), so a material's samples do not depend on the rest
    of its batch."""

    def __init__(self, key, lane):
        v0, v1 = mi.sample_tea_32(mi.UInt32(key), mi.UInt32(lane))
        self.rng = mi.PCG32(dr.width(lane))
        self.rng.seed(mi.UInt64(v0), mi.UInt64(v1))

    def next_1d(self, active=True):
        return self.rng.next_float32()

    def next_2d(self, active=True):
        return mi.Point2f(self.rng.next_float32(), self.rng.next_float32())


def _power_heuristic(a, b):
    a2, b2 = a * a, b * b
    return dr.select(a2 + b2 > 0, a2 / (a2 + b2), 0.0)


class ImportanceIntegrator(mi.SamplingIntegrator):
    """Direct illumination from the ``lcd`` emitter for all its patterns at once."""

    def __init__(self, props: mi.Properties):
        mi.SamplingIntegrator.__init__(self, props)
        self.hide_emitters = bool(props.get("hide_emitters", True))

    @staticmethod
    def lcd(scene):
        """The scene's ``lcd`` emitter (the Python object, with ``radiance_all``)."""
        ems = [e for e in scene.emitters() if hasattr(e, "radiance_all")]
        if len(ems) != 1:
            raise ValueError(f"importance integrator: the scene needs exactly one 'lcd' emitter, found {len(ems)}")
        return ems[0]

    def direct(self, scene, sampler, si, active, first=0, count=None) -> list:
        """Outgoing radiance towards ``si.wi`` for patterns first .. first + count - 1 of the
        ``lcd`` emitter (default: all): a list of Color3f, all from the same light samples."""
        lcd = self.lcd(scene)
        bsdf = si.bsdf()
        ctx = mi.BSDFContext()
        P = lcd.pattern_count if count is None else count
        out = [mi.Color3f(0.0) for _ in range(P)]

        # Light sample (uniform on the LCD, the same for all patterns).
        ds, _ = lcd.sample_direction(si, sampler.next_2d(active), active)
        em_ok = active & (ds.pdf > 0)
        wo = si.to_local(ds.d)
        f, bsdf_pdf = bsdf.eval_pdf(ctx, si, wo, em_ok)
        w_em = dr.detach(_power_heuristic(ds.pdf, bsdf_pdf))
        cos_emit = -dr.dot(ds.d, ds.n)
        scale = f * w_em / dr.maximum(dr.detach(ds.pdf), 1e-30)
        for p, rad in enumerate(lcd.radiance_all(ds.uv, cos_emit, em_ok, first, P)):
            out[p] += dr.select(em_ok, scale * rad, 0.0)

        # BSDF sample: direction detached, BSDF re-evaluated so gradients reach the maps.
        bs, _ = bsdf.sample(ctx, si, sampler.next_1d(active), sampler.next_2d(active), active)
        bs_ok = active & (bs.pdf > 0)
        d = dr.detach(si.to_world(bs.wo))
        si_l = scene.ray_intersect(si.spawn_ray(d), bs_ok)
        hit = bs_ok & si_l.is_valid() & (si_l.emitter(scene) == mi.EmitterPtr(lcd))
        f_b = bsdf.eval(ctx, si, dr.detach(bs.wo), hit)
        ds_l = mi.DirectionSample3f(scene, si_l, si)
        em_pdf = lcd.pdf_direction(si, ds_l, hit)
        w_bs = dr.detach(_power_heuristic(bs.pdf, em_pdf))
        scale_b = f_b * w_bs / dr.maximum(dr.detach(bs.pdf), 1e-30)
        cos_l = mi.Frame3f.cos_theta(si_l.wi)
        for p, rad in enumerate(lcd.radiance_all(si_l.uv, cos_l, hit, first, P)):
            out[p] += dr.select(hit, scale_b * rad, 0.0)
        return out

    def sample(self, scene, sampler, ray, medium=None, active=True):
        si = scene.ray_intersect(ray, active)
        valid = active & si.is_valid()
        on_sample = valid & (si.emitter(scene) == None)  # noqa: E711 (Dr.Jit pointer comparison)
        values = self.direct(scene, sampler, si, on_sample, count=1)
        return values[0], valid, []

    def aov_names(self):
        return []

    def render_texels(self, scene, resolution: tuple[int, int], spp: int, seed, batch: int = 1) -> mi.TensorXf:
        """(batch * P, 3, H, W) radiance on the sample's texel grid, ``spp`` samples per texel.

        A batch of materials renders in one pass: the BSDF's maps hold the ``batch`` materials
        stacked along rows (batch * H, W, C) and the emitter's ``data`` their patterns stacked
        along the first axis (batch * P, 3, h, w). Material b's random numbers are keyed by
        ``seed + b`` and the lane's (texel, sample) index, so its image does not depend on the
        rest of the batch. ``seed`` may be an opaque ``mi.UInt32`` (no recompilation).
        """
        H, W = resolution
        lcd = self.lcd(scene)
        if lcd.pattern_count % batch:
            raise ValueError(f"importance integrator: {lcd.pattern_count} patterns do not split into {batch} materials")
        P = lcd.pattern_count // batch
        sample_shape = [s for s in scene.shapes() if s.bsdf() is not None and hasattr(s.bsdf(), "MAPS")]
        if len(sample_shape) != 1:
            raise ValueError("importance integrator: the scene needs exactly one shape with an svbrdf_ggx BSDF")
        to_world = mi.traverse(sample_shape[0])["to_world"]
        cam = scene.sensors()[0].world_transform() @ mi.ScalarPoint3f(0.0, 0.0, 0.0)

        per_material = H * W * spp
        idx = dr.arange(mi.UInt32, batch * per_material)
        b = idx // per_material
        k = idx - b * per_material
        texel = k // spp
        row, col = texel // W, texel % W
        u = (mi.Float(col) + 0.5) / W
        v = 1.0 - (mi.Float(row) + 0.5) / H  # row 0 at the top (uv.y = 1)
        x = to_world @ mi.Point3f(2.0 * u - 1.0, 2.0 * v - 1.0, 0.0)
        ray = mi.Ray3f(mi.Point3f(cam), dr.normalize(x - mi.Point3f(cam)))
        si = scene.ray_intersect(ray)
        ok = si.is_valid() & (si.shape == mi.ShapePtr(sample_shape[0]))
        # Address material b's rows of the stacked maps.
        si.uv = mi.Point2f(si.uv.x, 1.0 - (mi.Float(b * H + row) + 0.5) / (batch * H))

        sampler = _LaneSampler(mi.UInt32(seed) + b, k)
        values = self.direct(scene, sampler, si, ok, first=b * P, count=P)
        # One kernel for all 3P channels; reduced one by one they would each re-trace the paths.
        dr.eval(values)
        chans = [dr.block_sum(c, spp) / spp for val in values for c in (val.x, val.y, val.z)]
        # chans[p * 3 + c] has batch * H * W entries ordered (b, row, col).
        hw = H * W
        flat = dr.zeros(mi.Float, batch * P * 3 * hw)
        t = dr.arange(mi.UInt32, batch * hw)
        tb = t // hw
        for pc, c in enumerate(chans):
            dr.scatter(flat, c, (tb * (P * 3) + pc) * hw + (t - tb * hw))
        return mi.TensorXf(flat, shape=(batch * P, 3, H, W))

    def to_string(self):
        return "ImportanceIntegrator[]"
