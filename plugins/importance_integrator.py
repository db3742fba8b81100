"""``importance``: one-bounce direct illumination from the LCD, every pattern in one pass.

A flat sample under a planar light has no inter-reflection, so one bounce is the whole light
transport. Each sample combines one LCD sample (uniform in area, or by the patterns' brightness)
and one BSDF sample with multiple importance sampling (power heuristic); both directions are
evaluated for all P patterns the ``lcd`` emitter holds, so P images cost one set of rays.

Parameters:
    hide_emitters    (bool, default true) camera rays that hit the LCD return black.
    sampler          (string, default "stratified") the random numbers of :meth:`render_texels`:
                     "independent" (one PCG32 stream per sample) or "stratified" (the spp samples
                     of a texel form an Owen-scrambled (0, 2)-sequence, every dimension pair
                     shuffled against the others). ``sample`` (``mi.render``) uses the scene's
                     own sampler.
    control_variate  (string, default "ltc-grid") what is known in closed form
                     (:mod:`mitsvbrdf.render.control_variate` computes it; the pointwise part is
                     :mod:`mitsvbrdf_plugins.lcd_integrals`): "none" (plain Monte Carlo),
                     "diffuse" (the diffuse term under block-averaged patterns), "ltc" (the
                     diffuse term and the fitted LTC specular lobe under one radiance per texel),
                     "ltc-cells" (both lobes, the specular where it is wide, under every LCD
                     cell's own radiance: for sparse patterns; narrower lobes under every cell of
                     a window around their peak and one radiance elsewhere), or "ltc-grid" (the
                     per-cell terms and the window of "ltc-cells", without its one-radiance term,
                     their per-texel work (LTC lookup, lobe grid, window form factors, K_p) done in
                     this integrator's kernels instead of torch's: a fraction of "ltc-cells"' time,
                     with more noise under sparse patterns; docs/benchmarks/cv_cost.md and
                     render_tradeoff_*_window.md); Monte Carlo estimates only the residual, so every
                     choice is unbiased.
    cv_blocks        (integer, default 8) the diffuse control variate sees the patterns averaged
                     over cv_blocks x cv_blocks blocks of cells (it must divide the LCD's cell
                     counts). More blocks: a closer control variate, more closed-form work per
                     texel (and H W K^2 3 floats of cached geometry).
    ltc_min_cos_view (float, default 0.1) likewise where cos(theta_v) is below this: at grazing views the
                     fitted LTC overestimates the lobe's tail several-fold (docs/benchmarks/render_tradeoff.md),
                     and a control variate that far off makes the residual larger than the integrand.
    light_sampling   (string, default "uniform") how :meth:`render_texels` samples the LCD:
                     "uniform" (area, as the emitter does) or "patterns" (cells by the patterns'
                     brightness, mixed with a uniform share; :class:`_PatternLight`). Adaptive
                     patterns are mostly dark with small bright regions, which uniform samples miss.
    uniform_share    (float, default 0.25) the uniform part of "patterns" sampling, in (0, 1].
    ltc_min_roughness (float, default 0.1) below this roughness the specular lobe is left to
                     Monte Carlo alone: a near-mirror LTC lobe that misses the true one by a
                     fraction of its width would make the residual spikier, not smoother.
    ltc_grid         (integer, default 4 for "ltc-grid", 16 for "ltc-cells") the lobe is
                     interpolated bilinearly from its values at the (ltc_grid + 1)^2 vertices of a
                     grid over the LCD (it must divide the LCD's cell counts); "ltc-cells" stores
                     (ltc_grid + 1)^2 floats per texel, "ltc-grid" unrolls that many lobe
                     evaluations into its closed-form kernel (its tracing time grows with them:
                     meant for ltc_grid <= 8).
    ltc_cells_min_roughness (float, default 0.2) below this roughness the lobe is too narrow for
                     the grid: "ltc-cells" and "ltc-grid" use the window there (down to
                     ltc_window_min_roughness), "ltc-cells" also the one-radiance term of "ltc"
                     outside the window; lobes below both are Monte Carlo's.
    ltc_window       (integer, default 8; 0: off) "ltc-cells", "ltc-grid": lobes narrower than
                     that (down to ltc_window_min_roughness) are known exactly under every cell of
                     a ltc_window x ltc_window window of cells around their peak; "ltc-cells"
                     stores 5 + ltc_window^2 more floats per texel, "ltc-grid" runs a loop over
                     the window's cells for the texels that have one.
    ltc_window_min_roughness (float, default 0.02) below this roughness the window term is off too
                     (the near-mirror caveat of ltc_min_roughness).
    freeze           (bool, default true) :meth:`render_texels` records its kernels once per
                     resolution, spp, batch and pattern count (``dr.freeze``) and replays them
                     when no input carries gradients (maps, patterns, control variate): no
                     tracing, no kernel assembly (docs/benchmarks/cv_cost.md). With gradients, or
                     false, every call traces its kernels. An integrator keeps the recordings of
                     its last FROZEN_RECORDINGS configurations; where Dr.Jit fails to record or
                     replay, it warns and traces from then on. Limitation: the scene is an input
                     of the frozen function, and Mitsuba brings every emitter, shape and sensor
                     of every scene loaded in the process with it; a process that renders through
                     several scenes in turn records again whenever another scene rendered since
                     (a recording costs about what tracing does), so there freeze gains nothing.
                     Training, capture and evaluation render through one scene.

The emission decay, gamma and colour matrix of the scene's display model all apply: the control
variate uses each block's mean radiance after the display model and the decay at the block's
centre; the residual carries the exact per-cell, per-direction emission.

Two entry points:
    * ``sample``: the standard SamplingIntegrator interface (``mi.render`` through the scene's
      perspective sensor, as a real photo would see the sample); renders pattern 0 by plain Monte
      Carlo with the scene's sampler (the control variate's coefficients are per texel).
    * :meth:`render_texels`: the texel-grid image of mitsvbrdf (pixel (i, j) = texel (i, j) of the
      sample, seen from the camera's centre of projection), (P, 3, H, W), used by
      ``mitsvbrdf.render(..., method="mitsuba")``; the closed-form part is computed once per
      texel, the residual per sample.

For gradients w.r.t. the maps, BSDF-sampled directions are detached and the BSDF re-evaluated
(detached sampling), and MIS weights are detached; patterns enter linearly through the emitter's
``data`` tensor. The closed-form part is differentiable w.r.t. patterns and maps.

Sampling the LCD by the patterns' brightness uses one distribution for all P patterns of a
material (their mean normalised brightness), because all P share one sample set; the uniform
share covers what the mixture misses (a black cell next to a bright block still carries control
variate residual).
"""

from __future__ import annotations

import warnings

import drjit as dr
import mitsuba as mi

from . import plugin_class
from .lcd_integrals import ViewFrame, grid_cell_form_factors, ltc_density, ltc_lookup, warp

SAMPLERS = ("independent", "stratified")
CONTROL_VARIATES = ("none", "diffuse", "ltc", "ltc-cells", "ltc-grid")
LIGHT_SAMPLINGS = ("uniform", "patterns")
#: configurations (resolution, spp, batch, pattern count) whose recorded kernels an integrator keeps
FROZEN_RECORDINGS = 8


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


