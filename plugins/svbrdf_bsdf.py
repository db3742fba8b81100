"""``svbrdf_ggx``: the project's BRDF (mitsvbrdf.brdf) as a Mitsuba 3 BSDF with per-texel maps.

Parameters (scene file or ``mi.load_dict``):
    normal      rgb, (H, W, 3) tensor or image file: tangent-space unit normals (x right, y up, z out)
    diffuse     rgb, (H, W, 3) tensor or image file: kd in [0, 1]
    roughness   float, (H, W, 1) tensor or image file: r in [0, 1], alpha = max(r^2, ALPHA_MIN)
    specular    rgb, (H, W, 3) tensor or image file: ks in [0, 1]

An image file (``<string name="diffuse" value="diffuse.exr"/>``, resolved like Mitsuba's other
files, relative to the scene) holds the values as they are used: linear EXR is the exact choice
(normals as raw xyz vectors, a one-channel EXR for roughness); PNG values are read as stored.

Maps are looked up at the texel containing the surface uv (nearest; texel (i, j) covers
uv.x in [j/W, (j+1)/W), 1 - uv.y in [i/H, (i+1)/H), so row 0 is the top of the sample as in
mitsvbrdf's convention). ``traverse`` exposes the four tensors as differentiable parameters so a
renderer can swap materials in place.

Mitsuba's naming: ``si.wi`` points to the viewer, ``wo`` to the light; both in the local
(geometric) frame of the sample. The BSDF is one-sided and zero when either direction is below
the geometric or the shading-normal horizon. Sampling mixes visible-normal GGX sampling
(Dupuy & Benyoub 2023) around the shading normal and cosine sampling of the diffuse lobe, with
the mixture pdf.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from mitsvbrdf.brdf import ALPHA_MIN
from mitsvbrdf.imageio import read_image


def _as_map(props, name: str, channels: int, default) -> mi.TensorXf:
    if name not in props:
        v = default
    else:
        v = props[name]
    if isinstance(v, str):
        t = _read_map(v, name, channels)
    elif isinstance(v, mi.TensorXf):
        t = v
    else:
        vals = [float(v[i]) for i in range(channels)] if channels > 1 and not isinstance(v, (int, float)) \
            else [float(v)] * channels
        t = mi.TensorXf(mi.Float(vals), shape=(1, 1, channels))
    if t.ndim != 3 or t.shape[2] != channels:
        raise ValueError(f"svbrdf_ggx: '{name}' must be an (H, W, {channels}) tensor, got shape {t.shape}")
    return t


def _read_map(filename: str, name: str, channels: int) -> mi.TensorXf:
    path = mi.file_resolver().resolve(filename)
    a = read_image(str(path))
    if a.shape[2] != channels:
        a = a[..., :1] if channels == 1 else a[..., :3]
    if a.shape[2] != channels:
        raise ValueError(f"svbrdf_ggx: '{name}' file {path} has {a.shape[2]} channels, {channels} needed")
    return mi.TensorXf(np.ascontiguousarray(a, dtype=np.float32))


class SVBRDFGGX(mi.BSDF):
    """The Deschaintre 2018 GGX SVBRDF with texel maps (see the module docstring)."""

    MAPS = (("normal", 3, (0.0, 0.0, 1.0)), ("diffuse", 3, (0.5, 0.5, 0.5)),
            ("roughness", 1, 0.5), ("specular", 3, (0.04, 0.04, 0.04)))

    def __init__(self, props: mi.Properties):
        mi.BSDF.__init__(self, props)
        for name, ch, default in self.MAPS:
            setattr(self, name, _as_map(props, name, ch, default))
        self._check_sizes()
        flags = (mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide | mi.BSDFFlags.SpatiallyVarying)
        dflags = (mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide | mi.BSDFFlags.SpatiallyVarying)
        self.m_components = [flags, dflags]
        self.m_flags = flags | dflags

    def _check_sizes(self):
        shapes = {name: tuple(getattr(self, name).shape[:2]) for name, _, _ in self.MAPS}
        big = {s for s in shapes.values() if s != (1, 1)}
        if len(big) > 1:
            raise ValueError(f"svbrdf_ggx: maps differ in size: {shapes}")

    # ---- texel lookup -------------------------------------------------------------------------

    def _lookup(self, t: mi.TensorXf, uv: mi.Point2f, active):
        h, w, c = t.shape
        col = dr.clip(mi.Int32(dr.floor(uv.x * w)), 0, w - 1)
        row = dr.clip(mi.Int32(dr.floor((1.0 - uv.y) * h)), 0, h - 1)
        idx = mi.UInt32(row * w + col) * c
        if c == 1:
            return dr.gather(mi.Float, t.array, idx, active)
        return mi.Vector3f(*(dr.gather(mi.Float, t.array, idx + k, active) for k in range(3)))

    def maps(self, si, active=True):
        """(unit normal, kd, ks, r) at the texel of ``si.uv``, normal in the local frame."""
        n = dr.normalize(self._lookup(self.normal, si.uv, active))
        kd = mi.Color3f(self._lookup(self.diffuse, si.uv, active))
        ks = mi.Color3f(self._lookup(self.specular, si.uv, active))
        return n, kd, ks, self._lookup(self.roughness, si.uv, active)

    def _material(self, si, active):
        n, kd, ks, r = self.maps(si, active)
        return n, kd, ks, dr.maximum(r * r, ALPHA_MIN)

    # ---- the BRDF -----------------------------------------------------------------------------

    @staticmethod
    def _schlick(c):
        c = dr.clip(c, 0.0, 1.0)
        return dr.exp2((-5.55473 * c - 6.98316) * c)

    def _f_cos(self, n, kd, ks, alpha, wi, wo, ctx):
        """f (n.wo)^+ with wi = view, wo = light (both local)."""
        nv, nl = dr.dot(n, wi), dr.dot(n, wo)
        h = dr.normalize(wi + wo)
        cos_h = dr.dot(n, h)
        sin2 = dr.squared_norm(dr.cross(n, h))
        a2 = alpha * alpha
        denom = a2 * cos_h * cos_h + sin2
        d = dr.select(cos_h > 0, a2 / (dr.pi * dr.maximum(denom * denom, 1e-30)), 0.0)
        k = 0.5 * alpha
        nlc, nvc = dr.maximum(nl, 0.0), dr.maximum(nv, 0.0)
        s = self._schlick(dr.dot(wi, h))
        spec = d * nlc / (4.0 * (nlc * (1.0 - k) + k) * (nvc * (1.0 - k) + k)) * (ks + (1.0 - ks) * s)
        diff = kd * (1.0 - ks) * (nlc / dr.pi)
        value = mi.Color3f(0.0)
        if ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 0):
            value += spec
        if ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 1):
            value += diff
        visible = (nv > 0) & (nl > 0) & (mi.Frame3f.cos_theta(wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
        return dr.select(visible, value, 0.0), d

    @staticmethod
    def _smith_g1(cos, alpha):
        c2 = dr.clip(cos * cos, 1e-12, 1.0)
        return 2.0 / (1.0 + dr.sqrt(1.0 + alpha * alpha * (1.0 - c2) / c2))

    def _spec_prob(self, n, kd, ks, wi, ctx):
        has_s = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 0)
        has_d = ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 1)
        if not has_d:
            return mi.Float(1.0)
        if not has_s:
            return mi.Float(0.0)
        s = self._schlick(dr.dot(n, wi))
        ws = dr.mean(ks + (1.0 - ks) * s)
        wd = dr.mean(kd * (1.0 - ks))
        return dr.clip(ws / dr.maximum(ws + wd, 1e-8), 0.1, 0.9)

    def _pdf(self, n, kd, ks, alpha, wi, wo, ctx, d=None):
        nv, nl = dr.dot(n, wi), dr.dot(n, wo)
        if d is None:
            h = dr.normalize(wi + wo)
            cos_h = dr.dot(n, h)
            a2 = alpha * alpha
            denom = a2 * cos_h * cos_h + dr.squared_norm(dr.cross(n, h))
            d = dr.select(cos_h > 0, a2 / (dr.pi * dr.maximum(denom * denom, 1e-30)), 0.0)
        p_spec = self._spec_prob(n, kd, ks, wi, ctx)
        pdf_s = self._smith_g1(nv, alpha) * d / (4.0 * dr.maximum(nv, 1e-12))
        pdf_d = dr.maximum(nl, 0.0) / dr.pi
        pdf = p_spec * pdf_s + (1.0 - p_spec) * pdf_d
        ok = (nv > 0) & (nl > 0) & (mi.Frame3f.cos_theta(wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
        return dr.select(ok, pdf, 0.0)

    def eval(self, ctx, si, wo, active=True):
        n, kd, ks, alpha = self._material(si, active)
        value, _ = self._f_cos(n, kd, ks, alpha, si.wi, wo, ctx)
        return dr.select(active, value, 0.0)

    def pdf(self, ctx, si, wo, active=True):
        n, kd, ks, alpha = self._material(si, active)
        return dr.select(active, self._pdf(n, kd, ks, alpha, si.wi, wo, ctx), 0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        n, kd, ks, alpha = self._material(si, active)
        value, d = self._f_cos(n, kd, ks, alpha, si.wi, wo, ctx)
        pdf = self._pdf(n, kd, ks, alpha, si.wi, wo, ctx, d)
        return dr.select(active, value, 0.0), dr.select(active, pdf, 0.0)

    def sample(self, ctx, si, sample1, sample2, active=True):
        n, kd, ks, alpha = self._material(si, active)
        frame = mi.Frame3f(n)
        wi_n = frame.to_local(si.wi)
        p_spec = self._spec_prob(n, kd, ks, si.wi, ctx)
        pick_spec = sample1 < p_spec

        # Visible-normal sample (spherical caps) in the shading frame.
        wstd = dr.normalize(mi.Vector3f(wi_n.x * alpha, wi_n.y * alpha, wi_n.z))
        phi = 2.0 * dr.pi * sample2.x
        z = dr.fma(1.0 - sample2.y, 1.0 + wstd.z, -wstd.z)
        sin_t = dr.safe_sqrt(1.0 - z * z)
        hstd = mi.Vector3f(sin_t * dr.cos(phi), sin_t * dr.sin(phi), z) + wstd
        h = dr.normalize(mi.Vector3f(hstd.x * alpha, hstd.y * alpha, dr.maximum(hstd.z, 0.0)))
        wo_spec = frame.to_world(2.0 * dr.dot(wi_n, h) * h - wi_n)
        wo_diff = frame.to_world(mi.warp.square_to_cosine_hemisphere(sample2))
        wo = dr.select(pick_spec, wo_spec, wo_diff)

        value, d = self._f_cos(n, kd, ks, alpha, si.wi, wo, ctx)
        pdf = self._pdf(n, kd, ks, alpha, si.wi, wo, ctx, d)
        bs = mi.BSDFSample3f()
        bs.wo = wo
        bs.pdf = pdf
        bs.eta = 1.0
        bs.sampled_type = mi.UInt32(dr.select(pick_spec, int(mi.BSDFFlags.GlossyReflection),
                                              int(mi.BSDFFlags.DiffuseReflection)))
        bs.sampled_component = dr.select(pick_spec, mi.UInt32(0), mi.UInt32(1))
        ok = active & (pdf > 0) & (mi.Frame3f.cos_theta(si.wi) > 0) & (wi_n.z > 0)
        weight = dr.select(ok, value / dr.maximum(pdf, 1e-30), 0.0)
        bs.pdf = dr.select(ok, pdf, 0.0)
        return bs, weight

    def eval_diffuse_reflectance(self, si, active=True):
        _, kd, ks, _ = self._material(si, active)
        return kd * (1.0 - ks)

    def traverse(self, cb):
        for name, _, _ in self.MAPS:
            cb.put(name, getattr(self, name), mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys):
        self._check_sizes()

    def to_string(self):
        return ("SVBRDFGGX[" + ", ".join(f"{n}={tuple(getattr(self, n).shape)}" for n, _, _ in self.MAPS) + "]")