def _unit_float(bits):
    return mi.Float(bits >> 8) * (1.0 / (1 << 24))


def _owen(x, seed):
    """Nested uniform (Owen) scrambling of the bits of x, most significant first, by the
    Laine-Karras hash (Burley 2020, "Practical hash-based Owen scrambling")."""
    x = dr.brev(x) + seed
    for c in (0x6C50B47C, 0xB82F1E52, 0xC7AFE638, 0x8D22F6E6):
        x ^= x * c
    return dr.brev(x)


def _sobol2(k):
    """Sobol's second dimension (the Pascal matrix) of index k, as 32 bits."""
    v, out = 1 << 31, mi.UInt32(0)
    for i in range(32):
        out ^= dr.select((k & (1 << i)) != 0, mi.UInt32(v), mi.UInt32(0))
        v ^= v >> 1
    return out


class _StratifiedSampler:
    """Sample k of a texel's spp samples is point k of the (0, 2)-sequence (radical inverse and
    Sobol's second dimension) after Owen scrambling, "shuffled" per dimension pair as in Burley
    2020: each call scrambles the sample index and both coordinates with fresh seeds, so every
    2-D projection the integrator uses is stratified, pairs are not correlated with each other, and
    points fall at random positions inside their strata (a plain XOR shift would put all of a
    texel's 4 points at one phase of any pattern with period 1/8, and the control variate's block
    residual has exactly such periods). The seeds come from a PCG32 stream keyed by (key, texel),
    a pure function of the seed and the texel, as for :class:`_LaneSampler`."""

    def __init__(self, key, texel, k):
        v0, v1 = mi.sample_tea_32(mi.UInt32(key), mi.UInt32(texel))
        self.rng = mi.PCG32(dr.width(k))
        self.rng.seed(mi.UInt64(v0), mi.UInt64(v1))
        self.k = mi.UInt32(k)

    def next_1d(self, active=True):
        k = _owen(self.k, self.rng.next_uint32())
        return _unit_float(_owen(dr.brev(k), self.rng.next_uint32()))

    def next_2d(self, active=True):
        k = _owen(self.k, self.rng.next_uint32())
        return mi.Point2f(_unit_float(_owen(dr.brev(k), self.rng.next_uint32())),
                          _unit_float(_owen(_sobol2(k), self.rng.next_uint32())))


def mis_weight(pdf_a, pdf_b):
    """Power-heuristic weight of strategy a, detached, and 0 where it is not finite (as in
    Mitsuba's own ``mis_weight``): both pdfs 0 or either infinite must not poison a lane with NaN."""
    a2, b2 = dr.square(pdf_a), dr.square(pdf_b)
    w = a2 / (a2 + b2)
    return dr.detach(dr.select(dr.isfinite(w), w, 0.0))


def _kinds(objects) -> str:
    """The plugin classes of Mitsuba objects, for error messages ("AreaLight, LCDEmitter")."""
    names = sorted(o.class_name() if type(o).__module__ == "mitsuba" else type(o).__name__ for o in objects)
    return ", ".join(names) or "none"


class _ControlVariate:
    """g_p of :mod:`mitsvbrdf.render.control_variate` in one direction per lane, from the
    coefficients that module computed (so the closed-form part and the residual cannot disagree).

    Args: the ``lcd`` emitter; ``block_rad`` the flat (B, P, 3, K^2) block radiance; ``coeffs`` the
    flat (B, H W, 7 + 3 P [+ 6 [+ 5 + w^2]]) per-texel coefficients; K; the lanes' material ``b`` and ``texel``
    index; the count P; the shading point's normal ``n`` and view direction (local); for
    "ltc-cells", ``lobe_grid`` the flat (B, H W, 2, (k + 1)^2) lobe values q_v, q^d_v, ``grid`` k and
    ``window`` w (0: no window term)."""

    def __init__(self, lcd, block_rad, coeffs, K: int, b, texel, hw: int, count: int, n, wi,
                 lobe_grid=None, grid: int = 0, window: int = 0):
        self.lcd, self.K, self.count = lcd, K, count
        self.block_rad, self.b = block_rad, b
        self.cells = lobe_grid is not None
        self.window = window if self.cells else 0
        eager = 7 + 3 * count + (6 if self.cells else 0) + (5 if self.window else 0)
        width = eager + self.window * self.window
        base = (b * hw + texel) * width
        c = [dr.gather(mi.Float, coeffs, base + j) for j in range(eager)]
        if self.window:  # omega_c is gathered for the one cell a direction meets
            self.coeffs, self.omega_base = coeffs, base + eager
            self.s_win = mi.Color3f(*c[13 + 3 * count:16 + 3 * count])
            self.win_row, self.win_col = mi.Int32(c[16 + 3 * count]), mi.Int32(c[17 + 3 * count])
        self.m = tuple(c[:4])
        self.kdd = mi.Color3f(c[4], c[5], c[6])
        self.spec = [mi.Color3f(c[7 + 3 * p], c[8 + 3 * p], c[9 + 3 * p]) for p in range(count)]
        self.lobe_grid, self.grid = lobe_grid, grid
        # the lobe grid's layout (torch's (B, H W, 2, V)) as first entry and step between vertices
        self.lobe_base, self.lobe_step = (b * hw + texel) * (2 * (grid + 1) ** 2), 1
        if self.cells:
            self.s_cells = mi.Color3f(*c[7 + 3 * count:10 + 3 * count])
            self.kd_cells = mi.Color3f(*c[10 + 3 * count:13 + 3 * count])
        self.frame = ViewFrame(n, wi)
        T = lcd.to_world()
        self.to_world = mi.Transform4f(T)
        self.lcd_n = lcd.normal()

    def _point(self, u, v):
        """The world position of LCD coordinates (u, v)."""
        return self.to_world @ mi.Point3f(2.0 * u - 1.0, 2.0 * v - 1.0, 0.0)

    def _decay(self, p_world, u, v):
        """e_b(x): the emission decay of the LCD point (u, v) towards the shading point."""
        if not self.lcd.has_decay:
            return mi.Float(1.0)
        y = self._point(u, v)
        return self.lcd._factor(mi.Point2f(u, v), dr.dot(dr.normalize(p_world - y), self.lcd_n))

    def _cells(self, si, uv, cell, hit, window_lobe) -> list:
        """Per pattern, the per-cell terms (S q(y) + kd (1 - ks) q^d(y)) R_c(y) / G(y) at the LCD
        point uv in ``cell`` (:meth:`_cell`), plus ``window_lobe`` R_c (the window term, per sr;
        None without one)."""
        k, side = self.grid, self.grid + 1
        gu, gv = uv.x * k, uv.y * k
        col = dr.clip(mi.Int32(dr.floor(gu)), 0, k - 1)
        row = dr.clip(mi.Int32(dr.floor(gv)), 0, k - 1)
        fu, fv = gu - mi.Float(col), gv - mi.Float(row)
        step = self.lobe_step
        v00 = self.lobe_base + mi.UInt32(row * side + col) * step

        def bilinear(at):
            q00, q01 = (dr.gather(mi.Float, self.lobe_grid, at + j * step, hit) for j in (0, 1))
            q10, q11 = (dr.gather(mi.Float, self.lobe_grid, at + (side + j) * step, hit) for j in (0, 1))
            return dr.lerp(dr.lerp(q00, q01, fu), dr.lerp(q10, q11, fu), fv)

        lobe = self.s_cells * bilinear(v00) + self.kd_cells * bilinear(v00 + side * side * step)
        rel = si.p - self._point(uv.x, uv.y)
        dist2 = dr.squared_norm(rel)
        cos_emit = dr.dot(rel, self.lcd_n) * dr.rsqrt(dr.maximum(dist2, 1e-30))
        per_sr = dr.select(cos_emit > 0, dist2 / dr.maximum(cos_emit, 1e-12), 0.0) * lobe
        if window_lobe is not None:
            per_sr = per_sr + window_lobe
        row_c, col_c = cell
        centre = mi.Point2f((col_c + 0.5) / self.lcd.w, (row_c + 0.5) / self.lcd.h)
        if self.lcd.has_decay:  # the position factor at the cell's centre
            per_sr = per_sr * self.lcd._factor(centre, mi.Float(1.0))
        first = self.b * self.count
        # looked up at uv, as the caller's emitted radiance: the same gathers, which the JIT then
        # computes once (through ``centre`` they were a second set per pattern and direction)
        return [self.lcd.cell_radiance(uv, first + p, hit) * per_sr for p in range(self.count)]

    def _cell(self, uv):
        """The row and column (Float) of the LCD cell that holds uv."""
        return (dr.clip(dr.floor(uv.y * self.lcd.h), 0, self.lcd.h - 1),
                dr.clip(dr.floor(uv.x * self.lcd.w), 0, self.lcd.w - 1))

    def _window_cell(self, cell, hit):
        """Whether ``cell`` (:meth:`_cell`) lies in the texel's window (never for texels without
        one: their window lies off the LCD), and its omega_c there (0 elsewhere)."""
        w = self.window
        row_c, col_c = cell
        i, j = mi.Int32(row_c) - self.win_row, mi.Int32(col_c) - self.win_col
        inside = hit & (i >= 0) & (i < w) & (j >= 0) & (j < w)
        at = self.omega_base + mi.UInt32(dr.select(inside, i * w + j, 0))
        return inside, dr.gather(mi.Float, self.coeffs, at, inside)

    def pointwise(self, si, wo, uv, hit) -> list:
        """Per pattern, g_p(wo) (Color3f) for the local light direction wo that meets the LCD at uv."""
        w = self.frame.to_view(wo)
        d_s = ltc_density(self.m, w)
        if self.cells:
            # "ltc-cells": the per-cell terms replace the block diffuse term (its weight is 0 in
            # this mode), so neither the block radiance nor the block decay is needed here
            cell = self._cell(uv)
            if not self.window:
                cells = self._cells(si, uv, cell, hit, None)
                return [dr.select(hit, self.spec[p] * d_s + cells[p], 0.0) for p in range(self.count)]
            # inside the window its cells' own radiance, outside it the one-radiance term
            inside, omega = self._window_cell(cell, hit)
            cells = self._cells(si, uv, cell, hit, self.s_win * (omega * d_s))
            one = dr.select(inside, 0.0, d_s)
            return [dr.select(hit, self.spec[p] * one + cells[p], 0.0) for p in range(self.count)]
        K = self.K
        bi = dr.clip(mi.Int32(dr.floor(uv.y * K)), 0, K - 1)
        bj = dr.clip(mi.Int32(dr.floor(uv.x * K)), 0, K - 1)
        decay = self._decay(si.p, (mi.Float(bj) + 0.5) / K, (mi.Float(bi) + 0.5) / K)
        g_d = self.kdd * (dr.maximum(w.z, 0.0) / dr.pi * decay)
        base = (self.b * self.count) * (3 * K * K) + mi.UInt32(bi * K + bj)
        out = []
        for p in range(self.count):
            idx = base + p * (3 * K * K)
            lbar = mi.Color3f(*(dr.gather(mi.Float, self.block_rad, idx + c * (K * K), hit) for c in range(3)))
            out.append(dr.select(hit, lbar * g_d + self.spec[p] * d_s, 0.0))
        return out


class _GridControlVariate(_ControlVariate):
    """"ltc-grid": the per-cell terms of "ltc-cells" (specular where roughness >=
    ``ltc_cells_min_roughness``, diffuse everywhere) and its window term (narrower lobes down to
    ``ltc_window_min_roughness``, under the w x w cells around their peak; no one-radiance term
    outside the window), with all of their per-texel work in this integrator's kernels: the maps,
    the view frame, the LTC lookup (:func:`~mitsvbrdf_plugins.lcd_integrals.ltc_lookup`), S and
    kd (1 - ks), the lobe values at the grid vertices, the window's place, its cells' form factors
    E_c and omega_c, and K_p, one lane per texel (:meth:`closed_form`); the sample lanes then take
    the lobe values and weights from that result (:meth:`use`) for the residual. torch supplies
    only the patterns' grid radiance T_{p,v}, a fixed linear map of the pattern, the cells'
    radiance for the window (:func:`mitsvbrdf.render.control_variate.control_variate`) and the
    LTC table.

    Args: the ``lcd`` emitter; ``grid_rad`` the flat (B, (k + 1)^2, width) T_{p,v}, a vertex's 3 P
    values zero-padded to a power of two (:func:`mitsvbrdf.render.control_variate.vertex_packet_width`); ``cell_rad`` the
    flat (B, P, h w, 3) cell radiance times the decay's position factor at the cell's centre (None
    without a window); ``table`` the flat (n, n, 6) LTC table, n = ``table_size``; k = ``grid``;
    w = ``window`` (0: off); the lanes' material ``b`` and ``texel`` index; hw = H W; the count P;
    ``min_cos_view``, ``min_roughness`` and ``window_min_roughness`` (the integrator's
    ltc_min_cos_view, ltc_cells_min_roughness and ltc_window_min_roughness)."""

    #: per-texel floats of the window after S and kd (1 - ks): S, first row and column, the view
    #: frame's x and n, the M^-1 entries, and the warped LCD's c0, cu, cv (:meth:`_window_closed_form`)
    WINDOW_FIELDS = 3 + 2 + 3 + 3 + 4 + 9

    def __init__(self, lcd, grid_rad, cell_rad, table, table_size: int, grid: int, window: int, b, texel, hw: int,
                 count: int, min_cos_view: float, min_roughness: float, window_min_roughness: float):
        self.lcd, self.count, self.b, self.grid, self.hw = lcd, count, b, grid, hw
        self.grid_rad, self.cell_rad, self.table, self.table_size = grid_rad, cell_rad, table, table_size
        self.min_cos_view, self.min_roughness = min_cos_view, min_roughness
        self.window_min_roughness = window_min_roughness
        self.cells, self.window = True, window
        self.to_world = mi.Transform4f(lcd.to_world())
        self.lcd_n = lcd.normal()
        self.texel_lane = b * hw + texel

    def _lcd_in_view(self, si):
        """The LCD seen from the shading point in the view frame: the point (u, v) lies along
        ``r0 + u ru + v rv`` (affine in u, v; a rotation keeps lengths), and ``plane`` = the
        shading point's signed distance from the LCD's plane along its normal (the same for every
        LCD point, since ru and rv lie in the plane)."""
        origin = self._point(0.0, 0.0)
        to_origin = origin - si.p
        r0, ru, rv = (self.frame.to_view(si.to_local(e)) for e in
                      (to_origin, self._point(1.0, 0.0) - origin, self._point(0.0, 1.0) - origin))
        return r0, ru, rv, -dr.dot(to_origin, self.lcd_n)

    def _vertex_lobes(self, lcd_view, u: float, v: float):
        """q_v = D_ltc(w_v) G_v d_v and q^d_v = (n . w_v)^+ / pi G_v d_v at the LCD point (u, v)
        (:meth:`_lcd_in_view`): w_v the direction to it, G_v = cos(theta_lcd) / r^2, d_v the
        decay's cosine factor (:func:`mitsvbrdf.render.control_variate._grid_geometry` and
        ``_lobe_grid``)."""
        r0, ru, rv, plane = lcd_view
        rel = r0 + u * ru + v * rv
        inv = dr.rsqrt(dr.maximum(dr.squared_norm(rel), 1e-30))
        cos_emit = plane * inv
        g = dr.maximum(cos_emit, 0.0) * inv * inv
        if self.lcd.has_decay:  # at the centre: the cosine factor alone
            g = g * self.lcd._factor(mi.Point2f(0.5, 0.5), cos_emit)
        w = rel * inv
        return ltc_density(self.m, w) * g, dr.maximum(w.z, 0.0) * (g / dr.pi)

    def closed_form(self, si, active, bsdf) -> tuple:
        """(One lane per texel, materials outermost.) The per-texel values the residual needs,
        ``[q_0 .. q_{V-1}, q^d_0 .. q^d_{V-1}, S (3), kd (1 - ks) (3)]`` (V = (k + 1)^2 vertices,
        row-major; Floats), with a window then :attr:`WINDOW_FIELDS`, and per pattern K_p (Color3f) at each lane's texel:
        ``S sum_v q_v T_{p,v} + kd (1 - ks) sum_v q^d_v T_{p,v}`` (plus the window's
        ``S_w sum_c omega_c E_c R_{p,c}``); 0 where ``active`` is false."""
        n, kd, ks, r = bsdf.maps(si, active)
        self.frame = ViewFrame(n, si.wi)
        cos_v = self.frame.cos_v
        self.m, a_one, a_s = ltc_lookup(self.table, self.table_size, r, cos_v)
        ok = active & (cos_v > 0) & (si.wi.z > 0)  # the shading normal and the sample face the camera
        fits = ok & (cos_v >= self.min_cos_view)
        s_all = ks * (a_one - a_s) + a_s
        self.s_cells = dr.select(fits & (r >= self.min_roughness), s_all, 0.0)
        self.kd_cells = dr.select(ok, kd * (1.0 - ks), 0.0)
        k, side = self.grid, self.grid + 1
        V = side * side
        q_all, qd_all = [], []
        lcd_view = self._lcd_in_view(si)
        lanes = dr.width(self.b)  # one per texel: B H W
        width = dr.width(self.grid_rad) * self.hw // (lanes * V)
        along_q = along_qd = 0.0  # sum_v q_v T_{., v} and sum_v q^d_v T_{., v}: 3 P entries (+ padding)
        # Unrolled: as a symbolic loop over the vertices it traced faster but ran 2-3x as long (k = 4).
        for row in range(side):
            for col in range(side):
                q, qd = self._vertex_lobes(lcd_view, col / k, row / k)
                q_all.append(dr.select(active, q, 0.0))
                qd_all.append(dr.select(active, qd, 0.0))
                # packet loads: the vertex's 3 P values lie side by side (the gathers of 3 P
                # scalars were two thirds of this kernel's time, k = 4, P = 5, llvm)
                t = dr.gather(mi.ArrayXf, self.grid_rad, self.b * V + (row * side + col), shape=(width, lanes))
                along_q, along_qd = dr.fma(t, q, along_q), dr.fma(t, qd, along_qd)
        out = [self.s_cells * mi.Color3f(*along_q[3 * p:3 * p + 3]) +
               self.kd_cells * mi.Color3f(*along_qd[3 * p:3 * p + 3]) for p in range(self.count)]
        weights = [self.s_cells.x, self.s_cells.y, self.s_cells.z, self.kd_cells.x, self.kd_cells.y, self.kd_cells.z]
        if self.window:
            on = fits & (r >= self.window_min_roughness) & (r < self.min_roughness)
            weights += self._window_closed_form(si, lcd_view, on, dr.select(on, s_all, 0.0), out)
        return q_all + qd_all + weights, [dr.select(active, o, 0.0) for o in out]

    def _peak_uv(self, si):
        """Where the LTC lobe's peak direction M z meets the LCD's plane (its centre, (0.5, 0.5),
        where it points away), as :func:`mitsvbrdf.render.control_variate._peak_uv`; detached (the
        window's place is piecewise constant in the maps)."""
        a, b, _, d = (dr.detach(e) for e in self.m)
        # For M^-1 = [[a, 0, b], [0, c, 0], [d, 0, 1]], M z runs along (-b, 0, a) / (a - b d).
        sign = dr.select(a - b * d < 0.0, -1.0, 1.0)
        peak = si.to_world(dr.normalize(dr.detach(self.frame.x) * (-b * sign) + dr.detach(self.frame.n) * (a * sign)))
        origin = self._point(0.0, 0.0)
        edge_u, edge_v = self._point(1.0, 0.0) - origin, self._point(0.0, 1.0) - origin
        denom = dr.dot(peak, self.lcd_n)
        front = denom < -1e-6
        rel = si.p + dr.dot(origin - si.p, self.lcd_n) / dr.select(front, denom, -1.0) * peak - origin
        return (dr.select(front, dr.dot(rel, edge_u) / dr.squared_norm(edge_u), 0.5),
                dr.select(front, dr.dot(rel, edge_v) / dr.squared_norm(edge_v), 0.5))

    def _cell_omega(self, si, c0, cu, cv, row, col):
        """omega_c of the LCD cell (row, col) (Floats): the decay's cosine factor at its centre, 0
        unless its four corners lie above the warped horizon (z > 0; the warped LCD point (u, v)
        is c0 + u cu + v cv); also the corners, rows of two Vector3f."""
        h, wc = self.lcd.h, self.lcd.w
        corners = [[c0 + ((col + dj) / wc) * cu + ((row + di) / h) * cv for dj in (0, 1)] for di in (0, 1)]
        up = (corners[0][0].z > 0) & (corners[0][1].z > 0) & (corners[1][0].z > 0) & (corners[1][1].z > 0)
        omega = dr.select(up, 1.0, 0.0)
        if self.lcd.has_decay:  # the cosine factor at the cell's centre
            centre = self._point((col + 0.5) / wc, (row + 0.5) / h)
            omega = omega * self.lcd._factor(mi.Point2f(0.5, 0.5), dr.dot(dr.normalize(si.p - centre), self.lcd_n))
        return omega, corners

    def _window_closed_form(self, si, lcd_view, on, s_win, out) -> list:
        """The window term where ``on``: adds ``S_w sum_c omega_c E_c R_{p,c}`` to K_p (``out``)
        and returns its per-texel floats (:attr:`WINDOW_FIELDS`). E_c is the form factor of cell
        c warped by M^-1 into the LTC's frame, omega_c (:meth:`_cell_omega`) the decay's cosine
        factor at its centre, 0 unless all four corners lie above the warped horizon (module
        docstring of :mod:`mitsvbrdf.render.control_variate`)."""
        w, h, wc = self.window, self.lcd.h, self.lcd.w
        u, v = self._peak_uv(si)
        # Centred on the peak, inside the LCD; texels without a window get one off it.
        off = -float(max(h, wc))
        row0 = dr.select(on, dr.clip(dr.round(v * h - w / 2), 0, h - w), off)
        col0 = dr.select(on, dr.clip(dr.round(u * wc - w / 2), 0, wc - w), off)
        c0, cu, cv = (warp(self.m, e) for e in lcd_view[:3])  # the warped LCD: affine in (u, v)
        first = self.b * self.count

        def cell_term(i, known):
            row, col = row0 + mi.Float(i // w), col0 + mi.Float(i % w)
            omega, corners = self._cell_omega(si, c0, cu, cv, row, col)
            weight = s_win * (omega * grid_cell_form_factors(corners)[0][0])
            cell = first * (h * wc) + mi.UInt32(row * wc + col)
            return i + 1, [k + weight * dr.gather(mi.Color3f, self.cell_rad, cell + p * (h * wc))
                           for p, k in enumerate(known)]

        # A symbolic loop over the w^2 cells: traced once (unrolled, w = 8 traced 10^4 operations
        # per render, whether any texel had a window or not), and only texels with a window run it.
        _, known = dr.while_loop((mi.UInt32(0), [mi.Color3f(0.0) for _ in range(self.count)]),
                                 lambda i, known: on & (i < w * w), cell_term, max_iterations=w * w,
                                 label="ltc-grid window")
        for p in range(self.count):
            out[p] += known[p]
        fields = [dr.select(on, e, 0.0) for vec in (self.frame.x, self.frame.n) for e in (vec.x, vec.y, vec.z)]
        fields += [dr.select(on, e, 0.0) for e in self.m]
        fields += [dr.select(on, e, 0.0) for vec in (c0, cu, cv) for e in (vec.x, vec.y, vec.z)]
        return [s_win.x, s_win.y, s_win.z, row0, col0, *fields]

    def use(self, per_texel):
        """(Sample lanes.) Take the lobe values and weights from ``per_texel``, the concatenation
        of :meth:`closed_form`'s first result (layout (fields, B H W))."""
        V = (self.grid + 1) ** 2
        fields = 2 * V + 6 + (self.WINDOW_FIELDS if self.window else 0)
        step = dr.width(per_texel) // fields
        self.lobe_grid, self.lobe_step = per_texel, step
        self.lobe_base = self.texel_lane

        def field(j):
            return dr.gather(mi.Float, per_texel, self.texel_lane + (2 * V + j) * step)

        self.s_cells = mi.Color3f(*(field(j) for j in range(3)))
        self.kd_cells = mi.Color3f(*(field(j) for j in range(3, 6)))
        if self.window:  # its first row and column here; the rest only for directions inside it
            self.win_row, self.win_col = mi.Int32(field(9)), mi.Int32(field(10))
            self.window_base = self.texel_lane + (2 * V + 6) * step
        return self

    def _window_lobe(self, si, wo, cell, hit):
        """S_w omega_c D_ltc(wo) (Color3f) for a direction that meets the LCD in ``cell`` (:meth:`_cell`)
        inside the texel's window, else 0 (never for texels without one: their window lies off the
        LCD); the window's fields gathered for those directions alone (most directions of most
        texels miss it)."""
        w = self.window
        row, col = cell
        i, j = mi.Int32(row) - self.win_row, mi.Int32(col) - self.win_col
        inside = hit & (i >= 0) & (i < w) & (j >= 0) & (j < w)

        def lobe(wo, row, col):
            f = [dr.gather(mi.Float, self.lobe_grid, self.window_base + j * self.lobe_step)
                 for j in (0, 1, 2, *range(5, self.WINDOW_FIELDS))]
            frame = ViewFrame.of_axes(mi.Vector3f(*f[3:6]), mi.Vector3f(*f[6:9]))
            c0, cu, cv = (mi.Vector3f(*f[13 + 3 * a:16 + 3 * a]) for a in range(3))
            omega, _ = self._cell_omega(si, c0, cu, cv, row, col)
            return mi.Color3f(*f[0:3]) * (omega * ltc_density(tuple(f[9:13]), frame.to_view(wo)))

        # A symbolic branch: packets of directions that all miss the window skip it.
        return dr.if_stmt((wo, row, col), inside, lobe, lambda wo, row, col: mi.Color3f(0.0), label="window lobe")

    def pointwise(self, si, wo, uv, hit) -> list:
        """Per pattern, g_p(wo) (Color3f): the per-cell terms, and inside the window its term."""
        cell = self._cell(uv)
        window_lobe = self._window_lobe(si, wo, cell, hit) if self.window else None
        return [dr.select(hit, c, 0.0) for c in self._cells(si, uv, cell, hit, window_lobe)]


class _PatternLight:
    """LCD sampling by the patterns' brightness: cell c of material b is chosen with probability
    ``w_bc = a / C + (1 - a) / P sum_p Y_bpc / sum_c' Y_bpc'`` (Y the cell's emitted radiance
    summed over RGB, before decay; a pattern that is black everywhere counts as uniform), then a
    uniform point inside the cell. One distribution for all P patterns of a material, since they
    share the samples; the uniform share ``a`` keeps every cell reachable, so the estimate stays
    unbiased for any pattern. The probabilities are detached: patterns still get their gradients
    through the emitted radiance. Serves ``direct`` in place of the emitter's uniform sampling."""

    def __init__(self, lcd, batch: int, count: int, uniform_share: float, b):
        self.lcd, self.b = lcd, b
        C = self.C = lcd.h * lcd.w
        idx = dr.arange(mi.UInt32, batch * C)
        mb = idx // C
        cell = idx - mb * C
        data = dr.detach(lcd.data.array)
        acc = mi.Float(0.0)
        for p in range(count):
            base = (mb * count + p) * (3 * C) + cell
            rad = lcd._drive_to_radiance([dr.gather(mi.Float, data, base + k * C) for k in range(3)])
            y = dr.maximum(rad.x + rad.y + rad.z, 0.0)
            total = dr.gather(mi.Float, dr.block_sum(y, C), mb)
            acc += dr.select(total > 0, y / dr.maximum(total, 1e-30), 1.0 / C)
        self.w = uniform_share / C + (1.0 - uniform_share) / count * acc
        # One prefix sum over all materials, in double so that a material's cdf does not depend on
        # the materials before it in the batch (its image must not depend on the batch).
        w64 = mi.Float64(self.w)
        cdf = dr.cumsum(w64)
        start = dr.gather(mi.Float64, cdf, mb * C) - dr.gather(mi.Float64, w64, mb * C)
        self.cdf = mi.Float(cdf - start)
        self.total = dr.gather(mi.Float, self.cdf, mb * C + (C - 1))
        dr.eval(self.w, self.cdf, self.total)
        T = lcd.to_world()
        self.to_world = mi.Transform4f(T)
        eu, ev = T @ mi.ScalarVector3f(2.0, 0.0, 0.0), T @ mi.ScalarVector3f(0.0, 2.0, 0.0)
        self.area = dr.norm(dr.cross(eu, ev))
        self.normal = lcd.normal()

    def _pdf_area(self, cell, active):
        w = dr.gather(mi.Float, self.w, self.b * self.C + cell, active)
        t = dr.gather(mi.Float, self.total, self.b, active)
        return w / dr.maximum(t, 1e-30) * (self.C / self.area)

    def sample_direction(self, it, sample, active=True):
        C, base = self.C, self.b * self.C
        target = sample.x * dr.gather(mi.Float, self.total, self.b, active)
        pos, step = mi.UInt32(0), 1 << (C - 1).bit_length()
        while step:  # branchless binary search: the number of cells whose inclusive cdf <= target
            cand = pos + step
            ok = (cand <= C) & (dr.gather(mi.Float, self.cdf, base + dr.minimum(cand, C) - 1, active) <= target)
            pos = dr.select(ok, cand, pos)
            step >>= 1
        cell = dr.minimum(pos, C - 1)
        w = dr.gather(mi.Float, self.w, base + cell, active)
        lo = dr.gather(mi.Float, self.cdf, base + cell, active) - w
        fu = dr.clip((target - lo) / dr.maximum(w, 1e-30), 0.0, 0.99999994)
        row, col = cell // self.lcd.w, cell % self.lcd.w
        uv = mi.Point2f((mi.Float(col) + fu) / self.lcd.w, (mi.Float(row) + sample.y) / self.lcd.h)
        ds = dr.zeros(mi.DirectionSample3f)
        ds.p = self.to_world @ mi.Point3f(2.0 * uv.x - 1.0, 2.0 * uv.y - 1.0, 0.0)
        ds.n = self.normal
        ds.uv = uv
        d = ds.p - it.p
        dist2 = dr.squared_norm(d)
        ds.dist = dr.sqrt(dist2)
        ds.d = d / ds.dist
        cos_emit = -dr.dot(ds.d, ds.n)
        ok = active & (cos_emit > 0)
        ds.pdf = dr.select(ok, self._pdf_area(cell, ok) * dist2 / dr.maximum(cos_emit, 1e-12), 0.0)
        ds.emitter = mi.EmitterPtr(self.lcd)
        return ds, mi.Color3f(0.0)

    def pdf_direction(self, it, ds, active=True):
        cos_emit = -dr.dot(ds.d, ds.n)
        col = dr.clip(mi.Int32(dr.floor(ds.uv.x * self.lcd.w)), 0, self.lcd.w - 1)
        row = dr.clip(mi.Int32(dr.floor(ds.uv.y * self.lcd.h)), 0, self.lcd.h - 1)
        cell = mi.UInt32(row * self.lcd.w + col)
        pdf = self._pdf_area(cell, active) * ds.dist * ds.dist / dr.maximum(cos_emit, 1e-12)
        return dr.select(active & (cos_emit > 0), pdf, 0.0)


class ImportanceIntegrator(mi.SamplingIntegrator):
    """Direct illumination from the ``lcd`` emitter for all its patterns at once (see the module
    docstring for the parameters)."""

    def __init__(self, props: mi.Properties):
        mi.SamplingIntegrator.__init__(self, props)
        self.hide_emitters = bool(props.get("hide_emitters", True))
        self.sampler = str(props.get("sampler", "stratified"))
        self.control_variate = str(props.get("control_variate", "ltc-grid"))
        self.cv_blocks = int(props.get("cv_blocks", 8))
        self.ltc_min_roughness = float(props.get("ltc_min_roughness", 0.1))
        self.ltc_min_cos_view = float(props.get("ltc_min_cos_view", 0.1))
        # each mode's own default: "ltc-grid" unrolls the grid into its kernel, "ltc-cells" stores it
        self.ltc_grid = int(props.get("ltc_grid", 4 if self.control_variate == "ltc-grid" else 16))
        self.ltc_cells_min_roughness = float(props.get("ltc_cells_min_roughness", 0.2))
        self.ltc_window = int(props.get("ltc_window", 8))
        self.ltc_window_min_roughness = float(props.get("ltc_window_min_roughness", 0.02))
        self.light_sampling = str(props.get("light_sampling", "uniform"))
        self.uniform_share = float(props.get("uniform_share", 0.25))
        self.freeze = bool(props.get("freeze", True))
        # Per integrator: its recordings go with it. A new configuration records again by design
        # (the configuration is part of the key), so no warning about re-recording.
        self._replay = dr.freeze(_recorded_render, limit=FROZEN_RECORDINGS, warn_after=1 << 30)
        if self.light_sampling not in LIGHT_SAMPLINGS:
            raise ValueError(f"importance integrator: light_sampling must be one of {', '.join(LIGHT_SAMPLINGS)}, "
                             f"got {self.light_sampling!r}")
        if not 0.0 < self.uniform_share <= 1.0:
            raise ValueError(f"importance integrator: uniform_share must lie in (0, 1], got {self.uniform_share}")
        if self.sampler not in SAMPLERS:
            raise ValueError(f"importance integrator: sampler must be one of {', '.join(SAMPLERS)}, "
                             f"got {self.sampler!r}")
        if self.control_variate not in CONTROL_VARIATES:
            raise ValueError(f"importance integrator: control_variate must be one of "
                             f"{', '.join(CONTROL_VARIATES)}, got {self.control_variate!r}")
        if self.cv_blocks < 1:
            raise ValueError(f"importance integrator: cv_blocks must be >= 1, got {self.cv_blocks}")
        if not self.ltc_min_roughness >= 0.0:
            raise ValueError(f"importance integrator: ltc_min_roughness must be >= 0, got {self.ltc_min_roughness}")
        if self.ltc_grid < 1:
            raise ValueError(f"importance integrator: ltc_grid must be >= 1, got {self.ltc_grid}")
        if not self.ltc_cells_min_roughness >= 0.0:
            raise ValueError(f"importance integrator: ltc_cells_min_roughness must be >= 0, "
                             f"got {self.ltc_cells_min_roughness}")
        if self.ltc_window < 0:
            raise ValueError(f"importance integrator: ltc_window must be >= 0 (0: off), got {self.ltc_window}")
        if not self.ltc_window_min_roughness >= 0.0:
            raise ValueError(f"importance integrator: ltc_window_min_roughness must be >= 0, "
                             f"got {self.ltc_window_min_roughness}")
        if not 0.0 <= self.ltc_min_cos_view < 1.0:
            raise ValueError(f"importance integrator: ltc_min_cos_view must lie in [0, 1), got {self.ltc_min_cos_view}")

    @staticmethod
    def lcd(scene):
        """The scene's one ``lcd`` emitter (an instance of the registered LCDEmitter class).

        Raises:
            ValueError: the scene has no ``lcd`` emitter or more than one.
        """
        lcd_class = plugin_class("lcd")
        ems = [e for e in scene.emitters() if isinstance(e, lcd_class)]
        if len(ems) != 1:
            raise ValueError(f"importance integrator: the scene needs exactly one emitter of type 'lcd', "
                             f"found {len(ems)} among its emitters ({_kinds(scene.emitters())})")
        return ems[0]

    def direct(self, scene, sampler, si, active, first=0, count=None, cv=None, light=None, bsdf=None) -> list:
        """Outgoing radiance towards ``si.wi`` for patterns first .. first + count - 1 of the
        ``lcd`` emitter (default: all): a list of Color3f, all from the same light samples. With a
        control variate ``cv``, only the residual f L e - g (the caller adds g's integral).
        ``light`` samples the LCD (default: the emitter's uniform sampling). ``bsdf``: the BSDF
        every active lane's ``si`` lies on, when the caller knows it (default: ``si.bsdf()``, a
        virtual call that Dr.Jit traces once for every BSDF of every scene loaded in the process)."""
        lcd = self.lcd(scene)
        light = lcd if light is None else light
        bsdf = si.bsdf() if bsdf is None else bsdf
        ctx = mi.BSDFContext()
        P = lcd.pattern_count if count is None else count
        out = [mi.Color3f(0.0) for _ in range(P)]

        # Light sample (uniform on the LCD, the same for all patterns).
        ds, _ = light.sample_direction(si, sampler.next_2d(active), active)
        em_ok = active & (ds.pdf > 0)
        wo = si.to_local(ds.d)
        f, bsdf_pdf = bsdf.eval_pdf(ctx, si, wo, em_ok)
        w_em = mis_weight(ds.pdf, bsdf_pdf)
        cos_emit = -dr.dot(ds.d, ds.n)
        scale = w_em / dr.maximum(dr.detach(ds.pdf), 1e-30)
        g = cv.pointwise(si, wo, ds.uv, em_ok) if cv is not None else None
        for p, rad in enumerate(lcd.radiance_all(ds.uv, cos_emit, em_ok, first, P)):
            value = f * rad if g is None else f * rad - g[p]
            out[p] += dr.select(em_ok, scale * value, 0.0)

        # BSDF sample: direction detached, BSDF re-evaluated so gradients reach the maps.
        bs, _ = bsdf.sample(ctx, si, sampler.next_1d(active), sampler.next_2d(active), active)
        bs_ok = active & (bs.pdf > 0)
        d = dr.detach(si.to_world(bs.wo))
        si_l, hit = self._intersect(scene, lcd.get_shape(), si.spawn_ray(d), bs_ok)
        f_b = bsdf.eval(ctx, si, dr.detach(bs.wo), hit)
        ds_l = self._direction_sample(si_l, si, lcd)
        em_pdf = light.pdf_direction(si, ds_l, hit)
        w_bs = mis_weight(bs.pdf, em_pdf)
        scale_b = w_bs / dr.maximum(dr.detach(bs.pdf), 1e-30)
        cos_l = mi.Frame3f.cos_theta(si_l.wi)
        g = cv.pointwise(si, dr.detach(bs.wo), si_l.uv, hit) if cv is not None else None
        for p, rad in enumerate(lcd.radiance_all(si_l.uv, cos_l, hit, first, P)):
            value = f_b * rad if g is None else f_b * rad - g[p]
            out[p] += dr.select(hit, scale_b * value, 0.0)
        return out

    def sample(self, scene, sampler, ray, medium=None, active=True):
        si = scene.ray_intersect(ray, active)
        valid = active & si.is_valid()
        on_sample = valid & (si.emitter(scene) == None)  # noqa: E711 (Dr.Jit pointer comparison)
        # The control variate's coefficients are per texel: only render_texels has them.
        values = self.direct(scene, sampler, si, on_sample, count=1)
        return values[0], valid, []

    def aov_names(self):
        return []

    @staticmethod
    def _sample_shape(scene):
        """The scene's one shape whose BSDF is ``svbrdf_ggx`` (the material sample).

        Raises:
            ValueError: no such shape, or more than one.
        """
        bsdf_class = plugin_class("svbrdf_ggx")
        shapes = [s for s in scene.shapes() if isinstance(s.bsdf(), bsdf_class)]
        if len(shapes) != 1:
            bsdfs = [s.bsdf() for s in scene.shapes() if s.bsdf() is not None]
            raise ValueError(f"importance integrator: the scene needs exactly one shape with a BSDF of type "
                             f"'svbrdf_ggx', found {len(shapes)} among its shapes' BSDFs ({_kinds(bsdfs)})")
        return shapes[0]

    @staticmethod
    def _intersect(scene, shape, ray, active=True):
        """The surface interaction of ``ray`` with ``shape``, as ``scene.ray_intersect`` computes
        it, and where ``shape`` is the first surface the ray meets in ``scene`` (a mask).

        ``scene.ray_intersect`` completes a hit with a virtual call on the shape hit, which
        Dr.Jit traces once for every shape of every scene loaded in the process (with the 18
        scenes of the estimator benchmarks, most of a 64 px render's time). Here the scene only
        finds the first hit (``ray_intersect_preliminary``, no virtual call), ``shape`` computes
        the interaction in one direct call, and the rest is what Mitsuba adds after its virtual
        call (``SurfaceInteraction::finalize_surface_interaction``)."""
        pi = scene.ray_intersect_preliminary(ray, False, active)
        hit = active & pi.is_valid() & (pi.shape == mi.ShapePtr(shape))
        si = shape.compute_surface_interaction(ray, pi, mi.RayFlags.All, hit)
        si.time, si.wavelengths = ray.time, ray.wavelengths
        si.initialize_sh_frame()
        si.wi = dr.select(hit, si.to_local(-ray.d), -ray.d)
        return si, hit

    @staticmethod
    def _direction_sample(si_l, si, lcd) -> mi.DirectionSample3f:
        """``mi.DirectionSample3f(scene, si_l, si)`` for a hit ``si_l`` on the ``lcd``'s shape
        seen from ``si``, with the emitter known (the constructor finds it by a virtual call on
        the shape, traced like :meth:`_intersect`'s)."""
        rel = si_l.p - si.p
        dist = dr.norm(rel)
        return mi.DirectionSample3f(si_l.p, si_l.sh_frame.n, si_l.uv, si_l.time, mi.Float(0.0), mi.Bool(False),
                                    rel / dist, dist, mi.EmitterPtr(lcd))

    @staticmethod
    def _texel_interactions(scene, shape, texel, b, H: int, W: int, batch: int):
        """Surface interactions at the centres of texels ``texel`` of materials ``b``, seen from
        the camera's centre of projection, with uv addressing material b's rows of the stacked maps."""
        to_world = mi.traverse(shape)["to_world"]
        cam = scene.sensors()[0].world_transform() @ mi.ScalarPoint3f(0.0, 0.0, 0.0)
        row, col = texel // W, texel % W
        u = (mi.Float(col) + 0.5) / W
        v = 1.0 - (mi.Float(row) + 0.5) / H  # row 0 at the top (uv.y = 1)
        x = to_world @ mi.Point3f(2.0 * u - 1.0, 2.0 * v - 1.0, 0.0)
        ray = mi.Ray3f(mi.Point3f(cam), dr.normalize(x - mi.Point3f(cam)))
        si, ok = ImportanceIntegrator._intersect(scene, shape, ray)
        si.uv = mi.Point2f(si.uv.x, 1.0 - (mi.Float(b * H + row) + 0.5) / (batch * H))
        return si, ok

    def render_texels(self, scene, resolution: tuple[int, int], spp: int, seed, batch: int = 1,
                      control=None) -> mi.TensorXf:
        """(batch * P, 3, H, W) radiance on the sample's texel grid, ``spp`` samples per texel.

        A batch of materials renders in one pass: the BSDF's maps hold the ``batch`` materials
        stacked along rows (batch * H, W, C) and the emitter's ``data`` their patterns stacked
        along the first axis (batch * P, 3, h, w). Material b's random numbers are keyed by
        ``seed + b`` and the lane's (texel, sample) index, so its image does not depend on the
        rest of the batch. ``seed`` may be an opaque ``mi.UInt32`` (no recompilation).

        ``control``: None (plain Monte Carlo), or ``(block_radiance, coefficients, lobe_grid,
        grid_radiance, ltc_table, cell_radiance)``, the flat arrays of
        :class:`mitsvbrdf.render.control_variate.ControlVariate` (lobe_grid None unless
        "ltc-cells"; in "ltc-grid" only the last three are used, cell_radiance only with a
        window); then the result is
        only the residual's estimate, to which the caller adds the control variate's ``known``,
        except in "ltc-grid", where these kernels add K_p themselves (one lane per texel).

        With ``freeze`` (the default) and no gradients, the call replays the kernels recorded by the
        first call of the same configuration (module docstring).
        """
        H, W = resolution
        lcd = self.lcd(scene)
        if lcd.pattern_count % batch:
            raise ValueError(f"importance integrator: {lcd.pattern_count} patterns do not split into {batch} materials")
        shape = self._sample_shape(scene)
        if self.freeze and not self._carries_gradients(shape.bsdf(), lcd, control):
            try:
                # The sizes are part of the key: recorded kernels keep the sizes they were traced
                # with. A Python int seed would be too: a recording per seed.
                return self._replay(self, scene, (int(H), int(W)), int(spp), mi.UInt32(seed), int(batch),
                                    lcd.pattern_count, control)
            except RuntimeError as e:
                # A recording Dr.Jit cannot make or replay (e.g. on a backend the tests did not
                # run): trace from now on. An error of the render itself recurs below.
                warnings.warn(f"importance integrator: replaying recorded kernels failed ({e}); "
                              "tracing every render instead (freeze off)", RuntimeWarning, stacklevel=2)
                self.freeze = False
        return self._render_texels(scene, (H, W), spp, seed, batch, control)

    @staticmethod
    def _carries_gradients(bsdf, lcd, control) -> bool:
        """Whether the sample's maps, the patterns or the control variate's arrays have gradients
        enabled (a frozen function cannot propagate them)."""
        arrays = [getattr(bsdf, name) for name, _, _ in bsdf.MAPS] + [lcd.data]
        return dr.grad_enabled(arrays, [c for c in (control or ()) if c is not None])

    def _render_texels(self, scene, resolution: tuple[int, int], spp: int, seed, batch: int, control) -> mi.TensorXf:
        """:meth:`render_texels`, traced."""
        H, W = resolution
        lcd = self.lcd(scene)
        P = lcd.pattern_count // batch
        shape = self._sample_shape(scene)

        per_material = H * W * spp
        idx = dr.arange(mi.UInt32, batch * per_material)
        b = idx // per_material
        k = idx - b * per_material
        texel = k // spp
        si, ok = self._texel_interactions(scene, shape, texel, b, H, W, batch)
        if self.sampler == "stratified":
            sampler = _StratifiedSampler(mi.UInt32(seed) + b, texel, k - texel * spp)
        else:
            sampler = _LaneSampler(mi.UInt32(seed) + b, k)
        cv = known = None
        if control is not None and self.control_variate == "ltc-grid":
            cv, known = self._grid_closed_form(scene, shape, lcd, control, resolution, batch, P, b, texel)
        elif control is not None:
            n, _, _, _ = shape.bsdf().maps(si, ok)
            cv = _ControlVariate(lcd, control[0], control[1], self.cv_blocks, b, texel, H * W, P, n, si.wi,
                                 control[2], self.ltc_grid, self.ltc_window)
        light = _PatternLight(lcd, batch, P, self.uniform_share, b) if self.light_sampling == "patterns" else None
        values = self.direct(scene, sampler, si, ok, first=b * P, count=P, cv=cv, light=light, bsdf=shape.bsdf())
        # One kernel for all 3P channels; reduced one by one they would each re-trace the paths.
        dr.eval(values)
        chans = [dr.block_sum(c, spp) / spp for val in values for c in (val.x, val.y, val.z)]
        # chans[p * 3 + c] has batch * H * W entries ordered (b, row, col).
        if known is not None:
            chans = [c + k for c, k in zip(chans, known)]
        hw = H * W
        flat = dr.zeros(mi.Float, batch * P * 3 * hw)
        t = dr.arange(mi.UInt32, batch * hw)
        tb = t // hw
        for pc, c in enumerate(chans):
            dr.scatter(flat, c, (tb * (P * 3) + pc) * hw + (t - tb * hw))
        return mi.TensorXf(flat, shape=(batch * P, 3, H, W))

    def _grid_closed_form(self, scene, shape, lcd, control, resolution, batch: int, P: int, b, texel):
        """"ltc-grid": the control variate of the sample lanes (material ``b``, ``texel``) and K_p,
        3 P Floats of batch H W entries ordered (b, row, col), from one kernel over the texels."""
        H, W = resolution
        hw = H * W
        t = dr.arange(mi.UInt32, batch * hw)
        tb = t // hw
        grid_rad, table, cell_rad = control[3], control[4], control[5]
        size = int(round((dr.width(table) // 6) ** 0.5))

        def variate(lane_b, lane_texel):
            return _GridControlVariate(lcd, grid_rad, cell_rad, table, size, self.ltc_grid, self.ltc_window, lane_b,
                                       lane_texel, hw, P, self.ltc_min_cos_view, self.ltc_cells_min_roughness,
                                       self.ltc_window_min_roughness)

        si_t, ok_t = self._texel_interactions(scene, shape, t - tb * hw, tb, H, W, batch)
        per_texel, known = variate(tb, t - tb * hw).closed_form(si_t, ok_t, shape.bsdf())
        known = [c for val in known for c in (val.x, val.y, val.z)]
        # One kernel that also concatenates its results: concatenated after evaluation, the copy
        # was a second kernel (a quarter of this one's time); scattered into one array, each
        # scatter became a kernel of its own.
        per_texel = dr.concat(per_texel)
        dr.eval(per_texel, known)
        return variate(b, texel).use(per_texel), known

    def to_string(self):
        return (f"ImportanceIntegrator[sampler={self.sampler}, control_variate={self.control_variate}, "
                f"cv_blocks={self.cv_blocks}, ltc_grid={self.ltc_grid}, ltc_window={self.ltc_window}, "
                f"light_sampling={self.light_sampling}, freeze={self.freeze}]")


def _recorded_render(integrator, scene, resolution, spp, seed, batch, count, control):
    """What :meth:`ImportanceIntegrator.render_texels` freezes; ``count`` (the LCD's pattern count)
    only keys the recording, like the other Python ints."""
    return integrator._render_texels(scene, resolution, spp, seed, batch, control)
